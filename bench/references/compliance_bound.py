"""Certified lower bounds on a task's optimum: compliance relaxations and branch-and-bound.

The objective of one task is m(S) = max over the measurement points p of |u_S(p)|, u = (ux, uy, w),
minimised over the joint layouts S (one action of each agent's own set). Proofs and measured figures:
docs/references.md, section "Lower bounds". A *node* fixes the actions of some agents; its completions
place the fixed pads F (surely) and pads among R, the fixed pads plus every candidate of the free
agents. K_X is the compliance operator with the pads X held (the Schur forms of the oracle's data,
f . K_X f = c0 - d0_X^T C_XX^-1 d0_X); adding pads only shrinks it: K_R <= K_S <= K_F.

- **Averaged bound.** With point forces a at the measurement points (P K^-1 P^T a = P u0) and
  A = sum_p |a_p|: m(S) >= max(0, c_R - rho_F(s) sqrt(c_R)) / (s A) for every s > 0, with
  rho_F(s)^2 = r K_F r, r = f - s P^T a. It bites near the root where the load is local.
- **Point bound.** |u_S(p)| >= e . u_R(p) - sqrt((c_F - c_R) e (K_F - K_R)_pp e) per field, e the
  direction of u_R(p) (Cauchy-Schwarz in the PSD form K_S - K_R <= K_F - K_R). Exact at a leaf.

**Branch-and-bound** fixes the agents in order, best bound first; a node with at most
``enumerate_max`` completions is closed by evaluating them on the oracle. Run to the end it returns
the optimum; at any time min(incumbent, least open bound) is a certified lower bound.

Written by hand: no library does branch-and-bound over this bound (the MILP route through HiGHS,
solvers/math_programming/exact.py, needs a pad-force bound; docs/references.md compares the two).
Floating point: every node bound is multiplied by (1 - ``safety``) against round-off in its Schur
solves (the oracle matches a direct solve to about 1e-13); a Schur block that is not numerically
positive definite gives the bound 0.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fixbench.cases.oracle import CHUNK
from fixbench.cases.problem import Problem, decode_layouts


@dataclass(frozen=True)
class BoundConfig:
    """Settings of :func:`lower_bound` (checked when made)."""

    time_limit_s: float = 60.0
    """Wall-clock limit of one task's branch-and-bound; the bound reached so far is returned."""

    safety: float = 1e-6
    """Relative margin taken off every node bound against round-off in its Schur solves."""

    enumerate_max: int = 2048
    """A node with at most this many completions is closed by evaluating them all (a node bound
    costs about as much as a thousand or so layouts on the oracle)."""

    scale_points: int = 41
    """Values of the load split s tried per node (a log grid around the s that minimises rho)."""

    scale_span: float = 100.0
    """The grid of s spans [s* / span, s* x span]."""

    def __post_init__(self) -> None:
        if not self.time_limit_s > 0:
            raise ValueError(f"BoundConfig.time_limit_s must be positive, got {self.time_limit_s}")
        if not 0 <= self.safety < 1:
            raise ValueError(f"BoundConfig.safety must be in [0, 1), got {self.safety}")
        if self.enumerate_max < 1:
            raise ValueError(f"BoundConfig.enumerate_max must be at least 1, got {self.enumerate_max}")
        if self.scale_points < 1:
            raise ValueError(f"BoundConfig.scale_points must be at least 1, got {self.scale_points}")
        if not self.scale_span >= 1:
            raise ValueError(f"BoundConfig.scale_span must be at least 1, got {self.scale_span}")


@dataclass(frozen=True)
class BoundResult:
    """One task's branch-and-bound: certified bound, best layout found, and what it cost."""

    task: int
    bound: float  # certified lower bound on the task's optimum (m)
    root_bound: float  # the bound of the root node alone (m)
    best: float  # max |u| of the best layout found (m)
    layout: np.ndarray  # that layout (global action indices)
    proven: bool  # the search ended: bound == best, the optimum
    nodes: int  # node bounds computed
    leaves: int  # layouts evaluated on the oracle
    seconds: float

    @property
    def gap(self) -> float:
        """(best - bound) / best: the proven relative gap of the best layout found."""
        return (self.best - self.bound) / self.best if self.best > 0 else 0.0


def solve_columns(lu, B, left) -> np.ndarray:
    """left K^-1 B for sparse ``B`` and ``left``, solved ``CHUNK`` columns of B at a time, as the
    oracle's columns are: SuperLU's solve costs more a column the more columns it is given at once
    (on wing_panel_small's bending field: 3 ms a column at 16, 19 ms at 256), and no DOFs x columns
    dense block is ever held."""
    B = B.tocsc()
    out = np.empty((left.shape[0], B.shape[1]))
    for lo in range(0, B.shape[1], CHUNK):
        out[:, lo:lo + CHUNK] = left @ lu.solve(B[:, lo:lo + CHUNK].toarray())
    return out


def point_compliance(model, name: str) -> np.ndarray:
    """P K^-1 P^T of one field of the free plate: the measurement rows' mutual compliance (symmetrised)."""
    P = model.measure_matrix(name)
    W = solve_columns(model.fields[name].lu, P.T, P)
    return 0.5 * (W + W.T)


def point_forces(W: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The point forces a with P K^-1 P^T a = m (m: the free plate's field at the measurement rows; a
    column per task where m has them)."""
    return np.linalg.lstsq(W, m, rcond=1e-12)[0]


def force_total(forces: list[np.ndarray], n_meas: int) -> np.ndarray:
    """A = sum over the points of |a_p| (the components of every field together): a number, or one per
    task where each field's forces have a column per task."""
    comp = sum((a.reshape(-1, n_meas, *a.shape[1:]) ** 2).sum(axis=0) for a in forces)
    return np.sqrt(comp).sum(axis=0)


class _Field:
    """One field's oracle data and the task-independent products the bound needs."""

    def __init__(self, problem: Problem, name: str):
        fo = problem.oracle.fields[name]
        fs = problem.model.fields[name]
        self.per, self.C, self.H, self.d0, self.m0 = fo.per, fo.C, fo.H, fo.d0, fo.m0
        F = problem.model.load_matrix(name)
        self.c0 = np.einsum("it,it->t", F, fs.lu.solve(F))  # free compliance f . K^-1 f of each task
        self.W = point_compliance(problem.model, name)
        n = problem.oracle.n_meas
        self.W_pp = np.diag(self.W).copy()  # each measurement row's own compliance
        self.W_xy = np.diag(self.W[:n, n:]).copy() if name == "membrane" else None  # ux-uy at a point

    def rows(self, cand: np.ndarray) -> np.ndarray:
        return (cand[:, None] * self.per + np.arange(self.per)).ravel()


@dataclass(frozen=True)
class _Held:
    """One field of one task with the pads of some candidates held (the K_R forms of the proofs)."""

    c: float  # compliance f . K_R f
    u: np.ndarray  # the field at the measurement points (component-major)
    q: np.ndarray  # each measurement row's own compliance e_p . P K_R P^T e_p
    q_xy: np.ndarray | None  # the ux-uy entry of each point's 2 x 2 block (membrane)
    fa: float  # f . K_R P^T a (a: the task's point forces)
    aa: float  # a . P K_R P^T a


def _held(f: _Field, task: int, a: np.ndarray, cand: np.ndarray) -> _Held | None:
    """The forms of ``f`` with ``cand`` held, from the oracle's Schur data; None when their block is
    not numerically positive definite (coincident pads: the caller then bounds by 0)."""
    r = f.rows(cand)
    rhs = np.column_stack([f.d0[task][r], f.H[r], f.H[r] @ a])
    try:
        L = np.linalg.cholesky(f.C[np.ix_(r, r)])
    except np.linalg.LinAlgError:
        return None
    X = scipy.linalg.solve_triangular(L, rhs, lower=True, check_finite=False) if len(r) else rhs
    y, Z, h = X[:, 0], X[:, 1:-1], X[:, -1]
    n = len(f.W_xy) if f.W_xy is not None else 0
    return _Held(c=float(f.c0[task] - y @ y), u=f.m0[task] - Z.T @ y, q=f.W_pp - np.einsum("ij,ij->j", Z, Z),
                 q_xy=None if not n else f.W_xy - np.einsum("ij,ij->j", Z[:, :n], Z[:, n:]),
                 fa=float(a @ f.m0[task] - y @ h), aa=float(a @ f.W @ a - h @ h))


class ComplianceBound:
    """Node bounds of one problem (see the module docstring); ``node(task, fixed)`` is the API.

    Needs every candidate's compliance data (``Oracle.prepare``); it is prepared here.
    """

    def __init__(self, problem: Problem, config: BoundConfig = BoundConfig()):
        problem.oracle.prepare(max_bytes=np.inf)
        self.problem, self.config = problem, config
        self.fields = [_Field(problem, f) for f in problem.oracle.fields]
        self.n_meas = problem.oracle.n_meas
        self._task = None

    def _weights(self, task: int) -> None:
        """The point forces a of ``task`` (per field: P K^-1 P^T a = P u0) and A = sum_p |a_p|."""
        if self._task == task:
            return
        self.a = [point_forces(f.W, f.m0[task]) for f in self.fields]
        self.A = float(force_total(self.a, self.n_meas))
        self._task = task

    def pads(self, fixed: dict[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Candidates of the pads that the fixed actions ({agent: action}) hold: (every pad they may
        place, the pads every completion surely places).

        With a pad limit, pads are handed out in robot order: a completion surely places the fixed
        agents' pads up to the limit when the fixed agents are the first ones, and none is sure
        otherwise (an earlier free robot may use the pads up).
        """
        order = sorted(fixed)
        opts = self.problem.options[[fixed[a] for a in order]].ravel() if fixed else np.zeros(0, dtype=np.int64)
        opts = opts[opts >= 0]
        limit = self.problem.spec.effector.pads
        if not limit:
            return np.unique(opts), np.unique(opts)
        sure = opts[:limit] if order == list(range(len(order))) else opts[:0]
        return np.unique(opts), np.unique(sure)

    def node(self, task: int, fixed: dict[int, int]) -> float:
        """Certified lower bound on max |u| of every layout that takes the actions ``fixed``: the
        larger of the averaged-compliance bound and the point bound (module docstring)."""
        self._weights(task)
        pads, sure = self.pads(fixed)
        free = [s for a, s in enumerate(self.problem.candidate_sets) if a not in fixed]
        held = np.unique(np.concatenate([pads, *free]))
        R = [_held(f, task, a, held) for f, a in zip(self.fields, self.a)]
        F = [_held(f, task, a, sure) for f, a in zip(self.fields, self.a)]
        if any(h is None for h in R + F):
            return 0.0
        best = max(self._averaged(R, F), self._pointwise(R, F), 0.0)
        return best * (1 - self.config.safety)

    def _averaged(self, R: list[_Held], F: list[_Held]) -> float:
        """max over s of (c_R - rho_F(s) sqrt(c_R)) / (s A), rho_F(s)^2 = r K_F r for r = f - s P^T a."""
        c_node = sum(h.c for h in R)
        if c_node <= 0 or self.A == 0:
            return 0.0
        alpha, beta, gamma = sum(h.c for h in F), sum(h.fa for h in F), sum(h.aa for h in F)
        s_star = beta / gamma if gamma > 0 and beta > 0 else 1.0
        span = self.config.scale_span
        s = s_star * np.geomspace(1 / span, span, self.config.scale_points)
        rho = np.sqrt(np.maximum(alpha - 2 * beta * s + gamma * s**2, 0.0))
        return float(np.max((c_node - rho * np.sqrt(c_node)) / (s * self.A)))

    def _pointwise(self, R: list[_Held], F: list[_Held]) -> float:
        """max over the points of e . u_R(p) - sum over fields sqrt((c_F - c_R) e (K_F - K_R)_pp e),
        e = u_R(p) / |u_R(p)|."""
        n = self.n_meas
        u = np.vstack([r.u.reshape(-1, n) for r in R])  # (components, points)
        norm = np.linalg.norm(u, axis=0)
        e = u / np.where(norm > 0, norm, 1.0)
        spread, k = np.zeros(n), 0
        for r, h in zip(R, F):
            m = len(r.u) // n
            ef, D = e[k:k + m], (h.q - r.q).reshape(m, n)
            quad = (ef**2 * D).sum(axis=0)
            if h.q_xy is not None:
                quad += 2 * ef[0] * ef[1] * (h.q_xy - r.q_xy)
            spread += np.sqrt(max(h.c - r.c, 0.0) * np.maximum(quad, 0.0))
            k += m
        return float(np.max(norm - spread))


def lower_bound(problem: Problem, task: int, config: BoundConfig = BoundConfig(),
                bounder: ComplianceBound | None = None, incumbent: np.ndarray | None = None) -> BoundResult:
    """Best-first branch-and-bound of one task over the agents' actions, within ``config.time_limit_s``.

    A node whose completions number at most ``config.enumerate_max`` is closed by evaluating them all
    on the oracle (cheaper than bounding its children). ``incumbent``: a known layout (e.g. a shipped
    reference's) to prune with from the start.
    """
    task = problem.check_task(task)
    bounder = bounder or ComplianceBound(problem, config)
    start = time.perf_counter()
    sizes = [len(a) for a in problem.action_sets]
    best, best_layout = np.inf, None
    if incumbent is not None:
        best_layout = problem.check_layouts(incumbent)[0]
        best = float(problem.measure(task, best_layout[None])[0, 3])
    root = bounder.node(task, {})
    heap, nodes, leaves, tie = [(root, 0, ())], 1, 0, 0

    def out_of_time() -> bool:
        return time.perf_counter() - start >= config.time_limit_s

    while heap and heap[0][0] < best and not out_of_time():
        parent = heapq.heappop(heap)
        prefix = parent[2]
        k = len(prefix)
        count = math.prod(sizes[k:])
        if count <= config.enumerate_max:  # close it on the oracle
            rest = decode_layouts(problem.action_sets[k:], 0, count)
            layouts = np.hstack([np.broadcast_to(np.asarray(prefix, dtype=np.int64), (count, k)), rest])
            values = problem.measure(task, layouts)[:, 3]
            leaves += len(layouts)
            i = int(np.argmin(values))
            if values[i] < best:
                best, best_layout = float(values[i]), layouts[i]
            continue
        children = []
        for act in problem.action_sets[k]:
            if out_of_time():  # the parent stays open: its bound still covers its children
                heapq.heappush(heap, parent)
                break
            child = (*prefix, int(act))
            children.append((bounder.node(task, dict(enumerate(child))), child))
            nodes += 1
        else:
            for b, child in children:
                if b < best:
                    tie += 1
                    heapq.heappush(heap, (b, tie, child))
    proven = not heap or heap[0][0] >= best
    bound = best if proven else min(best, heap[0][0])
    return BoundResult(task, float(bound), float(min(root, best)), float(best), best_layout, proven, nodes,
                       leaves, time.perf_counter() - start)


__all__ = ["BoundConfig", "BoundResult", "ComplianceBound", "force_total", "lower_bound", "point_compliance",
           "point_forces", "solve_columns"]
