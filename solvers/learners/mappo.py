"""MAPPO from TorchRL's components, on the PettingZoo env, behind the Planner interface; the PPO that
``ippo`` (:mod:`fixbench.solvers.learners.ippo`) shares.

Reference: C. Yu, A. Velu, E. Vinitsky, J. Gao, Y. Wang, A. Bayen, Y. Wu, "The Surprising Effectiveness
of PPO in Cooperative Multi-Agent Games", NeurIPS 2022 Datasets and Benchmarks (arXiv:2103.01955):
MAPPO, PPO with a centralised critic V(s) and decentralised actors pi_i(a_i | o_i), and IPPO, the same
with a critic of each agent's own observation, V_i(o_i).

What TorchRL provides and what is fixbench's (the env, the budget as episodes, the reward, the seeding,
the result) is :mod:`fixbench.solvers.learners.torchrl_learner`'s, shared with ``qmix``. Here: the actors
and critics (``MultiAgentMLP``), the policy (a ``ProbabilisticActor`` over a ``MaskedCategorical``) and
the loss (``ClipPPOLoss``). Each step ends its own bandit round, so the value target is the reward itself
and the advantage is reward - V: GAE with any gamma and lambda gives the same on one-step episodes (no
bootstrap), so no value estimator is built.

Parameter sharing: every robot observes the same task features, so actors that share parameters without
an agent id give every robot the same distribution over the same indices (BenchMARL's default sharing
collapses this way, docs/planners.md). The actors therefore never share (``share_params=False``: one MLP
a robot, vectorised by ``MultiAgentMLP``). MAPPO's critic is centralised and shared (one V(s) for the
team, the reward being shared); IPPO's critic is one per robot on its own observation. On this env a
robot's observation is the state, so the two differ in the critic's form only, not in what it sees.

Budget: each rollout of ``batch_episodes`` episodes is followed by ``epochs`` passes of PPO over it in
``minibatches`` minibatches. The returned layouts are the policy's mode (each robot's most probable
action, no sample) on every task.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.problem import Problem
from fixbench.cases.rewards import LogScale
from fixbench.solvers.base import at_least, require
from fixbench.solvers.learners.common import LearnerConfig, StepRecord
from fixbench.solvers.learners.torchrl_learner import GROUP, MASK, OBS, TorchRLLearner, gradient_step


@dataclass(frozen=True)
class PPOConfig(LearnerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "lr": ("log", 3e-4, 3e-2),
        "entropy_coeff": ("log", 1e-4, 1e-1),
        "hidden": ("choice", [32, 64, 128]),
        "batch_episodes": ("choice", [1, 2, 4, 8]),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    batch_episodes: int = 2
    """Episodes a rollout collects before PPO updates on it (on-policy: the batch is then dropped)."""

    epochs: int = 8
    """PPO passes over each rollout."""

    minibatches: int = 1
    """Minibatches a pass splits the rollout into (at most one step each)."""

    clip_epsilon: float = 0.2
    """PPO's clip of the probability ratio (the paper: 0.2)."""

    entropy_coeff: float = 0.1
    """Weight of the policy's entropy bonus in the loss."""

    critic_coeff: float = 1.0
    """Weight of the critic's loss (smooth L1 on reward - V)."""

    lr: float = 5e-3
    """Adam learning rate of actors and critic together."""

    max_grad_norm: float = 1.0
    """Gradient norm clip per update."""

    hidden: int = 64
    """Width of each hidden layer (actors and critic)."""

    layers: int = 2
    """Hidden layers (Tanh, TorchRL's default) of actors and critic."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "batch_episodes", "epochs", "minibatches", "hidden", "layers")
        require(self, "clip_epsilon", 0 < self.clip_epsilon < 1, "in (0, 1)")
        require(self, "entropy_coeff", self.entropy_coeff >= 0, "0 or more")
        require(self, "critic_coeff", self.critic_coeff > 0, "positive")
        require(self, "lr", self.lr > 0, "positive")
        require(self, "max_grad_norm", self.max_grad_norm > 0, "positive")


class PPOPlanner(TorchRLLearner):
    """PPO on the env through TorchRL (the module docstring); MAPPO and IPPO differ in ``centralised``."""

    Config = PPOConfig
    #: the critic: one centralised V(s) shared by the team (MAPPO), or one V_i(o_i) a robot (IPPO)
    centralised: ClassVar[bool] = True

    def _modules(self, n_obs: int, n_actions: int, n_agents: int):
        """(actor, critic): a masked categorical policy of one MLP a robot, and the critic."""
        from tensordict.nn import TensorDictModule
        from torchrl.modules import MaskedCategorical, MultiAgentMLP, ProbabilisticActor

        cfg = self.config
        logits = MultiAgentMLP(n_obs, n_actions, n_agents, centralized=False, share_params=False,
                               depth=cfg.layers, num_cells=cfg.hidden)
        actor = ProbabilisticActor(
            TensorDictModule(logits, in_keys=[OBS], out_keys=[(GROUP, "logits")]),
            in_keys={"logits": (GROUP, "logits"), "mask": MASK}, out_keys=[(GROUP, "action")],
            distribution_class=MaskedCategorical, return_log_prob=True, log_prob_key=(GROUP, "action_log_prob"))
        value = MultiAgentMLP(n_obs, 1, n_agents, centralized=self.centralised, share_params=self.centralised,
                              depth=cfg.layers, num_cells=cfg.hidden)
        critic = TensorDictModule(value, in_keys=[OBS], out_keys=[(GROUP, "state_value")])
        return actor, critic

    def _learner(self, env, problem: Problem, steps_total: int):
        """PPO's actor (exploring by sampling, greedy by its mode) and its update of a rollout: ``epochs``
        passes of ``minibatches`` clipped-PPO steps over the rollout's batch."""
        from torchrl.objectives import ClipPPOLoss

        cfg = self.config
        n_actions = max(len(s) for s in problem.action_sets)
        actor, critic = self._modules(problem.features.shape[1], n_actions, problem.n_agents)
        loss = ClipPPOLoss(actor, critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff,
                           critic_coeff=cfg.critic_coeff, normalize_advantage=False)
        loss.set_keys(action=(GROUP, "action"), sample_log_prob=(GROUP, "action_log_prob"),
                      value=(GROUP, "state_value"), advantage=(GROUP, "advantage"),
                      value_target=(GROUP, "value_target"), reward=(GROUP, "reward"),
                      done=(GROUP, "done"), terminated=(GROUP, "terminated"))
        opt = torch.optim.Adam(loss.parameters(), lr=cfg.lr)

        def learn(td, scale: LogScale, record: StepRecord) -> list[float]:
            batch = self._batch(td, scale, record, critic)
            losses = []
            for _ in range(cfg.epochs):
                for mb in torch.randperm(len(batch)).chunk(min(cfg.minibatches, len(batch))):
                    parts = loss(batch[mb])
                    total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                    losses.append(gradient_step(opt, loss, total, cfg.max_grad_norm))
            return losses

        return actor, actor, learn

    @staticmethod
    def _batch(td, scale: LogScale, record: StepRecord, critic):
        """The rollout as PPO's batch: each step's scaled reward (the statistics after the rollout's
        samples) as the value target, reward - V as the advantage (one-step episodes)."""
        max_u = td["next", GROUP, "info", "max_u"][:, 0].double().numpy()
        task = td["next", GROUP, "info", "task"][:, 0].numpy()
        log_u = np.log(max_u)
        for x in log_u:
            scale.add(float(x))
        reward = scale.reward(log_u)
        for step in zip(reward.tolist(), max_u.tolist(), task.tolist()):
            record.add(*step)
        n = td[GROUP, "action"].shape[1]
        r = torch.tensor(reward, dtype=torch.float32)[:, None, None].expand(-1, n, 1)
        with torch.no_grad():
            v = critic(td.select(OBS).clone())[GROUP, "state_value"]
        td[GROUP, "value_target"] = r.clone()
        td[GROUP, "advantage"] = r - v
        return td


class MAPPO(PPOPlanner):
    name = "mappo"
    description = "MAPPO from TorchRL: PPO with a centralised critic, one masked-categorical actor a robot"
    centralised = True
