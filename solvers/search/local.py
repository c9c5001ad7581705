"""Local search in the plane: each robot tries the pads nearest its own, the neighbourhood widening
when nothing nearby helps; a kick when even the widest does not.

The deformation field is smooth in where a pad stands, so a good move is usually a short one. From a
start layout, agents take turns (Gauss-Seidel, like ``greedy``): agent a evaluates its
``neighbours`` candidates nearest its current pad and ``explore`` random ones of its set (its own
set only, in one batched call) and moves to the best if it lowers the fitness. When a whole round of
agents brings no improvement, the neighbourhood doubles, up to the agent's whole set: at that width
a round without a move is a person-by-person optimum (no single agent can improve), and the search
*kicks*: ``kick_agents`` agents, drawn at random, jump to random candidates of their sets, and the
descent goes on from there (iterated local search; each kick starts from the best optimum found so
far). Layouts already evaluated on the task are never paid for twice. "Nearest" is distance between
actions in ``Problem.points``: for a robot that places m pads, its pads' coordinates together.

Fitness: the soft max of |u| (power mean over the measurement points, ``soft_power``; why: see
:mod:`fixbench.solvers.search.greedy`), the max itself with ``soft_power = 0``. The returned layout of a task is
the one with the lowest *true* max evaluated on it.

Start: with ``transfer`` k > 0 (per-task mode), tasks are solved in order and each starts from the
best of the best layouts of the k already-solved tasks nearest by task features
(:mod:`fixbench.solvers.transfer`): on a drilling job, the last drilling positions' layouts. Otherwise, or
for the first task, the best of ``max(starts, start_share x budget)`` random layouts (at most half the
task's budget).

Budget: per-task mode splits it equally over the tasks, shared mode judges every layout on every
task (``n_tasks`` samples a layout): the budget loop of :meth:`~fixbench.solvers.base.Planner.drive`.
When a batch no longer fits, the moves that fit are evaluated (in random order) and the task ends. At
least one layout per task must fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from fixbench.cases.problem import Problem
from fixbench.solvers.base import Planner, PlannerConfig, Share, TracedEvaluator, at_least, random_layouts, require


@dataclass(frozen=True)
class LocalConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "neighbours": ("int", 2, 16),
        "explore": ("int", 2, 16),
        "starts": ("int", 4, 32),
        "soft_power": ("float", 1.0, 8.0),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    neighbours: int = 8
    """First neighbourhood: each agent's candidates nearest its current pad; doubles when a round of
    all agents brings no improvement, up to the agent's whole set."""

    explore: int = 8
    """Random candidates of the agent's whole set tried beside its neighbours at every check: long
    moves, without which a robot never crosses the part (a drill moving into another robot's
    region needs that robot far from where it stood)."""

    kick_agents: int = 1
    """Agents moved to random candidates when the widest neighbourhood brings no improvement."""

    starts: int = 16
    """Random layouts a cold start is the best of, at least (fewer when the budget is smaller)."""

    start_share: float = 0.0
    """Share of a task's budget a cold start spends on random layouts when that is more than
    ``starts``. Measured (mean max |u|, 5 agents): wing_panel at 100 samples a task 24.6 um with
    ``starts`` only, 18.9 um with 0.5 (random search: 22.1 um); at 1,000 a task 4.05 vs 3.67 um
    (one seed); wing_spar at 100 a task 0.370 vs 0.318 um. But at one round of checks a task
    (n_agents x (neighbours + explore) samples, 4 seeds) 0.5 loses on fan_small (34.7 -> 45.7 um)
    and wins on wing_panel_small (35.4 -> 33.8 um): it pays
    where each agent's set is large (the full parts: ~670 candidates) and descent sees little of it.
    The default keeps the published runs' setting."""

    soft_power: float = 4.0
    """Exponent p of the power mean the moves minimise (a soft max, see greedy); 0: the max."""

    transfer: int = 0
    """Warm start: a task starts from the best layouts of this many solved tasks nearest by task
    features (0: cold starts)."""

    samples_per_task: int = 2000
    """Samples per task (per layout judged on all tasks in shared mode) when the budget is unlimited."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "neighbours", "kick_agents", "starts", "samples_per_task")
        at_least(self, 0, "explore", "soft_power", "transfer")
        require(self, "start_share", 0 <= self.start_share <= 1, "in [0, 1]")


class LocalSearch(Planner):
    name = "local"
    family = "local-search"
    description = "widening local search in the plane with kicks; warm-starts from solved tasks (transfer)"
    Config = LocalConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        trees = [cKDTree(problem.points[s]) for s in problem.action_sets]

        def search(share: Share) -> tuple[int, int]:
            warm = share.warm if len(share.warm) else None
            return local_search(problem, share.score, share.allowance, warm, rng, cfg, trees)

        layouts, stats = self.drive(problem, ev, mode, search, unlimited=cfg.samples_per_task,
                                    soft_power=cfg.soft_power or None, transfer=cfg.transfer)
        return layouts, _info(stats)


def local_search(problem: Problem, fitness, budget: int, starts: np.ndarray | None, rng: np.random.Generator,
                 cfg: LocalConfig, trees: list[cKDTree] | None = None) -> tuple[int, int]:
    """One search within ``budget`` layouts from the best of ``starts`` (else of ``cfg.starts`` random
    layouts): (moves, kicks). ``fitness`` maps (L, n_agents) layouts to values (and is where a
    traced evaluator keeps the best); ``trees``: a KD-tree per agent over its candidates."""
    sets, n = problem.action_sets, problem.n_agents
    if trees is None:
        trees = [cKDTree(problem.points[s]) for s in sets]
    seen: dict[tuple, float] = {}

    def evaluate(layouts: np.ndarray) -> np.ndarray:
        nonlocal budget
        fresh = [i for i, x in enumerate(map(tuple, layouts.tolist())) if x not in seen]
        if len(fresh) > budget:
            fresh = sorted(rng.permutation(fresh)[:budget].tolist())
        if fresh:
            values = fitness(layouts[fresh])
            budget -= len(fresh)
            for i, v in zip(fresh, values):
                seen[tuple(layouts[i].tolist())] = float(v)
        return np.array([seen.get(tuple(x), math.inf) for x in layouts.tolist()])

    if starts is None:
        n_starts = max(cfg.starts, int(cfg.start_share * budget))
        starts = random_layouts(problem, rng, max(1, min(n_starts, budget // 2)))
    values = evaluate(starts[:max(1, budget)])
    i = int(np.argmin(values))
    layout, value = starts[i].copy(), float(values[i])
    best, best_value = layout, value  # kicks start from the best descent's end
    width = [min(cfg.neighbours, len(s) - 1) for s in sets]
    moves = kicks = 0
    since = 0  # agents checked since the last improvement
    a = int(rng.integers(n))  # the first agent to move: a small budget must not always favour agent 0
    stale, at_kick = 0, budget  # kicks that found nothing new to evaluate: a tiny space is used up
    while budget > 0 and stale < 100:
        if since >= n:  # a whole round without a move
            if all(w >= len(s) - 1 for w, s in zip(width, sets)):
                stale, at_kick = (stale + 1 if budget == at_kick else 0), budget
                if value < best_value:
                    best, best_value = layout, value
                layout = best.copy()  # person-by-person optimum: kick from the best one so far
                for b in rng.choice(n, size=min(cfg.kick_agents, n), replace=False):
                    layout[b] = rng.choice(sets[b])
                value = float(evaluate(layout[None])[0])
                width = [min(cfg.neighbours, len(s) - 1) for s in sets]
                kicks += 1
            else:
                width = [min(2 * w, len(s) - 1) for w, s in zip(width, sets)]
            since = 0
            continue
        k = width[a]
        if k > 0:
            _, idx = trees[a].query(problem.points[layout[a]], k=k + 1)
            alts = sets[a][np.atleast_1d(idx)]
            alts = alts[alts != layout[a]][:k]
            if cfg.explore:
                alts = np.unique(np.concatenate([alts, rng.choice(sets[a], size=cfg.explore)]))
                alts = alts[alts != layout[a]]
            trial = np.tile(layout, (len(alts), 1))
            trial[:, a] = alts
            values = evaluate(trial)
            j = int(np.argmin(values))
            if values[j] < value:
                layout, value, since = trial[j], float(values[j]), -1
                moves += 1
        since += 1
        a = (a + 1) % n
    return moves, kicks


def _info(stats: list[tuple[int, int]]) -> dict:
    """Per task (one entry in shared mode): moves taken and kicks."""
    return {"moves": [m for m, _ in stats], "kicks": [k for _, k in stats]}


def revise_budget(cap: int, share: float, unlimited: int) -> int:
    """Samples a planner's revising search may spend on one task (one shared search): ``cap``
    (-1: the task's whole fair ``share``; with an unlimited budget, ``unlimited``)."""
    if cap >= 0:
        return int(min(cap, share))
    return int(share) if math.isfinite(share) else unlimited


def revise(problem: Problem, ev, task: int | None, budget: int, starts, rng: np.random.Generator) -> None:
    """Revise a start: :func:`local_search` with the ``local`` planner's defaults (its soft max
    included) from the best of ``starts`` (as many as ``budget`` pays for), on ``task`` (None: the
    shared layout, judged on every task), within ``budget``. The traced evaluator ``ev`` keeps the
    best layout it evaluates."""
    if budget < 1:
        return
    soft = LocalConfig.soft_power or None
    if task is None:
        def fitness(layouts):
            return ev.shared_fitness(layouts, soft)
    else:
        def fitness(layouts):
            return ev.fitness(task, layouts, soft)
    local_search(problem, fitness, budget, np.asarray(starts)[:budget], rng, LocalConfig())
