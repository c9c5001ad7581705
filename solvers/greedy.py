"""Person-by-person best response with random restarts (team decision theory).

From a random layout, each agent in turn evaluates every other candidate of its own set with the
other agents fixed (one batched oracle call) and moves to the best one if it is strictly better.
A restart stops at a *person-by-person optimum*: once every agent has been checked since the last
move without improving (no single agent can improve alone). Restarts run one after another, each
with all the budget that is left, until ``restarts`` have run or the budget is spent: a small
budget goes to one descent that can converge rather than to several that cannot. The best layout
found is returned.

Per-task mode runs this on each task with an equal share of the budget (``split_budget``);
shared mode runs it once on the worst-over-tasks objective (``evaluate_shared``, n_tasks samples
per layout). Budget: at least one layout must fit (one sample per task, or n_tasks in shared mode),
else :class:`PlannerError`. Beyond that it is a documented best effort: when the budget ends in the
middle of an agent's check, the alternatives that still fit are evaluated (in random order), the
best move among them is taken, and the restart stops unconverged (``info["converged"]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cases.problem import Problem
from solvers.base import Planner, PlannerConfig, TracedEvaluator, random_layouts, require_budget, split_budget
from solvers.registry import register


@dataclass(frozen=True)
class GreedyConfig(PlannerConfig):
    restarts: int = 4
    """Most random starting layouts; the best person-by-person optimum over them is returned."""


@register
class Greedy(Planner):
    name = "greedy"
    description = "person-by-person best response from random starts (a team-theory local optimum)"
    Config = GreedyConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        T = problem.n_tasks
        if mode == "shared":
            require_budget(self.name, ev.remaining, T, "one shared layout on every task")
            layout, _, runs = self._restarts(problem, ev.evaluate_shared, T, ev.remaining, rng)
            return np.tile(layout, (T, 1)), _info([runs])
        require_budget(self.name, ev.remaining, T, "one layout per task")
        layouts = np.zeros((T, problem.n_agents), dtype=np.int64)
        all_runs = []
        for task, budget in enumerate(split_budget(ev.budget, T, math.inf)):
            def evaluate(L, task=task):
                return ev.evaluate(task, L).max_u
            layouts[task], _, runs = self._restarts(problem, evaluate, 1, budget, rng)
            all_runs.append(runs)
        return layouts, _info(all_runs)

    def _restarts(self, problem: Problem, evaluate, cost: int, budget: float, rng: np.random.Generator):
        """Best of the restarts: (layout, value, [(sweeps, converged) per restart run])."""
        best_layout, best, runs, spent = None, np.inf, [], 0
        for _ in range(self.config.restarts):
            if budget - spent < cost:
                break
            layout, value, sweeps, converged, used = _descend(problem, evaluate, cost, budget - spent, rng)
            spent += used
            runs.append((sweeps, converged))
            if value < best:
                best_layout, best = layout, value
        return best_layout, best, runs


def _descend(problem: Problem, evaluate, cost: int, budget: float, rng: np.random.Generator):
    """One restart: (layout, value, sweeps, converged, samples spent) within ``budget`` samples."""
    n = problem.n_agents
    layout = random_layouts(problem, rng, 1)[0]
    value = evaluate(layout[None])[0]
    spent, checks, since = cost, 0, 0  # since: agents checked since the last move
    a = 0
    while since < n:
        alts = problem.action_sets[a][problem.action_sets[a] != layout[a]]
        fit = len(alts) if math.isinf(budget) else int((budget - spent) // cost)
        partial = fit < len(alts)
        if partial:
            alts = rng.permutation(alts)[:fit]  # best effort: what the budget still allows
        if len(alts):
            trial = np.tile(layout, (len(alts), 1))
            trial[:, a] = alts
            values = evaluate(trial)
            spent += cost * len(alts)
            i = int(np.argmin(values))
            if values[i] < value:
                layout, value, since = trial[i], values[i], 0
        checks += 1
        if partial:
            break
        since += 1
        a = (a + 1) % n
    return layout, value, math.ceil(checks / n), since >= n, spent


def _info(runs: list[list[tuple[int, bool]]]) -> dict:
    """Per task (one entry in shared mode): restarts run, sweeps and convergence of each."""
    return {"restarts": [len(r) for r in runs], "sweeps": [[s for s, _ in r] for r in runs],
            "converged": [[c for _, c in r] for r in runs]}
