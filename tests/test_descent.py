"""The reference per-agent best response (fixbench.solvers.descent) and nashq's compiled kernel against it."""

import itertools

import numpy as np
import pytest

from fixbench.solvers.descent import descend, table_scores
from fixbench.solvers.learners.marl_engine import _best_response, _q_row

STOPS = ("sweep", "others", "all")
RULES = [(ties, stop) for ties in ("first", "stay") for stop in STOPS]


def _pbp(table: np.ndarray) -> np.ndarray:
    """True where no single agent can lower the table's value by moving alone (by enumeration)."""
    mask = np.ones(table.shape, dtype=bool)
    for axis in range(table.ndim):
        mask &= table <= table.min(axis=axis, keepdims=True)
    return mask


def _every_layout(shape) -> np.ndarray:
    return np.array(list(itertools.product(*map(range, shape))))


@pytest.mark.parametrize("ties,stop", RULES)
def test_converges_to_a_person_by_person_optimum(ties, stop):
    """From every layout of a small enumerated table (with ties): each descent converges where no single
    agent can improve; "stay" never rises; the three stopping rules stop at the same layouts."""
    rng = np.random.default_rng(0)
    table = np.round(rng.random((5, 4, 3)), 1)  # few levels: many ties
    start = _every_layout(table.shape)
    out = descend(table, start, range(3), ties=ties, stop=stop)
    assert out.converged.all() and _pbp(table)[tuple(out.layout.T)].all()
    assert ((out.moves == 0) == (out.layout == start).all(1)).all()
    if ties == "stay":
        assert (table[tuple(out.layout.T)] <= table[tuple(start.T)]).all()
    for other in STOPS:
        assert np.array_equal(out.layout, descend(table_scores(table), start, range(3), ties=ties, stop=other).layout)


def test_ties_first_takes_the_first_lowest_and_stay_keeps_the_current():
    table = np.array([1.0, 1.0, 2.0])  # one agent, positions 0 and 1 tie
    first = descend(table, np.array([[1]]), [0], ties="first")
    stay = descend(table, np.array([[1]]), [0], ties="stay")
    assert first.layout.tolist() == [[0]] and first.moves.tolist() == [1]
    assert stay.layout.tolist() == [[1]] and stay.moves.tolist() == [0]


def _pennies(i, rows, cur):
    """Agent 0 wants to match agent 1, agent 1 to differ from agent 0: best response cycles (period 2)."""
    other = cur[:, 1 - i]
    scores = np.ones((len(rows), 2))
    scores[np.arange(len(rows)), other if i == 0 else 1 - other] = 0.0
    return scores


@pytest.mark.parametrize("max_sweeps", [4, 5, 10, 11])
def test_a_cycle_built_by_hand_is_detected_and_read_off(max_sweeps):
    start = _every_layout((2, 2))
    kw = dict(max_sweeps=max_sweeps, ties="first", stop="others")
    cut = descend(_pennies, start, [0, 1], cycles=True, **kw)
    plain = descend(_pennies, start, [0, 1], **kw)
    assert np.array_equal(cut.layout, plain.layout)  # what max_sweeps sweeps reach, read off the cycle
    assert not cut.converged.any() and not plain.converged.any()
    assert (plain.sweeps == max_sweeps).all() and (cut.sweeps <= 3).all()
    after_one = descend(_pennies, np.array([[0, 0]]), [0, 1], max_sweeps=1, ties="first", stop="others")
    assert after_one.layout.tolist() == [[0, 1]]  # agent 0 matches (stays), agent 1 moves away


@pytest.mark.parametrize("ties,stop", RULES)
def test_the_sweep_limit_is_honoured(ties, stop):
    rng = np.random.default_rng(1)
    table = rng.random((6, 6, 6, 6))
    start = rng.integers(0, 6, (200, 4))
    free = descend(table, start, range(4), ties=ties, stop=stop)
    assert free.sweeps.max() > 2  # the limits below bind
    for limit in (1, 2):
        out = descend(table, start, range(4), max_sweeps=limit, ties=ties, stop=stop)
        assert out.sweeps.max() == limit
        assert np.array_equal(out.converged, free.sweeps <= limit)
        assert np.array_equal(out.layout[out.converged], free.layout[out.converged])


def test_a_score_may_stop_the_descent():
    """A score that returns None (a budget spent) stops every query still going, unconverged."""
    table = np.random.default_rng(0).random((5, 5, 5))
    turns = []

    def score(i, rows, cur, limit):
        if len(turns) == limit:
            return None
        turns.append(i)
        return table_scores(table)(i, rows, cur)

    start = np.array([[2, 3, 0]])  # three sweeps from here
    full = descend(lambda *a: score(*a, None), start, [2, 0, 1], ties="stay", stop="others")
    assert full.converged[0] and len(turns) > 4  # the limit below binds
    turns.clear()
    out = descend(lambda *a: score(*a, 4), start, [2, 0, 1], ties="stay", stop="others")
    assert turns == [2, 0, 1, 2] and out.sweeps.tolist() == [2] and not out.converged[0]


def _marl_inputs(rng, n, sizes, m, batch, hidden=8, n_feats=3):
    """Random Q-network weights and inputs of the compiled kernel: (kernel args before max_sweeps)."""
    width, d = max(sizes), 2 * m
    n_in = n_feats + d * (n - 1)
    dims = [n_in, hidden, hidden, hidden, m * width]
    ws = [rng.normal(0, 1.5, (n, dims[k], dims[k + 1])).astype(np.float32) for k in range(4)]
    ws += [rng.normal(0, 0.5, (n, 1, dims[k + 1])).astype(np.float32) for k in range(4)]
    cols = np.zeros((n, width, m), dtype=np.int64)
    for i, size in enumerate(sizes):
        cols[i, :size] = rng.integers(0, width, (size, m)) + width * np.arange(m)
    pos = rng.random((n, width, d)).astype(np.float32)
    centre = rng.random((n, d)).astype(np.float32)
    others = np.array([[j for j in range(n) if j != i] for i in range(n)], dtype=np.int64)
    s = rng.random((batch, n_feats)).astype(np.float32)
    return tuple(ws), cols, np.array(sizes, dtype=np.int64), s, pos, centre, others


def _q_scores(args, i, rows, seen):
    """Minus agent i's Q of each of its actions (sum over its pads' columns, in float32 as the kernel adds
    them) for the batch ``rows``, the agents at positions ``seen`` (len(rows), N, D)."""
    ws, cols, n_opts, s, pos, centre, others = args
    out = []
    for r, row in enumerate(rows):
        q = _q_row(ws, i, np.concatenate([s[row], seen[r, others[i]].ravel()]).astype(np.float32))
        v = q[cols[i, :n_opts[i], 0]]
        for k in range(1, cols.shape[2]):
            v = v + q[cols[i, :n_opts[i], k]]
        out.append(-v)
    return np.array(out)


def _reference(args, fixed, fixed_actions, max_sweeps, cycles=True):
    """nashq's joint action by the reference: each free agent's argmax with the others at their centres
    (fixed ones where they are), then best response, the first of equal Q, until every agent but the last
    mover is checked."""
    _, _, n_opts, s, pos, centre, _ = args
    nb, n = fixed.shape
    agents = np.arange(n)
    seen = np.where(fixed[..., None], pos[agents, fixed_actions], centre[None])
    start = fixed_actions.copy()
    for i in range(n):
        free = np.flatnonzero(~fixed[:, i])
        if len(free):
            start[free, i] = _q_scores(args, i, free, seen[free]).argmin(1)
    return descend(lambda i, rows, cur: _q_scores(args, i, rows, pos[agents, cur]), start, range(n),
                   max_sweeps=max_sweeps, ties="first", stop="others", cycles=cycles, fixed=fixed)


@pytest.mark.parametrize("m", [1, 2])
def test_the_compiled_nashq_kernel_equals_the_reference(m):
    """On random Q weights: per state (with fixed agents), the kernel's actions, sweeps and convergence equal
    the reference's to the bit, cycles read off included; a batch of states gives the same actions."""
    rng = np.random.default_rng(3)
    n, sizes, nb = 4, [7, 5, 6, 7], 60
    args = _marl_inputs(rng, n, sizes, m, nb)
    fixed = rng.random((nb, n)) < 0.1
    fixed[fixed.all(1), 0] = False  # at least one free agent a state
    fixed_actions = np.where(fixed, rng.integers(0, 5, (nb, n)), 0).astype(np.int64)
    seen = {"converged": 0, "cycle": 0, "limit": 0}
    for max_sweeps in (3, 8):
        ref = _reference(args, fixed, fixed_actions, max_sweeps)
        plain = _reference(args, fixed, fixed_actions, max_sweeps, cycles=False)
        assert np.array_equal(ref.layout, plain.layout)
        for r in range(nb):
            a, sweeps, converged = _best_response(*args[:3], args[3][r:r + 1], *args[4:], fixed[r:r + 1],
                                                  fixed_actions[r:r + 1], max_sweeps, True)
            assert a[0].tolist() == ref.layout[r].tolist()
            assert (sweeps, converged) == (ref.sweeps[r], ref.converged[r])
            seen["converged" if converged else "cycle" if sweeps < max_sweeps else "limit"] += 1
        none = np.zeros((nb, n), dtype=bool)
        a, _, converged = _best_response(*args, none, np.zeros((nb, n), dtype=np.int64), max_sweeps, True)
        batch = _reference(args, none, np.zeros((nb, n), dtype=np.int64), max_sweeps)
        assert np.array_equal(a, batch.layout) and converged == batch.converged.all()
    assert min(seen.values()) > 0, seen  # converged, cycling and cut at the limit all happened
