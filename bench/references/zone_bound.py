"""Zone bound: a certified lower bound on every task of a problem at once, with one robot free and the
others' zones clamped.

For robot k and each of its actions o, hold the pads of o and clamp every degree of freedom that a
pad of any *other* robot's candidates touches (the support of their constraint rows). Every layout
that gives robot k the action o holds a subset of those constraints (each other pad's rows vanish on
clamped DOFs), so by monotonicity (docs/references.md#lower-bounds) its compliance is at least the
node's c_R, and the averaged bound of :mod:`fixbench.bench.references.compliance_bound` applies with rho taken on the
free plate (K_S <= K^-1 for every S, so r . K_S r <= r . K^-1 r):

    m(S) >= max over s of (c_R - rho_0(s) sqrt(c_R)) / (s A),   rho_0(s)^2 = (f - s P^T a) . K^-1 (f - s P^T a).

The task's one-robot bound is the largest over the robots of the least over that robot's actions.
With two neighbouring robots k and j free (the other zones clamped) a node holds fewer constraints than
k's one-robot node, so its bound is at least that node's: the least over the pair nodes is searched k's
actions least one-robot bound first, stopping where that bound reaches the least pair bound found
(:meth:`ZoneBound.pair_bounds`). The task's bound is the largest of all of these. It is what
:class:`~fixbench.bench.references.compliance_bound.ComplianceBound` cannot give on the full parts:
there the held blocks of thousands of overlapping pads are not numerically positive definite, while
clamped DOFs are always well posed (a direct sparse factorisation of the remaining stiffness). Its cost
is one factorisation and one back-solve per constraint row of robot k's candidates, per robot and field, then a few
small dense solves per (action, task) and per expansion of a pair; docs/references.md#zone-bound has the
measured cost and gaps.

Written by hand: no library bounds this combinatorial problem; the linear algebra is SciPy's.
Floating point: each bound is multiplied by (1 - ``safety``); an action whose held block is not
numerically positive definite (pads almost wholly on clamped DOFs) gives 0 (still valid: m >= 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from fixbench.bench.references.compliance_bound import force_total, point_compliance, point_forces, solve_columns
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

    pairs: bool = True
    """Also free two neighbouring robots at once (the others' zones clamped; :meth:`ZoneBound.neighbours`):
    tighter, about 2-3 x the time."""

    expand_max: int = 32
    """A pair node expands at most this many of the first robot's actions a task (least bound first);
    the next one's one-robot bound covers the rest."""

    def __post_init__(self) -> None:
        if not 0 <= self.safety < 1:
            raise ValueError(f"ZoneConfig.safety must be in [0, 1), got {self.safety}")
        if not 0 < self.pivot < 1:
            raise ValueError(f"ZoneConfig.pivot must be in (0, 1), got {self.pivot}")
        if self.scale_points < 1 or self.task_chunk < 1 or self.expand_max < 1:
            raise ValueError("ZoneConfig.scale_points, task_chunk and expand_max must be at least 1")
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
        self.F = {n: model.load_matrix(n) for n in self.fields}  # (free DOFs, tasks)
        c0, fa, aa, forces = 0.0, 0.0, 0.0, []
        for n in self.fields:  # the point forces a of every task (a column each), as ComplianceBound's
            W = point_compliance(model, n)
            U0 = model.fields[n].lu.solve(self.F[n])
            m0 = model.measure_matrix(n) @ U0
            a = point_forces(W, m0)
            c0 = c0 + np.einsum("it,it->t", self.F[n], U0)
            fa = fa + np.einsum("pt,pt->t", a, m0)
            aa = aa + np.einsum("pt,pq,qt->t", a, W, a)
            forces.append(a)
        self.c0, self.fa, self.aa = c0, fa, aa  # rho_0(s)^2 = c0 - 2 s fa + s^2 aa, per task
        self.A = force_total(forces, len(model.measure_points))

    def _held(self, free: tuple[int, ...]):
        """Per field: the clamped system of a zone node with the robots ``free`` (factorisation, kept
        DOFs) and the constraint rows of their candidates (in that order) on the kept DOFs, with their
        coupling block."""
        p, model = self.problem, self.problem.model
        mine = np.concatenate([p.candidate_sets[k] for k in free])
        others = np.unique(np.concatenate([s for j, s in enumerate(p.candidate_sets) if j not in free] or [[]]))
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
            C = solve_columns(lu, Bk.T, Bk)
            out.append((n, keep, lu, Bk, per, 0.5 * (C + C.T)))
        return out

    def _solved(self, held, tasks: np.ndarray):
        """Per chunk of tasks: (the chunk's slice, per field (clamped compliance, pad rows' d = B u))."""
        for lo in range(0, len(tasks), self.config.task_chunk):
            t = tasks[lo:lo + self.config.task_chunk]
            fields = []
            for n, keep, lu, Bk, per, _ in held:
                f = self.F[n][keep][:, t]
                u = lu.solve(f)
                fields.append((np.einsum("it,it->t", f, u), Bk @ u if per else None))
            yield slice(lo, lo + len(t)), fields

    def _averaged(self, c_R: np.ndarray, tasks: np.ndarray) -> np.ndarray:
        """The averaged bound of compliances ``c_R`` (..., tasks), best s on the grid, less the safety."""
        cfg = self.config
        c_R = np.maximum(np.where(np.isfinite(c_R), c_R, 0.0), 0.0)
        s_star = np.where((self.aa[tasks] > 0) & (self.fa[tasks] > 0),
                          self.fa[tasks] / np.where(self.aa[tasks] > 0, self.aa[tasks], 1.0), 1.0)
        best = np.zeros_like(c_R)
        for g in np.geomspace(1 / cfg.scale_span, cfg.scale_span, cfg.scale_points):
            s = s_star * g
            rho = np.sqrt(np.maximum(self.c0[tasks] - 2 * s * self.fa[tasks] + s**2 * self.aa[tasks], 0.0))
            with np.errstate(invalid="ignore", divide="ignore"):
                val = (c_R - rho * np.sqrt(c_R)) / (s * self.A[tasks])
            best = np.maximum(best, np.nan_to_num(val, nan=0.0, posinf=0.0, neginf=0.0))
        best[..., ~(self.A[tasks] > 0)] = 0.0
        return best * (1 - cfg.safety)

    def node_bounds(self, k: int, tasks=None) -> np.ndarray:
        """(actions of robot k, tasks) certified lower bounds on max |u| of every layout that gives
        robot k that action (in the order of ``problem.action_sets[k]``)."""
        p = self.problem
        tasks = np.arange(p.n_tasks) if tasks is None else np.asarray(tasks, dtype=np.int64)
        local = {int(c): i for i, c in enumerate(p.candidate_sets[k])}
        opts = p.options[p.action_sets[k]]  # (actions, pads a robot places), -1 for none
        held = self._held((k,))
        solvers = [_ActionSolver(opts, local, per, C, self.config.pivot) for *_, per, C in held]
        c_R = np.zeros((len(opts), len(tasks)))
        for cols, fields in self._solved(held, tasks):
            for solver, (c_clamp, d) in zip(solvers, fields):
                c_R[:, cols] += c_clamp[None, :] - solver.reduction(d, cols.stop - cols.start)
        return self._averaged(c_R, tasks)

    def neighbours(self) -> list[tuple[int, int]]:
        """Pairs of robots (k < j) whose zones touch: j holds the nearest other-zone candidate of some
        candidate of k (or k of j). No length scale is assumed (grids may be far from square)."""
        from scipy.spatial import cKDTree

        p = self.problem
        sets = p.candidate_sets
        trees = [cKDTree(p.candidates[s]) if len(s) else None for s in sets]
        pairs = set()
        for k, s in enumerate(sets):
            others = [j for j in range(p.n_agents) if j != k and trees[j] is not None]
            if not len(s) or not others:
                continue
            dist = np.column_stack([trees[j].query(p.candidates[s])[0] for j in others])
            pairs |= {tuple(sorted((k, others[i]))) for i in np.unique(dist.argmin(axis=1))}
        return sorted(pairs)

    def pair_bounds(self, k: int, j: int, tasks, first_k: np.ndarray, first_j: np.ndarray) -> np.ndarray:
        """(tasks,) certified bounds with robots k and j free and every other zone clamped. For each task
        and each order (a, b) of the two: the least over a's actions of the least over b's actions, a's
        actions taken least one-robot bound (``first_a``: node_bounds(a), actions x tasks) first and
        stopped where that bound reaches the least found (it is below every pair node under that action:
        more DOFs clamped); the larger of the two orders."""
        p, cfg = self.problem, self.config
        tasks = np.asarray(tasks, dtype=np.int64)
        held = self._held((k, j))
        nk = len(p.candidate_sets[k])
        local = ({int(c): i for i, c in enumerate(p.candidate_sets[k])},
                 {int(c): nk + i for i, c in enumerate(p.candidate_sets[j])})
        opts = (p.options[p.action_sets[k]], p.options[p.action_sets[j]])
        orders = [(first_k, [_PairSolver(opts[0], opts[1], local[0], local[1], per, C, cfg.pivot)
                             for *_, per, C in held]),
                  (first_j, [_PairSolver(opts[1], opts[0], local[1], local[0], per, C, cfg.pivot)
                             for *_, per, C in held])]
        out = np.zeros(len(tasks))
        for cols, fields in self._solved(held, tasks):
            for i in range(cols.start, cols.stop):
                col = i - cols.start
                for first, solvers in orders:
                    least = np.inf
                    for n_done, o in enumerate(np.argsort(first[:, i], kind="stable")):
                        if first[o, i] >= least:
                            break
                        if n_done == cfg.expand_max:
                            least = first[o, i]
                            break
                        least = min(least, float(self._pair_row(solvers, fields, o, col, tasks[i]).min()))
                    out[i] = max(out[i], least if np.isfinite(least) else 0.0)
        return out

    def _pair_row(self, solvers, fields, o: int, col: int, task: int) -> np.ndarray:
        """Bounds of the pair nodes (o, each action of the second robot) on one task (column ``col``)."""
        c_R = sum(c[col] - s.reduction(o, None if d is None else d[:, col]) for s, (c, d) in zip(solvers, fields))
        return self._averaged(c_R[:, None], np.array([task]))[:, 0]

    def pair_nodes(self, k: int, j: int, task: int) -> np.ndarray:
        """(actions of k, actions of j) the bound of every pair node of one task (for checks: the search
        above computes only the rows it needs)."""
        p, cfg = self.problem, self.config
        held = self._held((k, j))
        nk = len(p.candidate_sets[k])
        local_k = {int(c): i for i, c in enumerate(p.candidate_sets[k])}
        local_j = {int(c): nk + i for i, c in enumerate(p.candidate_sets[j])}
        solvers = [_PairSolver(p.options[p.action_sets[k]], p.options[p.action_sets[j]], local_k, local_j, per, C,
                               cfg.pivot) for *_, per, C in held]
        _, fields = next(self._solved(held, np.array([task])))
        return np.array([self._pair_row(solvers, fields, o, 0, task) for o in range(len(p.action_sets[k]))])

    def bounds(self, tasks=None) -> np.ndarray:
        """(tasks,) the zone bound of each task: the largest over the robots of the least over that
        robot's actions and, with ``pairs``, over the ordered neighbour pairs of their pair bounds."""
        tasks = np.arange(self.problem.n_tasks) if tasks is None else np.asarray(tasks, dtype=np.int64)
        first = [self.node_bounds(k, tasks) for k in range(self.problem.n_agents)]
        out = np.max([b.min(axis=0) for b in first], axis=0)
        for k, j in self.neighbours() if self.config.pairs else []:
            out = np.maximum(out, self.pair_bounds(k, j, tasks, first[k], first[j]))
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


class _PairSolver:
    """The compliance reduction of one action o of a first robot together with each action of a second
    (their pads' rows), by block elimination: with L L^T = C_oo, z = L^-1 d_o and W = L^-1 C_o,b,
    d C^-1 d = z . z + e . S^-1 e, S = C_bb - W^T W, e = d_b - W^T z. A block that fails the pivot
    test reduces by +inf (bound 0)."""

    def __init__(self, opts_a, opts_b, local_a, local_b, per: int, C: np.ndarray, pivot: float):
        self.per, self.C, self.pivot = per, C, pivot
        self.scale = float(np.abs(np.diag(C)).max()) if len(C) else 1.0
        self.rows_a = [self._rows(o, local_a) for o in opts_a]
        self.n_b = len(opts_b)
        self.groups = []  # the second robot's actions by pad count: (indices, rows, C_bb blocks)
        placed = (opts_b >= 0).sum(axis=1)
        for m in np.unique(placed):
            idx = np.flatnonzero(placed == m)
            rows = np.array([self._rows(o, local_b) for o in opts_b[idx]]).reshape(len(idx), -1)
            block = C[rows[:, :, None], rows[:, None, :]] if rows.shape[1] and per else None
            if block is not None:  # rows wholly on clamped DOFs: d = 0 and C = 0 there; make them inert
                zero = np.abs(np.einsum("aii->ai", block)) <= 0
                block = block + np.einsum("ai,ij->aij", zero.astype(float), np.eye(rows.shape[1])) * self.scale
            self.groups.append((idx, rows, block))

    def _rows(self, opt, local) -> np.ndarray:
        pads = np.array([local[int(c)] for c in opt if c >= 0], dtype=np.int64)
        return (pads[:, None] * self.per + np.arange(self.per)).ravel() if self.per else pads[:0]

    def reduction(self, o: int, d: np.ndarray | None) -> np.ndarray:
        """(actions of the second robot,) d C^-1 d of action ``o`` with each; d: the rows' values (one task)."""
        out = np.zeros(self.n_b)
        if d is None or self.per == 0:
            return out
        ra = self.rows_a[o]
        Ca = self.C[np.ix_(ra, ra)]
        Ca = Ca + np.diag((np.abs(np.diag(Ca)) <= 0) * self.scale)
        try:
            L = np.linalg.cholesky(Ca) if len(ra) else np.zeros((0, 0))
        except np.linalg.LinAlgError:
            return np.full(self.n_b, np.inf)
        if len(ra) and np.diag(L).min() ** 2 <= self.pivot * self.scale:
            return np.full(self.n_b, np.inf)
        z = np.linalg.solve(L, d[ra]) if len(ra) else np.zeros(0)
        for idx, rows, block in self.groups:
            if block is None:
                out[idx] = z @ z
                continue
            W = np.linalg.solve(L, self.C[ra][:, rows].reshape(len(ra), -1)).reshape(len(ra), *rows.shape) \
                if len(ra) else np.zeros((0, *rows.shape))
            S = block - np.einsum("pai,paj->aij", W, W)
            e = d[rows] - np.einsum("pai,p->ai", W, z)
            lam = np.linalg.eigvalsh(S)
            ok = lam.min(axis=1) > self.pivot * self.scale
            red = np.full(len(idx), np.inf)
            if ok.any():
                red[ok] = z @ z + np.einsum("ai,ai->a", e[ok], np.linalg.solve(S[ok], e[ok][..., None])[..., 0])
            out[idx] = red
        return out


__all__ = ["ZoneBound", "ZoneConfig"]
