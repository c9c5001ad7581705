"""QMIX (Rashid et al., ICML 2018) from TorchRL's QMixer, QValueModule, EGreedyModule and QMixerLoss, on
the env, budget and seeding the TorchRL learners share (:mod:`fixbench.solvers.learners.torchrl_learner`):
:class:`QMIX` says what it takes from TorchRL and what it adds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.problem import Problem
from fixbench.cases.rewards import LogScale
from fixbench.solvers.base import at_least, require
from fixbench.solvers.learners.common import QLearnerConfig, StepRecord
from fixbench.solvers.learners.torchrl_learner import GROUP, MASK, OBS, TorchRLLearner, gradient_step


@dataclass(frozen=True)
class QMIXConfig(QLearnerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "lr": ("log", 3e-4, 3e-2),
        "eps_decay": ("log", 0.1, 1.0),
        "hidden": ("choice", [32, 64, 128]),
        "batch": ("choice", [16, 32, 64]),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    batch_episodes: int = 1
    """Episodes a rollout collects (the epsilon-greedy policy fixed during it) before the updates."""

    updates_per_step: int = 1
    """Replay updates after a rollout for each of its env steps (vdn: one an env step)."""

    batch: int = 32
    """Replay minibatch (transitions) per update; updates start once the replay holds this many."""

    eps_decay: float = 0.5
    """Fraction of the run's steps over which epsilon falls linearly from ``eps_start`` to ``eps_end``
    (TorchRL's ``EGreedyModule`` anneals linearly), then stays there."""

    lr: float = 5e-3
    """Adam learning rate of the agents' networks and the mixer together."""

    max_grad_norm: float = 10.0
    """Gradient norm clip per update (the paper: 10)."""

    hidden: int = 64
    """Width of each hidden layer of a robot's Q-network."""

    layers: int = 2
    """Hidden layers (Tanh, TorchRL's default) of a robot's Q-network."""

    mixing_embed_dim: int = 32
    """Width of QMixer's hidden layer, the hyper-networks' output (the paper: 32)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "batch_episodes", "updates_per_step", "batch", "hidden", "layers", "mixing_embed_dim")
        require(self, "eps_end", self.eps_end <= self.eps_start, "at most eps_start (epsilon only falls)")
        require(self, "eps_decay", 0 < self.eps_decay <= 1, "in (0, 1]")
        require(self, "lr", self.lr > 0, "positive")
        require(self, "max_grad_norm", self.max_grad_norm > 0, "positive")


class QMIX(TorchRLLearner):
    """QMIX: each robot's Q_i(o, a_i), mixed into the team's Q_tot(s, Q_1, ..., Q_N) by a network whose
    weights a hyper-network makes from the state s and keeps non-negative, so Q_tot is monotone in every
    Q_i and the joint argmax is every robot's own argmax (decentralised greedy actions, exact).

    From TorchRL: the env and its normalised observation (as ``mappo``), each robot's Q-network
    (``MultiAgentMLP``, one MLP a robot), ``QValueModule`` (the masked argmax: a padded index is never
    chosen), ``EGreedyModule`` (per-robot exploration among the robot's own actions, epsilon annealed
    linearly), the mixer ``QMixer`` (the paper's: hyper-networks, absolute weights, ELU, V(s)), the loss
    ``QMixerLoss`` (Q_tot regressed on its TD(0) target, l2), the replay ``ReplayBuffer`` over a
    ``LazyTensorStorage`` and the rollouts ``EnvBase.rollout`` (not a ``SyncDataCollector``: it collects
    whole batches of ``frames_per_batch`` and rounds ``total_frames`` up to one, which would overspend a
    budget of episodes that is no multiple of ``batch_episodes``). Written by hand, because TorchRL has no
    part for it: the transitions the replay keeps (below: a one-step round, the mixer's state) and the
    reward.

    - Networks: one Q-network a robot, not one shared with the robot's identity among its inputs. A
      library Q-network has one output per action index and output k is a different pad for each robot,
      so a shared trunk would share little; without the identity every robot, seeing the same task
      features, would pick the same index (docs/planners.md). The actors of ``mappo`` are built the same.
    - The mixer's state is the task features (normalised as the observation): every robot observes the
      whole state on this env.
    - One-step episodes: every step ends its own bandit round, so the replay stores each transition as
      terminal (``done`` and ``terminated`` true) and QMixerLoss's TD(0) target is the reward itself (no
      bootstrap, gamma irrelevant, no target network: ``delay_value=False``).
    - Reward: the scaled log reward (:class:`fixbench.cases.rewards.LogScale`, as ``vdn`` and ``mappo``);
      the replay keeps ln u and every update rescales it with the statistics of that moment, as ``vdn``.

    Budget and seeding as ``mappo`` (:mod:`fixbench.solvers.learners.torchrl_learner`): rollouts of
    ``batch_episodes`` episodes (the last may be shorter), ``updates_per_step`` updates per step collected;
    every torch draw (initial weights, exploration, replay minibatches) from torch's generator seeded from
    ``rng`` inside ``torch.random.fork_rng``. The returned layouts are every robot's greedy action on every
    task.
    """

    name = "qmix"
    description = "QMIX from TorchRL: one Q-network a robot, mixed monotonically by QMixer on the task features"
    Config = QMIXConfig

    def _modules(self, env, n_obs: int, n_agents: int, steps_total: int):
        """(greedy policy, exploring policy, loss): one MLP a robot, its masked argmax, epsilon-greedy
        on top, and QMixerLoss around the policy and QMixer."""
        from tensordict.nn import TensorDictModule, TensorDictSequential
        from torchrl.modules import EGreedyModule, MultiAgentMLP, QMixer, QValueModule
        from torchrl.objectives import QMixerLoss

        cfg = self.config
        spec = env.full_action_spec[GROUP, "action"]
        q = MultiAgentMLP(n_obs, spec.space.n, n_agents, centralized=False, share_params=False,
                          depth=cfg.layers, num_cells=cfg.hidden)
        greedy = TensorDictSequential(
            TensorDictModule(q, in_keys=[OBS], out_keys=[(GROUP, "action_value")]),
            QValueModule(action_value_key=(GROUP, "action_value"), action_mask_key=MASK, spec=spec,
                         out_keys=[(GROUP, "action"), (GROUP, "action_value"), (GROUP, "chosen_action_value")]))
        explore = TensorDictSequential(greedy, EGreedyModule(
            spec, eps_init=cfg.eps_start, eps_end=cfg.eps_end, action_key=(GROUP, "action"), action_mask_key=MASK,
            annealing_num_steps=max(1, round(cfg.eps_decay * steps_total))))
        mixer = TensorDictModule(QMixer(state_shape=(n_obs,), mixing_embed_dim=cfg.mixing_embed_dim,
                                        n_agents=n_agents, device="cpu"),
                                 in_keys=[(GROUP, "chosen_action_value"), "state"], out_keys=["chosen_action_value"])
        loss = QMixerLoss(greedy, mixer, delay_value=False, action_space=spec)
        loss.set_keys(action_value=(GROUP, "action_value"), local_value=(GROUP, "chosen_action_value"),
                      action=(GROUP, "action"))
        return greedy, explore, loss

    def _learner(self, env, problem: Problem, steps_total: int):
        """QMIX's exploring and greedy policies and its update of a rollout: the rollout's steps into the
        replay, then ``updates_per_step`` QMixerLoss steps per step collected once the replay holds a batch."""
        from torchrl.data import LazyTensorStorage, ReplayBuffer

        cfg = self.config
        greedy, explore, loss = self._modules(env, problem.features.shape[1], problem.n_agents, steps_total)
        opt = torch.optim.Adam(loss.parameters(), lr=cfg.lr)
        replay = ReplayBuffer(storage=LazyTensorStorage(min(cfg.capacity, steps_total)), batch_size=cfg.batch)

        def learn(td, scale: LogScale, record: StepRecord) -> list[float]:
            explore[-1].step(len(td))  # epsilon's annealing, by the steps collected
            replay.extend(self._transitions(td, scale, record))
            losses = []
            for _ in range(cfg.updates_per_step * len(td) if len(replay) >= cfg.batch else 0):
                batch = replay.sample()
                batch["next", "reward"] = scale.reward(batch["log_u"])[:, None]
                losses.append(gradient_step(opt, loss, loss(batch)["loss"], cfg.max_grad_norm))
            return losses

        return explore, greedy, learn

    @staticmethod
    def _transitions(td, scale: LogScale, record: StepRecord):
        """The rollout's steps as the replay keeps them: observation, mask, joint action and state (the
        task features), ln u, and a terminal next step (one-step bandit rounds); each step's scaled reward
        (the statistics after the rollout's samples) into the record."""
        max_u = td["next", GROUP, "info", "max_u"][:, 0].double().numpy()
        task = td["next", GROUP, "info", "task"][:, 0].numpy()
        log_u = np.log(max_u)
        for x in log_u:
            scale.add(float(x))
        for step in zip(scale.reward(log_u).tolist(), max_u.tolist(), task.tolist()):
            record.add(*step)
        out = td.select(OBS, MASK, (GROUP, "action"))
        out["state"] = td[OBS][:, 0]
        nxt = td["next"].select(OBS, MASK)
        nxt["state"] = nxt[OBS][:, 0]
        nxt["done"] = nxt["terminated"] = torch.ones(len(td), 1, dtype=torch.bool)
        out["next"] = nxt
        out["log_u"] = torch.tensor(log_u, dtype=torch.float32)
        return out
