"""Example plugin: random layouts drawn from each agent's candidates nearest the task's load."""

from dataclasses import dataclass

import numpy as np

from fixbench.solvers import Planner, PlannerConfig


@dataclass(frozen=True)
class NearLoadConfig(PlannerConfig):
    nearest: int = 3
    """Each agent draws from this many of its candidates nearest the load."""

    samples_per_task: int = 20
    """Layouts a task (shared layouts in shared mode) when the budget is unlimited."""


class NearLoad(Planner):
    name = "near-load"
    description = "random layouts from each agent's candidates nearest the load"
    Config = NearLoadConfig

    def plan(self, problem, ev, rng, mode):
        def search(share):  # a task's share of the budget (share.task None: the shared layout)
            task = problem.tasks[share.task or 0]  # the shared layout: near the first task's load
            points = [ld.at for ld in task.loads if ld.at is not None]
            target = points[0] if points else problem.candidates.mean(axis=0)
            near = [c[np.argsort(np.linalg.norm(problem.candidates[c] - target, axis=1))[:self.config.nearest]]
                    for c in problem.action_sets]
            share.score(np.column_stack([rng.choice(n, size=share.allowance) for n in near]))

        layouts, _ = self.drive(problem, ev, mode, search, unlimited=self.config.samples_per_task)
        return layouts, {}
