"""Example plugin: each agent holds the part as close to the task's load as its own set allows."""

from dataclasses import dataclass

import numpy as np

from fixbench.solvers import Planner, PlannerConfig


@dataclass(frozen=True)
class NearLoadConfig(PlannerConfig):
    offset_mm: float = 0.0
    """Preferred distance from the load point (mm); 0 = as close as possible."""


class NearLoad(Planner):
    name = "near-load"
    description = "each agent takes its candidate nearest the load (zero samples)"
    Config = NearLoadConfig

    def plan(self, problem, ev, rng, mode):
        layouts = np.zeros((problem.n_tasks, problem.n_agents), dtype=int)
        for t, task in enumerate(problem.tasks):
            points = [ld.at for ld in task.loads if ld.at is not None]
            target = points[0] if points else problem.candidates.mean(axis=0)
            for a, cands in enumerate(problem.action_sets):
                dist = np.linalg.norm(problem.candidates[cands] - target, axis=1)
                layouts[t, a] = cands[np.argmin(abs(dist - self.config.offset_mm / 1e3))]
        if mode == "shared":
            layouts[:] = layouts[0]
        return layouts, {}
