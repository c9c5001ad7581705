"""Nash-Q multi-robot fixture planner (MRFP) and its independent-learner ablation, in PyTorch.

Read top to bottom (cleanrl style): hyper-parameters, the training loop on the PettingZoo env, the
greedy policy, the two planners. The engine that makes it fast (batched Q-networks, fused optimiser,
compiled best response) lives beside it in :mod:`fixbench.solvers.marl_engine`.

The game (docs/protocol.md#the-game): each step shows the agents one task (its feature vector); each agent
picks one candidate of its own set; the layout is evaluated once on the counted oracle (one sample
per step, through :class:`fixbench.cases.env.FixtureEnv`) and every agent gets the same reward. One episode is
one pass over the training tasks. Defaults equal the seed's Table I: 100 episodes, epsilon
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

``iql`` (the reference code's independent learners): the same networks over the task features
only; each agent acts on its own argmax.

Budget: one sample per env step. The run trains for ``episodes`` passes over the training tasks, or,
if the budget is smaller, for as many full episodes as fit (best effort; ``info["episodes_run"]``);
if not even one episode fits, :class:`PlannerError`. The returned layouts are the greedy policy's
(epsilon = 0, no samples) for every task, training tasks and held-out tasks alike. Scored as every
planner is (:mod:`fixbench.solvers.base`): by the best layout evaluated on each training task, the
policy as the second figure ``policy``; on held-out tasks (no samples) by the policy.

Regret (``info``): ``episode_regret_ref`` is the reference's N T r* - N sum(step rewards), with r* its
stand-in for the optimal step reward, :data:`fixbench.cases.rewards.REFERENCE_OPTIMAL_REWARD` (0.7854);
``episode_regret_true`` is sum over the episode's steps of (max_u - u*) in metres, with u* the
task's optimum from ``Config.optima`` when given, else the best max_u the run itself saw on the
task; ``episode_regret_reward`` is sum of (r* - r) with r* the best reward seen on the task.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.env import FixtureEnv
from fixbench.cases.problem import Problem
from fixbench.cases.rewards import REFERENCE_OPTIMAL_REWARD, LogScale
from fixbench.solvers.base import Planner, PlannerConfig, PlannerError, TracedEvaluator, at_least, require
from fixbench.solvers.marl_engine import Learner, Update
from fixbench.solvers.registry import register
from fixbench.solvers.torch_run import torch_run

#: the learners' rewards (docs/protocol.md#reward-functions)
REWARDS = ("scaled", "gaussian", "bell")


# ---------------------------------------------------------------------------------------------
# hyper-parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NashQConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "lr": ("log", 1e-05, 0.001),
        "eps_decay": ("log", 100.0, 10000.0),
        "alpha": ("float", 0.3, 1.0),
        "hidden": ("choice", [64, 128, 256]),
        "batch": ("choice", [16, 32, 64]),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    episodes: int = 100
    """Passes over the training tasks (seed Table I: 100)."""

    eps_start: float = 0.9
    """Initial exploration probability (per agent)."""

    eps_end: float = 0.05
    """Final exploration probability."""

    eps_decay: float = 3500.0
    """Epsilon = end + (start - end) exp(-steps / decay), steps counted over the whole run."""

    alpha: float = 0.8
    """Bandit learning rate: target = (1 - alpha) Q_target(s, a) + alpha r."""

    lr: float = 1e-4
    """AdamW learning rate (amsgrad)."""

    batch: int = 32
    """Replay minibatch per agent per step; updates start once the buffer holds this many."""

    capacity: int = 1_000_000
    """Replay capacity (transitions); never more is allocated than the run has steps."""

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

    scale_samples: int = 500
    """'scaled' reward: the first samples whose ln u give its mean and spread (then frozen)."""

    max_sweeps: int = 10
    """nashq: most Gauss-Seidel best-response sweeps per joint action."""

    shuffle: bool = False
    """Visit the training tasks in a new random order each episode (reference: in order)."""

    train_tasks: tuple[int, ...] = ()
    """Train only on these task indices (held-out tasks get the greedy policy, no samples)."""

    train_fraction: float = 1.0
    """If train_tasks is empty: train on this fraction of tasks, evenly spaced over the task list."""

    optima: tuple[float, ...] = ()
    """Per-task optimal max deformation (m) for the true regret; empty: best seen in the run."""

    device: str = "cpu"
    """'cpu' or 'cuda' (only if available)."""

    threads: int = 1
    """torch intra-op threads during the run (0: torch's setting). 1: tiny ops gain nothing from
    more, and spinning OpenMP threads on a shared, loaded machine slowed updates 40x (measured)."""

    save_path: str = ""
    """If set, torch.save(state_dict) of the trained Q-networks to this file."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check_learner(self)
        at_least(self, 1, "max_sweeps")
        require(self, "alpha", 0 < self.alpha <= 1, "in (0, 1]")
        require(self, "grad_clip", self.grad_clip > 0, "positive")
        require(self, "tau", 0 < self.tau <= 1, "in (0, 1]")
        require(self, "reward", self.reward in REWARDS, f"one of {', '.join(REWARDS)}")
        require(self, "device", self.device in ("cpu", "cuda"), "'cpu' or 'cuda'")
        require(self, "optima", all(u > 0 for u in self.optima), "positive deformations (m)")


def check_learner(cfg: PlannerConfig) -> None:
    """The checks of the fields nashq/iql and vdn share (same names, same meanings)."""
    at_least(cfg, 1, "episodes", "hidden", "batch", "capacity")
    at_least(cfg, 2, "scale_samples")
    at_least(cfg, 0, "threads")
    require(cfg, "lr", cfg.lr > 0, "positive")
    require(cfg, "eps_start", 0 <= cfg.eps_start <= 1, "in [0, 1]")
    require(cfg, "eps_end", 0 <= cfg.eps_end <= 1, "in [0, 1]")
    require(cfg, "eps_decay", cfg.eps_decay > 0, "positive")
    require(cfg, "train_tasks", all(t >= 0 for t in cfg.train_tasks), "task indices (0 or more)")
    require(cfg, "train_fraction", 0 < cfg.train_fraction <= 1, "in (0, 1]")


def train_ids(problem: Problem, cfg: NashQConfig) -> np.ndarray:
    """Training task indices from ``train_tasks`` or ``train_fraction`` (evenly spaced)."""
    t = problem.n_tasks
    if cfg.train_tasks:
        ids = np.unique(np.asarray(cfg.train_tasks, dtype=np.int64))
        if ids.max() >= t:
            raise PlannerError(f"train_tasks must be in 0..{t - 1}")
        return ids
    k = max(1, round(cfg.train_fraction * t))
    return np.unique(np.round(np.linspace(0, t - 1, k)).astype(np.int64))


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class _QPlanner(Planner):
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
        device = torch.device(cfg.device)
        # the held-out track restricts the evaluator to the training tasks; else the config chooses
        ids = ev.tasks.copy() if len(ev.tasks) < problem.n_tasks else train_ids(problem, cfg)
        n, n_train = problem.n_agents, len(ids)
        fit = cfg.episodes if math.isinf(ev.remaining) else int(ev.remaining // n_train)
        if fit < 1:
            raise PlannerError(f"planner '{self.name}': budget too small: one episode needs {n_train} "
                               f"samples, {int(ev.remaining)} available")
        episodes = min(cfg.episodes, fit)

        # seeding: everything random comes from rng (numpy) and a torch generator seeded from it (the
        # networks' initial weights); torch's global generator is neither seeded nor drawn from
        gen = torch.Generator().manual_seed(int(rng.integers(2**31 - 1)))
        with torch_run(cfg.threads):
            run = self._train(problem, ev, rng, ids, episodes, device, gen)
        layouts, (step_reward, step_u, step_task, ep_return, ep_loss) = run["layouts"], run["record"]
        sweeps_sum, conv_sum, br_calls = run["sweeps"]
        t_oracle, t_select, t_update, t_greedy = run["times"]
        g_sweeps, g_conv = run["greedy"]

        # training record -------------------------------------------------------------------------
        rew_arr, u_arr, task_arr = np.array(step_reward), np.array(step_u), np.array(step_task)
        best_u = np.full(problem.n_tasks, np.inf)
        best_r = np.full(problem.n_tasks, -np.inf)
        np.minimum.at(best_u, task_arr, u_arr)
        np.maximum.at(best_r, task_arr, rew_arr)
        u_star = np.asarray(cfg.optima, dtype=float) if cfg.optima else best_u
        per_ep = lambda x: x.reshape(episodes, n_train).sum(axis=1).tolist()  # noqa: E731
        info = {
            "algorithm": self.name,
            "episodes_run": episodes,
            "budget_limited": episodes < cfg.episodes,
            "train_tasks": ids.tolist(),
            "held_out_tasks": np.setdiff1d(np.arange(problem.n_tasks), ids).tolist(),
            "steps": len(step_reward),
            "step_reward": rew_arr.tolist(),
            "step_max_u": u_arr.tolist(),
            "step_task": task_arr.tolist(),
            "episode_return": ep_return,
            "episode_regret_ref": [n * n_train * REFERENCE_OPTIMAL_REWARD - n * r for r in ep_return],
            "episode_regret_true": per_ep(u_arr - u_star[task_arr]),
            "episode_regret_reward": per_ep(best_r[task_arr] - rew_arr),
            "regret_reference": "optima" if cfg.optima else "best seen in run",
            "best_seen_max_u": [float(x) if np.isfinite(x) else None for x in best_u],
            "td_loss": [[ep[i] for ep in ep_loss] for i in range(n)],  # per agent, mean per episode
            "br_sweeps_mean": sweeps_sum / br_calls if br_calls else 0.0,
            "br_converged_frac": conv_sum / br_calls if br_calls else 1.0,
            "greedy_sweeps": g_sweeps,
            "greedy_converged": bool(g_conv),
            "time_oracle_s": t_oracle,
            "time_select_s": t_select,
            "time_update_s": t_update,
            "time_greedy_s": t_greedy,
            "time_setup_s": run["setup"],  # oracle set-up before training (in no other timer)
            "time_total_s": time.perf_counter() - t_start,
            # cumulative seconds at the end of each episode (where a run slows down, and why)
            "time_oracle_cum_s": [t[0] for t in run["episode_times"]],
            "time_select_cum_s": [t[1] for t in run["episode_times"]],
            "time_update_cum_s": [t[2] for t in run["episode_times"]],
            "torch_threads": cfg.threads or torch.get_num_threads(),  # restored: the setting outside the run
        }
        return layouts, info


    def _train(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, ids: np.ndarray,
               episodes: int, device: torch.device, gen: torch.Generator) -> dict:
        """The training loop and the greedy policy (run under :func:`torch_run`)."""
        cfg, n = self.config, problem.n_agents
        steps_total = episodes * len(ids)
        t_setup = time.perf_counter()
        problem.oracle.prepare()  # set-up, not training: every column now (or from the disk cache), no samples
        t_setup = time.perf_counter() - t_setup
        L = Learner(problem, cfg.hidden, cfg.max_sweeps, self.joint, device, gen)
        opt = Update(L.q, L.target, cfg.lr, cfg.grad_clip, cfg.tau, device)
        # the scaled reward is the learner's own transform of the env's max_u (the env pays the Gaussian)
        scale = LogScale(cfg.scale_samples) if cfg.reward == "scaled" else None
        env = FixtureEnv(problem, reward="gaussian" if scale else cfg.reward, shuffle=cfg.shuffle,
                         task_ids=ids, evaluator=ev)
        agents = env.possible_agents

        cap = min(cfg.capacity, steps_total)
        buf_task = torch.zeros(cap, dtype=torch.long, device=device)
        buf_act = torch.zeros(cap, n, dtype=torch.long, device=device)
        buf_rew = torch.zeros(cap, dtype=torch.float32, device=device)
        sizes = np.array(L.sizes)

        step_reward, step_u, step_task = [], [], []
        ep_return, ep_loss, ep_times = [], [], []
        sweeps_sum, conv_sum, br_calls = 0, 0, 0
        t_oracle = t_select = t_update = 0.0
        steps = 0
        for _ in range(episodes):
            obs, _ = env.reset(seed=int(rng.integers(2**31 - 1)))
            loss_sum, n_upd, ret = torch.zeros(n, device=device), 0, 0.0
            while env.agents:
                t0 = time.perf_counter()
                task = env.task
                eps = cfg.eps_end + (cfg.eps_start - cfg.eps_end) * math.exp(-steps / cfg.eps_decay)
                explore = rng.random(n) < eps
                rand = (rng.random(n) * sizes).astype(np.int64)
                if explore.all():
                    act = rand
                else:
                    a, sw, cv = L.greedy(np.array([task]), explore[None], rand[None])
                    act = a[0]
                    sweeps_sum, conv_sum, br_calls = sweeps_sum + sw, conv_sum + cv, br_calls + 1
                t1 = time.perf_counter()
                _, rew, _, _, infos = env.step({ag: int(act[i]) for i, ag in enumerate(agents)})
                t2 = time.perf_counter()
                r = rew[agents[0]]
                info = infos[agents[0]]
                stored = r  # what the replay keeps: the reward, or ln u for the scaled reward
                if scale is not None:
                    stored = math.log(info["max_u"])
                    scale.add(stored)
                    r = float(scale.reward(stored))
                step_reward.append(r)
                step_u.append(info["max_u"])
                step_task.append(task)
                ret += r
                k = steps % cap
                buf_task[k] = task
                buf_act[k] = torch.from_numpy(act)
                buf_rew[k] = stored
                steps += 1
                size = min(steps, cap)
                if size >= cfg.batch:
                    idx = torch.from_numpy(rng.integers(0, size, (n, cfg.batch))).to(device)
                    batch_r = buf_rew[idx] if scale is None else scale.reward(buf_rew[idx])
                    loss = L.td_grad(buf_task[idx], buf_act[idx], batch_r, cfg.alpha)
                    opt.step()  # clip, AdamW, soft target update
                    loss_sum += loss
                    n_upd += 1
                t_select += t1 - t0
                t_oracle += t2 - t1
                t_update += time.perf_counter() - t2
            ep_return.append(ret)
            ep_loss.append((loss_sum / max(n_upd, 1)).cpu().tolist())
            ep_times.append((t_oracle, t_select, t_update))

        # greedy policy on every task (training and held-out): no samples
        t3 = time.perf_counter()
        actions, g_sweeps, g_conv = L.greedy(np.arange(problem.n_tasks))
        layouts = np.column_stack([problem.action_sets[i][actions[:, i]] for i in range(n)])
        t_greedy = time.perf_counter() - t3
        if cfg.save_path:
            torch.save(L.q.state_dict(), cfg.save_path)
        return {"layouts": layouts, "record": (step_reward, step_u, step_task, ep_return, ep_loss),
                "sweeps": (sweeps_sum, conv_sum, br_calls), "times": (t_oracle, t_select, t_update, t_greedy),
                "greedy": (g_sweeps, g_conv), "episode_times": ep_times, "setup": t_setup}


@register
class NashQ(_QPlanner):
    name = "nashq"
    description = "Nash-Q MRFP: per-agent joint-action Q-networks, person-by-person equilibrium"
    joint = True


@register
class IQL(_QPlanner):
    name = "iql"
    description = "independent Q-learners of the reference code (ablation of nashq)"
    joint = False
