"""Transfer between tasks: what a planner solved on some tasks, reused on the next.

The learners carry what they learned from one drilling position to the next; these helpers give
every other planner the same chance, and nothing more: only layouts the planner itself found
(``TracedEvaluator.best_layout``) are passed on, and nothing is read about a task that has not been
evaluated.

Tasks are near when their *features* are near (``Problem.features``: for a drilling job, the
drilling position). Each feature column is divided by its spread over the case's tasks, so that
columns in different units weigh alike; a column that never changes is ignored
(:func:`fixbench.solvers.encoding.task_features`, ``scale="spread"``).

- :func:`nearest_tasks`: the solved tasks nearest to a task, nearest first;
- :func:`warm_layouts`: the best layouts of those tasks (what a warm-started search starts from);
- :func:`fill_held_out`: a layout for every unsolved task, the best layout of its nearest solved
  task (zero samples; what a classical planner does on held-out tasks).
"""

from __future__ import annotations

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.encoding import task_features


def nearest_tasks(problem: Problem, solved, task: int, k: int, features: np.ndarray | None = None) -> np.ndarray:
    """Up to ``k`` of the ``solved`` task indices nearest to ``task`` by features (nearest first;
    ties by index, so the order is deterministic). ``features``: the problem's
    ``task_features(problem, "spread")``, when a caller asks for many tasks (computed here otherwise)."""
    solved = np.asarray(solved, dtype=np.int64)
    if k <= 0 or len(solved) == 0:
        return np.empty(0, dtype=np.int64)
    f = task_features(problem, "spread") if features is None else features
    d = np.linalg.norm(f[solved] - f[task], axis=1)
    order = np.lexsort((solved, d))
    return solved[order[:k]]


def warm_layouts(problem: Problem, best: np.ndarray, best_layout: np.ndarray, task: int, k: int) -> np.ndarray:
    """Distinct best layouts of up to ``k`` solved tasks nearest to ``task`` ((m, n_agents), m <= k).

    ``best``/``best_layout`` are a traced evaluator's per-task bests; a task is solved once it has a
    finite best. ``task`` itself is never a source.
    """
    solved = np.flatnonzero(np.isfinite(best))
    solved = solved[solved != task]
    src = nearest_tasks(problem, solved, task, k)
    if len(src) == 0:
        return np.empty((0, problem.n_agents), dtype=np.int64)
    layouts = best_layout[src]
    _, first = np.unique(layouts, axis=0, return_index=True)
    return layouts[np.sort(first)]


def fill_held_out(problem: Problem, layouts: np.ndarray, solved) -> tuple[np.ndarray, dict]:
    """``layouts`` with every row outside ``solved`` that holds a -1 replaced by the layout of its
    nearest solved task; returns (layouts, {task: source task}) for the rows filled."""
    out = np.array(layouts, dtype=np.int64, copy=True)
    solved = np.asarray(solved, dtype=np.int64)
    filled, f = {}, task_features(problem, "spread")
    for t in np.setdiff1d(np.arange(problem.n_tasks), solved):
        if (out[t] < 0).any():
            src = int(nearest_tasks(problem, solved, int(t), 1, f)[0])
            out[t] = out[src]
            filled[int(t)] = src
    return out, filled
