"""Uniform random search: the floor every planner must beat."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.base import Planner, PlannerConfig, Share, TracedEvaluator, at_least, random_layouts


@dataclass(frozen=True)
class RandomConfig(PlannerConfig):
    batch: int = 1024
    """Layouts evaluated per oracle call (larger is faster; results do not depend on it)."""

    samples_per_task: int = 200
    """Samples per task when the budget is unlimited."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "batch", "samples_per_task")


class RandomSearch(Planner):
    name = "random"
    family = "random"
    description = "uniform random layouts; the floor every method must beat"
    Config = RandomConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        batch = self.config.batch

        def search(share: Share) -> None:
            n = share.allowance
            if share.task is None:  # the shared layout: drawn a batch at a time
                for start in range(0, n, batch):
                    share.score(random_layouts(problem, rng, min(batch, n - start)))
                return
            layouts = random_layouts(problem, rng, n)  # drawn at once: independent of batch size
            for start in range(0, n, batch):
                share.score(layouts[start:start + batch])

        layouts, _ = self.drive(problem, ev, mode, search, unlimited=self.config.samples_per_task)
        return layouts, {}
