"""MAPPO and IPPO from TorchRL's components, on the PettingZoo env, behind the Planner interface.

Reference: C. Yu, A. Velu, E. Vinitsky, J. Gao, Y. Wang, A. Bayen, Y. Wu, "The Surprising Effectiveness
of PPO in Cooperative Multi-Agent Games", NeurIPS 2022 Datasets and Benchmarks (arXiv:2103.01955):
MAPPO, PPO with a centralised critic V(s) and decentralised actors pi_i(a_i | o_i), and IPPO, the same
with a critic of each agent's own observation, V_i(o_i).

Nothing here is written by hand that TorchRL provides: the env is TorchRL's ``PettingZooWrapper`` around
:class:`fixbench.cases.env.FixtureEnv` (``pad_actions=True``: one action size for the group ``robot``,
each robot's own actions unmasked), its observation normalised by TorchRL's ``ObservationNorm``; the
actors and critics are ``MultiAgentMLP``; the policy a ``ProbabilisticActor`` over a
``MaskedCategorical`` (a padded index is never drawn); the loss ``ClipPPOLoss``; the rollouts
``EnvBase.rollout``. What is fixbench's: the budget as episodes, the reward, the seeding and the result
(:mod:`fixbench.solvers.learners`). TorchRL is imported inside :meth:`PPOPlanner.plan`, so that the
registry (and a process without the ``marl`` extra) imports this module without it.

The game (docs/protocol.md#the-game): each step shows every robot one task; each robot picks an action
of its own set; the joint layout is evaluated once on the run's counted evaluator (the env is given
``evaluator=ev``, as ``vdn`` does: every env step is a counted sample, and the policy is never evaluated
outside the training rollouts). An episode is one pass over the training tasks, each task one step that
ends its own bandit round, so:

- the value target is the reward itself and the advantage is reward - V: GAE with any gamma and lambda
  gives the same on one-step episodes (no bootstrap), so no value estimator is built;
- the reward optimised is the project's scaled reward (:class:`fixbench.cases.rewards.LogScale`, the
  standardised log deformation, as ``vdn`` and ``nashq``), computed from the env's ``max_u`` info (float32
  in TorchRL's tensordict, and so in ``info["step_max_u"]``); the env's own reward (Gaussian) is not used.
  Each batch is scored with the statistics after its samples.

Parameter sharing: every robot observes the same task features, so actors that share parameters without
an agent id give every robot the same distribution over the same indices (BenchMARL's default sharing
collapses this way, docs/planners.md). The actors therefore never share (``share_params=False``: one MLP
a robot, vectorised by ``MultiAgentMLP``). MAPPO's critic is centralised and shared (one V(s) for the
team, the reward being shared); IPPO's critic is one per robot on its own observation. On this env a
robot's observation is the state, so the two differ in the critic's form only, not in what it sees.

Budget: the run plays ``episodes`` passes over the training tasks, or as many whole passes as the budget
pays for (:func:`fixbench.solvers.learners.episodes_that_fit`: a remainder under one episode is left
unspent; not even one episode is a :class:`PlannerError`), in rollouts of ``batch_episodes`` episodes
(the last may be shorter), each followed by ``epochs`` passes of PPO over it in ``minibatches``
minibatches. Seeding: every torch draw (initial weights, actions, minibatch order) comes from torch's
generator seeded from ``rng`` inside ``torch.random.fork_rng``, so torch's global state is restored after
the run; the wrapper's reset seed (the task order with ``shuffle``) comes from ``rng`` too. The returned
layouts are the policy's mode (each robot's most probable action, no sample) on every task
(``returns_policy``); the harness scores the run by its incumbents.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.env import FixtureEnv
from fixbench.cases.problem import Problem
from fixbench.cases.rewards import LogScale
from fixbench.solvers.base import Planner, PlannerError, TracedEvaluator, at_least, require
from fixbench.solvers.learners import (
    LearnerConfig,
    StepRecord,
    Timings,
    episodes_that_fit,
    learner_info,
    per_episode,
    policy_layouts,
    train_split,
)
from fixbench.solvers.registry import register
from fixbench.solvers.torch_run import torch_run

GROUP = "robot"  # TorchRL's group of the agents robot_0, robot_1, ...
OBS = (GROUP, "observation", "observation")
MASK = (GROUP, "action_mask")
INSTALL = "pip install 'fixbench[marl]'"


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


def require_torchrl(name: str) -> None:
    """Refuse in one line (:class:`PlannerError`, naming the extra to install) where TorchRL or tensordict
    does not import."""
    try:
        import tensordict  # noqa: F401
        import torchrl  # noqa: F401
    except ImportError:
        raise PlannerError(f"planner '{name}' needs TorchRL and tensordict, which do not import here: "
                           f"{INSTALL}") from None


class PPOPlanner(Planner):
    """PPO on the env through TorchRL (the module docstring); MAPPO and IPPO differ in ``centralised``."""

    family = "marl"
    Config = PPOConfig
    modes = ("per-task",)
    returns_policy = True
    same_on_every_host = False
    #: the critic: one centralised V(s) shared by the team (MAPPO), or one V_i(o_i) a robot (IPPO)
    centralised: ClassVar[bool] = True

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        require_torchrl(self.name)
        cfg = self.config
        t_start = time.perf_counter()
        ids = train_split(problem, ev, cfg)
        episodes = episodes_that_fit(self.name, cfg.episodes, ev, len(ids))
        seeds = rng.integers(2**31 - 1, size=2)
        with torch_run(cfg.threads), torch.random.fork_rng(devices=[]), warnings.catch_warnings():
            warnings.filterwarnings("ignore", "PettingZoo in TorchRL is tested", UserWarning)
            warnings.filterwarnings("ignore", "size_average and reduce args", UserWarning)  # ClipPPOLoss's smooth L1
            torch.manual_seed(int(seeds[0]))
            run = self._train(problem, ev, ids, episodes, int(seeds[1]))
        record = run["record"]
        own = {"updates": run["updates"], "batch_loss": run["batch_loss"]}  # PPO's loss, mean per rollout
        info = learner_info(self.name, cfg, problem, ids, episodes, record, per_episode(record.arrays()[0], episodes),
                            own, run["times"], t_start)
        return run["layouts"], info

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

    def _env(self, problem: Problem, ev: TracedEvaluator, ids: np.ndarray, seed: int):
        """TorchRL's wrapper around the padded env on the run's evaluator, the observation normalised to
        [0, 1] over the problem's tasks (a constant feature: shifted to 0); and the normaliser."""
        from torchrl.envs import ObservationNorm, PettingZooWrapper, TransformedEnv

        base = FixtureEnv(problem, shuffle=self.config.shuffle, task_ids=ids, evaluator=ev, pad_actions=True)
        f = torch.tensor(problem.features, dtype=torch.float32)
        lo, span = f.min(dim=0).values, f.max(dim=0).values - f.min(dim=0).values
        norm = ObservationNorm(loc=lo, scale=torch.where(span > 0, span, 1.0), in_keys=[OBS], standard_normal=True)
        return TransformedEnv(PettingZooWrapper(base, categorical_actions=True, seed=seed), norm), norm

    def _train(self, problem: Problem, ev: TracedEvaluator, ids: np.ndarray, episodes: int, seed: int) -> dict:
        """Rollouts and PPO updates, then the policy's mode on every task."""
        from torchrl.envs.utils import ExplorationType, set_exploration_type
        from torchrl.objectives import ClipPPOLoss

        cfg = self.config
        t0 = time.perf_counter()
        problem.oracle.prepare()
        tm = Timings(setup=time.perf_counter() - t0)
        env, norm = self._env(problem, ev, ids, seed)
        n_actions = max(len(s) for s in problem.action_sets)
        actor, critic = self._modules(problem.features.shape[1], n_actions, problem.n_agents)
        loss = ClipPPOLoss(actor, critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff,
                           critic_coeff=cfg.critic_coeff, normalize_advantage=False)
        loss.set_keys(action=(GROUP, "action"), sample_log_prob=(GROUP, "action_log_prob"),
                      value=(GROUP, "state_value"), advantage=(GROUP, "advantage"),
                      value_target=(GROUP, "value_target"), reward=(GROUP, "reward"),
                      done=(GROUP, "done"), terminated=(GROUP, "terminated"))
        opt = torch.optim.Adam(loss.parameters(), lr=cfg.lr)
        scale, record = LogScale(cfg.scale_samples), StepRecord()
        batch_loss, updates, left = [], 0, episodes
        while left:
            k = min(cfg.batch_episodes, left)
            t1 = time.perf_counter()
            with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # sample, not the mode
                td = env.rollout(k * len(ids), actor, break_when_any_done=False)
            t2 = time.perf_counter()
            batch = self._batch(td, scale, record, critic)
            losses = []
            for _ in range(cfg.epochs):
                for mb in torch.randperm(len(batch)).chunk(min(cfg.minibatches, len(batch))):
                    parts = loss(batch[mb])
                    total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                    opt.zero_grad()
                    total.backward()
                    torch.nn.utils.clip_grad_norm_(loss.parameters(), cfg.max_grad_norm)
                    opt.step()
                    losses.append(total.item())
                    updates += 1
            batch_loss.append(float(np.mean(losses)))
            left -= k
            tm.oracle += t2 - t1  # the rollout: the oracle's samples and the policy's draws
            tm.update += time.perf_counter() - t2
        t3 = time.perf_counter()
        layouts = policy_layouts(problem, self._mode(actor, norm, problem))
        tm.greedy = time.perf_counter() - t3
        return {"layouts": layouts, "record": record, "batch_loss": batch_loss, "updates": updates, "times": tm}

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

    @staticmethod
    @torch.no_grad()
    def _mode(actor, norm, problem: Problem) -> np.ndarray:
        """Each robot's most probable action (TorchRL's deterministic interaction: the masked
        categorical's mode) on every task, training and held-out: (T, N) indices into own sets."""
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        t, n = problem.n_tasks, problem.n_agents
        sizes = torch.tensor([len(s) for s in problem.action_sets])
        mask = torch.arange(int(sizes.max()))[None, :] < sizes[:, None]
        obs = torch.tensor(problem.features, dtype=torch.float32)[:, None, :].expand(-1, n, -1)
        td = norm(TensorDict({OBS: obs.clone(), MASK: mask.expand(t, -1, -1).clone()}, batch_size=[t]))
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return actor(td)[GROUP, "action"].numpy().astype(np.int64)


@register
class MAPPO(PPOPlanner):
    name = "mappo"
    description = "MAPPO from TorchRL: PPO with a centralised critic, one masked-categorical actor a robot"
    centralised = True


@register
class IPPO(PPOPlanner):
    name = "ippo"
    description = "IPPO from TorchRL: PPO with one critic a robot on its own observation, one actor a robot"
    centralised = False
