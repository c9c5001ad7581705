"""Uniform random search: the floor every planner must beat."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.base import (
    Planner,
    PlannerConfig,
    TracedEvaluator,
    at_least,
    random_layouts,
    require_budget,
    split_budget,
)
from fixbench.solvers.registry import register


@dataclass(frozen=True)
class RandomConfig(PlannerConfig):
    batch: int = 1024
    """Layouts evaluated per oracle call (larger is faster; results do not depend on it)."""

    samples_per_task: int = 200
    """Samples per task when the budget is unlimited."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "batch", "samples_per_task")


@register
class RandomSearch(Planner):
    name = "random"
    description = "uniform random layouts; the floor every method must beat"
    Config = RandomConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        if mode == "shared":
            n = cfg.samples_per_task if ev.budget is None else int(ev.remaining // problem.n_tasks)
            require_budget(self.name, ev.remaining, problem.n_tasks, "one shared layout on every task")
            for start in range(0, n, cfg.batch):
                ev.evaluate_shared(random_layouts(problem, rng, min(cfg.batch, n - start)))
            return np.tile(ev.shared_layout, (problem.n_tasks, 1)), {}
        require_budget(self.name, ev.remaining, len(ev.tasks), "one layout per task")
        for task, n in zip(ev.tasks, split_budget(ev.budget, len(ev.tasks), cfg.samples_per_task)):
            layouts = random_layouts(problem, rng, n)  # drawn at once: independent of batch size
            for start in range(0, n, cfg.batch):
                ev.evaluate(task, layouts[start:start + cfg.batch])
        return ev.best_layout.copy(), {}
