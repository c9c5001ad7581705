"""Independent Q-learners (``iql``), the reference code's ablation of ``nashq``: the same networks over
the task features only (no other agent's position among the inputs), each agent acting on its own argmax.
Everything else (config, training loop, budget, greedy policy, regrets) is ``nashq``'s planner
(:mod:`fixbench.solvers.learners.nashq`) with ``joint = False``."""

from __future__ import annotations

from fixbench.solvers.learners.nashq import QPlanner


class IQL(QPlanner):
    name = "iql"
    description = "independent Q-learners of the reference code (ablation of nashq)"
    joint = False
