"""Nash-Q multi-robot fixture planner (MRFP) and its independent-learner ablation, in PyTorch.

One file, read top to bottom (cleanrl style): hyper-parameters, the batched Q-networks, the
person-by-person equilibrium, the training loop on the PettingZoo env, the greedy policy.

The game (REFERENCE section 5): each step shows the agents one task (its feature vector); each agent
picks one candidate of its own set; the layout is evaluated once on the counted oracle (one sample
per step, through :class:`cases.env.FixtureEnv`) and every agent gets the same reward. One episode is
one pass over the training tasks. Defaults equal the seed's Table I: 100 episodes, epsilon
0.05 + 0.85 exp(-steps / 3500) over the whole run, one-step bandit target
(1 - alpha) Q_target(s, a) + alpha r with alpha = 0.8 (no bootstrap), AdamW lr 1e-4 amsgrad,
batch 32, replay capacity 1e6, Huber loss, gradient values clipped at 100, soft target update
tau = 0.005, MLP input -> 256 -> 256 -> 256 -> one Q per own action with ReLU, one network per agent.

``nashq`` (joint-action learner). Agent i's Q-network sees the task features AND the normalised
(x, y) positions (in the candidates' bounding box) of the candidates the other agents chose, in agent
order: input = F + 2 (N - 1) numbers. With one shared reward the game is a team game; the joint
action is a person-by-person optimum found by iterated best response (Gauss-Seidel: agents in
order, each taking the argmax of its own Q given the others' current choices, until a sweep changes
nothing, at most ``max_sweeps`` sweeps; the start is each agent's argmax with the others placed at
the centres of their sets). Exploring agents (each with probability epsilon, independently) play a
uniform random action and the greedy agents best-respond to them. Iterations and convergence are
reported in ``info``.

``iql`` (the reference code's independent learners): the same networks over the task features
only; each agent acts on its own argmax.

Budget: one sample per env step. The run trains for ``episodes`` passes over the training tasks, or,
if the budget is smaller, for as many full episodes as fit (best effort; ``info["episodes_run"]``);
if not even one episode fits, :class:`PlannerError`. The returned layouts are the greedy policy's
(epsilon = 0, no samples) for every task, training tasks and held-out tasks alike.

Regret (``info``): ``episode_regret_ref`` is the reference's N T 0.7854 - N sum(step rewards);
``episode_regret_true`` is sum over the episode's steps of (max_u - u*) in metres, with u* the
task's optimum from ``Config.optima`` when given, else the best max_u the run itself saw on the
task; ``episode_regret_reward`` is sum of (r* - r) with r* the best reward seen on the task.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cases.env import FixtureEnv
from cases.problem import Problem
from solvers.base import Planner, PlannerConfig, PlannerError, TracedEvaluator
from solvers.registry import register


# ---------------------------------------------------------------------------------------------
# hyper-parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NashQConfig(PlannerConfig):
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

    reward: str = "gaussian"
    """Shared reward: 'gaussian' (seed paper) or 'bell' (reference code)."""

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


# ---------------------------------------------------------------------------------------------
# the agents' Q-networks, batched: agent n's layer k is W[k][n] (in, out) and b[k][n] (1, out)
# ---------------------------------------------------------------------------------------------
class StackedQ(nn.Module):
    """N MLPs of the same shape in stacked tensors (one ``torch.baddbmm`` per layer for all agents).

    Output width is the largest action set; the padded actions of smaller sets are masked.
    Initialised as ``nn.Linear`` is (uniform +-1/sqrt(fan_in)) from ``generator``.
    """

    def __init__(self, n_agents: int, n_in: int, hidden: int, n_out: int,
                 generator: torch.Generator | None = None):
        super().__init__()
        dims = [n_in, hidden, hidden, hidden, n_out]
        self.shape = (n_agents, n_in, hidden, n_out)
        for k in range(4):
            bound = 1.0 / math.sqrt(dims[k])
            w = (torch.rand(n_agents, dims[k], dims[k + 1], generator=generator) * 2 - 1) * bound
            b = (torch.rand(n_agents, 1, dims[k + 1], generator=generator) * 2 - 1) * bound
            self.register_parameter(f"w{k}", nn.Parameter(w))
            self.register_parameter(f"b{k}", nn.Parameter(b))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, B, in) -> Q (N, B, out): every agent on its own batch."""
        h = torch.relu(torch.baddbmm(self.b0, x, self.w0))
        h = torch.relu(torch.baddbmm(self.b1, h, self.w1))
        h = torch.relu(torch.baddbmm(self.b2, h, self.w2))
        return torch.baddbmm(self.b3, h, self.w3)

    def chosen(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """Q of the chosen actions only: x (N, B, in), a (N, B) -> (N, B).

        Equal to ``forward(x).gather(2, a[..., None])`` but the output layer computes only the
        chosen columns (the output layer is most of the network's work on large action sets).
        """
        h = torch.relu(torch.baddbmm(self.b0, x, self.w0))
        h = torch.relu(torch.baddbmm(self.b1, h, self.w1))
        h = torch.relu(torch.baddbmm(self.b2, h, self.w2))
        w = self.w3.gather(2, a[:, None, :].expand(-1, self.w3.shape[1], -1))  # (N, H, B)
        return (h * w.transpose(1, 2)).sum(dim=2) + self.b3[:, 0].gather(1, a)

    def one(self, i: int, x: torch.Tensor) -> torch.Tensor:
        """x (B, in) -> Q (B, out) of agent i alone."""
        h = torch.relu(torch.addmm(self.b0[i], x, self.w0[i]))
        h = torch.relu(torch.addmm(self.b1[i], h, self.w1[i]))
        h = torch.relu(torch.addmm(self.b2[i], h, self.w2[i]))
        return torch.addmm(self.b3[i], h, self.w3[i])

    @classmethod
    def from_state_dict(cls, state: dict) -> StackedQ:
        """Rebuild from a saved state dict (``torch.load(path, weights_only=True)``)."""
        n, n_in, hidden = state["w0"].shape
        net = cls(n, n_in, hidden, state["w3"].shape[2])
        net.load_state_dict(state)
        return net


class Update:
    """clip_grad_value_, AdamW (amsgrad; torch's fused CPU kernel on CPU), soft target update."""

    def __init__(self, params, targets, lr, clip, tau, device):
        self.params, self.targets, self.clip, self.tau = list(params), list(targets), clip, tau
        kind = {"fused": True} if device.type == "cpu" else {"foreach": True}
        self.opt = torch.optim.AdamW(self.params, lr=lr, amsgrad=True, **kind)

    def zero_grad(self):
        self.opt.zero_grad(set_to_none=True)

    @torch.no_grad()
    def step(self):
        torch.nn.utils.clip_grad_value_(self.params, self.clip)
        self.opt.step()
        torch._foreach_lerp_(self.targets, self.params, self.tau)


def load_weights(path: str) -> StackedQ:
    """Trained Q-networks saved by ``Config.save_path`` (loaded with ``weights_only=True``)."""
    return StackedQ.from_state_dict(torch.load(path, weights_only=True, map_location="cpu"))


# ---------------------------------------------------------------------------------------------
# the learner (nashq when joint=True, iql when joint=False)
# ---------------------------------------------------------------------------------------------
class _Learner:
    """Networks, inputs and action choice of N agents on one problem."""

    def __init__(self, problem: Problem, cfg: NashQConfig, joint: bool, device: torch.device,
                 generator: torch.Generator):
        self.n = n = problem.n_agents
        self.max_sweeps = cfg.max_sweeps
        self.joint = joint and n > 1
        self.device = device
        sizes = [len(s) for s in problem.action_sets]
        self.sizes = sizes
        a_max = max(sizes)
        # state features min-max normalised over the problem's tasks (constant features -> 0.5)
        f = problem.features.astype(np.float64)
        lo, span = f.min(axis=0), np.ptp(f, axis=0)
        feats = np.where(span > 0, (f - lo) / np.where(span > 0, span, 1), 0.5)
        self.feats = torch.tensor(feats, dtype=torch.float32, device=device)  # (T, F)
        # candidate positions normalised to the candidates' bounding box, padded per agent
        c = problem.candidates
        cmin, cspan = c.min(axis=0), np.where(np.ptp(c, axis=0) > 0, np.ptp(c, axis=0), 1)
        pos = np.full((n, a_max, 2), 0.5)
        centre = np.zeros((n, 2))
        for i, s in enumerate(problem.action_sets):
            pos[i, :len(s)] = (c[s] - cmin) / cspan
            centre[i] = pos[i, :len(s)].mean(axis=0)
        self.pos = torch.tensor(pos, dtype=torch.float32, device=device)  # (N, A, 2)
        self.centre = torch.tensor(centre, dtype=torch.float32, device=device)  # (N, 2)
        self.others = torch.tensor([[j for j in range(n) if j != i] for i in range(n)],
                                   dtype=torch.long, device=device).reshape(n, max(n - 1, 0))
        mask = torch.zeros(n, a_max, device=device)
        for i, s in enumerate(sizes):
            mask[i, s:] = -torch.inf
        self.mask = mask
        n_in = feats.shape[1] + (2 * (n - 1) if self.joint else 0)
        self.q = StackedQ(n, n_in, cfg.hidden, a_max, generator).to(device)
        self.target = StackedQ(n, n_in, cfg.hidden, a_max).to(device)
        self.target.load_state_dict(self.q.state_dict())
        self.target.requires_grad_(False)
        self.agent_idx = torch.arange(n, device=device)

    # inputs -----------------------------------------------------------------------------------
    def inputs(self, states: torch.Tensor, joint_pos: torch.Tensor | None) -> torch.Tensor:
        """Inputs of every agent: states (N, B, F), joint_pos (N, B, N, 2) -> (N, B, in)."""
        if not self.joint:
            return states
        nb = joint_pos.shape[1]
        idx = self.others[:, None, :, None].expand(self.n, nb, self.n - 1, 2)
        oth = joint_pos.gather(2, idx).reshape(self.n, nb, 2 * (self.n - 1))
        return torch.cat([states, oth], dim=2)

    def joint_pos(self, actions: torch.Tensor) -> torch.Tensor:
        """Positions of a batch of joint actions: (..., N) -> (..., N, 2)."""
        return self.pos[self.agent_idx, actions]

    # action choice ----------------------------------------------------------------------------
    @torch.no_grad()
    def greedy(self, tasks: torch.Tensor, fixed: torch.Tensor | None = None,
               fixed_actions: torch.Tensor | None = None) -> tuple[torch.Tensor, int, bool]:
        """Greedy joint actions (B, N) for tasks (B,), keeping ``fixed`` agents' actions.

        iql: each agent's argmax. nashq: person-by-person equilibrium of the agents' Q-networks by
        Gauss-Seidel best response; returns (actions, sweeps, converged).
        """
        s = self.feats[tasks]  # (B, F)
        nb = len(tasks)
        if fixed is None:
            fixed = torch.zeros(nb, self.n, dtype=torch.bool, device=self.device)
            fixed_actions = torch.zeros(nb, self.n, dtype=torch.long, device=self.device)
        states = s.expand(self.n, nb, s.shape[1])
        if self.joint:  # start: others at their sets' centres (fixed agents where they are)
            jp = self.centre.expand(nb, self.n, 2).clone()
            jp[fixed] = self.joint_pos(fixed_actions)[fixed]
            jp = jp.expand(self.n, nb, self.n, 2)
        else:
            jp = None
        q = self.q(self.inputs(states, jp)) + self.mask[:, None, :]
        a = torch.where(fixed, fixed_actions, q.argmax(dim=2).T)
        if not self.joint:
            return a, 0, True
        free = (~fixed).any(dim=0).tolist()
        dirty = list(free)
        sweeps, converged = 0, False
        while sweeps < self.max_sweeps:
            sweeps += 1
            for i in range(self.n):
                if not dirty[i]:
                    continue
                dirty[i] = False
                oth = self.joint_pos(a)[:, self.others[i]].reshape(nb, -1)
                qi = self.q.one(i, torch.cat([s, oth], dim=1)) + self.mask[i]
                new = torch.where(fixed[:, i], a[:, i], qi.argmax(dim=1))
                if bool((new != a[:, i]).any()):
                    a[:, i] = new
                    for j in range(self.n):
                        dirty[j] = free[j] and j != i or dirty[j]
            if not any(dirty):
                converged = True
                break
        return a, sweeps, converged

    # learning ---------------------------------------------------------------------------------
    def loss(self, tasks: torch.Tensor, actions: torch.Tensor, rewards: torch.Tensor,
             alpha: float) -> torch.Tensor:
        """Huber loss per agent (N,) on replay samples: tasks (N, B), actions (N, B, N), rewards (N, B)."""
        states = self.feats[tasks]
        x = self.inputs(states, self.joint_pos(actions) if self.joint else None)
        own = actions.gather(2, self.agent_idx[:, None, None].expand(self.n, actions.shape[1], 1))[..., 0]
        q = self.q.chosen(x, own)
        with torch.no_grad():
            target = (1 - alpha) * self.target.chosen(x, own) + alpha * rewards
        return F.smooth_l1_loss(q, target, reduction="none").mean(dim=1)


def train_ids(problem: Problem, cfg: NashQConfig) -> np.ndarray:
    """Training task indices from ``train_tasks`` or ``train_fraction`` (evenly spaced)."""
    t = problem.n_tasks
    if cfg.train_tasks:
        ids = np.unique(np.asarray(cfg.train_tasks, dtype=np.int64))
        if ids.min() < 0 or ids.max() >= t:
            raise PlannerError(f"train_tasks must be in 0..{t - 1}")
        return ids
    if not 0 < cfg.train_fraction <= 1:
        raise PlannerError(f"train_fraction must be in (0, 1], got {cfg.train_fraction}")
    k = max(1, round(cfg.train_fraction * t))
    return np.unique(np.round(np.linspace(0, t - 1, k)).astype(np.int64))


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class _QPlanner(Planner):
    Config = NashQConfig
    modes = ("per-task",)
    joint = True

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        t_start = time.perf_counter()
        if cfg.reward not in ("gaussian", "bell"):
            raise PlannerError(f"planner '{self.name}': reward must be 'gaussian' or 'bell'")
        if cfg.device == "cuda" and not torch.cuda.is_available():
            raise PlannerError(f"planner '{self.name}': device 'cuda' asked but CUDA is not available")
        if cfg.device not in ("cpu", "cuda"):
            raise PlannerError(f"planner '{self.name}': device must be 'cpu' or 'cuda', got '{cfg.device}'")
        if cfg.optima and len(cfg.optima) != problem.n_tasks:
            raise PlannerError(f"optima: {len(cfg.optima)} values for {problem.n_tasks} tasks")
        device = torch.device(cfg.device)
        ids = train_ids(problem, cfg)
        n, n_train = problem.n_agents, len(ids)
        fit = cfg.episodes if math.isinf(ev.remaining) else int(ev.remaining // n_train)
        if fit < 1:
            raise PlannerError(f"planner '{self.name}': budget too small: one episode needs {n_train} "
                               f"samples, {int(ev.remaining)} available")
        episodes = min(cfg.episodes, fit)
        steps_total = episodes * n_train

        # seeding: everything random comes from rng (numpy) and a torch generator seeded from it
        seed = int(rng.integers(2**31 - 1))
        torch.manual_seed(seed)
        gen = torch.Generator().manual_seed(seed)
        threads, numba_threads = torch.get_num_threads(), numba.get_num_threads()
        det = torch.are_deterministic_algorithms_enabled()
        torch.use_deterministic_algorithms(True, warn_only=True)
        if cfg.threads:
            torch.set_num_threads(cfg.threads)
        numba.set_num_threads(1)  # one layout per step: the oracle's threads would only spin beside torch's
        try:
            L = _Learner(problem, cfg, self.joint, device, gen)
            opt = Update(L.q.parameters(), L.target.parameters(), cfg.lr, cfg.grad_clip, cfg.tau, device)
            env = FixtureEnv(problem, reward=cfg.reward, shuffle=cfg.shuffle, task_ids=ids, evaluator=ev)
            agents = env.possible_agents

            cap = min(cfg.capacity, steps_total)
            buf_task = torch.zeros(cap, dtype=torch.long, device=device)
            buf_act = torch.zeros(cap, n, dtype=torch.long, device=device)
            buf_rew = torch.zeros(cap, dtype=torch.float32, device=device)
            sizes = np.array(L.sizes)

            step_reward, step_u, step_task = [], [], []
            ep_return, ep_loss = [], []
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
                        a, sw, cv = L.greedy(torch.tensor([task], device=device),
                                             torch.from_numpy(explore)[None].to(device),
                                             torch.from_numpy(rand)[None].to(device))
                        act = a[0].cpu().numpy()
                        sweeps_sum, conv_sum, br_calls = sweeps_sum + sw, conv_sum + cv, br_calls + 1
                    t1 = time.perf_counter()
                    _, rew, _, _, infos = env.step({ag: int(act[i]) for i, ag in enumerate(agents)})
                    t2 = time.perf_counter()
                    r = rew[agents[0]]
                    info = infos[agents[0]]
                    step_reward.append(r)
                    step_u.append(info["max_u"])
                    step_task.append(task)
                    ret += r
                    k = steps % cap
                    buf_task[k] = task
                    buf_act[k] = torch.from_numpy(act)
                    buf_rew[k] = r
                    steps += 1
                    size = min(steps, cap)
                    if size >= cfg.batch:
                        idx = torch.from_numpy(rng.integers(0, size, (n, cfg.batch))).to(device)
                        loss = L.loss(buf_task[idx], buf_act[idx], buf_rew[idx], cfg.alpha)
                        opt.zero_grad()
                        loss.sum().backward()
                        opt.step()  # clip, AdamW, soft target update
                        loss_sum += loss.detach()
                        n_upd += 1
                    t_select += t1 - t0
                    t_oracle += t2 - t1
                    t_update += time.perf_counter() - t2
                ep_return.append(ret)
                ep_loss.append((loss_sum / max(n_upd, 1)).cpu().tolist())

            # greedy policy on every task (training and held-out): no samples
            t3 = time.perf_counter()
            a, g_sweeps, g_conv = L.greedy(torch.arange(problem.n_tasks, device=device))
            actions = a.cpu().numpy()
            layouts = np.column_stack([problem.action_sets[i][actions[:, i]] for i in range(n)])
            t_greedy = time.perf_counter() - t3
            if cfg.save_path:
                torch.save(L.q.state_dict(), cfg.save_path)
        finally:
            torch.set_num_threads(threads)
            numba.set_num_threads(numba_threads)
            torch.use_deterministic_algorithms(det)

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
            "steps": steps,
            "step_reward": rew_arr.tolist(),
            "step_max_u": u_arr.tolist(),
            "step_task": task_arr.tolist(),
            "episode_return": ep_return,
            "episode_regret_ref": [n * n_train * 0.7854 - n * r for r in ep_return],
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
            "time_total_s": time.perf_counter() - t_start,
            "torch_threads": cfg.threads or threads,
        }
        return layouts, info


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
