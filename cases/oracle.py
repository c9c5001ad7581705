"""The fast deformation oracle: Green's functions and a small Schur solve per layout.

Derivation: docs/oracle.md. For each field, with the base supports' stiffness K factored once:

- a fixture candidate j contributes constraint rows B_j (its pad's mean of each held component);
- its *compliance columns* G_j = K^-1 B_j^T are one back-solve each and are computed lazily, the
  first time a layout uses candidate j, or all at once by :meth:`Oracle.prepare` (set-up before a
  run, stored in and later memory-mapped from the disk cache of :mod:`fixbench.cases.cache`); from them we
  keep C_j = B G_j (the coupling of every candidate row to j's rows) and H_j = P G_j (j's
  influence on the measurement points P);
- each task's unconstrained response u0 = K^-1 f is solved once, with d0 = B u0 and P u0.

A layout S (rows R) then costs a |R| x |R| solve: lambda = C_RR^-1 d0_R and
u(P) = P u0 - H_R^T lambda. This equals the direct constrained solve of the same model to
round-off (tested against :meth:`fixbench.cases.fem.PlateModel.solve_direct`).

What is stored, and why (memory): C and H are float64 (the oracle must match a direct solve to
1e-9) and only rows of candidates that have been used are ever touched, so memory grows with the
candidates a planner explores: for the 3,333-candidate wing panel with all of them used, C is
(6,666^2 + 3,333^2) x 8 B = 0.44 GB and H 0.1 GB. Deformation is measured at a fixed set of
physical points (:func:`fixbench.cases.geometry.measurement_points`), not at every node.

The per-layout work is a numba kernel, parallel over layouts (``prange``); each layout is computed
independently, so results do not depend on the number of threads.
"""

from __future__ import annotations

import numba
import numpy as np

from fixbench.cases import cache
from fixbench.cases.errors import NumericalError
from fixbench.cases.fem import COMPONENTS, PlateModel

#: compliance columns are computed this many at a time: the dense right-hand sides, solutions and
#: refinement residuals are (DOFs x CHUNK) each. Measured on bus_panel_small (33,558 membrane DOFs):
#: 512 -> +265 MB transient and 3.2 s for all columns; 32 -> +57 MB and 2.0 s.
CHUNK = 32
#: :meth:`Oracle.prepare` computes every column only while the complete data stays below this size
#: (the wing panel's is 0.49 GiB, the wing spar's 3.15 GiB); beyond it, columns are computed as
#: layouts first use them (and the first planners to use them pay for them in their wall time).
PREPARE_MAX_BYTES = 4 * 2**30
#: a batch of at least LOCALITY_MIN layouts is evaluated in an order that keeps the rows it reads in
#: cache: sorted by the blocks of their candidates, a block being as many consecutive candidates as have
#: LOCALITY_BYTES of influence rows (about a core's L2 cache). Each layout is computed as before, alone,
#: so the results are the same bits in any order; random layouts of the wing panel at 5 agents read
#: 51 KB of rows each, and in their given order most of it comes from main memory.
LOCALITY_MIN = 4096
LOCALITY_BYTES = 2**20


class FieldOracle:
    """Green's-function data of one field (bending or membrane) of one model.

    ``saved``: the complete data (C, H, d0, m0) of an earlier build, e.g. memory-mapped from the
    disk cache (:mod:`fixbench.cases.cache`); then nothing is factorised or solved here.
    """

    def __init__(self, model: PlateModel, field: str, candidates: np.ndarray,
                 saved: dict[str, np.ndarray] | None = None):
        self.name = field
        self.per = sum(c in model.spec.fixture_holds for c in COMPONENTS[field])
        self.n_rows = self.per * len(candidates)
        self.n_meas = model.measure_matrix(field).shape[0]
        if saved is not None:
            self.C, self.H, self.d0, self.m0 = (saved[k] for k in ("C", "H", "d0", "m0"))
            if self.C.shape != (self.n_rows, self.n_rows) or self.H.shape != (self.n_rows, self.n_meas):
                raise NumericalError(f"{field}: saved oracle data of the wrong shape")
            self.done = np.ones(self.n_rows, dtype=bool)
            self.lu = self.B = self.P = None  # complete: never needed
            return
        fs = model.fields[field]
        self.lu = fs.lu
        B, _ = model.fixture_rows(field, candidates)
        self.B = B[:, fs.free].tocsr()
        self.P = model.measure_matrix(field)
        # Lazily filled: only rows of used candidates are written, so untouched pages cost nothing.
        self.C = np.zeros((self.n_rows, self.n_rows))
        self.H = np.zeros((self.n_rows, self.n_meas))
        self.done = np.zeros(self.n_rows, dtype=bool)
        F = model.load_matrix(field)
        U0 = self.lu.solve(F)
        if not np.all(np.isfinite(U0)):
            raise NumericalError(f"{field}: non-finite unconstrained response")
        self.d0 = np.ascontiguousarray((self.B @ U0).T)  # (n_tasks, n_rows)
        self.m0 = np.ascontiguousarray((self.P @ U0).T)  # (n_tasks, n_meas)

    def rows(self, cand: np.ndarray) -> np.ndarray:
        """Row indices of candidates: (..., k) -> (..., k * per); "no pad" (-1) gives rows -1."""
        cand = np.asarray(cand, dtype=np.int64)
        rows = (cand[..., None] * self.per + np.arange(self.per)).reshape(*cand.shape[:-1], -1)
        if cand.size == 0 or cand.min() >= 0:
            return rows
        return np.where(np.repeat(cand, self.per, axis=-1) >= 0, rows, -1)

    def ensure(self, cand: np.ndarray, progress=None) -> int:
        """Compute the compliance columns of the candidates not yet done; returns how many."""
        cand = np.unique(cand)
        rows = np.unique(self.rows(cand[cand >= 0][None, :]))
        todo = rows[~self.done[rows]]
        for start in range(0, len(todo), CHUNK):
            r = todo[start:start + CHUNK]
            G = self.lu.solve(self.B[r].T.toarray())
            if not np.all(np.isfinite(G)):
                raise NumericalError(f"{self.name}: non-finite compliance columns")
            self.C[r] = (self.B @ G).T
            self.H[r] = (self.P @ G).T
            self.done[r] = True
            if progress is not None:
                progress(len(r))
        return len(todo)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"C": self.C, "H": self.H, "d0": self.d0, "m0": self.m0}


class Oracle:
    """Batched, exact evaluation of fixture layouts for every task of a model.

    Not counted: planners reach it through :class:`fixbench.cases.problem.Evaluator`, which charges samples.
    ``cache_key``: where the complete data lives in the disk cache (:mod:`fixbench.cases.cache`); opened from
    there when present, written there by :meth:`prepare`.
    """

    def __init__(self, model: PlateModel, candidates: np.ndarray, cache_key: str | None = None):
        self.model = model
        self.n_candidates = len(candidates)
        self.n_meas = len(model.measure_points)
        self.cache_key = cache_key
        saved = cache.load(cache_key) if cache_key else None
        if saved is not None and set(saved) != {f"{f}.{k}" for f in model.active for k in ("C", "H", "d0", "m0")}:
            saved = None
        self.from_cache = saved is not None
        self._stored = False
        self._complete = False
        self.fields = {f: FieldOracle(model, f, candidates,
                                      None if saved is None else {k: saved[f"{f}.{k}"] for k in ("C", "H", "d0", "m0")})
                       for f in model.active}
        self.n_tasks = len(model.spec.tasks)

    @property
    def complete(self) -> bool:
        """Whether every candidate's compliance columns are computed (once true, for good: asked on
        every evaluation, so the scan over the done flags stops then)."""
        if not self._complete:
            self._complete = all(fo.done.all() for fo in self.fields.values())
        return self._complete

    def full_bytes(self) -> int:
        """Memory of the complete data (C, H, d0, m0 of every field)."""
        return sum(8 * (fo.n_rows * (fo.n_rows + fo.n_meas + self.n_tasks) + self.n_tasks * fo.n_meas)
                   for fo in self.fields.values())

    def prepare(self, progress=None, max_bytes: float = PREPARE_MAX_BYTES) -> bool:
        """Every candidate's compliance columns, from the disk cache or computed and stored there.

        Set-up, not search: it costs no samples (planners still pay for what they read through the
        :class:`~fixbench.cases.problem.Evaluator`). Returns False, leaving the oracle lazy, when the complete
        data would exceed ``max_bytes`` (the columns are then computed as layouts first use them).
        """
        if not self.complete:
            if self.full_bytes() > max_bytes:
                return False
            self.ensure(np.arange(self.n_candidates), progress)
        if self.cache_key and not (self.from_cache or self._stored):  # also after layouts used every column
            spec = self.model.spec
            arrays = {f"{f}.{k}": v for f, fo in self.fields.items() for k, v in fo.arrays().items()}
            what = f"{spec.name} ({spec.material.name}, {self.n_candidates} candidates, {self.n_tasks} tasks)"
            cache.store(self.cache_key, arrays, description=what)
            self._stored = True  # tried once (a cache that cannot be written is not retried)
        return True

    def ensure(self, cand: np.ndarray, progress=None) -> None:
        for fo in self.fields.values():
            fo.ensure(cand, progress)

    def n_columns(self, cand: np.ndarray) -> int:
        """How many compliance columns the candidates have (rows of all active fields)."""
        cand = np.unique(cand)
        return sum(fo.per for fo in self.fields.values()) * int(np.count_nonzero(cand >= 0))

    def evaluate(self, task: int, layouts: np.ndarray, soft_power: float | None = None) -> np.ndarray:
        """Per layout over the measurement points: (L, 6) = max |ux|, |uy|, |w|, |u|, |u_xy|, soft |u|.

        ``layouts``: (L, k) candidate indices of the pads, -1 for "no pad" (an idle robot).

        |u| is the full magnitude, |u_xy| the in-plane magnitude sqrt(ux^2 + uy^2). With
        ``soft_power`` p, the last column is the power mean (mean over the points of |u|^p)^(1/p), a
        smooth stand-in for the max (p = 1: the mean; p -> inf: the max) from the same solve; NaN
        without it (it costs a power per point).
        """
        layouts = np.ascontiguousarray(np.atleast_2d(layouts), dtype=np.int64)
        if not self.complete:
            self.ensure(layouts)
        empty = (np.zeros((0, 0)), np.zeros((0, self.n_meas)), np.zeros(0),
                 np.zeros(self.n_meas), np.zeros((len(layouts), 0), dtype=np.int64))
        args = []
        for field in ("bending", "membrane"):
            fo = self.fields.get(field)
            if fo is None:
                c, h, d, m, r = empty
                if field == "membrane":
                    h, m = np.zeros((0, 2 * self.n_meas)), np.zeros(2 * self.n_meas)
            else:
                c, h, d, m, r = fo.C, fo.H, fo.d0[task], fo.m0[task], fo.rows(layouts)
            args += [c, h, d, m, np.ascontiguousarray(r)]
        out = np.empty((len(layouts), 7))
        blocks = max(1, min(len(layouts), 8 * numba.get_num_threads()))
        if len(layouts) >= LOCALITY_MIN:
            order = self._locality_order(layouts)
            args = [a[order] if i % 5 == 4 else a for i, a in enumerate(args)]  # each field's rows
            sorted_out = np.empty_like(out)
            _evaluate(*args, self.n_meas, float(soft_power or 0.0), blocks, sorted_out)
            out[order] = sorted_out
        else:
            _evaluate(*args, self.n_meas, float(soft_power or 0.0), blocks, out)
        bad = out[:, 6] > 0
        if bad.any():
            raise NumericalError(f"layout {layouts[np.argmax(bad)].tolist()} of task {task} gives a "
                                 "singular constraint system (coincident or overlapping pads?)")
        return out[:, :6]

    def _locality_order(self, layouts: np.ndarray) -> np.ndarray:
        """Evaluation order of a large batch: lexicographic in the candidates' blocks (LOCALITY_BYTES)."""
        row_bytes = 8 * sum(fo.per * fo.H.shape[1] for fo in self.fields.values())
        block = max(1, LOCALITY_BYTES // max(row_bytes, 1))
        keys = np.floor_divide(layouts, block)  # "no pad" (-1) falls in block -1
        return np.lexsort(keys.T[::-1])

    def compliance(self, field: str, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coupling rows C and measurement influence H of candidates (what a QP planner reads)."""
        fo = self.fields[field]
        fo.ensure(cand)
        r = fo.rows(np.atleast_1d(cand)[None, :])[0]
        return fo.C[r], fo.H[r]


@numba.njit(cache=True)
def _chol_solve(A: np.ndarray, b: np.ndarray, L: np.ndarray, y: np.ndarray, x: np.ndarray, k: int) -> bool:
    """Solve the small SPD system A x = b (leading k x k block) by Cholesky into ``x``, with scratch
    L and y (no allocation: this runs once per field per layout); False when A is (near) singular."""
    scale = 0.0
    for i in range(k):
        scale = max(scale, A[i, i])
    for j in range(k):
        s = A[j, j]
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if s <= 1e-13 * scale:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, k):
            s = A[i, j]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            L[i, j] = s / L[j, j]
    for i in range(k):
        s = b[i]
        for p in range(i):
            s -= L[i, p] * y[p]
        y[i] = s / L[i, i]
    for i in range(k - 1, -1, -1):
        s = y[i]
        for p in range(i + 1, k):
            s -= L[p, i] * x[p]
        x[i] = s / L[i, i]
    return True


@numba.njit(cache=True)
def _response(C, H, d0, m0, given, u, A, b, L, y, x, rows) -> bool:
    """Field values at the measurement points for one layout's constraint rows ``given``, written into
    ``u``; rows -1 (no pad) are left out (A, b, L, y, x, rows: scratch of at least the row count)."""
    k = 0
    for i in range(given.shape[0]):
        if given[i] >= 0:
            rows[k] = given[i]
            k += 1
    for p in range(u.shape[0]):
        u[p] = m0[p]
    if k == 0:
        return True
    for i in range(k):  # C is symmetric: read one triangle (half the cache misses), the same
        b[i] = d0[rows[i]]  # one whatever the order of the rows
        for j in range(i, k):
            lo, hi = min(rows[i], rows[j]), max(rows[i], rows[j])
            A[i, j] = A[j, i] = C[lo, hi]
    ok = _chol_solve(A, b, L, y, x, k)
    for i in range(k):
        hi = H[rows[i]]
        li = x[i]
        for p in range(u.shape[0]):
            u[p] -= li * hi[p]
    return ok


@numba.njit(cache=True)
def _power_mean(uv, w, n_meas, power, top):
    """(mean over the points of |u|^p)^(1/p), scaled by the max ``top`` so that no power overflows."""
    if top == 0.0 or n_meas == 0:
        return 0.0
    s = 0.0
    for p in range(n_meas):
        r2 = (uv[p] ** 2 + uv[n_meas + p] ** 2 + w[p] ** 2) / (top * top)
        s += r2 ** (0.5 * power)
    return top * (s / n_meas) ** (1.0 / power)


@numba.njit(parallel=True, cache=True)
def _evaluate(Cb, Hb, db, mb, rb, Cm, Hm, dm, mm, rm, n_meas, power, blocks, out):
    """Every layout's maxima into ``out``; layouts in ``blocks`` contiguous blocks (a few per thread),
    each with its own scratch (allocating it per layout cost 10-15 % of the kernel)."""
    n = rb.shape[0]
    k = max(rb.shape[1], rm.shape[1], 1)
    for blk in numba.prange(blocks):
        w, uv = np.empty(mb.shape[0]), np.empty(mm.shape[0])
        A, L, b, y, x = np.empty((k, k)), np.empty((k, k)), np.empty(k), np.empty(k), np.empty(k)
        rows = np.empty(k, dtype=np.int64)
        for ell in range(blk * n // blocks, (blk + 1) * n // blocks):
            ok_b = _response(Cb, Hb, db, mb, rb[ell], w, A, b, L, y, x, rows)
            ok_m = _response(Cm, Hm, dm, mm, rm[ell], uv, A, b, L, y, x, rows)
            ax = ay = aw = au = axy = 0.0
            for p in range(n_meas):
                px, py, pz = uv[p], uv[n_meas + p], w[p]
                ax = max(ax, abs(px))
                ay = max(ay, abs(py))
                aw = max(aw, abs(pz))
                axy = max(axy, px * px + py * py)
                au = max(au, px * px + py * py + pz * pz)
            out[ell, 0] = ax
            out[ell, 1] = ay
            out[ell, 2] = aw
            out[ell, 3] = np.sqrt(au)
            out[ell, 4] = np.sqrt(axy)
            out[ell, 5] = _power_mean(uv, w, n_meas, power, np.sqrt(au)) if power > 0 else np.nan
            out[ell, 6] = 0.0 if (ok_b and ok_m) else 1.0


__all__ = ["Oracle", "FieldOracle", "COMPONENTS"]
