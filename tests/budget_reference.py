"""A second, independent reading of the budget driver's contract (``Planner.drive``), for the tests.

The contract, as the planners' docstrings and ``docs/`` state it (and as random, greedy, local, ga/pso
and optuna each wrote it by hand before the driver existed):

- per-task mode: the tasks the evaluator allows, in order, one search each; the budget split into
  near-equal shares, the first ``budget mod n`` tasks one layout more (the planner's own ``unlimited``
  number each when the budget is unlimited); a budget that pays for less than one layout a task is
  refused. With ``transfer`` k > 0 a search starts from the distinct best layouts of the k solved
  tasks nearest it by task features (each feature column divided by its spread over the tasks, a
  constant column ignored; nearest first, ties by task index), read when its turn comes. The layouts
  returned are each task's best evaluated by the true max (the first of equals), -1 on a task never
  searched.
- shared mode: one search on the worst task of one layout, the budget divided by ``n_tasks`` (a
  layout costs ``n_tasks`` samples); a budget that pays for no shared layout is refused; no warm
  start; the layouts returned are the best shared layout (by its worst true max) on every task.
- the search minimises the max |u|, or the soft max with the driver's ``soft_power``.

Written from that text, not from the driver's code: it keeps its own record of each task's best
layout (from the values it hands back, not from the evaluator's ``best``), computes the shares with
a ceiling instead of ``split_budget``'s ``divmod``, and finds the nearest solved tasks and their
distinct layouts with a sort and a list rather than ``transfer.warm_layouts``. What it shares with
the driver is only the evaluator (the counted oracle) and the :class:`~fixbench.solvers.base.Share`
a search receives. :func:`watch` runs a real planner with this loop in place of its driver (so that
the planner's own search step runs under each) and records what each search is handed.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.base import Planner, PlannerError, Share, TracedEvaluator


def reference_drive(name: str, problem: Problem, ev: TracedEvaluator, mode: str, search, unlimited,
                    soft_power: float | None = None, transfer: int = 0) -> tuple[np.ndarray, list]:
    """What ``Planner.drive`` must do (module docstring): (layouts, what each search returned)."""
    if mode == "shared":
        return _shared(name, problem, ev, search, unlimited, soft_power)
    return _per_task(name, problem, ev, search, unlimited, soft_power, transfer)


def _per_task(name, problem, ev, search, unlimited, soft_power, transfer):
    tasks = [int(t) for t in ev.tasks]
    if ev.budget is not None and ev.budget < len(tasks):
        raise PlannerError(f"planner '{name}': budget too small for one layout per task")
    best: dict[int, tuple[float, np.ndarray]] = {}  # task -> (true max, layout) of its best so far

    def scorer(task: int):
        def score(layouts):
            d = ev.evaluate(task, layouts, soft_power)
            i = int(np.argmin(d.max_u))
            if task not in best or d.max_u[i] < best[task][0]:
                best[task] = (float(d.max_u[i]), np.array(layouts, dtype=np.int64).reshape(len(d.max_u), -1)[i])
            return d.soft_u if soft_power else d.max_u
        return score

    stats = []
    for i, task in enumerate(tasks):
        share = unlimited if ev.budget is None else -(-(ev.budget - i) // len(tasks))  # ceil((B - i) / n)
        warm = nearest_best(problem, best, task, transfer)
        stats.append(search(Share(task, scorer(task), share, warm)))
    layouts = np.full((problem.n_tasks, problem.n_agents), -1, dtype=np.int64)
    for task, (_, layout) in best.items():
        layouts[task] = layout
    return layouts, stats


def nearest_best(problem: Problem, best: dict, task: int, k: int) -> np.ndarray:
    """The distinct best layouts of the (up to) ``k`` solved tasks nearest ``task``, nearest first."""
    solved = [t for t in best if t != task]
    warm: list[np.ndarray] = []
    if k > 0 and solved:
        f = np.asarray(problem.features, dtype=float).reshape(problem.n_tasks, -1)
        spread = f.max(axis=0) - f.min(axis=0)
        f = f[:, spread > 0] / spread[spread > 0]
        distance = {t: float(np.sqrt(np.sum((f[t] - f[task]) ** 2))) for t in solved}
        for t in sorted(solved, key=lambda t: (distance[t], t))[:k]:
            if not any(np.array_equal(best[t][1], w) for w in warm):
                warm.append(best[t][1])
    return np.array(warm, dtype=np.int64).reshape(len(warm), problem.n_agents)


def _shared(name, problem, ev, search, unlimited, soft_power):
    n = problem.n_tasks
    if ev.budget is not None and ev.budget < n:
        raise PlannerError(f"planner '{name}': budget too small for one shared layout on every task")
    best: list = [math.inf, None]  # worst true max over the tasks, layout

    def score(layouts):
        worst, soft = ev.evaluate_shared_soft(layouts, soft_power)
        i = int(np.argmin(worst))
        if worst[i] < best[0]:
            best[:] = float(worst[i]), np.array(layouts, dtype=np.int64).reshape(len(worst), -1)[i]
        return soft if soft_power else worst

    allowance = unlimited if ev.budget is None else ev.budget // n
    stats = [search(Share(None, score, allowance, np.empty((0, problem.n_agents), dtype=np.int64)))]
    return np.tile(best[1], (n, 1)), stats


def watch(planner: Planner, reference: bool) -> list[tuple]:
    """Make ``planner`` run its searches under :func:`reference_drive` (``reference``) or its own
    ``Planner.drive``, and return the list that records what each search is handed, in order:
    (task, allowance, warm layouts as lists). Empty after a run: the planner never used the loop."""
    handed: list[tuple] = []
    drive = functools.partial(reference_drive, planner.name) if reference else planner.drive

    def watched(problem, ev, mode, search, *args, **kwargs):
        def recorded(share: Share):
            handed.append((share.task, share.allowance, share.warm.tolist()))
            return search(share)
        return drive(problem, ev, mode, recorded, *args, **kwargs)

    planner.drive = watched  # an instance attribute: the class and other instances keep the driver
    return handed
