"""Flat-shell plate FEA with scikit-fem (docs/plate.md).

A flat shell in linear theory is two decoupled problems on one mesh:

- **bending** (Kirchhoff): deflection w, Morley element (nonconforming quadratic; its DOFs are the
  vertex deflections and the normal slopes at edge midpoints), stiffness D = E t^3 / (12 (1 - nu^2));
- **membrane** (plane stress): (u_x, u_y), quadratic Lagrange (P2) element, which unlike linear
  triangles does not lock when a web bends in its own plane.

Supports, fixtures and loads act on both through the same mesh. A field that no task loads is left
out (its response is zero), so a purely in-plane case does not need bending supports and vice versa.
Fixture pads and load patches are clouds of quadrature points with weights; a pad's constraint
row is the weighted mean of the field over its disc, a patch's load vector spreads its force
uniformly over its disc or boundary arc (in-plane forces and holds need area:
docs/plate.md#point-loads-and-patches).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import shapely
from scipy.spatial import cKDTree
from skfem import Basis, BilinearForm, ElementTriMorley, ElementTriP2, ElementVector, LinearForm
from skfem.assembly import Dofs
from skfem.helpers import dd, ddot, sym_grad, trace

from fixbench.cases.errors import CaseError, NumericalError
from fixbench.cases.geometry import inward, make_mesh, measurement_points
from fixbench.cases.materials import Material
from fixbench.cases.sections import section_index
from fixbench.cases.spec import FIELD_OF, STANDARD_GRAVITY, CaseSpec, Load, Task

FIELDS = ("bending", "membrane")
#: components of each field, in the order they are stored
COMPONENTS = {"bending": ("w",), "membrane": ("ux", "uy")}


# ---- weak forms ------------------------------------------------------------------------------
@BilinearForm
def bending_form(u, v, w):
    """Kirchhoff plate: D [(1 - nu) k(u):k(v) + nu tr k(u) tr k(v)], k = Hessian."""
    ku, kv = dd(u), dd(v)
    return w["D"] * ((1.0 - w["nu"]) * ddot(ku, kv) + w["nu"] * trace(ku) * trace(kv))


@BilinearForm
def membrane_form(u, v, w):
    """Plane stress times thickness: t [2 mu e(u):e(v) + lambda* tr e(u) tr e(v)]."""
    eu, ev = sym_grad(u), sym_grad(v)
    return w["t"] * (2.0 * w["mu"] * ddot(eu, ev) + w["lam"] * trace(eu) * trace(ev))


def _voigt_product(a, b, w):
    """a^T C b for symmetric tensors a, b in Voigt order (xx, yy, 2 xy) and the symmetric 3 x 3 C
    given as its six entries w["c00"], w["c01"], ... (each per element and quadrature point)."""
    va, vb = (a[0, 0], a[1, 1], 2.0 * a[0, 1]), (b[0, 0], b[1, 1], 2.0 * b[0, 1])
    total = 0.0
    for i in range(3):
        total = total + w[f"c{i}{i}"] * va[i] * vb[i]
        for j in range(i + 1, 3):
            total = total + w[f"c{i}{j}"] * (va[i] * vb[j] + va[j] * vb[i])
    return total


@BilinearForm
def laminate_bending_form(u, v, w):
    """The general plate: k(u)^T D k(v), k = (w_xx, w_yy, 2 w_xy), D with its D16 and D26 (a
    laminate's, or thickness regions'); for an isotropic D it is :func:`bending_form`."""
    return _voigt_product(dd(u), dd(v), w)


@BilinearForm
def laminate_membrane_form(u, v, w):
    """The general membrane: e(u)^T A e(v), e = (e_xx, e_yy, 2 e_xy), A the membrane stiffness (N/m)."""
    return _voigt_product(sym_grad(u), sym_grad(v), w)


@LinearForm
def pressure_form(v, w):
    """Transverse pressure q (Pa) on the plate, optionally only where ``inside`` is 1."""
    return w["q"] * w["inside"] * v


@LinearForm
def centrifugal_form(v, w):
    """In-plane body force rho t omega^2 (x - c) of a plate spinning about its normal at c."""
    x = w.x
    return w["rtw2"] * ((x[0] - w["cx"]) * v[0] + (x[1] - w["cy"]) * v[1])


# ---- quadrature clouds -----------------------------------------------------------------------
def disc_cloud(center: np.ndarray, radius: float, n_rings: int = 4):
    """Points and weights (summing to 1) of a uniform density over a disc; radius 0 is a point."""
    if radius == 0.0:
        return center[None, :], np.ones(1)
    pts, wts = [center], [1.0]
    for i in range(1, n_rings + 1):
        r = radius * i / n_rings
        n = 6 * i
        ang = 2 * np.pi * (np.arange(n) + 0.5 * (i % 2)) / n
        pts.extend(center + r * np.column_stack([np.cos(ang), np.sin(ang)]))
        wts.extend([2.0 * i] * n)  # area of ring i ~ r, shared by 6 i points
    return np.array(pts), np.array(wts) / np.sum(wts)


def arc_cloud(polygon: shapely.Polygon, center: np.ndarray, radius: float, n: int = 24):
    """Points and equal weights along the part's boundary within ``radius`` (arc length) of center."""
    rings = [polygon.exterior, *polygon.interiors]
    ring = min(rings, key=lambda r: r.distance(shapely.Point(center)))
    s0 = ring.project(shapely.Point(center))
    s = (s0 + radius * (2 * (np.arange(n) + 0.5) / n - 1.0)) % ring.length
    return np.array([ring.interpolate(si).coords[0] for si in s]), np.full(n, 1.0 / n)


def segment_cloud(segment: np.ndarray, n: int = 64):
    t = (np.arange(n) + 0.5) / n
    return segment[0] + np.outer(t, segment[1] - segment[0]), np.full(n, 1.0 / n)


@dataclass
class FieldSystem:
    """One field's discrete system: basis, stiffness, free DOFs and (lazily) its factorisation."""

    name: str
    basis: Basis
    K: sp.csr_matrix
    fixed: np.ndarray
    free: np.ndarray
    _lu: object = None

    @property
    def lu(self):
        """Factorisation of the free-free stiffness, computed once (see :class:`ScaledLU`)."""
        if self._lu is None:
            Kff = self.K[self.free][:, self.free].tocsc()
            self._lu = ScaledLU(Kff)
            check_solution(self._lu, Kff, self.name)
        return self._lu


class ScaledLU:
    """Sparse LU (SuperLU, COLAMD) of the symmetrically equilibrated matrix S A S, S = |diag A|^-1/2.

    Plate bending is ill-conditioned (kappa grows like h^-4), and fixtures turn a large
    unconstrained response into a small constrained one, so the oracle needs back-solves accurate
    well beyond what LU alone gives. Each solve therefore ends with iterative refinement whose
    residual is computed in double-double arithmetic (:func:`residual_dd`): the classical
    mixed-precision refinement that makes the forward error independent of kappa.
    """

    def __init__(self, A: sp.spmatrix, spd: bool = True, refine: int = 1):
        self.A = A.tocsr()
        self.A.sort_indices()
        d = np.abs(A.diagonal())
        self.s = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))
        S = sp.diags(self.s)
        if spd:  # symmetric ordering, no pivoting: stable for SPD and least fill
            self._lu = spla.splu((S @ A @ S).tocsc(), permc_spec="MMD_AT_PLUS_A",
                                 diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        else:  # saddle-point (KKT) systems need pivoting
            self._lu = spla.splu((S @ A @ S).tocsc(), permc_spec="COLAMD")
        self.refine = refine

    def _solve(self, b: np.ndarray) -> np.ndarray:
        s = self.s if b.ndim == 1 else self.s[:, None]
        return s * self._lu.solve(np.asfortranarray(s * b))

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = self._solve(b)
        for _ in range(self.refine):
            x = x + self._solve(residual(self.A, x, b))
        return x


def residual(A: sp.csr_matrix, x: np.ndarray, b: np.ndarray) -> np.ndarray:
    """b - A x, accurate to the last bit (double-double accumulation), any number of columns."""
    X = np.ascontiguousarray(x.reshape(len(x), -1))
    B = np.ascontiguousarray(b.reshape(len(b), -1))
    out = np.empty_like(B)
    residual_dd(A.indptr, A.indices, A.data, X, B, out)
    return out.reshape(b.shape)


@numba.njit(cache=True, inline="always")
def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@numba.njit(cache=True, inline="always")
def _two_prod(a, b):
    p = a * b
    f = 134217729.0  # 2^27 + 1, Dekker's split
    t = f * a
    ah = t - (t - a)
    al = a - ah
    t = f * b
    bh = t - (t - b)
    bl = b - bh
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


@numba.njit(parallel=True, cache=True)
def residual_dd(indptr, indices, data, X, B, out):
    """out = B - A X for CSR A and row-major X, B (n x m), each entry summed in double-double."""
    m = X.shape[1]
    for i in numba.prange(len(indptr) - 1):
        hi = B[i].copy()
        lo = np.zeros(m)
        for p in range(indptr[i], indptr[i + 1]):
            a = -data[p]
            xr = X[indices[p]]
            for c in range(m):
                ph, pl = _two_prod(a, xr[c])
                h, e = _two_sum(hi[c], ph)
                hi[c] = h
                lo[c] += e + pl
        for c in range(m):
            out[i, c] = hi[c] + lo[c]


def find_cells(mesh, pts: np.ndarray) -> np.ndarray:
    """The triangle holding each point (pts: (n, 2)); linear time, unlike a dense search."""
    if not hasattr(mesh, "_fixbench_tree"):
        mesh._fixbench_tree = cKDTree(mesh.p[:, mesh.t].mean(axis=1).T)
    cells = np.full(len(pts), -1)
    for k in (8, 32, 128):
        todo = np.flatnonzero(cells < 0)
        if len(todo) == 0:
            break
        _, near = mesh._fixbench_tree.query(pts[todo], k=min(k, mesh.t.shape[1]))
        near = near.reshape(len(todo), -1)
        v = mesh.p[:, mesh.t[:, near]]  # (2, 3, n, k)
        p = pts[todo].T[:, :, None]
        d = (v[1, 1] - v[1, 2]) * (v[0, 0] - v[0, 2]) + (v[0, 2] - v[0, 1]) * (v[1, 0] - v[1, 2])
        a = ((v[1, 1] - v[1, 2]) * (p[0] - v[0, 2]) + (v[0, 2] - v[0, 1]) * (p[1] - v[1, 2])) / d
        b = ((v[1, 2] - v[1, 0]) * (p[0] - v[0, 2]) + (v[0, 0] - v[0, 2]) * (p[1] - v[1, 2])) / d
        inside = (a >= -1e-10) & (b >= -1e-10) & (1 - a - b >= -1e-10)
        hit = inside.any(axis=1)
        cells[todo[hit]] = near[hit, inside[hit].argmax(axis=1)]
    if np.any(cells < 0):
        x, y = pts[np.argmax(cells < 0)] * 1e3
        raise NumericalError(f"point ({x:.2f}, {y:.2f}) mm is outside the mesh")
    return cells


def probe_matrix(basis: Basis, pts: np.ndarray) -> sp.csr_matrix:
    """Rows evaluating a scalar basis' function at points (as skfem's ``probes``, fast location)."""
    cells = find_cells(basis.mesh, pts)
    local = basis.mapping.invF(pts.T[:, :, None], tind=cells)
    phis = np.array([basis.elem.gbasis(basis.mapping, local, k, tind=cells)[0]
                     for k in range(basis.Nbfun)]).reshape(basis.Nbfun, -1)
    rows = np.tile(np.arange(len(pts)), basis.Nbfun)
    cols = basis.element_dofs[:, cells].ravel()
    return sp.csr_matrix((phis.ravel(), (rows, cols)), shape=(len(pts), basis.N))


def check_solution(lu, K, name: str) -> None:
    """Refuse a factorisation that does not solve its own system (singular or NaN stiffness)."""
    rng = np.random.default_rng(0)
    b = rng.standard_normal(K.shape[0])
    x = lu.solve(b)
    res = np.linalg.norm(K @ x - b) / np.linalg.norm(b)
    if not np.all(np.isfinite(x)) or res > 1e-6:
        raise NumericalError(f"{name} stiffness is singular or ill-conditioned "
                             f"(relative residual {res:.1e})")


def _loaded(spec: CaseSpec, field: str) -> bool:
    """Whether any task loads ``field`` (bending: out-of-plane loads; membrane: in-plane ones)."""
    for task in spec.tasks:
        for ld in task.loads:
            if field == "bending" and (ld.kind == "pressure" and ld.magnitude != 0 or ld.kind == "weight"
                                       or ld.kind in ("patch", "edge_traction") and ld.force[2] != 0):
                return True
            if field == "membrane" and (ld.kind == "centrifugal" and ld.magnitude != 0
                                        or ld.kind in ("patch", "edge_traction") and np.any(ld.force[:2] != 0)):
                return True
    return False


def active_fields(spec: CaseSpec) -> tuple[str, ...]:
    """The fields a case's tasks load (an unloaded field is not assembled: it cannot deform)."""
    active = tuple(f for f in FIELDS if _loaded(spec, f))
    if not active:
        raise CaseError(spec.source, "tasks", "no task loads the part")
    return active


def element(field: str):
    """The finite element of ``field``: Morley plates for bending, vector P2 for the membrane."""
    return ElementTriMorley() if field == "bending" else ElementVector(ElementTriP2())


def dof_count(spec: CaseSpec, mesh=None) -> int:
    """Degrees of freedom of the case's active fields, from the mesh's numbering alone (no
    quadrature, no assembly: what ``fixbench cases`` shows; equal to the assembled bases' sizes)."""
    mesh = mesh if mesh is not None else make_mesh(spec)
    return sum(int(Dofs(mesh, element(f)).N) for f in active_fields(spec))


def section_stiffness(spec: CaseSpec) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(A, D, mass per area) of the plate, then of each thickness region."""
    return [spec.material.stiffness(spec.thickness), *(r.stiffness() for r in spec.regions)]


def element_sections(spec: CaseSpec, mesh) -> np.ndarray:
    """Each element's section: 0 the plate, i + 1 region i (by its centroid; the mesh follows the
    regions' outlines, so no element straddles one)."""
    c = mesh.p[:, mesh.t].mean(axis=1)
    return section_index(spec.regions, c[0], c[1])


class PlateModel:
    """The FE model of one case: mesh, both fields, supports, loads, probes.

    Construction meshes the part and assembles the active fields; factorisations are lazy. The plate's
    stiffness is taken element by element: each element lies in the plate or in one of the case's
    thickness regions (the mesh follows their outlines), whose material or layup gives its A and D.
    """

    def __init__(self, spec: CaseSpec, mesh=None):
        self.spec = spec
        self.mesh = mesh if mesh is not None else make_mesh(spec)
        self.section = element_sections(spec, self.mesh)
        self.active = active_fields(spec)
        self.fields = {f: self._field(f) for f in self.active}
        self.measure_points = measurement_points(spec)
        self._measure = {f: self.component_probes(f, self.measure_points) for f in self.active}

    # -- construction --------------------------------------------------------------------------
    @property
    def uniform_isotropic(self) -> bool:
        """One isotropic plate of one thickness: the scalar forms, no per-element data."""
        return isinstance(self.spec.material, Material) and not self.spec.regions

    def per_element(self, values, basis: Basis) -> np.ndarray:
        """A value per section (plate, then each region) spread to (elements, quadrature points)."""
        v = np.asarray(values, dtype=float)[self.section]
        return np.ascontiguousarray(np.broadcast_to(v[:, None], (len(v), basis.X.shape[-1])))

    def mass_per_area(self, basis: Basis) -> np.ndarray:
        """rho t (kg/m^2) per element and quadrature point."""
        return self.per_element([stiffness[2] for stiffness in section_stiffness(self.spec)], basis)

    def stiffness(self, field: str, basis: Basis | None = None) -> sp.csr_matrix:
        """Assemble the stiffness of ``field`` (a fresh assembly every call)."""
        basis = basis or Basis(self.mesh, element(field))
        if self.uniform_isotropic:
            m, t = self.spec.material, self.spec.thickness
            if field == "bending":
                D = m.E * t**3 / (12.0 * (1.0 - m.nu**2))
                return bending_form.assemble(basis, D=D, nu=m.nu).tocsr()
            lam, mu = m.E * m.nu / (1.0 - m.nu**2), m.E / (2.0 * (1.0 + m.nu))
            return membrane_form.assemble(basis, t=t, lam=lam, mu=mu).tocsr()
        mats = [s[1] if field == "bending" else s[0] for s in section_stiffness(self.spec)]
        coeffs = {f"c{i}{j}": self.per_element([C[i, j] for C in mats], basis)
                  for i in range(3) for j in range(i, 3)}
        form = laminate_bending_form if field == "bending" else laminate_membrane_form
        return form.assemble(basis, **coeffs).tocsr()

    def _field(self, field: str) -> FieldSystem:
        basis = Basis(self.mesh, element(field))
        fixed = self._support_dofs(field, basis)
        free = np.setdiff1d(np.arange(basis.N), fixed)
        return FieldSystem(field, basis, self.stiffness(field, basis), fixed, free)

    def _support_facets(self, sup) -> np.ndarray:
        mesh, poly = self.mesh, self.spec.polygon
        tol = 1e-6 * max(poly.bounds[2] - poly.bounds[0], poly.bounds[3] - poly.bounds[1])
        if sup.segment is not None:
            geom = shapely.LineString(sup.segment)
        elif sup.hole is not None:
            geom = poly.interiors[sup.hole]
        else:
            geom = poly.exterior
        mid = mesh.p[:, mesh.facets].mean(axis=1)
        near = shapely.distance(geom, shapely.points(mid.T)) < tol
        return np.intersect1d(np.flatnonzero(near), mesh.boundary_facets())

    def _support_nodes(self, sup) -> np.ndarray:
        d = np.linalg.norm(self.mesh.p.T - sup.point, axis=1)
        return np.union1d(np.flatnonzero(d <= sup.radius), [int(np.argmin(d))])

    def _support_dofs(self, field: str, basis: Basis) -> np.ndarray:
        """DOFs held by the base supports, after checking that no rigid motion is left free."""
        dofs: list[np.ndarray] = []
        rows: list[list[float]] = []  # rigid-motion constraints, see _check_rigid
        mesh = self.mesh
        for sup in self.spec.supports:
            holds = [h for h in sup.holds if FIELD_OF[h] == field]
            if not holds:
                continue
            if sup.point is not None:
                nodes = self._support_nodes(sup)
                facets = np.zeros(0, dtype=int)
            else:
                facets = self._support_facets(sup)
                if len(facets) == 0:
                    raise CaseError(self.spec.source, f"supports ({sup.name})",
                                    "holds no boundary facet of the mesh")
                nodes = np.unique(mesh.facets[:, facets])
            for h in holds:
                if h == "w":
                    dofs.append(basis.nodal_dofs[0, nodes])
                    rows += [[1.0, x, y] for x, y in mesh.p[:, nodes].T]
                elif h == "rot" and len(facets):
                    dofs.append(basis.facet_dofs[0, facets])
                    a, b = mesh.p[:, mesh.facets[0, facets]], mesh.p[:, mesh.facets[1, facets]]
                    tangent = (b - a) / np.linalg.norm(b - a, axis=0)
                    rows += [[0.0, -ty, tx] for tx, ty in tangent.T]
                elif h in ("ux", "uy"):
                    c = 0 if h == "ux" else 1
                    dofs.append(basis.nodal_dofs[c, nodes])
                    if len(facets):
                        dofs.append(basis.facet_dofs[c, facets])
                    rows += [[1.0, 0.0, -y] if c == 0 else [0.0, 1.0, x]
                             for x, y in mesh.p[:, nodes].T]
        self._check_rigid(field, np.array(rows).reshape(-1, 3))
        return np.unique(np.concatenate(dofs)) if dofs else np.zeros(0, dtype=int)

    def _check_rigid(self, field: str, rows: np.ndarray) -> None:
        """The held DOFs must stop all three rigid motions of the field.

        Bending's rigid motions are w = a + b x + c y; membrane's are two translations and a
        rotation. Each held DOF is a linear condition on (a, b, c): rank 3 means none is left.
        """
        scale = np.array([1.0, *(1.0 / max(np.ptp(self.mesh.p, axis=1)),) * 2])
        if len(rows) == 0 or np.linalg.matrix_rank(rows * scale, tol=1e-8) < 3:
            what = "out of plane (w)" if field == "bending" else "in plane (ux, uy)"
            raise CaseError(self.spec.source, "supports",
                            f"the part is free to move rigidly {what}: hold more DOFs")

    # -- probes, loads, fixture rows ---------------------------------------------------------------
    def component_probes(self, field: str, points: np.ndarray) -> sp.csr_matrix:
        """Rows evaluating each component of ``field`` at ``points``, component-major."""
        fs = self.fields[field]
        pts = inward(self.spec.polygon, points)
        if field == "bending":
            return probe_matrix(fs.basis, pts)
        P = probe_matrix(fs.basis.split_bases()[0], pts).tocoo()
        blocks = []
        for idx in fs.basis.split_indices():
            blocks.append(sp.csr_matrix((P.data, (P.row, idx[P.col])), shape=(P.shape[0], fs.basis.N)))
        return sp.vstack(blocks).tocsr()

    def cloud_rows(self, field: str, clouds) -> sp.csr_matrix:
        """One weighted-mean row per (cloud, component): ``clouds`` is a list of (points, weights)."""
        ncomp = len(COMPONENTS[field])
        if not clouds:
            return sp.csr_matrix((0, self.fields[field].basis.N))
        sizes = [len(w) for _, w in clouds]
        pts = np.vstack([p for p, _ in clouds])
        probes = self.component_probes(field, pts)  # (ncomp * npts, N)
        npts = len(pts)
        owner = np.repeat(np.arange(len(clouds)), sizes)
        wts = np.concatenate([w for _, w in clouds])
        rows = []
        for c in range(ncomp):
            avg = sp.csr_matrix((wts, (owner, np.arange(npts))), shape=(len(clouds), npts))
            rows.append(avg @ probes[c * npts:(c + 1) * npts])
        # interleave: cloud j's components are rows j * ncomp + c
        out = sp.vstack(rows).tocsr()
        order = np.arange(len(clouds) * ncomp).reshape(ncomp, -1).T.ravel()
        return out[order]

    def fixture_clouds(self, candidates: np.ndarray):
        poly = self.spec.polygon
        clouds = []
        for c in candidates:
            p, w = disc_cloud(c, self.spec.fixture_radius)
            keep = shapely.contains_xy(poly, p[:, 0], p[:, 1])
            clouds.append((p[keep], w[keep] / w[keep].sum()))
        return clouds

    def fixture_rows(self, field: str, candidates: np.ndarray) -> tuple[sp.csr_matrix, int]:
        """Constraint rows of the fixture pads for ``field``: rows per candidate, held comps only."""
        comps = [i for i, c in enumerate(COMPONENTS[field]) if c in self.spec.fixture_holds]
        ncomp = len(COMPONENTS[field])
        if not comps:
            return sp.csr_matrix((0, self.fields[field].basis.N)), 0
        B = self.cloud_rows(field, self.fixture_clouds(candidates))
        keep = (np.arange(len(candidates))[:, None] * ncomp + np.array(comps)[None, :]).ravel()
        return B[keep], len(comps)

    def _patch_cloud(self, ld: Load):
        poly = self.spec.polygon
        if ld.kind == "edge_traction":
            return segment_cloud(ld.segment)
        if ld.patch_shape == "edge":
            return arc_cloud(poly, ld.at, ld.radius)
        p, w = disc_cloud(ld.at, ld.radius)
        keep = shapely.contains_xy(poly.buffer(1e-9), p[:, 0], p[:, 1])
        return p[keep], w[keep] / w[keep].sum()

    def _distributed(self, field: str, ld: Load) -> np.ndarray:
        """Load vector of a pressure, weight or centrifugal load (zero where the field does not feel it)."""
        fs = self.fields[field]
        if ld.kind == "weight" and field == "bending":  # rho g t along -z: a pressure of the material
            if self.uniform_isotropic:
                q = -self.spec.material.density * STANDARD_GRAVITY * self.spec.thickness
            else:
                q = -self.mass_per_area(fs.basis) * STANDARD_GRAVITY
            return pressure_form.assemble(fs.basis, q=q, inside=1.0)
        if ld.kind == "pressure" and field == "bending":
            inside = 1.0
            if ld.region is not None:
                x = fs.basis.mapping.F(fs.basis.X)  # quadrature points (2, elements, points)
                inside = shapely.contains_xy(shapely.Polygon(ld.region), x[0], x[1]).astype(float)
            return pressure_form.assemble(fs.basis, q=ld.magnitude, inside=inside)
        if ld.kind == "centrifugal" and field == "membrane":
            if self.uniform_isotropic:
                rtw2 = self.spec.material.density * self.spec.thickness * ld.magnitude**2
            else:
                rtw2 = self.mass_per_area(fs.basis) * ld.magnitude**2
            return centrifugal_form.assemble(fs.basis, rtw2=rtw2, cx=ld.at[0], cy=ld.at[1])
        return np.zeros(fs.basis.N)

    def load_vectors(self, field: str, tasks) -> np.ndarray:
        """Load vectors (N, len(tasks)) of a field; patch loads of all tasks in one probe pass."""
        fs = self.fields[field]
        F = np.zeros((fs.basis.N, len(tasks)))
        patches, owners, distributed = [], [], {}
        for j, task in enumerate(tasks):
            for ld in task.loads:
                if ld.kind in ("patch", "edge_traction"):
                    patches.append(ld)
                    owners.append(j)
                else:  # the same background load object recurs in every task: assemble it once
                    if id(ld) not in distributed:
                        distributed[id(ld)] = self._distributed(field, ld)
                    F[:, j] += distributed[id(ld)]
        if patches:
            rows = self.cloud_rows(field, [self._patch_cloud(ld) for ld in patches])
            ncomp = len(COMPONENTS[field])
            force = np.array([ld.force[2:] if field == "bending" else ld.force[:2] for ld in patches])
            weights = sp.csr_matrix((force.ravel(), (np.repeat(owners, ncomp),
                                                     np.arange(len(patches) * ncomp))),
                                    shape=(len(tasks), len(patches) * ncomp))
            F += (weights @ rows).T.toarray()
        if not np.all(np.isfinite(F)):
            raise NumericalError(f"{self.spec.source}: non-finite load vector in {field}")
        return F

    def load_vector(self, field: str, loads: tuple[Load, ...]) -> np.ndarray:
        return self.load_vectors(field, [Task("", loads, np.zeros(0))])[:, 0]

    def load_matrix(self, field: str) -> np.ndarray:
        """Load vectors of every task, restricted to the free DOFs: (n_free, n_tasks)."""
        return self.load_vectors(field, self.spec.tasks)[self.fields[field].free]

    def measure_matrix(self, field: str) -> sp.csr_matrix:
        """Probe rows at the measurement points (component-major), restricted to free DOFs."""
        return self._measure[field][:, self.fields[field].free]

    # -- direct solves (the reference the oracle is checked against) ------------------------------
    def solve_direct(self, task: int, candidates: np.ndarray, reassemble: bool = False) -> dict:
        """Full displacement of each active field with fixtures at ``candidates`` (KKT, spsolve).

        ``reassemble`` rebuilds the stiffness from scratch, as a planner without an oracle would.
        """
        out = {}
        loads = self.spec.tasks[task].loads
        for name in self.active:
            fs = self.fields[name]
            K = self.stiffness(name, fs.basis) if reassemble else fs.K
            B, _ = self.fixture_rows(name, np.asarray(candidates).reshape(-1, 2))
            Bf = B[:, fs.free]
            Kff = K[fs.free][:, fs.free]
            kkt = sp.bmat([[Kff, Bf.T], [Bf, None]], format="csr")
            rhs = np.concatenate([self.load_vector(name, loads)[fs.free], np.zeros(Bf.shape[0])])
            sol = ScaledLU(kkt, spd=False, refine=2).solve(rhs) if Bf.shape[0] else fs.lu.solve(rhs)
            if not np.all(np.isfinite(sol)):
                raise NumericalError(f"direct solve of {name} gave non-finite values "
                                     "(singular fixture layout?)")
            u = np.zeros(fs.basis.N)
            u[fs.free] = sol[: len(fs.free)]
            out[name] = u
        return out

    def measure(self, fields: dict) -> dict[str, np.ndarray]:
        """Components at the measurement points from full field vectors; absent fields are 0."""
        n = len(self.measure_points)
        vals = {c: np.zeros(n) for c in ("ux", "uy", "w")}
        for name, u in fields.items():
            v = self._measure[name] @ u
            for i, c in enumerate(COMPONENTS[name]):
                vals[c] = v[i * n:(i + 1) * n]
        return vals

    def nodal(self, fields: dict) -> dict[str, np.ndarray]:
        """Components at the mesh vertices (for pictures and VTK)."""
        nv = self.mesh.p.shape[1]
        vals = {c: np.zeros(nv) for c in ("ux", "uy", "w")}
        for name, u in fields.items():
            nd = self.fields[name].basis.nodal_dofs
            for i, c in enumerate(COMPONENTS[name]):
                vals[c] = u[nd[i]]
        return vals
