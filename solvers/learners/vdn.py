"""VDN: value-decomposition networks for the multi-robot fixture planning game, in PyTorch.

Reference: P. Sunehag, G. Lever, A. Gruslys, W. M. Czarnecki, V. Zambaldi, M. Jaderberg, M. Lanctot,
N. Sonnerat, J. Z. Leibo, K. Tuyls, T. Graepel, "Value-Decomposition Networks For Cooperative
Multi-Agent Learning", AAMAS 2018 (arXiv:1706.05296, 2017): the team's action value is the sum of the
agents' values, Q_tot(s, a) = sum_i Q_i(s, a_i), trained end to end on the shared reward, each agent
acting on its own Q_i; with parameter sharing (one network for all agents, an agent one-hot among its
inputs), the paper's strongest variant. The cooperative MARL reference beside ``nashq`` / ``iql``.

Read top to bottom (cleanrl style): hyper-parameters, the shared Q-network, the training loop on the
game's env batched over positions (:class:`fixbench.cases.env.PositionBatchEnv`), the greedy policy.
What every learner shares (the split, the budget as episodes, the replay, the step record, the
``info`` keys) is in :mod:`fixbench.solvers.learners.common`.

The game (docs/protocol.md#the-game): each step shows every agent one task (its feature vector); each
agent picks one action of its own set; the layout is evaluated once on the counted oracle (one sample
per step) and every agent gets the same reward. One episode is one pass over the training tasks; an
episode of the bandit is one step, so the target is the reward itself (no bootstrap, no target network).

Design:

- one network for every action of every agent (parameter sharing over pad coordinates):
  Q_i(s, a) = MLP(task features of s, pad coordinates of action a, one-hot of agent i) -> a scalar.
  Task features are min-max normalised over the problem's tasks; an action's pads' (x, y) are
  normalised to [0, 1] of the candidates' bounding box (a robot that places m pads: 2 m numbers, and m flags
  "this pad is placed", a "no pad" sitting at its robot's candidates' centroid), both from
  :mod:`fixbench.solvers.encoding` (``task_features(..., "min-max")``, ``action_inputs``). Actions near each
  other get near values before either was tried: what is learned on one candidate carries to its
  neighbours, and from one agent to the others through the shared weights.
- VDN: Q_tot(s, a) = sum_i Q_i(s, a_i), regressed (mean squared error) on the shared reward of the
  one-step episode, from minibatches of a replay buffer, AdamW.
- reward: the project's scaled reward (:class:`fixbench.cases.rewards.LogScale`, the standardised log
  deformation, (mu - ln u) / sd, calibrated on the run's first ``scale_samples`` samples). The buffer
  keeps ln u and every update rescales it with the statistics of that moment, as ``nashq`` does.
- acting: each agent explores on its own with probability epsilon (a uniform random action of its
  set), epsilon = end + (start - end) exp(-step / (eps_decay * run steps)); the greedy joint action is
  every agent's own argmax, exact for VDN (the sum decomposes). One step scores every action of every
  non-exploring agent in one batched forward pass (the wing panel: 3,333 rows a position).
- positions a step (``positions_per_step``, :class:`fixbench.cases.env.PositionBatchEnv`): 1, the
  seed's protocol, acts on one position and makes one update a sample; P acts on P positions with one
  forward pass and makes the step's P updates as one, on all their transitions. Every answer is still
  one counted sample. What it saves and costs on the wing panel: docs/performance.md.

Budget: one sample per position answered. The run trains for ``episodes`` passes over the training tasks, or,
if the budget is smaller, for as many full episodes as fit (best effort, ``info["episodes_run"]``); if
not even one fits, :class:`PlannerError`. The returned layouts are the greedy policy's (epsilon 0, no
samples) on every task, training and held-out alike (``returns_policy``); the harness scores the run by
its incumbents (the best layout evaluated on each training task) and reports the policy beside them;
held-out tasks (no samples) are scored by the policy.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import nn

from fixbench.cases.problem import Problem
from fixbench.cases.rewards import LogScale
from fixbench.solvers.base import Planner, TracedEvaluator, at_least, require
from fixbench.solvers.encoding import action_inputs, task_features
from fixbench.solvers.learners.common import (
    QLearnerConfig,
    Replay,
    StepRecord,
    Timings,
    episodes_that_fit,
    epsilon_by_run_fraction,
    explore,
    learner_info,
    learner_training,
    per_episode,
    policy_layouts,
    scaled_reward,
    torch_generator,
    train_split,
    training_env,
)
from fixbench.solvers.torch_run import torch_run


# ---------------------------------------------------------------------------------------------
# hyper-parameters (and those every Q-learner has: fixbench.solvers.learners.QLearnerConfig)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class VDNConfig(QLearnerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "lr": ("log", 3e-4, 1e-2),
        "eps_decay": ("log", 0.05, 0.5),
        "hidden": ("choice", [64, 128, 256]),
        "batch": ("choice", [32, 64, 128]),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    hash_omits: ClassVar[dict[str, object]] = {"positions_per_step": 1}
    """One position a step is what every run made before the field existed did."""

    hidden: int = 128
    """Width of each hidden layer of the shared Q-network."""

    layers: int = 2
    """Hidden layers (ReLU) of the shared Q-network."""

    lr: float = 3e-3
    """AdamW learning rate."""

    weight_decay: float = 1e-4
    """AdamW decoupled weight decay."""

    batch: int = 64
    """Replay minibatch (joint transitions) per update; updates start once the buffer holds this many."""

    update_every: int = 1
    """One update every this many env steps."""

    eps_decay: float = 0.2
    """Epsilon decay as a fraction of the run's steps: epsilon = end + (start - end) exp(-step / (eps_decay
    * run steps)), so that a short run exploits too (the 50,000-step protocol run: 10,000 steps; nashq's
    ``eps_decay`` is in steps, 3,500 in any run; ``learners.epsilon_by_run_fraction``)."""

    positions_per_step: int = 1
    """Positions acted on in one step (:class:`fixbench.cases.env.PositionBatchEnv`): one batched forward
    scores every action on all of them, and the updates due in the step (one every ``update_every``
    samples, ``batch`` transitions each) are made as one update on all their transitions. 1: one
    position, one update a sample, the seed's protocol."""

    greedy_chunk: int = 32
    """Tasks scored at once by the final greedy policy (memory: chunk x all actions x hidden floats)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "hidden", "layers", "batch", "update_every", "positions_per_step", "greedy_chunk")
        require(self, "lr", self.lr > 0, "positive")
        require(self, "weight_decay", self.weight_decay >= 0, "0 or more")
        require(self, "eps_decay", self.eps_decay > 0, "positive")


# ---------------------------------------------------------------------------------------------
# the shared Q-network
# ---------------------------------------------------------------------------------------------
class SharedQ(nn.Module):
    """MLP rows (task features, action's pad coordinates [and pad flags], agent one-hot) -> Q (rows,).

    Initialised as ``nn.Linear`` is (uniform +-1/sqrt(fan_in)) but from ``generator``, never from
    torch's global generator.
    """

    def __init__(self, n_in: int, hidden: int, layers: int, generator: torch.Generator):
        super().__init__()
        dims = [n_in] + [hidden] * layers + [1]
        self.w, self.b = nn.ParameterList(), nn.ParameterList()
        for k in range(len(dims) - 1):
            bound = 1.0 / math.sqrt(dims[k])
            self.w.append(nn.Parameter((torch.rand(dims[k], dims[k + 1], generator=generator) * 2 - 1) * bound))
            self.b.append(nn.Parameter((torch.rand(dims[k + 1], generator=generator) * 2 - 1) * bound))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for w, b in zip(self.w[:-1], self.b[:-1]):
            x = torch.relu(torch.addmm(b, x, w))
        return torch.addmm(self.b[-1], x, self.w[-1])[:, 0]


class Actions:
    """The static part of every (agent, action) row, and where each agent's actions lie among them.

    ``rows`` (R, D): an action's normalised pad coordinates (and pad flags), then its agent's one-hot,
    all agents' actions one after the other (R = sum of the set sizes); agent i's action a is row
    ``start[i] + a``; ``table`` (N, A_max) the row of each agent's action, padded with row 0 where
    ``valid`` is False.
    """

    def __init__(self, problem: Problem):
        n, sizes = problem.n_agents, [len(s) for s in problem.action_sets]
        pos = action_inputs(problem, interval=(0.0, 1.0))  # (options, 2 m [+ m pad flags])
        parts = [np.concatenate([pos[s], np.tile(np.eye(n)[i], (len(s), 1))], axis=1)
                 for i, s in enumerate(problem.action_sets)]
        self.rows = torch.tensor(np.concatenate(parts), dtype=torch.float32)
        self.start = torch.tensor(np.concatenate([[0], np.cumsum(sizes)[:-1]]), dtype=torch.long)
        self.sizes = np.array(sizes, dtype=np.int64)
        a = torch.arange(max(sizes))
        self.valid = a[None, :] < torch.tensor(sizes)[:, None]  # (N, A_max)
        self.table = torch.where(self.valid, self.start[:, None] + a[None, :], 0)


@torch.no_grad()
def greedy(q: SharedQ, acts: Actions, feats: torch.Tensor, tasks: np.ndarray) -> np.ndarray:
    """Each agent's argmax of its own Q on each task: (len(tasks), N) action indices (own sets).

    Exact for VDN: Q_tot = sum_i Q_i(s, a_i), so the joint argmax is the agents' argmaxes."""
    r = len(acts.rows)
    x = torch.cat([feats[torch.as_tensor(tasks)][:, None, :].expand(-1, r, -1),
                   acts.rows[None].expand(len(tasks), -1, -1)], dim=2)
    qv = q(x.reshape(len(tasks) * r, -1)).reshape(len(tasks), r)
    qa = qv[:, acts.table].masked_fill(~acts.valid, -math.inf)  # (B, N, A_max)
    return qa.argmax(dim=2).numpy()


def q_tot(q: SharedQ, acts: Actions, feats: torch.Tensor, tasks: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """VDN's team value of joint actions: tasks (B,), actions (B, N) -> sum_i Q_i(s, a_i) (B,)."""
    b, n = actions.shape
    rows = acts.rows[acts.start[None, :] + actions]  # (B, N, D)
    x = torch.cat([feats[tasks][:, None, :].expand(-1, n, -1), rows], dim=2)
    return q(x.reshape(b * n, -1)).reshape(b, n).sum(dim=1)


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class VDN(Planner):
    name = "vdn"
    family = "marl"
    description = "value-decomposition networks (VDN): summed per-agent Q, one network shared over pad coordinates"
    Config = VDNConfig
    modes = ("per-task",)
    returns_policy = True
    same_on_every_host = False

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        t_start = time.perf_counter()
        ids = train_split(problem, ev, cfg)
        episodes = episodes_that_fit(self.name, cfg.episodes, ev, len(ids))
        gen = torch_generator(rng)
        with torch_run(cfg.threads):
            run = self._train(problem, ev, rng, ids, episodes, gen)
        record = run["record"]
        info = learner_info(self.name, cfg, problem, ids, episodes, record, {"updates": run["updates"]},
                            run["times"], t_start)
        training = learner_training(record, per_episode(record.arrays()[0], episodes)).add(
            "episode", episode_loss=run["episode_loss"])  # MSE of Q_tot, mean per episode (NaN: no update)
        return run["layouts"], info, training

    def _train(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, ids: np.ndarray,
               episodes: int, gen: torch.Generator) -> dict:
        """The training loop and the greedy policy (the caller restores thread settings)."""
        cfg, n = self.config, problem.n_agents
        steps_total = episodes * len(ids)
        # the env pays the seed's Gaussian reward; the learner's reward is its own transform of max_u
        env, setup_s = training_env(problem, ev, ids, cfg.shuffle, per_step=cfg.positions_per_step)
        tm = Timings(setup=setup_s)
        acts, feats = Actions(problem), torch.tensor(task_features(problem, "min-max"), dtype=torch.float32)
        q = SharedQ(feats.shape[1] + acts.rows.shape[1], cfg.hidden, cfg.layers, gen)
        opt = torch.optim.AdamW(q.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        scale = LogScale(cfg.scale_samples)
        replay = Replay(cfg.capacity, steps_total, n)  # ln u: rescaled at each update

        record, episode_loss = StepRecord(), []
        steps = updates = 0
        for _ in range(episodes):
            env.reset(seed=int(rng.integers(2**31 - 1)))
            loss_sum, n_upd = 0.0, 0
            while not env.done:
                # act: per-agent epsilon-greedy on each position; the greedy answers from one batched pass
                t0 = time.perf_counter()
                tasks = env.tasks
                eps = [epsilon_by_run_fraction(steps + k, steps_total, cfg.eps_start, cfg.eps_end, cfg.eps_decay)
                       for k in range(len(tasks))]
                explorers, act = explore(rng, eps, acts.sizes)
                if not explorers.all():
                    act = np.where(explorers, act, greedy(q, acts, feats, tasks))
                t1 = time.perf_counter()
                max_u = env.step(act)["max_u"]
                t2 = time.perf_counter()

                # record: each position's scaled reward, its ln u into the replay
                log_us = []
                for t, u in zip(tasks, max_u):
                    r, log_u = scaled_reward(scale, float(u))
                    record.add(r, float(u), int(t))
                    log_us.append(log_u)
                replay.add_many(tasks, act, np.array(log_us))
                due = sum((s + 1) % cfg.update_every == 0 for s in range(steps, steps + len(tasks)))
                steps += len(tasks)

                # learn: regress Q_tot on the shared reward (one-step episodes: no bootstrap); one update
                # a step on the transitions of every update due in it (cfg.batch each)
                if len(replay) >= cfg.batch and due:
                    tasks_b, actions, log_ub = replay.sample(rng, cfg.batch * due)
                    loss = torch.mean((q_tot(q, acts, feats, tasks_b, actions) - scale.reward(log_ub)) ** 2)
                    opt.zero_grad(set_to_none=False)
                    loss.backward()
                    opt.step()
                    loss_sum += loss.item()
                    n_upd += 1
                    updates += 1
                tm.select += t1 - t0
                tm.oracle += t2 - t1
                tm.update += time.perf_counter() - t2
            episode_loss.append(loss_sum / n_upd if n_upd else None)

        # greedy policy on every task (training and held-out): no samples
        t3 = time.perf_counter()
        tasks = np.arange(problem.n_tasks)
        choice = np.vstack([greedy(q, acts, feats, tasks[i:i + cfg.greedy_chunk])
                            for i in range(0, len(tasks), cfg.greedy_chunk)])
        layouts = policy_layouts(problem, choice)
        tm.greedy = time.perf_counter() - t3
        return {"layouts": layouts, "record": record, "episode_loss": episode_loss, "updates": updates,
                "times": tm}
