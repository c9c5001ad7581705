"""Zone bound: a certified lower bound on every task of a problem at once, with one robot free and the
others' zones clamped.

For robot k and each of its actions o, hold the pads of o and clamp every degree of freedom that a
pad of any *other* robot's candidates touches (the support of their constraint rows). Every layout
that gives robot k the action o holds a subset of those constraints (each other pad's rows vanish on
clamped DOFs), so by monotonicity (docs/references.md#lower-bounds) its compliance is at least the
node's c_R, and the averaged bound of :mod:`fixbench.solvers.bound` applies with rho taken on the
free plate (K_S <= K^-1 for every S, so r . K_S r <= r . K^-1 r):

    m(S) >= max over s of (c_R - rho_0(s) sqrt(c_R)) / (s A),   rho_0(s)^2 = (f - s P^T a) . K^-1 (f - s P^T a).

The task's bound is the largest over the robots of the least over that robot's actions. It is what
:class:`~fixbench.solvers.bound.ComplianceBound` cannot give on the full parts: there the held blocks of
thousands of overlapping pads are not numerically positive definite, while clamped DOFs are always
well posed (a direct sparse factorisation of the remaining stiffness). Its cost is one factorisation
and one back-solve per constraint row of robot k's candidates, per robot and field, then a few small
dense solves per (action, task): the whole wing panel (500 positions) in one to two minutes of CPU.

Written by hand: no library bounds this combinatorial problem; the linear algebra is SciPy's.
Floating point: each bound is multiplied by (1 - ``safety``); an action whose held block is not
numerically positive definite (pads almost wholly on clamped DOFs) gives 0 (still valid: m >= 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from fixbench.cases.fem import ScaledLU
from fixbench.cases.problem import Problem


@dataclass(frozen=True)
class ZoneConfig:
    """Settings of :class:`ZoneBound` (checked when made)."""

    safety: float = 1e-6
    """Relative margin taken off every bound against round-off in its solves."""

    pivot: float = 1e-10
    """An action's held block counts as not positive definite below this relative Cholesky pivot."""

    scale_points: int = 41
    """Values of the load split s tried (a log grid around the s that minimises rho_0)."""

    scale_span: float = 100.0
    """The grid of s spans [s* / span, s* x span]."""

    task_chunk: int = 100
    """Tasks solved together (memory: DOFs x chunk doubles per field)."""

    def __post_init__(self) -> None:
        if not 0 <= self.safety < 1:
            raise ValueError(f"ZoneConfig.safety must be in [0, 1), got {self.safety}")
        if not 0 < self.pivot < 1:
            raise ValueError(f"ZoneConfig.pivot must be in (0, 1), got {self.pivot}")
        if self.scale_points < 1 or self.task_chunk < 1:
            raise ValueError("ZoneConfig.scale_points and task_chunk must be at least 1")
        if not self.scale_span >= 1:
            raise ValueError(f"ZoneConfig.scale_span must be at least 1, got {self.scale_span}")


def _support(B: sp.spmatrix) -> np.ndarray:
    """Columns (DOFs) on which some row of ``B`` is non-zero."""
    return np.flatnonzero(np.diff(B.tocsc().indptr) > 0)


class ZoneBound:
    """Zone bounds of one problem (module docstring): ``bounds(tasks)`` per task, ``node_bounds(k, tasks)``
    per action of robot k."""

    def __init__(self, problem: Problem, config: ZoneConfig = ZoneConfig()):
        self.problem, self.config = problem, config
        model = problem.model
        self.fields = model.active
        tasks = range(problem.n_tasks)
        self.F = {n: model.load_matrix(n) for n in self.fields}  # (free DOFs, tasks)
        n_meas = len(model.measure_points)
        c0, fa, aa, comp = 0.0, 0.0, 0.0, np.zeros((n_meas, len(tasks)))
        for n in self.fields:  # the point forces a of every task, as ComplianceBound._weights
            fs, P = model.fields[n], model.measure_matrix(n)
            W = P @ fs.lu.solve(P.T.toarray())
            W = 0.5 * (W + W.T)
            U0 = fs.lu.solve(self.F[n])
            m0 = P @ U0
            a = np.linalg.lstsq(W, m0, rcond=1e-12)[0]
            c0 = c0 + np.einsum("it,it->t", self.F[n], U0)
            fa = fa + np.einsum("pt,pt->t", a, m0)
            aa = aa + np.einsum("pt,pq,qt->t", a, W, a)
            comp += (a.reshape(-1, n_meas, len(tasks)) ** 2).sum(axis=0)
        self.c0, self.fa, self.aa = c0, fa, aa  # rho_0(s)^2 = c0 - 2 s fa + s^2 aa, per task
        self.A = np.sqrt(comp).sum(axis=0)

    def _held(self, k: int):
        """Per field: the clamped system of robot k's zone node (factorisation, kept DOFs) and the
        constraint rows of k's candidates on the kept DOFs, with their coupling block."""
        p, model = self.problem, self.problem.model
        mine = p.candidate_sets[k]
        others = np.unique(np.concatenate([s for j, s in enumerate(p.candidate_sets) if j != k] or [[]]))
        out = []
        for n in self.fields:
            fs = model.fields[n]
            pos = np.full(fs.basis.N, -1)
            pos[fs.free] = np.arange(len(fs.free))
            Bo, _ = model.fixture_rows(n, p.candidates[others.astype(np.int64)])
            clamp = pos[_support(Bo)] if Bo.shape[0] else np.zeros(0, dtype=np.int64)
            keep = np.setdiff1d(np.arange(len(fs.free)), clamp[clamp >= 0])
            Bk, per = model.fixture_rows(n, p.candidates[mine])
            if per == 0:  # the pads hold nothing of this field: only the clamps act on it
                Bk = sp.csr_matrix((0, len(keep)))
            else:
                Bk = Bk[:, fs.free][:, keep].tocsr()
            lu = ScaledLU(fs.K[fs.free][:, fs.free][keep][:, keep].tocsc())
            C = np.zeros((Bk.shape[0], Bk.shape[0]))
            for lo in range(0, Bk.shape[0], 256):  # column blocks: a DOFs x rows dense solve would not fit
                C[:, lo:lo + 256] = Bk @ lu.solve(Bk[lo:lo + 256].T.toarray())
            out.append((n, keep, lu, Bk, per, 0.5 * (C + C.T)))
        return out

    def node_bounds(self, k: int, tasks=None) -> np.ndarray:
        """(actions of robot k, tasks) certified lower bounds on max |u| of every layout that gives
        robot k that action (in the order of ``problem.action_sets[k]``)."""
        p, cfg = self.problem, self.config
        tasks = np.arange(p.n_tasks) if tasks is None else np.asarray(tasks, dtype=np.int64)
        local = {int(c): i for i, c in enumerate(p.candidate_sets[k])}
        opts = p.options[p.action_sets[k]]  # (actions, pads a robot places), -1 for none
        c_R = np.zeros((len(opts), len(tasks)))
        for n, keep, lu, Bk, per, C in self._held(k):
            solver = _ActionSolver(opts, local, per, C, cfg.pivot)
            for lo in range(0, len(tasks), cfg.task_chunk):
                t = tasks[lo:lo + cfg.task_chunk]
                f = self.F[n][keep][:, t]
                u = lu.solve(f)
                c_clamp = np.einsum("it,it->t", f, u)
                c_R[:, lo:lo + len(t)] += c_clamp[None, :] - solver.reduction(Bk @ u if per else None, len(t))
        c_R[~np.isfinite(c_R)] = 0.0
        c_R = np.maximum(c_R, 0.0)
        s_star = np.where((self.aa[tasks] > 0) & (self.fa[tasks] > 0),
                          self.fa[tasks] / np.where(self.aa[tasks] > 0, self.aa[tasks], 1.0), 1.0)
        best = np.zeros_like(c_R)
        for g in np.geomspace(1 / cfg.scale_span, cfg.scale_span, cfg.scale_points):
            s = s_star * g
            rho = np.sqrt(np.maximum(self.c0[tasks] - 2 * s * self.fa[tasks] + s**2 * self.aa[tasks], 0.0))
            with np.errstate(invalid="ignore", divide="ignore"):
                val = (c_R - rho * np.sqrt(c_R)) / (s * self.A[tasks])
            best = np.maximum(best, np.nan_to_num(val, nan=0.0, posinf=0.0, neginf=0.0))
        best[:, ~(self.A[tasks] > 0)] = 0.0
        return best * (1 - cfg.safety)

    def bounds(self, tasks=None) -> np.ndarray:
        """(tasks,) the zone bound of each task: the largest over the robots of the least over that
        robot's actions."""
        tasks = np.arange(self.problem.n_tasks) if tasks is None else np.asarray(tasks, dtype=np.int64)
        out = np.zeros(len(tasks))
        for k in range(self.problem.n_agents):
            out = np.maximum(out, self.node_bounds(k, tasks).min(axis=0))
        return out


class _ActionSolver:
    """The compliance reduction d_o . C_oo^-1 d_o of each action o (its pads' rows), batched by the
    number of pads; an action whose block fails the pivot test reduces by +inf (its bound is 0)."""

    def __init__(self, opts: np.ndarray, local: dict[int, int], per: int, C: np.ndarray, pivot: float):
        self.groups = []
        scale = float(np.abs(np.diag(C)).max()) if len(C) else 1.0
        placed = (opts >= 0).sum(axis=1)
        for m in np.unique(placed):
            idx = np.flatnonzero(placed == m)
            if m == 0 or per == 0:
                self.groups.append((idx, None, None, None))
                continue
            pads = np.array([[local[int(c)] for c in o if c >= 0] for o in opts[idx]])
            rows = (pads[:, :, None] * per + np.arange(per)).reshape(len(idx), -1)
            block = C[rows[:, :, None], rows[:, None, :]]
            zero = np.abs(np.einsum("aii->ai", block)) <= 0  # rows wholly on clamped DOFs: d = 0 there
            block = block + np.einsum("ai,ij->aij", zero.astype(float), np.eye(rows.shape[1])) * scale
            ok = np.ones(len(idx), dtype=bool)
            L = np.zeros_like(block)
            for i in range(len(idx)):  # small blocks (pads x components): a loop of tiny Choleskys
                try:
                    L[i] = np.linalg.cholesky(block[i])
                except np.linalg.LinAlgError:
                    ok[i] = False
                    continue
                ok[i] = np.diag(L[i]).min() ** 2 > pivot * scale
            self.groups.append((idx, rows, L, ok))

    def reduction(self, d: np.ndarray | None, n_tasks: int) -> np.ndarray:
        out = np.zeros((sum(len(g[0]) for g in self.groups), n_tasks))
        for idx, rows, L, ok in self.groups:
            if rows is None or d is None:
                continue
            z = np.linalg.solve(L[ok], d[rows[ok]])  # L z = d: z . z = d C^-1 d
            out[idx[ok]] = (z * z).sum(axis=1)
            out[idx[~ok]] = np.inf
        return out


__all__ = ["ZoneBound", "ZoneConfig"]
