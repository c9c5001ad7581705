"""Nash-Q multi-robot fixture planner (MRFP) and its independent-learner ablation, in PyTorch.

Read top to bottom (cleanrl style): hyper-parameters, the training loop on the env, the
greedy policy, the planner (``iql`` is the same planner without the joint inputs, a class of its own in
:mod:`fixbench.solvers.learners.iql`). The engine that makes it fast (batched Q-networks, fused optimiser,
compiled best response) lives beside it in :mod:`fixbench.solvers.learners.marl_engine`; what every learner
shares (the split, the budget as episodes, the replay, the step record, the ``info`` keys) in
:mod:`fixbench.solvers.learners.common`.

The game (docs/protocol.md#the-game): each step shows the agents one task (its feature vector); each agent
picks one candidate of its own set; the layout is evaluated once on the counted oracle (one sample
a position, through :class:`fixbench.cases.env.PositionBatchEnv`) and every agent gets the same reward. One
episode is one pass over the training tasks. ``positions_per_step`` = 1 (the default, the seed's protocol:
one position a step, one update a sample) or P: P positions a step, their best responses in one batched
pass, and one update a step on P minibatches' worth of transitions (docs/performance.md).
Defaults equal the seed's Table I: 100 episodes, epsilon
0.05 + 0.85 exp(-steps / 3500) over the whole run, one-step bandit target
(1 - alpha) Q_target(s, a) + alpha r with alpha = 0.8 (no bootstrap), AdamW lr 1e-4 amsgrad,
batch 32, replay capacity 1e6, Huber loss, gradient values clipped at 100, soft target update
tau = 0.005, MLP input -> 256 -> 256 -> 256 -> one Q per own action with ReLU, one network per agent.

A robot that places m pads (a pair end effector, m pads, or one that may idle: ``Effector``) has a
factored output instead of one Q per pad tuple: one head per pad over the robot's candidates (and
"no pad"), an action's Q the sum of its pads' outputs, trained on that sum; best response takes the
best sum over the robot's feasible tuples (exact, ``marl_engine._argmax_q``). Positions fed to a
joint learner are then every pad's (x, y): 2 m numbers per other agent.

``nashq`` (joint-action learner). Agent i's Q-network sees the task features AND the normalised
(x, y) positions (in the candidates' bounding box) of the candidates the other agents chose, in agent
order: input = F + 2 (N - 1) numbers. With one shared reward the game is a team game; the joint
action is a person-by-person optimum found by iterated best response (Gauss-Seidel: agents in
order, each taking the argmax of its own Q given the others' current choices, until a sweep changes
nothing, at most ``max_sweeps`` sweeps; the start is each agent's argmax with the others placed at
the centres of their sets; a cycle is recognised when a sweep ends where an earlier one did, and
the joint action after ``max_sweeps`` sweeps is read off it). Exploring agents (each with
probability epsilon, independently) play a uniform random action and the greedy agents
best-respond to them. Iterations and convergence are reported in ``info``.

``iql`` (the reference code's independent learners, :mod:`fixbench.solvers.learners.iql`): the same
networks over the task features only; each agent acts on its own argmax.

Budget: one sample per position answered. The run trains for ``episodes`` passes over the training tasks, or,
if the budget is smaller, for as many full episodes as fit (best effort; ``info["episodes_run"]``);
if not even one episode fits, :class:`PlannerError`. The returned layouts are the greedy policy's
(epsilon = 0, no samples) for every task, training tasks and held-out tasks alike. Scored as every
planner is (:mod:`fixbench.solvers.base`): by the best layout evaluated on each training task, the
policy as the second figure ``policy``; on held-out tasks (no samples) by the policy.

Regret (curves of the run's ``training``): ``episode_regret_ref`` is the reference's N T r* - N sum(step
rewards), with r* its stand-in for the optimal step reward,
:data:`fixbench.cases.rewards.REFERENCE_OPTIMAL_REWARD` (0.7854);
``episode_regret_true`` is sum over the episode's steps of (max_u - u*) in metres, with u* the
task's optimum from ``Config.optima`` when given, else the best max_u the run itself saw on the
task; ``episode_regret_reward`` is sum of (r* - r) with r* the best reward seen on the task.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.problem import Problem
from fixbench.cases.rewards import REFERENCE_OPTIMAL_REWARD, LogScale
from fixbench.solvers.base import Planner, PlannerError, TracedEvaluator, at_least, require
from fixbench.solvers.learners.common import (
    QLearnerConfig,
    Replay,
    StepRecord,
    Timings,
    episodes_that_fit,
    epsilon_by_step,
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
from fixbench.solvers.learners.marl_engine import Learner, Update
from fixbench.solvers.torch_run import torch_run

#: the learners' rewards (docs/protocol.md#reward-functions)
REWARDS = ("scaled", "gaussian", "bell")


# ---------------------------------------------------------------------------------------------
# hyper-parameters (and those every Q-learner has: fixbench.solvers.learners.common.QLearnerConfig)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NashQConfig(QLearnerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "lr": ("log", 1e-05, 0.001),
        "eps_decay": ("log", 100.0, 10000.0),
        "alpha": ("float", 0.3, 1.0),
        "hidden": ("choice", [64, 128, 256]),
        "batch": ("choice", [16, 32, 64]),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    hash_omits: ClassVar[dict[str, object]] = {"positions_per_step": 1}
    """One position a step is what every run made before the field existed did."""

    eps_decay: float = 3500.0
    """Epsilon decay in env steps, the same in a run of any length: epsilon = end + (start - end)
    exp(-steps / eps_decay), steps counted over the whole run (``learners.epsilon_by_step``)."""

    alpha: float = 0.8
    """Bandit learning rate: target = (1 - alpha) Q_target(s, a) + alpha r."""

    lr: float = 1e-4
    """AdamW learning rate (amsgrad)."""

    batch: int = 32
    """Replay minibatch per agent per step; updates start once the buffer holds this many."""

    hidden: int = 256
    """Width of the three hidden layers."""

    grad_clip: float = 100.0
    """Gradient values clipped to [-clip, clip]."""

    tau: float = 0.005
    """Soft target update: target <- tau policy + (1 - tau) target, after every update."""

    reward: str = "scaled"
    """Shared reward: 'scaled' (the standardised log deformation, scaled from the run's own first
    samples: no width set by hand; :class:`fixbench.cases.rewards.LogScale`), 'gaussian' (seed paper,
    the case's hand-set ``[reward]`` widths) or 'bell' (reference code)."""

    positions_per_step: int = 1
    """Positions acted on in one step (:class:`fixbench.cases.env.PositionBatchEnv`): the best responses of
    all of them in one batched pass, and one update on ``batch`` transitions a position of the step for
    every agent. 1: one position, one update a sample, the seed's protocol."""

    max_sweeps: int = 10
    """nashq: most Gauss-Seidel best-response sweeps per joint action."""

    optima: tuple[float, ...] = ()
    """Per-task optimal max deformation (m) for the true regret; empty: best seen in the run."""

    device: str = "cpu"
    """'cpu' or 'cuda' (only if available)."""

    save_path: str = ""
    """If set, torch.save(state_dict) of the trained Q-networks to this file."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "hidden", "batch", "positions_per_step", "max_sweeps")
        require(self, "lr", self.lr > 0, "positive")
        require(self, "eps_decay", self.eps_decay > 0, "positive")
        require(self, "alpha", 0 < self.alpha <= 1, "in (0, 1]")
        require(self, "grad_clip", self.grad_clip > 0, "positive")
        require(self, "tau", 0 < self.tau <= 1, "in (0, 1]")
        require(self, "reward", self.reward in REWARDS, f"one of {', '.join(REWARDS)}")
        require(self, "device", self.device in ("cpu", "cuda"), "'cpu' or 'cuda'")
        require(self, "optima", all(u > 0 for u in self.optima), "positive deformations (m)")


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class QPlanner(Planner):
    family = "marl"
    Config = NashQConfig
    modes = ("per-task",)
    joint = True
    returns_policy = True
    same_on_every_host = False

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        t_start = time.perf_counter()
        if cfg.device == "cuda" and not torch.cuda.is_available():  # the machine's, not the config's fault
            raise PlannerError(f"planner '{self.name}': device 'cuda' asked but CUDA is not available")
        if cfg.optima and len(cfg.optima) != problem.n_tasks:
            raise PlannerError(f"optima: {len(cfg.optima)} values for {problem.n_tasks} tasks")
        ids = train_split(problem, ev, cfg)
        n, n_train = problem.n_agents, len(ids)
        episodes = episodes_that_fit(self.name, cfg.episodes, ev, n_train)
        gen = torch_generator(rng)
        with torch_run(cfg.threads):
            run = self._train(problem, ev, rng, ids, episodes, torch.device(cfg.device), gen)
        record, ep_loss = run["record"], run["episode_loss"]
        sweeps_sum, conv_sum, br_calls = run["sweeps"]
        g_sweeps, g_conv = run["greedy"]

        # regrets: the reference code's, the true one (against the optima, else the best seen), the reward's
        rew_arr, u_arr, task_arr = record.arrays()
        best_u = np.full(problem.n_tasks, np.inf)
        best_r = np.full(problem.n_tasks, -np.inf)
        np.minimum.at(best_u, task_arr, u_arr)
        np.maximum.at(best_r, task_arr, rew_arr)
        u_star = np.asarray(cfg.optima, dtype=float) if cfg.optima else best_u
        own = {
            "regret_reference": "optima" if cfg.optima else "best seen in run",
            "best_seen_max_u": [float(x) if np.isfinite(x) else None for x in best_u],
            "br_sweeps_mean": sweeps_sum / br_calls if br_calls else 0.0,
            "br_converged_frac": conv_sum / br_calls if br_calls else 1.0,
            "greedy_sweeps": g_sweeps,
            "greedy_converged": bool(g_conv),
        }
        info = learner_info(self.name, cfg, problem, ids, episodes, record, own, run["times"], t_start)
        training = learner_training(record, run["episode_return"]).add(
            "episode",
            episode_regret_ref=[n * n_train * REFERENCE_OPTIMAL_REWARD - n * r for r in run["episode_return"]],
            episode_regret_true=per_episode(u_arr - u_star[task_arr], episodes),
            episode_regret_reward=per_episode(best_r[task_arr] - rew_arr, episodes),
            # cumulative seconds at the end of each episode (where a run slows down, and why)
            time_oracle_cum_s=[t[0] for t in run["episode_times"]],
            time_select_cum_s=[t[1] for t in run["episode_times"]],
            time_update_cum_s=[t[2] for t in run["episode_times"]],
            # each agent's TD loss, mean per episode
            **{f"td_loss/agent{i}": [ep[i] for ep in ep_loss] for i in range(n)})
        return run["layouts"], info, training

    def _train(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, ids: np.ndarray,
               episodes: int, device: torch.device, gen: torch.Generator) -> dict:
        """The training loop and the greedy policy (run under :func:`torch_run`)."""
        cfg, n = self.config, problem.n_agents
        # the scaled reward is the learner's own transform of the env's max_u (the env pays the Gaussian)
        scale = LogScale(cfg.scale_samples) if cfg.reward == "scaled" else None
        env, setup_s = training_env(problem, ev, ids, cfg.shuffle, per_step=cfg.positions_per_step)
        tm = Timings(setup=setup_s)
        L = Learner(problem, cfg.hidden, cfg.max_sweeps, self.joint, device, gen)
        opt = Update(L.q, L.target, cfg.lr, cfg.grad_clip, cfg.tau, device)
        replay = Replay(cfg.capacity, episodes * len(ids), n, device)  # the reward, or ln u for the scaled reward
        sizes = np.array(L.sizes)

        record, ep_return, ep_loss, ep_times = StepRecord(), [], [], []
        sweeps_sum, conv_sum, br_calls = 0, 0, 0
        steps = 0
        for _ in range(episodes):
            env.reset(seed=int(rng.integers(2**31 - 1)))
            loss_sum, n_upd, ret = torch.zeros(n, device=device), 0, 0.0
            while not env.done:
                # act: on each position, exploring agents play a random action, the others best-respond to them
                t0 = time.perf_counter()
                tasks = env.tasks
                eps = [epsilon_by_step(steps + k, cfg.eps_start, cfg.eps_end, cfg.eps_decay) for k in range(len(tasks))]
                explorers, act = explore(rng, eps, sizes)
                greedy_rows = ~explorers.all(axis=1)
                if greedy_rows.any():
                    a, sw, cv = L.greedy(tasks[greedy_rows], explorers[greedy_rows], act[greedy_rows])
                    act[greedy_rows] = a  # one Gauss-Seidel run over the step's positions together
                    sweeps_sum, conv_sum, br_calls = sweeps_sum + sw, conv_sum + cv, br_calls + 1
                t1 = time.perf_counter()
                out = env.step(act)
                t2 = time.perf_counter()

                # record: each position's reward (scaled from max_u, or the env's), into the replay
                stored = []
                for t, u, r in zip(tasks, out["max_u"], out[f"reward_{'gaussian' if scale else cfg.reward}"]):
                    r, s = (scaled_reward(scale, float(u)) if scale is not None else (float(r), float(r)))
                    record.add(r, float(u), int(t))
                    ret += r
                    stored.append(s)
                replay.add_many(tasks, act, np.array(stored))
                steps += len(tasks)

                # learn: every agent on its own minibatch, target (1 - alpha) Q_target + alpha r; one update a
                # step on the transitions of the step's positions (cfg.batch each)
                if len(replay) >= cfg.batch:
                    tasks_b, acts, stored_r = replay.sample(rng, (n, cfg.batch * len(tasks)))
                    batch_r = stored_r if scale is None else scale.reward(stored_r)
                    loss = L.td_grad(tasks_b, acts, batch_r, cfg.alpha)
                    opt.step()  # clip, AdamW, soft target update
                    loss_sum += loss
                    n_upd += 1
                tm.select += t1 - t0
                tm.oracle += t2 - t1
                tm.update += time.perf_counter() - t2
            ep_return.append(ret)  # summed in step order, as the reference code does
            ep_loss.append((loss_sum / max(n_upd, 1)).cpu().tolist())
            ep_times.append((tm.oracle, tm.select, tm.update))

        # greedy policy on every task (training and held-out): no samples
        t3 = time.perf_counter()
        actions, g_sweeps, g_conv = L.greedy(np.arange(problem.n_tasks))
        layouts = policy_layouts(problem, actions)
        tm.greedy = time.perf_counter() - t3
        if cfg.save_path:
            torch.save(L.q.state_dict(), cfg.save_path)
        return {"layouts": layouts, "record": record, "episode_return": ep_return, "episode_loss": ep_loss,
                "sweeps": (sweeps_sum, conv_sum, br_calls), "times": tm, "greedy": (g_sweeps, g_conv),
                "episode_times": ep_times}


class NashQ(QPlanner):
    name = "nashq"
    description = "Nash-Q MRFP: per-agent joint-action Q-networks, person-by-person equilibrium"
    joint = True
