"""Person-by-person optima of the max-deformation objective (team decision theory), by enumeration.

With one shared objective the fixture game is a team game: a layout from which no single agent can
lower the max deformation by moving its own pad alone is a *person-by-person* (PBP) optimum
(docs/equilibria.md). Every planner that moves one robot at a time (``greedy``, the best-response
step of ``nashq``) stops at one. This module measures, on problems small enough to enumerate, how
many PBP optima there are, how far each lies from the global optimum (regret) and how often a
best-response descent from a uniform random layout ends in each (its basin).

This is analysis, not a planner: the joint table of every layout is computed on the oracle
directly (batched, uncounted); no planner's budget is charged and nothing here is a benchmark
result. Tables are indexed by each agent's position in its own candidate set (agent 0 first), in
the mixed-radix order of :func:`fixbench.cases.problem.decode_layouts`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.descent import descend, table_scores

#: layouts per oracle call while enumerating (memory against call overhead; same result)
CHUNK = 2**18


def enumeration_chunks(problem: Problem, tasks, chunk: int = CHUNK):
    """Every layout of ``problem`` in chunks: yields (first flat index, {task: max |u| in metres})."""
    from fixbench.cases.problem import decode_layouts as decode

    n = problem.joint_size
    for start in range(0, n, chunk):
        layouts = decode(problem.action_sets, start, min(n, start + chunk))
        yield start, {t: problem.deformation(problem.measure(t, layouts)).max_u for t in tasks}


def joint_table(problem: Problem, task: int) -> np.ndarray:
    """Max deformation (m) of every layout of ``task``: an array with one axis per agent, of its set's size."""
    task = problem.check_task(task)
    table = np.empty(problem.joint_size)
    for start, values in enumeration_chunks(problem, [task]):
        table[start:start + len(values[task])] = values[task]
    return table.reshape([len(a) for a in problem.action_sets])


def pbp_mask(table: np.ndarray) -> np.ndarray:
    """True where a layout is a PBP optimum: no single agent's move gives a strictly lower value
    (equal values do not count as a move that lowers it)."""
    mask = np.ones(table.shape, dtype=bool)
    for axis in range(table.ndim):
        mask &= table <= table.min(axis=axis, keepdims=True)
    return mask


def best_response_descent(table: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy best response from each start (flat indices into ``table``), all starts at once.

    Agents take turns 0, 1, ..., n-1, 0, ...; at its turn an agent moves to its best response (the
    lowest value over its own candidates, the others fixed; the first of equal ones) if that is
    strictly lower than the current value. A descent stops once n turns in a row made no move: a PBP
    optimum. Every move lowers the value, so every descent stops. Returns the flat index where each
    descent stopped, the number of moves it made and the layouts a planner doing it on the oracle
    would evaluate (the start, then every other candidate of the agent at each turn). The descent is
    :func:`fixbench.solvers.descent.descend` (``ties="stay"``, ``stop="all"``).
    """
    shape, n = table.shape, table.ndim
    state = np.array(np.unravel_index(np.asarray(starts, dtype=np.int64), shape)).T.reshape(-1, n)
    samples = np.ones(len(state), dtype=np.int64)
    scores = table_scores(table)

    def score(i: int, rows: np.ndarray, cur: np.ndarray) -> np.ndarray:
        samples[rows] += shape[i] - 1
        return scores(i, rows, cur)

    out = descend(score, state, range(n), ties="stay", stop="all")
    return np.ravel_multi_index(out.layout.T, shape), out.moves, samples


@dataclass(frozen=True)
class Landscape:
    """The PBP optima of one task's joint table and their basins under best-response descent."""

    optima: np.ndarray  # flat indices of every PBP optimum, lowest value first
    values_m: np.ndarray  # their max deformation (m)
    regret: np.ndarray  # their relative regret against the global optimum (0 = a global optimum)
    basin: np.ndarray  # how many of the starts descended to each
    starts: int  # uniform random starts (with replacement from every layout)
    moves: np.ndarray  # moves each descent made
    samples: np.ndarray  # layouts each descent evaluates (see best_response_descent)
    end_regret: np.ndarray  # relative regret where each descent stopped

    @property
    def global_share(self) -> float:
        """Fraction of descents that end at a global optimum."""
        return float(self.basin[self.regret == 0].sum() / self.starts)

    def summary(self) -> dict:
        """The figures the landscape table shows (regrets and shares as fractions, not per cent)."""
        return {"pbp_optima": len(self.optima), "optimum_m": float(self.values_m[0]),
                "worst_pbp_m": float(self.values_m[-1]),
                "pbp_regret_median": float(np.median(self.regret)), "pbp_regret_max": float(self.regret.max()),
                "pbp_within_5pct": int((self.regret <= 0.05).sum()),
                "optima_reached": int((self.basin > 0).sum()), "starts": self.starts,
                "global_basin_share": self.global_share,
                "descents_within_5pct": float((self.end_regret <= 0.05).mean()),
                "descent_regret_mean": float(self.end_regret.mean()),
                "descent_regret_median": float(np.median(self.end_regret)),
                "moves_mean": float(self.moves.mean()), "samples_mean": float(self.samples.mean()),
                "samples_to_5pct": self.samples_to(0.05)}

    def samples_to(self, regret: float) -> float | None:
        """Expected layouts evaluated by restarted descents until one ends within ``regret``: the
        mean cost of a descent over the share of descents that end there (None if none did)."""
        share = float((self.end_regret <= regret).mean())
        return float(self.samples.mean() / share) if share > 0 else None


def landscape(table: np.ndarray, starts: int, seed: int) -> Landscape:
    """Every PBP optimum of ``table``, its regret, and its basin among ``starts`` best-response
    descents from uniform random layouts (``numpy.random.default_rng(seed)``)."""
    optima = np.flatnonzero(pbp_mask(table))
    flat = table.ravel()
    optima = optima[np.argsort(flat[optima], kind="stable")]
    best = flat[optima[0]]
    start = np.random.default_rng(seed).integers(0, flat.size, size=starts)
    end, moves, samples = best_response_descent(table, start)
    by_index = np.sort(optima)
    counts = np.bincount(np.searchsorted(by_index, end), minlength=len(optima))
    basin = counts[np.searchsorted(by_index, optima)]  # back to the optima's order (lowest value first)
    return Landscape(optima, flat[optima], flat[optima] / best - 1, basin, starts, moves, samples,
                     flat[end] / best - 1)


def task_record(problem: Problem, task: int, table: np.ndarray, land: Landscape) -> dict:
    """One task's landscape as a JSON-ready record: :meth:`Landscape.summary` and every PBP optimum
    (layout as global candidate indices, its max deformation, regret and basin share)."""
    layouts = np.array(np.unravel_index(land.optima, table.shape)).T
    optima = [{"layout": [int(problem.action_sets[a][i]) for a, i in enumerate(idx)],
               "max_deformation_m": float(v), "regret": float(r), "basin_share": float(b / land.starts)}
              for idx, v, r, b in zip(layouts, land.values_m, land.regret, land.basin)]
    return {"task": int(task), **land.summary(), "optima": optima}


def analyse(problem: Problem, tasks, starts: int, seed: int) -> tuple[dict, dict, dict]:
    """The landscape of each of ``tasks``: a JSON-ready record of them all, and the joint tables and
    :class:`Landscape` objects by task."""
    tables = {int(t): joint_table(problem, t) for t in tasks}
    lands = {t: landscape(table, starts, seed) for t, table in tables.items()}
    return {"analysis": "every layout evaluated on the oracle directly (uncounted): not a planner",
            "case": problem.name, "material": problem.spec.material.name, "agents": problem.n_agents,
            "joint_size": problem.joint_size, "starts": starts, "seed": seed,
            "descent": "greedy best response, agents 0..n-1 in turn, a move only if strictly lower",
            "tasks": [task_record(problem, t, tables[t], lands[t]) for t in tables]}, tables, lands
