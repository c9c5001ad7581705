"""What the learners built from TorchRL's components share (``mappo`` and ``ippo``:
:mod:`fixbench.solvers.learners.mappo`, :mod:`fixbench.solvers.learners.ippo`; ``qmix``:
:mod:`fixbench.solvers.learners.qmix`): the env, the seeding, the rollout loop and the result, on the
PettingZoo env, behind the Planner interface.

Nothing here is written by hand that TorchRL provides: the env is TorchRL's ``PettingZooWrapper`` around
:class:`fixbench.cases.env.FixtureEnv` (``pad_actions=True``: one action size for the group ``robot``,
each robot's own actions unmasked), its observation normalised by TorchRL's ``ObservationNorm``; the
actors and critics are ``MultiAgentMLP``; the policy a ``ProbabilisticActor`` over a
``MaskedCategorical`` (a padded index is never drawn); the loss ``ClipPPOLoss``; the rollouts
``EnvBase.rollout``. What is fixbench's: the budget as episodes, the reward, the seeding and the result
(:mod:`fixbench.solvers.learners.common`). TorchRL is imported inside :meth:`TorchRLLearner.plan`, so that the
registry (and a process without the ``marl`` extra) imports these modules without it.

The game (docs/protocol.md#the-game): each step shows every robot one task; each robot picks an action
of its own set; the joint layout is evaluated once on the run's counted evaluator (the env is given
``evaluator=ev``, as ``vdn`` does: every env step is a counted sample, and the policy is never evaluated
outside the training rollouts). An episode is one pass over the training tasks, each task one step that
ends its own bandit round. The reward optimised is the project's scaled reward
(:class:`fixbench.cases.rewards.LogScale`, the standardised log deformation, as ``vdn`` and ``nashq``),
computed from the env's ``max_u`` info (float32 in TorchRL's tensordict, and so in the curve
``step_max_u``); the env's own reward (Gaussian) is not used. Each batch is scored with the statistics
after its samples.

Budget: the run plays ``episodes`` passes over the training tasks, or as many whole passes as the budget
pays for (:func:`fixbench.solvers.learners.common.episodes_that_fit`: a remainder under one episode is left
unspent; not even one episode is a :class:`PlannerError`), in rollouts of ``batch_episodes`` episodes
(the last may be shorter), each followed by the learner's update of it. Seeding: every torch draw (initial
weights, actions, minibatch order) comes from torch's generator seeded from ``rng`` inside
``torch.random.fork_rng``, so torch's global state is restored after the run; the wrapper's reset seed (the
task order with ``shuffle``) comes from ``rng`` too. The returned layouts are the policy's mode (each robot's
most probable action, no sample) on every task (``returns_policy``); the harness scores the run by its
incumbents.
"""

from __future__ import annotations

import contextlib
import logging
import time
import warnings

import numpy as np
import torch

from fixbench.cases.env import FixtureEnv
from fixbench.cases.problem import Problem
from fixbench.cases.rewards import LogScale
from fixbench.solvers.base import Planner, PlannerError, TracedEvaluator
from fixbench.solvers.encoding import min_max_loc_scale
from fixbench.solvers.learners.common import (
    StepRecord,
    Timings,
    episodes_that_fit,
    learner_info,
    learner_training,
    per_episode,
    policy_layouts,
    train_split,
)
from fixbench.solvers.torch_run import torch_run

GROUP = "robot"  # TorchRL's group of the agents robot_0, robot_1, ...
OBS = (GROUP, "observation", "observation")
MASK = (GROUP, "action_mask")
INSTALL = "pip install 'fixbench[marl]'"


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
