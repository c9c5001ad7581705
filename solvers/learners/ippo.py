"""IPPO from TorchRL's components: MAPPO's PPO (:mod:`fixbench.solvers.learners.mappo`, which says what
both take from TorchRL and Yu et al.) with one critic a robot on its own observation, V_i(o_i), instead
of the team's centralised V(s)."""

from __future__ import annotations

from fixbench.solvers.learners.mappo import PPOPlanner


class IPPO(PPOPlanner):
    name = "ippo"
    description = "IPPO from TorchRL: PPO with one critic a robot on its own observation, one actor a robot"
    centralised = False
