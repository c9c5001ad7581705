"""MAPPO, IPPO and QMIX from TorchRL's components, on the PettingZoo env, behind the Planner interface.

Reference: C. Yu, A. Velu, E. Vinitsky, J. Gao, Y. Wang, A. Bayen, Y. Wu, "The Surprising Effectiveness
of PPO in Cooperative Multi-Agent Games", NeurIPS 2022 Datasets and Benchmarks (arXiv:2103.01955):
MAPPO, PPO with a centralised critic V(s) and decentralised actors pi_i(a_i | o_i), and IPPO, the same
with a critic of each agent's own observation, V_i(o_i). QMIX (T. Rashid et al., ICML 2018) is the last
section: :class:`QMIX` says what it takes from TorchRL and what it adds.

Nothing here is written by hand that TorchRL provides: the env is TorchRL's ``PettingZooWrapper`` around
:class:`fixbench.cases.env.FixtureEnv` (``pad_actions=True``: one action size for the group ``robot``,
each robot's own actions unmasked), its observation normalised by TorchRL's ``ObservationNorm``; the
actors and critics are ``MultiAgentMLP``; the policy a ``ProbabilisticActor`` over a
``MaskedCategorical`` (a padded index is never drawn); the loss ``ClipPPOLoss``; the rollouts
``EnvBase.rollout``. What is fixbench's: the budget as episodes, the reward, the seeding and the result
(:mod:`fixbench.solvers.learners`). TorchRL is imported inside :meth:`TorchRLLearner.plan`, so that the
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
  in TorchRL's tensordict, and so in the curve ``step_max_u``); the env's own reward (Gaussian) is not used.
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

import contextlib
import logging
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
from fixbench.solvers.encoding import min_max_loc_scale
from fixbench.solvers.learners import (
    LearnerConfig,
    QLearnerConfig,
    StepRecord,
    Timings,
    episodes_that_fit,
    learner_info,
    learner_training,
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


@contextlib.contextmanager
def torchrl_quiet():
    """TorchRL's logger at WARNING during a run, restored after: it writes INFO lines to stdout (its
    replay storage: "Initialized LazyTensorStorage ..."), where ``fixbench solve --json`` writes JSON."""
    log = logging.getLogger("torchrl")
    level = log.level
    log.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        log.setLevel(level)


def gradient_step(opt, loss_module, value, max_grad_norm: float) -> float:
    """One optimiser step on ``value`` (a scalar loss of ``loss_module``'s parameters), its gradient
    clipped to ``max_grad_norm``; returns the loss."""
    opt.zero_grad()
    value.backward()
    torch.nn.utils.clip_grad_norm_(loss_module.parameters(), max_grad_norm)
    opt.step()
    return value.item()


class TorchRLLearner(Planner):
    """What the learners built from TorchRL's components share (``mappo``, ``ippo``, ``qmix``): the run's
    set-up (split, episodes, seeding inside ``torch.random.fork_rng``, torch threads), the env, the policy's
    greedy layouts, the rollout loop, the ``info`` and the ``training`` curves (``batch_loss``: the mean loss
    of each rollout's updates, None where there was none); a subclass has a ``Config`` and ``_learner``,
    its exploring and greedy policies and its update of a rollout."""

    family = "marl"
    modes = ("per-task",)
    returns_policy = True
    same_on_every_host = False

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        require_torchrl(self.name)
        cfg = self.config
        t_start = time.perf_counter()
        ids = train_split(problem, ev, cfg)
        episodes = episodes_that_fit(self.name, cfg.episodes, ev, len(ids))
        seeds = rng.integers(2**31 - 1, size=2)
        with torch_run(cfg.threads), torch.random.fork_rng(devices=[]), warnings.catch_warnings(), \
                torchrl_quiet():
            warnings.filterwarnings("ignore", "PettingZoo in TorchRL is tested", UserWarning)
            warnings.filterwarnings("ignore", "size_average and reduce args", UserWarning)  # ClipPPOLoss's smooth L1
            torch.manual_seed(int(seeds[0]))
            run = self._train(problem, ev, ids, episodes, int(seeds[1]))
        record = run["record"]
        info = learner_info(self.name, cfg, problem, ids, episodes, record, run["own"], run["times"], t_start)
        training = learner_training(record, per_episode(record.arrays()[0], episodes)).add(
            "batch", batch_loss=run["batch_loss"])
        return run["layouts"], info, training

    def _train(self, problem: Problem, ev: TracedEvaluator, ids: np.ndarray, episodes: int, seed: int) -> dict:
        """Rollouts of ``batch_episodes`` episodes (the last may be shorter) with the exploring policy,
        the subclass's update after each (:meth:`_learner`), then the greedy policy on every task."""
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        cfg = self.config
        t0 = time.perf_counter()
        problem.oracle.prepare()
        tm = Timings(setup=time.perf_counter() - t0)
        env, norm = self._env(problem, ev, ids, seed)
        explore, greedy, learn = self._learner(env, problem, episodes * len(ids))
        scale, record = LogScale(cfg.scale_samples), StepRecord()
        batch_loss, updates, left = [], 0, episodes
        while left:
            k = min(cfg.batch_episodes, left)
            t1 = time.perf_counter()
            with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # PPO samples, QMIX explores
                td = env.rollout(k * len(ids), explore, break_when_any_done=False)
            t2 = time.perf_counter()
            losses = learn(td, scale, record)
            batch_loss.append(float(np.mean(losses)) if losses else None)  # None: no update
            updates += len(losses)
            left -= k
            tm.oracle += t2 - t1  # the rollout: the oracle's samples and the policy's draws
            tm.update += time.perf_counter() - t2
        t3 = time.perf_counter()
        layouts = policy_layouts(problem, self._mode(greedy, norm, problem))
        tm.greedy = time.perf_counter() - t3
        return {"layouts": layouts, "record": record, "own": {"updates": updates}, "times": tm,
                "batch_loss": batch_loss}

    def _env(self, problem: Problem, ev: TracedEvaluator, ids: np.ndarray, seed: int):
        """TorchRL's wrapper around the padded env on the run's evaluator, the observation (the env's raw
        features) normalised to [0, 1] over the problem's tasks (a constant feature: shifted to 0;
        :func:`fixbench.solvers.encoding.min_max_loc_scale`); and the normaliser."""
        from torchrl.envs import ObservationNorm, PettingZooWrapper, TransformedEnv

        base = FixtureEnv(problem, shuffle=self.config.shuffle, task_ids=ids, evaluator=ev, pad_actions=True)
        loc, scale = (torch.from_numpy(v) for v in min_max_loc_scale(problem, np.float32))
        norm = ObservationNorm(loc=loc, scale=scale, in_keys=[OBS], standard_normal=True)
        return TransformedEnv(PettingZooWrapper(base, categorical_actions=True, seed=seed), norm), norm

    @staticmethod
    @torch.no_grad()
    def _mode(actor, norm, problem: Problem) -> np.ndarray:
        """Each robot's action under TorchRL's deterministic interaction (PPO: the masked categorical's
        mode; QMIX: the argmax of the robot's own Q) on every task, training and held-out: (T, N) indices
        into own sets. No sample."""
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        t, n = problem.n_tasks, problem.n_agents
        sizes = torch.tensor([len(s) for s in problem.action_sets])
        mask = torch.arange(int(sizes.max()))[None, :] < sizes[:, None]
        obs = torch.tensor(problem.features, dtype=torch.float32)[:, None, :].expand(-1, n, -1)
        td = norm(TensorDict({OBS: obs.clone(), MASK: mask.expand(t, -1, -1).clone()}, batch_size=[t]))
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return actor(td)[GROUP, "action"].numpy().astype(np.int64)


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


# ---------------------------------------------------------------------------------------------
# QMIX (Rashid et al., ICML 2018) from TorchRL's QMixer, QValueModule, EGreedyModule and QMixerLoss
# ---------------------------------------------------------------------------------------------
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


@register
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

    Budget and seeding as ``mappo`` (the module docstring): rollouts of ``batch_episodes`` episodes (the
    last may be shorter), ``updates_per_step`` updates per step collected; every torch draw (initial
    weights, exploration, replay minibatches) from torch's generator seeded from ``rng`` inside
    ``torch.random.fork_rng``. The returned layouts are every robot's greedy action on every task.
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
