"""What the learners (``nashq``, ``iql``, ``vdn``; ``mappo``, ``ippo``, ``qmix`` in part, through
solvers/learners/torchrl_learner.py) share.

A learner plays the game of docs/protocol.md#the-game on the PettingZoo env or on the same game batched
over positions (:class:`~fixbench.cases.env.PositionBatchEnv`): one episode is one pass over the
training tasks, one position answered one counted sample. Around its own network and update, every
learner does the same things, and they live here once:

- :class:`LearnerConfig`: the hyper-parameters with the same name, meaning and default in every
  learner (``mappo``/``ippo`` too: solvers/learners/mappo.py), and :class:`QLearnerConfig`, what the
  Q-learners add (exploration, replay); a learner's config subclasses one and adds its own,
  ``eps_decay`` among them: its unit is the learner's, see the two schedules below;
- the split: :func:`train_split` (the held-out track's tasks, else :func:`train_ids` from the config),
  :func:`episodes_that_fit` (the budget as whole episodes), :func:`torch_generator` (the seeding);
- the loop's parts: :func:`training_env`, :func:`explore` and the epsilon schedules
  (:func:`epsilon_by_step`, :func:`epsilon_by_run_fraction`), :func:`scaled_reward`, :class:`Replay`,
  :class:`StepRecord` (and :func:`per_episode`), :class:`Timings`;
- the result: :func:`policy_layouts`, :func:`learner_info` (the ``info`` keys every learner emits) and
  :func:`learner_training` (the curves every learner declares, among them those Figure 4 draws:
  bench/reporting/figures.py ``FIGURE4_CURVES``).

Their inputs (task features, pad coordinates and flags) are encoded in :mod:`fixbench.solvers.encoding`.
docs/planners.md#write-a-learner says how a new learner uses them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fixbench.cases.env import FixtureEnv, PositionBatchEnv
from fixbench.cases.problem import Problem
from fixbench.cases.rewards import LogScale
from fixbench.solvers.base import PlannerConfig, PlannerError, TracedEvaluator, Training, at_least, require


# ---------------------------------------------------------------------------------------------
# hyper-parameters every learner has
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LearnerConfig(PlannerConfig):
    """The fields every learner shares (same names, same meanings, same defaults), checked here; a
    learner's config adds its own (network, optimiser, exploration) and checks them."""

    episodes: int = 100
    """Passes over the training tasks, one sample a training task each (seed Table I: 100)."""

    scale_samples: int = 500
    """The scaled reward: the first samples whose ln u give its mean and spread (then frozen;
    :class:`fixbench.cases.rewards.LogScale`)."""

    shuffle: bool = False
    """Visit the training tasks in a new random order each episode (reference: in order)."""

    train_tasks: tuple[int, ...] = ()
    """Train only on these task indices (held-out tasks get the learned policy's layouts, no samples)."""

    train_fraction: float = 1.0
    """If train_tasks is empty: train on this fraction of tasks, evenly spaced over the task list."""

    threads: int = 1
    """torch intra-op threads during the run (0: torch's setting); restored afterwards. 1: tiny ops gain
    nothing from more, and spinning OpenMP threads on a shared, loaded machine slowed updates 40x
    (measured on nashq)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "episodes")
        at_least(self, 2, "scale_samples")
        at_least(self, 0, "threads")
        require(self, "train_tasks", all(t >= 0 for t in self.train_tasks), "task indices (0 or more)")
        require(self, "train_fraction", 0 < self.train_fraction <= 1, "in (0, 1]")


@dataclass(frozen=True)
class QLearnerConfig(LearnerConfig):
    """What the Q-learners add: epsilon-greedy exploration and a replay buffer (``eps_decay`` is each
    learner's own: its unit is the learner's, see the two schedules below)."""

    eps_start: float = 0.9
    """Initial exploration probability (per agent, independently)."""

    eps_end: float = 0.05
    """Final exploration probability."""

    capacity: int = 1_000_000
    """Replay capacity (transitions); never more is allocated than the run has steps."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "capacity")
        require(self, "eps_start", 0 <= self.eps_start <= 1, "in [0, 1]")
        require(self, "eps_end", 0 <= self.eps_end <= 1, "in [0, 1]")


# ---------------------------------------------------------------------------------------------
# the split: training tasks, episodes, seeding
# ---------------------------------------------------------------------------------------------
def train_ids(problem: Problem, cfg: LearnerConfig) -> np.ndarray:
    """Training task indices from ``train_tasks`` or ``train_fraction`` (evenly spaced)."""
    t = problem.n_tasks
    if cfg.train_tasks:
        ids = np.unique(np.asarray(cfg.train_tasks, dtype=np.int64))
        if ids.max() >= t:
            raise PlannerError(f"train_tasks must be in 0..{t - 1}")
        return ids
    k = max(1, round(cfg.train_fraction * t))
    return np.unique(np.round(np.linspace(0, t - 1, k)).astype(np.int64))


def train_split(problem: Problem, ev: TracedEvaluator, cfg: LearnerConfig) -> np.ndarray:
    """The tasks a run trains on: the held-out track restricts the evaluator to its training tasks
    (``Planner.solve(train_tasks=...)``); else the config chooses (:func:`train_ids`)."""
    return ev.tasks.copy() if len(ev.tasks) < problem.n_tasks else train_ids(problem, cfg)


def episodes_that_fit(name: str, episodes: int, ev: TracedEvaluator, n_train: int) -> int:
    """Episodes to run: ``episodes``, or as many whole passes over ``n_train`` tasks as the budget pays
    for (best effort: a remainder under one episode is left unspent); :class:`PlannerError` if not one."""
    fit = episodes if math.isinf(ev.remaining) else int(ev.remaining // n_train)
    if fit < 1:
        raise PlannerError(f"planner '{name}': budget too small: one episode needs {n_train} "
                           f"samples, {int(ev.remaining)} available")
    return min(episodes, fit)


def torch_generator(rng: np.random.Generator) -> torch.Generator:
    """The torch generator of a run (the networks' initial weights), seeded from ``rng``: everything random
    comes from ``rng``, and torch's global generator is neither seeded nor drawn from."""
    return torch.Generator().manual_seed(int(rng.integers(2**31 - 1)))


# ---------------------------------------------------------------------------------------------
# the training loop's parts
# ---------------------------------------------------------------------------------------------
def training_env(problem: Problem, ev: TracedEvaluator, ids: np.ndarray, shuffle: bool,
                 reward: str = "gaussian", per_step: int | None = None) -> tuple[Any, float]:
    """The env over the training tasks on the run's counted evaluator, and the seconds the oracle's
    set-up took first (every column now, or from the disk cache; no samples; in no training timer).
    ``reward`` is what the env pays; a learner on the scaled reward transforms the env's ``max_u``
    itself (:func:`scaled_reward`). With ``per_step``, the env vectorised over positions
    (:class:`~fixbench.cases.env.PositionBatchEnv`: that many positions a step), else the PettingZoo
    :class:`~fixbench.cases.env.FixtureEnv`."""
    t0 = time.perf_counter()
    problem.oracle.prepare()
    setup_s = time.perf_counter() - t0
    if per_step is not None:
        return PositionBatchEnv(problem, per_step, evaluator=ev, task_ids=ids, shuffle=shuffle), setup_s
    return FixtureEnv(problem, reward=reward, shuffle=shuffle, task_ids=ids, evaluator=ev), setup_s


def epsilon_by_step(step: int, start: float, end: float, decay_steps: float) -> float:
    """Exploration probability after ``step`` env steps: end + (start - end) exp(-step / decay_steps),
    ``decay_steps`` in env steps, the same in a run of any length (nashq, iql: ``eps_decay``)."""
    return end + (start - end) * math.exp(-step / decay_steps)


def epsilon_by_run_fraction(step: int, steps_total: int, start: float, end: float, decay_fraction: float) -> float:
    """Exploration probability after ``step`` of the run's ``steps_total`` env steps:
    end + (start - end) exp(-step / (decay_fraction steps_total)), ``decay_fraction`` a fraction of the
    run, so that a short run exploits too (vdn: ``eps_decay``)."""
    return epsilon_by_step(step, start, end, decay_fraction * steps_total)


def explore(rng: np.random.Generator, eps, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which agents explore this step (each with probability ``eps``, independently) and a uniform random
    action of each agent's set (``sizes``: the set sizes), for the explorers to play: (agents,) arrays
    for a float ``eps``; (n, agents) for an array of n epsilons, one a position of a batched step (with
    n = 1, the same draws as a float ``eps``)."""
    shape = np.shape(eps) + (len(sizes),)
    explorers = rng.random(shape) < np.asarray(eps)[..., None]
    return explorers, (rng.random(shape) * sizes).astype(np.int64)


def scaled_reward(scale: LogScale, max_u: float) -> tuple[float, float]:
    """One step's scaled reward (docs/protocol.md#scaled-reward) and its ln u, the value a replay keeps
    (rescaled with the statistics of the moment at each update); ``scale`` takes ln u in first."""
    log_u = math.log(max_u)
    scale.add(log_u)
    return float(scale.reward(log_u)), log_u


class Replay:
    """Replay of joint transitions in a ring of ``min(capacity, steps)`` slots: task, joint action (one
    index an agent) and one stored value (the reward, or ln u for the scaled reward).

    Three preallocated tensors and a modulo, by hand rather than TorchRL's ``ReplayBuffer``: its samplers
    draw from torch's generator, and a run draws everything random from its own numpy ``rng``."""

    def __init__(self, capacity: int, steps: int, n_agents: int, device: torch.device | str = "cpu"):
        self.cap, self.device, self.added = min(capacity, steps), device, 0
        self.task = torch.zeros(self.cap, dtype=torch.long, device=device)
        self.act = torch.zeros(self.cap, n_agents, dtype=torch.long, device=device)
        self.value = torch.zeros(self.cap, dtype=torch.float32, device=device)

    def __len__(self) -> int:
        return min(self.added, self.cap)

    def add(self, task: int, act: np.ndarray, value: float) -> None:
        k = self.added % self.cap
        self.task[k], self.value[k] = task, value
        self.act[k] = torch.from_numpy(act)
        self.added += 1

    def add_many(self, tasks: np.ndarray, acts: np.ndarray, values: np.ndarray) -> None:
        """:meth:`add` for each row of a batched step, in order (of more rows than the capacity, the last
        ``cap`` are kept, as one by one: a repeated index in one assignment would leave the order to torch)."""
        skip = max(len(tasks) - self.cap, 0)
        self.added += skip
        tasks, acts, values = tasks[skip:], acts[skip:], values[skip:]
        k = (self.added + np.arange(len(tasks))) % self.cap
        self.task[k] = torch.as_tensor(tasks, dtype=torch.long)
        self.act[k] = torch.as_tensor(acts, dtype=torch.long)
        self.value[k] = torch.as_tensor(values, dtype=torch.float32)
        self.added += len(tasks)

    def sample(self, rng: np.random.Generator, shape) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Transitions drawn uniformly with replacement, ``shape`` of them: (tasks, joint actions, values)."""
        idx = torch.from_numpy(rng.integers(0, len(self), shape)).to(self.device)
        return self.task[idx], self.act[idx], self.value[idx]


class StepRecord:
    """Every training step's reward (the learner's), max deformation (m) and task, in step order."""

    def __init__(self):
        self.reward, self.max_u, self.task = [], [], []

    def add(self, reward: float, max_u: float, task: int) -> None:
        self.reward.append(reward)
        self.max_u.append(max_u)
        self.task.append(task)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.array(self.reward), np.array(self.max_u), np.array(self.task)


def per_episode(values: np.ndarray, episodes: int) -> list[float]:
    """Sums of a per-step array over each episode (the steps of a run are ``episodes`` equal passes)."""
    return values.reshape(episodes, -1).sum(axis=1).tolist()


@dataclass
class Timings:
    """Seconds a run spent: oracle set-up, then per phase of the training steps (choosing actions, the
    oracle's sample, recording and learning), then the greedy policy."""

    setup: float = 0.0
    select: float = 0.0
    oracle: float = 0.0
    update: float = 0.0
    greedy: float = 0.0


# ---------------------------------------------------------------------------------------------
# the result
# ---------------------------------------------------------------------------------------------
def policy_layouts(problem: Problem, actions: np.ndarray) -> np.ndarray:
    """Layouts (T, N) of the greedy policy's actions (T, N), indices into each agent's own set."""
    return np.column_stack([problem.action_sets[i][actions[:, i]] for i in range(problem.n_agents)])


def learner_training(record: StepRecord, episode_return: list[float]) -> Training:
    """The curves every learner declares: ``step_reward``, ``step_max_u`` (m) and ``step_task``, one value
    a training step, and ``episode_return``, one an episode (what Figure 4 draws, with
    ``episode_regret_ref`` / ``episode_regret_true`` where a learner adds them: ``FIGURE4_CURVES`` in
    bench/reporting/figures.py). A learner adds its own with :meth:`Training.add`."""
    rew, u, task = record.arrays()
    return Training().add("step", step_reward=rew, step_max_u=u, step_task=task).add(
        "episode", episode_return=episode_return)


def learner_info(name: str, cfg: LearnerConfig, problem: Problem, ids: np.ndarray, episodes: int,
                 record: StepRecord, own: dict[str, Any], times: Timings, t_start: float) -> dict:
    """The ``info`` of a learner's run: the figures every learner emits (scalars and the task lists), the
    learner's ``own`` among them; its curves go in its :class:`Training` (:func:`learner_training`).
    Call after :func:`torch_run` restored the thread setting (``torch_threads`` reports the run's)."""
    return {
        "algorithm": name,
        "episodes_run": episodes,
        "budget_limited": episodes < cfg.episodes,
        "train_tasks": ids.tolist(),
        "held_out_tasks": np.setdiff1d(np.arange(problem.n_tasks), ids).tolist(),
        "steps": len(record.reward),
        **own,
        "time_setup_s": times.setup,  # oracle set-up before training (in no other timer)
        "time_select_s": times.select,
        "time_oracle_s": times.oracle,
        "time_update_s": times.update,
        "time_greedy_s": times.greedy,
        "time_total_s": time.perf_counter() - t_start,
        "torch_threads": cfg.threads or torch.get_num_threads(),  # restored: the setting outside the run
    }
