"""The performance engine of :mod:`fixbench.solvers.learners.nashq`: batched Q-networks, a fused optimiser
and compiled best-response kernels. The algorithm (hyper-parameters, training loop, greedy policy)
reads top to bottom in ``solvers/learners/nashq.py``; this module only makes it fast, with every shortcut
tested against the plain computation it replaces (``tests/test_nashq.py``).

Speed (``python -m studies.marl speed``; times per phase in the planner's ``info``): the N
networks are one batched module with all weights in one flat vector; the update computes only the
chosen actions' outputs, back-propagates by hand into a persistent gradient buffer (tested against
autograd) and runs clip + AdamW + soft target update as one fused numba pass (tested against torch's
AdamW); best response is one compiled (numba) call per step on zero-copy views of the same weights.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from fixbench.cases.problem import Problem
from fixbench.solvers.encoding import pad_coordinates, robot_centres, task_features


# ---------------------------------------------------------------------------------------------
# the agents' Q-networks, batched: agent n's layer k is w[k][n] (in, out) and b[k][n] (1, out)
# ---------------------------------------------------------------------------------------------
class StackedQ(nn.Module):
    """N MLPs of the same shape, all weights in one flat parameter (one batched matmul per layer
    for all agents; one clip, one fused AdamW step and one target lerp per update for all of them).

    Output width is the largest action set (one head of the largest candidate set per pad when a
    robot places several: :func:`_heads`); padded outputs are never chosen.
    Initialised as ``nn.Linear`` is (uniform +-1/sqrt(fan_in)) from ``generator``, never from torch's
    global generator; without one the weights are zeros, for a network whose weights are loaded next
    (the target network, a saved network). Training uses
    :meth:`chosen` and :meth:`backward` (hand-written backprop into a persistent gradient buffer, checked
    against autograd by a test): autograd's gather backward allocates and zero-fills a fresh
    (N, hidden, actions) gradient every update, which cost more than the layer's arithmetic.
    """

    def __init__(self, n_agents: int, n_in: int, hidden: int, n_out: int,
                 generator: torch.Generator | None = None):
        super().__init__()
        dims = [n_in, hidden, hidden, hidden, n_out]
        self.shapes = []
        for k in range(4):
            self.shapes += [(n_agents, dims[k], dims[k + 1]), (n_agents, 1, dims[k + 1])]
        self.register_buffer("dims", torch.tensor([n_agents, n_in, hidden, n_out]))
        self.flat = nn.Parameter(torch.zeros(sum(math.prod(s) for s in self.shapes)))
        if generator is None:
            return
        with torch.no_grad():
            for k, v in enumerate(self._views(self.flat)):
                bound = 1.0 / math.sqrt(dims[k // 2])
                v.copy_((torch.rand(v.shape, generator=generator) * 2 - 1) * bound)

    def _views(self, flat: torch.Tensor) -> list[torch.Tensor]:
        out, off = [], 0
        for s in self.shapes:
            size = math.prod(s)
            out.append(flat[off:off + size].view(s))
            off += size
        return out

    def weights(self) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """([w0..w3], [b0..b3]) as views of the flat parameter (no autograd)."""
        v = self._views(self.flat.detach())
        return v[0::2], v[1::2]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, B, in) -> Q (N, B, out): every agent on its own batch."""
        w, b = self.weights()
        h = torch.relu(torch.baddbmm(b[0], x, w[0]))
        h = torch.relu(torch.baddbmm(b[1], h, w[1]))
        h = torch.relu(torch.baddbmm(b[2], h, w[2]))
        return torch.baddbmm(b[3], h, w[3])

    def chosen(self, x: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, tuple]:
        """Q of the chosen actions only: x (N, B, in), a (N, B) -> (N, B), and what :meth:`backward` needs.

        Equal to ``forward(x).gather(2, a[..., None])``; the output layer computes only the chosen
        columns (it is most of the network's work on large action sets). Factored (a robot places m
        pads): ``a`` (N, B, m) names one output column per pad and the Q is their sum,
        ``forward(x).gather(2, a).sum(2)``.
        """
        w, b = self.weights()
        h0 = torch.bmm(x, w[0]).add_(b[0]).relu_()
        h1 = torch.bmm(h0, w[1]).add_(b[1]).relu_()
        h2 = torch.bmm(h1, w[2]).add_(b[2]).relu_()
        if a.dim() == 3:  # factored: the sum of one output per pad, a (N, B, m) output columns
            nb, m = a.shape[1], a.shape[2]
            flat = a.reshape(a.shape[0], nb * m)
            w3a = w[3].gather(2, flat[:, None, :].expand(-1, w[3].shape[1], -1)).transpose(1, 2)
            w3a = w3a.reshape(a.shape[0], nb, m, -1)  # (N, B, m, H)
            q = (h2[:, :, None, :] * w3a).sum(dim=3).sum(dim=2) + b[3][:, 0].gather(1, flat).reshape(-1, nb, m).sum(2)
            return q, (x, a, h0, h1, h2, w3a)
        w3a = w[3].gather(2, a[:, None, :].expand(-1, w[3].shape[1], -1)).transpose(1, 2)  # (N, B, H)
        q = (h2 * w3a).sum(dim=2) + b[3][:, 0].gather(1, a)
        return q, (x, a, h0, h1, h2, w3a)

    def backward(self, gq: torch.Tensor, saved: tuple) -> None:
        """Write d(loss)/d(weights) into ``flat.grad`` given gq = d(loss)/d(chosen Q) (N, B)."""
        x, a, h0, h1, h2, w3a = saved
        if self.flat.grad is None:
            self.flat.grad = torch.zeros_like(self.flat)
        w, _ = self.weights()
        gv = self._views(self.flat.grad)
        gw, gb = gv[0::2], gv[1::2]
        gw[3].zero_()
        gb[3].zero_()
        relu_backward = torch.ops.aten.threshold_backward  # what autograd runs for relu: grad where h > 0
        if a.dim() == 3:  # factored: every pad's output gets the sum's gradient
            n, nb, m = a.shape
            flat = a.reshape(n, nb * m)
            g2 = (h2 * gq[..., None])[:, :, None, :].expand(n, nb, m, -1).reshape(n, nb * m, -1)
            gw[3].scatter_add_(2, flat[:, None, :].expand(-1, h2.shape[2], -1), g2.transpose(1, 2))
            gb[3][:, 0].scatter_add_(1, flat, gq[:, :, None].expand(n, nb, m).reshape(n, nb * m))
            dz = relu_backward(w3a.sum(dim=2) * gq[..., None], h2, 0.0)
        else:
            col = a[:, None, :].expand(-1, h2.shape[2], -1)
            gw[3].scatter_add_(2, col, (h2 * gq[..., None]).transpose(1, 2))
            gb[3][:, 0].scatter_add_(1, a, gq)
            dz = relu_backward(w3a.contiguous() * gq[..., None], h2, 0.0)  # contiguous: 6x faster product
        for k, h_in in ((2, h1), (1, h0), (0, x)):
            torch.bmm(h_in.transpose(1, 2), dz, out=gw[k])
            torch.sum(dz, dim=1, keepdim=True, out=gb[k])
            if k:
                dz = relu_backward(torch.bmm(dz, w[k].transpose(1, 2)), h_in, 0.0)

    @classmethod
    def from_state_dict(cls, state: dict) -> StackedQ:
        """Rebuild from a saved state dict (``torch.load(path, weights_only=True)``)."""
        net = cls(*(int(d) for d in state["dims"]))
        net.load_state_dict(state)
        return net


@numba.njit(parallel=True, cache=True)
def _adamw_step(p, g, m, v, vmax, target, lr, weight_decay, beta1, beta2, eps, step, clip, tau):
    """Gradient-value clip, AdamW (amsgrad) and soft target update in one pass over the weights.

    The arithmetic of ``torch.optim.AdamW(amsgrad=True)`` (decoupled weight decay, bias-corrected
    moments, the running max of the second moment) followed by ``target.lerp_(p, tau)``; moments
    below the smallest normal float are set to zero, as a CPU's flush-to-zero mode would.
    """
    f32 = np.float32  # all arithmetic in float32, as torch's kernels do (and it vectorises twice as wide)
    bc2_sqrt = f32(np.sqrt(1.0 - beta2 ** step))
    step_size = f32(lr / (1.0 - beta1 ** step))
    decay, b2 = f32(1.0 - lr * weight_decay), f32(beta2)
    one_b1, one_b2, eps, clip, tau = f32(1.0 - beta1), f32(1.0 - beta2), f32(eps), f32(clip), f32(tau)
    tiny, zero = np.finfo(np.float32).tiny, f32(0.0)
    for i in numba.prange(p.size):
        gi = min(max(g[i], -clip), clip)
        mi = m[i] + one_b1 * (gi - m[i])
        vi = b2 * v[i] + one_b2 * gi * gi
        mi = mi if abs(mi) >= tiny else zero
        vi = vi if vi >= tiny else zero
        vmx = max(vmax[i], vi)
        pi = p[i] * decay - step_size * mi / (np.sqrt(vmx) / bc2_sqrt + eps)
        m[i], v[i], vmax[i], p[i] = mi, vi, vmx, pi
        target[i] += tau * (pi - target[i])


class Update:
    """One training update of all agents: clip gradient values, AdamW (amsgrad), soft target update.

    On CPU one fused numba pass over the flat weights (:func:`_adamw_step`, tested equal to
    ``clip_grad_value_`` + ``torch.optim.AdamW(amsgrad=True)`` + ``lerp_``). Why not torch's own fused
    AdamW: the moments of weights without gradient (unchosen actions, inactive units) decay by beta1 per
    update into denormal floats, on which arithmetic is 10-100x slower, and torch can flush denormals only
    in the calling thread, not in its worker threads (measured on the full protocol: torch's AdamW took
    1.7 ms per update instead of 0.7 ms); and one pass instead of three (clip, AdamW, lerp) saves memory
    traffic. On CUDA: torch's AdamW (foreach) and lerp.
    """

    def __init__(self, q: StackedQ, target: StackedQ, lr: float, clip: float, tau: float, device: torch.device,
                 weight_decay: float = 0.01, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8,
                 fused: bool | None = None):
        """``fused``: the numba pass (None: on CPU only); False: torch's AdamW and lerp, what runs on a
        GPU (a test runs that path on the CPU against the fused one)."""
        self.q, self.target, self.lr, self.clip, self.tau = q, target, lr, clip, tau
        self.weight_decay, self.betas, self.eps = weight_decay, betas, eps
        self.cpu = device.type == "cpu" if fused is None else fused
        if self.cpu and device.type != "cpu":
            raise ValueError("the fused update runs on the CPU only")
        self.steps = 0
        if self.cpu:
            self.state = [torch.zeros_like(q.flat) for _ in range(3)]  # m, v, max v
        else:
            self.opt = torch.optim.AdamW([q.flat], lr=lr, betas=betas, eps=eps, weight_decay=weight_decay,
                                         amsgrad=True, foreach=True)

    @torch.no_grad()
    def step(self):
        self.steps += 1
        if not self.cpu:
            self.q.flat.grad.clamp_(-self.clip, self.clip)
            self.opt.step()
            self.target.flat.lerp_(self.q.flat, self.tau)
            return
        m, v, vmax = (t.numpy() for t in self.state)
        oracle_threads = numba.get_num_threads()
        numba.set_num_threads(min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
        _adamw_step(self.q.flat.detach().numpy(), self.q.flat.grad.numpy(), m, v, vmax,
                    self.target.flat.detach().numpy(), self.lr, self.weight_decay, self.betas[0], self.betas[1],
                    self.eps, self.steps, self.clip, self.tau)
        numba.set_num_threads(oracle_threads)


def load_weights(path: str) -> StackedQ:
    """Trained Q-networks saved by the learner's ``save_path`` (loaded with ``weights_only=True``)."""
    return StackedQ.from_state_dict(torch.load(path, weights_only=True, map_location="cpu"))


# ---------------------------------------------------------------------------------------------
# best response on the host: one agent's Q for one input row, and the Gauss-Seidel iteration
# ---------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _dense(x, w, b, relu):
    """x (in,) @ w (in, out) + b (1, out), optionally ReLU; skips zero inputs (half of them after a ReLU)."""
    h = b[0].copy()
    for k in range(w.shape[0]):
        xk = x[k]
        if xk != 0.0:
            for j in range(w.shape[1]):
                h[j] += xk * w[k, j]
    if relu:
        for j in range(h.size):
            h[j] = max(h[j], np.float32(0.0))
    return h


@numba.njit(cache=True)
def _q_row(ws, i, x):
    """Agent i's network outputs for one input row; ws = (w0, w1, w2, w3, b0, b1, b2, b3)."""
    h = _dense(x, ws[0][i], ws[4][i], True)
    h = _dense(h, ws[1][i], ws[5][i], True)
    h = _dense(h, ws[2][i], ws[6][i], True)
    return _dense(h, ws[3][i], ws[7][i], False)


@numba.njit(cache=True)
def _argmax_q(ws, cols, n_opts, i, s_r, jp_r, others, joint, x):
    """Agent i's best action for one state: s_r (F,) task features, jp_r (N, D) every agent's
    position (a joint learner sees the others', in agent order); x is scratch for the input row.
    An action's Q is the sum of its pads' outputs (``cols``: one output column per pad), so the
    best over all of the robot's pad tuples is exact; the first of equal ones."""
    nf, d = s_r.size, jp_r.shape[1]
    x[:nf] = s_r
    if joint:
        for jj in range(others.shape[1]):
            x[nf + d * jj:nf + d * jj + d] = jp_r[others[i, jj]]
    q = _q_row(ws, i, x)
    best, arg = -np.inf, 0
    for o in range(n_opts[i]):
        v = q[cols[i, o, 0]]
        for k in range(1, cols.shape[2]):
            v += q[cols[i, o, k]]
        if v > best:
            best, arg = v, o
    return arg


@numba.njit(cache=True)
def _best_response(ws, cols, n_opts, s, pos, centre, others, fixed, fixed_actions, max_sweeps, joint):
    """Greedy joint actions of a batch of states; see ``Learner.greedy`` and :mod:`fixbench.solvers.learners.nashq`.

    Start: every free agent's argmax with the others at their sets' centres (fixed agents where they
    are). Then Gauss-Seidel sweeps (joint learners only): each agent that needs a turn takes its argmax
    given the others' current actions; when its action changes in any row, every other free agent needs
    a turn again; converged when a sweep ends with no agent needing one. Best response is deterministic,
    so when the state at the end of a sweep (actions, agents needing a turn) repeats an earlier one the
    rest is a cycle, and the actions after ``max_sweeps`` sweeps are read off it. Returns
    (actions (B, N), sweeps computed, converged).

    The descent is :func:`fixbench.solvers.descent.descend` (``ties="first"``, ``stop="others"``,
    ``cycles=True``), compiled: ``tests/test_descent.py`` checks this kernel against it to the bit (per
    state; in a batch the agents needing a turn are pooled over the states: the same actions).
    """
    nb, n = fixed.shape
    d = pos.shape[2]
    x = np.empty(s.shape[1] + (d * (n - 1) if joint else 0), dtype=np.float32)
    a = fixed_actions.copy()
    jp = np.empty((nb, n, d), dtype=np.float32)  # positions the agents see: start at the centres
    free = np.zeros(n, dtype=np.bool_)
    for r in range(nb):
        for j in range(n):
            jp[r, j] = pos[j, a[r, j]] if fixed[r, j] else centre[j]
            free[j] |= not fixed[r, j]
    start = a.copy()
    for i in range(n):
        for r in range(nb):
            if not fixed[r, i]:
                start[r, i] = _argmax_q(ws, cols, n_opts, i, s[r], jp[r], others, joint, x)
    a = start
    if not joint:
        return a, 0, True
    for r in range(nb):
        for j in range(n):
            jp[r, j] = pos[j, a[r, j]]
    dirty = free.copy()
    hist_a = np.empty((max_sweeps + 1, nb, n), dtype=np.int64)
    hist_d = np.empty((max_sweeps + 1, n), dtype=np.bool_)
    hist_a[0], hist_d[0] = a, dirty
    for sweep in range(1, max_sweeps + 1):
        for i in range(n):
            if not dirty[i]:
                continue
            dirty[i] = False
            changed = False
            for r in range(nb):
                if fixed[r, i]:
                    continue
                new = _argmax_q(ws, cols, n_opts, i, s[r], jp[r], others, joint, x)
                if new != a[r, i]:
                    a[r, i], jp[r, i] = new, pos[i, new]
                    changed = True
            if changed:
                for j in range(n):
                    dirty[j] = free[j] and j != i
        if not dirty.any():
            return a, sweep, True
        for k in range(sweep):
            if (hist_a[k] == a).all() and (hist_d[k] == dirty).all():  # a cycle of period sweep - k
                return hist_a[k + (max_sweeps - k) % (sweep - k)].copy(), sweep, False
        hist_a[sweep], hist_d[sweep] = a, dirty
    return a, max_sweeps, False


def _heads(problem: Problem) -> tuple[list[np.ndarray], int, int]:
    """Output columns of every action's pads, per agent ((actions, m) each), the width of one head
    and the number of heads m. One pad a robot: one column per action (the identity). Else head k
    holds one output per candidate of the robot's set, and one more for "no pad" when it may idle."""
    eff = problem.spec.effector
    if eff.simple:
        return [np.arange(len(s))[:, None] for s in problem.action_sets], max(map(len, problem.action_sets)), 1
    width = max(len(s) for s in problem.candidate_sets) + (1 if eff.idle else 0)
    cols = []
    for s, acts in zip(problem.candidate_sets, problem.action_sets):
        where = np.full(len(problem.candidates), -1, dtype=np.int64)
        where[s] = np.arange(len(s))
        opt = problem.options[acts]
        cols.append(np.where(opt >= 0, where[np.maximum(opt, 0)], width - 1))
    return cols, width, eff.per_agent


# ---------------------------------------------------------------------------------------------
# the learner (nashq when joint=True, iql when joint=False)
# ---------------------------------------------------------------------------------------------
class Learner:
    """Networks, inputs and action choice of N agents on one problem: ``hidden`` units in each of
    the three hidden layers, at most ``max_sweeps`` best-response sweeps per greedy choice."""

    def __init__(self, problem: Problem, hidden: int, max_sweeps: int, joint: bool, device: torch.device,
                 generator: torch.Generator):
        self.n = n = problem.n_agents
        self.max_sweeps = max_sweeps
        self.joint = joint and n > 1
        self.device = device
        sizes = [len(s) for s in problem.action_sets]
        self.sizes = sizes
        # outputs: one head per pad over the robot's candidates (and "no pad" when it may idle); an
        # action's Q is the sum of its pads' outputs (one pad a robot: one output per candidate)
        cols, width, m = _heads(problem)
        self.factored = not problem.spec.effector.simple
        opt_max = max(sizes)
        cols_pad = np.zeros((n, opt_max, m), dtype=np.int64)
        for i, c in enumerate(cols):
            cols_pad[i, :len(c)] = c + width * np.arange(m)  # head k's columns start at k * width
        feats = task_features(problem, "min-max")  # state features, [0, 1] over the problem's tasks
        self.feats = torch.tensor(feats, dtype=torch.float32, device=device)  # (T, F)
        # action positions (its pads' (x, y)) in [0, 1] of the candidates' bounding box, padded per agent;
        # no "placed" flags: the others' positions are the only action inputs (the module docstring of
        # fixbench.solvers.encoding says why)
        options_pos = pad_coordinates(problem, interval=(0.0, 1.0))
        d = options_pos.shape[1]
        pos = np.full((n, opt_max, d), 0.5)
        for i, s in enumerate(problem.action_sets):
            pos[i, :len(s)] = options_pos[s]
        centre = robot_centres(problem, options_pos)  # where a robot not chosen yet sits
        self.pos = torch.tensor(pos, dtype=torch.float32, device=device)  # (N, A, D)
        self.others = torch.tensor([[j for j in range(n) if j != i] for i in range(n)],
                                   dtype=torch.long, device=device).reshape(n, max(n - 1, 0))
        n_in = feats.shape[1] + (d * (n - 1) if self.joint else 0)
        self.q = StackedQ(n, n_in, hidden, m * width, generator).to(device)
        self.target = StackedQ(n, n_in, hidden, m * width).to(device)  # zeros, then the policy's weights
        self.target.load_state_dict(self.q.state_dict())
        self.target.requires_grad_(False)
        self.agent_idx = torch.arange(n, device=device)
        self.cols = torch.tensor(cols_pad, device=device)  # (N, A, m) output columns of each action's pads
        # host arrays for action choice
        self.feats_np, self.pos_np, self.centre_np = (feats.astype(np.float32), pos.astype(np.float32),
                                                      centre.astype(np.float32))
        self.others_np = self.others.cpu().numpy()
        self.cols_np, self.n_opts = cols_pad, np.array(sizes, dtype=np.int64)

    # inputs -----------------------------------------------------------------------------------
    def inputs(self, states: torch.Tensor, joint_pos: torch.Tensor | None) -> torch.Tensor:
        """Inputs of every agent: states (N, B, F), joint_pos (N, B, N, D) -> (N, B, in)."""
        if not self.joint:
            return states
        nb, d = joint_pos.shape[1], joint_pos.shape[3]
        idx = self.others[:, None, :, None].expand(self.n, nb, self.n - 1, d)
        oth = joint_pos.gather(2, idx).reshape(self.n, nb, d * (self.n - 1))
        return torch.cat([states, oth], dim=2)

    def joint_pos(self, actions: torch.Tensor) -> torch.Tensor:
        """Positions of a batch of joint actions: (..., N) -> (..., N, D) (D = 2 per pad)."""
        return self.pos[self.agent_idx, actions]

    # action choice ----------------------------------------------------------------------------
    def _host_weights(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """The policy network's weights as numpy arrays: zero-copy views on CPU (the optimiser
        updates the flat parameter in place, so the views stay current); a copy from a GPU."""
        flat = self.q.flat.detach()
        if flat.device.type != "cpu":
            v = [t.numpy() for t in self.q._views(flat.cpu())]
            return v[0::2], v[1::2]
        if getattr(self, "_host_ptr", None) != flat.data_ptr():
            v = [t.numpy() for t in self.q._views(flat)]
            self._host, self._host_ptr = (v[0::2], v[1::2]), flat.data_ptr()
        return self._host

    def greedy(self, tasks: np.ndarray, fixed: np.ndarray | None = None,
               fixed_actions: np.ndarray | None = None) -> tuple[np.ndarray, int, bool]:
        """Greedy joint actions (B, N) for tasks (B,), keeping ``fixed`` agents' actions (B, N).

        iql: each agent's argmax. nashq: person-by-person equilibrium of the agents' Q-networks by
        Gauss-Seidel best response (:func:`_best_response`, compiled: batch-1 products are far below
        torch's or numpy's per-call overhead); returns (actions, sweeps computed, converged).
        """
        nb = len(tasks)
        if fixed is None:
            fixed = np.zeros((nb, self.n), dtype=bool)
            fixed_actions = np.zeros((nb, self.n), dtype=np.int64)
        w, b = self._host_weights()
        a, sweeps, converged = _best_response(tuple(w + b), self.cols_np, self.n_opts, self.feats_np[tasks],
                                              self.pos_np, self.centre_np, self.others_np, fixed,
                                              fixed_actions.astype(np.int64), self.max_sweeps, self.joint)
        return a, int(sweeps), bool(converged)

    # learning ---------------------------------------------------------------------------------
    @torch.no_grad()
    def td_grad(self, tasks: torch.Tensor, actions: torch.Tensor, rewards: torch.Tensor,
                alpha: float) -> torch.Tensor:
        """Huber loss per agent (N,) on replay samples, its gradient written into ``q.flat.grad``.

        tasks (N, B), actions (N, B, N), rewards (N, B). Target (1 - alpha) Q_target(s, a) + alpha r;
        the gradient is that of the sum over agents of each agent's mean Huber loss (delta 1).
        """
        states = self.feats[tasks]
        x = self.inputs(states, self.joint_pos(actions) if self.joint else None)
        own = actions.gather(2, self.agent_idx[:, None, None].expand(self.n, actions.shape[1], 1))[..., 0]
        if self.factored:  # each action's pads' output columns (N, B, m)
            own = self.cols[self.agent_idx[:, None], own]
        q, saved = self.q.chosen(x, own)
        target = (1 - alpha) * self.target.chosen(x, own)[0] + alpha * rewards
        diff = q - target
        self.q.backward(diff.clamp(-1.0, 1.0) / diff.shape[1], saved)
        return F.smooth_l1_loss(q, target, reduction="none").mean(dim=1)
