"""Per-agent best response (person-by-person coordinate descent, Gauss-Seidel): the one loop that every
planner moving one robot at a time runs (``greedy`` on the oracle, ``surrogate-ts`` on a network
ensemble, ``gp-ucb`` on a confidence bound, ``nashq`` on its Q-networks, the equilibria analysis on
an enumerated table).

A batch of queries (each a layout: every agent's position in its own action set) descends at once.
A *sweep* visits the agents in ``order``; at its turn an agent scores every position of its own set
with the others fixed and takes the lowest. What a planner may choose, each an argument:

- what scores a move: ``score(i, rows, cur)``, agent i's scores (len(rows), size of its set), lower
  better, for the queries ``rows`` whose layouts are ``cur``; or a joint table (:func:`table_scores`).
  It may return ``None``: no more turns (a budget is spent), every query still going stops unconverged.
  A score of ``inf`` is a position not worth taking (pruned, or not evaluated within a budget).
- ``ties``: ``"first"`` takes the first lowest score even where the current position ties it (an
  argmin: ``surrogate-ts``, ``gp-ucb``, ``nashq``); ``"stay"`` moves only to a strictly lower score
  (every move lowers the value, so a descent on one table ends: ``greedy``, the equilibria analysis).
- ``stop``: what is checked after the last move before a query stops. ``"sweep"``: a whole sweep in
  which no agent moved (``surrogate-ts``, ``gp-ucb``). ``"others"``: every agent but the last mover,
  once (it is at its best response already; ``greedy``, where a check costs samples, ``nashq``).
  ``"all"``: every agent, the mover too: n turns in a row without a move (the equilibria analysis,
  whose sample count follows it). Under the last two an agent takes a turn only if it has not been
  checked since the last move. With deterministic scores all three stop at the same layout; they
  differ in the turns taken (and so in a batched score's batches).
- ``max_sweeps`` (None: no limit) and ``fixed`` agents (per query) that never move.
- ``cycles``: scores that are not one shared table (one Q-network an agent) may make best response
  cycle. The state at the end of a sweep (layout, agents needing a turn) determines the rest, so
  when a query's state repeats an earlier one the descent is periodic, and its layout after
  ``max_sweeps`` sweeps is read off the cycle: the same layout, fewer sweeps computed.

Written by hand: coordinate descent over discrete action sets with these stopping rules is a dozen
lines in no maintained library (scipy and pymoo optimise continuous or whole-vector problems).
``nashq``'s compiled kernel (:func:`fixbench.solvers.learners.marl_engine._best_response`) runs this same
descent in numba; ``tests/test_descent.py`` checks it against :func:`descend` to the bit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

#: ``score(i, rows, cur)``: agent i's score of every position of its set for the queries ``rows``
#: (indices into the batch) whose layouts are ``cur`` (len(rows), n_agents); a numpy array or a torch
#: tensor (anything with ``argmin(1)``), or None to stop
Score = Callable[[int, np.ndarray, np.ndarray], object]


@dataclass
class Descent:
    """Where each query of a batch stopped and what it took."""

    layout: np.ndarray  # (Q, n_agents) positions in the agents' sets
    sweeps: np.ndarray  # (Q,) sweeps in which the query took a turn (read off a cycle: computed, fewer)
    converged: np.ndarray  # (Q,) stopped at a person-by-person optimum of the scores
    moves: np.ndarray  # (Q,) moves made (computed)


def table_scores(table: np.ndarray) -> Score:
    """The scores of a joint table (one axis per agent, of its set's size): agent i's row of every
    query, the others fixed at its positions."""

    def score(i: int, rows: np.ndarray, cur: np.ndarray) -> np.ndarray:
        row = np.moveaxis(table, i, -1)[tuple(cur[:, j] for j in range(cur.shape[1]) if j != i)]
        return np.broadcast_to(row, (len(cur), table.shape[i]))  # one agent: the same row for every query

    return score


def descend(score: Score | np.ndarray, start: np.ndarray, order: Sequence[int], *, max_sweeps: int | None = None,
            ties: str = "first", stop: str = "sweep", cycles: bool = False,
            fixed: np.ndarray | None = None) -> Descent:
    """Best response of every row of ``start`` (Q, n_agents) positions (module doc for the arguments)."""
    if ties not in ("first", "stay") or stop not in ("sweep", "others", "all"):
        raise ValueError(f"ties must be 'first' or 'stay' and stop 'sweep', 'others' or 'all', not {ties!r}, {stop!r}")
    if cycles and max_sweeps is None:
        raise ValueError("cycles are read off at max_sweeps: give one")
    if isinstance(score, np.ndarray):
        score = table_scores(score)
    layout = np.array(start, dtype=np.int64)
    q, n = layout.shape
    free = np.ones((q, n), dtype=bool) if fixed is None else ~np.asarray(fixed, dtype=bool)
    dirty = free.copy()  # agents that need a turn, per query
    live = np.ones(q, dtype=bool)
    sweeps, moves = np.zeros(q, dtype=np.int64), np.zeros(q, dtype=np.int64)
    converged = np.zeros(q, dtype=bool)
    history = [(layout.copy(), dirty.copy())]
    s = 0
    while live.any() and (max_sweeps is None or s < max_sweeps):
        s += 1
        if stop == "sweep":
            dirty[live] = free[live]
        moved = np.zeros(q, dtype=bool)
        for i in order:
            rows = np.flatnonzero(live & dirty[:, i])
            if not len(rows):
                continue
            scores = score(i, rows, layout[rows])
            if scores is None:  # no more turns: what is still going stops unconverged
                return Descent(layout, sweeps, converged, moves)
            go, best = _moves(scores, layout[rows, i], ties)
            sweeps[rows], dirty[rows, i] = s, False
            m = rows[go]
            layout[m, i] = best[go]
            moves[m] += 1
            moved[m] = True
            if stop != "sweep":  # every agent needs a turn again, the mover too under "all"
                dirty[m] = free[m]
                if stop == "others":
                    dirty[m, i] = False
        done = live & (~moved if stop == "sweep" else ~dirty.any(axis=1))
        converged |= done
        live &= ~done
        if cycles:
            _cut_cycles(history, layout, dirty, live, max_sweeps)
    return Descent(layout, sweeps, converged, moves)


def _moves(scores, cur: np.ndarray, ties: str) -> tuple[np.ndarray, np.ndarray]:
    """(which queries move, each one's best position): the first lowest score (``scores.argmin(1)``,
    the returned array's own argmin), taken if it is not the current position ("first") or is
    strictly lower than the current one's ("stay")."""
    best = np.asarray(scores.argmin(1))
    if ties == "first":
        return best != cur, best
    values, r = np.asarray(scores), np.arange(len(cur))
    return values[r, best] < values[r, cur], best


def _cut_cycles(history: list, layout: np.ndarray, dirty: np.ndarray, live: np.ndarray, max_sweeps: int) -> None:
    """Stop every live query whose end-of-sweep state (layout, agents needing a turn) repeats an earlier
    sweep's: its layout becomes the one the periodic rest reaches after ``max_sweeps`` sweeps."""
    s = len(history)  # the sweep just ended
    past_layout = np.stack([h[0] for h in history])  # (s, Q, n)
    past_dirty = np.stack([h[1] for h in history])
    for r in np.flatnonzero(live):
        same = np.flatnonzero((past_layout[:, r] == layout[r]).all(1) & (past_dirty[:, r] == dirty[r]).all(1))
        if len(same):
            k = int(same[0])  # a cycle of period s - k
            layout[r] = past_layout[k + (max_sweeps - k) % (s - k), r]
            live[r] = False
    history.append((layout.copy(), dirty.copy()))
