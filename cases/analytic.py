"""Analytic checks of the plate FEA (docs/plate.md).

A catalog case's ``[validation]`` table (or each of its ``[[validation]]`` rows) names a quantity
(``w``, ``ux`` or ``uy``), a point, and a reference. :func:`validate` solves each such case without
fixtures and compares. The references are exact or tabulated:

- plates (Timoshenko & Woinowsky-Krieger): ``q a^4 / D`` or ``P a^2 / D`` times a coefficient
  for nu = 0.3, printed to 3-4 significant digits, so a converged model agrees to about 0.1 %;
- the membrane strip: ``F L / (E b t)`` is exact (uniform stress), and for a laminate
  ``F L / (b (A11 - A12^2 / A22))`` (free contraction, A16 = A26 = 0);
- ``navier``: Navier's double series of a simply supported rectangle, isotropic or specially
  orthotropic (D16 = D26 = 0), exact to any precision (:func:`navier_ss_rectangle`);
- ``strip``: a strip along x whose sections change along it (thickness regions), held so that each
  field is one-dimensional: its end stretch F/b integral dx / A11(x) and its cantilever tip deflection
  P/b integral (L - x)^2 / D11(x) dx (:func:`strip_reference`);
- ``case``: another catalog case's value at a point (a mirror image, the plate turned by 90 degrees
  with its layup, the same plate written as a one-ply layup): symmetry and consistency checks.

For a simply supported rectangle, :func:`validate` also reports Navier's value (``series``), and the
tests use it to show the Morley element converging under mesh refinement.
"""

from __future__ import annotations

import numpy as np
import shapely

from fixbench.cases.errors import CaseError
from fixbench.cases.materials import Material
from fixbench.cases.sections import section_index
from fixbench.cases.spec import CaseSpec, Validation, case_names, load_case_spec

#: D16, D26 (A16, A26) below this fraction of D11 (A11) count as zero: specially orthotropic
ORTHOTROPIC_TOLERANCE = 1e-12


def flexural_rigidity(spec: CaseSpec) -> float:
    """D = E t^3 / (12 (1 - nu^2)) of the case's isotropic material and thickness (N m)."""
    m = spec.material
    if not isinstance(m, Material):
        raise CaseError(spec.source, "material", "a laminate has no single flexural rigidity D (its D is a matrix)")
    return m.E * spec.thickness**3 / (12.0 * (1.0 - m.nu**2))


def _orthotropic(C: np.ndarray) -> bool:
    return abs(C[0, 2]) <= ORTHOTROPIC_TOLERANCE * C[0, 0] and abs(C[1, 2]) <= ORTHOTROPIC_TOLERANCE * C[0, 0]


def navier_ss_rectangle(a: float, b: float, D, load, x: float, y: float,
                        terms: int = 801) -> float:
    """Deflection at (x, y) of a simply supported a x b plate (corner at the origin), Navier series.

    ``load`` is ``("uniform", q)`` (pressure q in Pa over the whole plate) or ``("point", P)``
    (force P in N at the centre) or ``("point", P, (xi, eta))`` (at (xi, eta)). Deflection is along
    the load. The series is

        w = sum_{m,n >= 1} q_mn sin(m pi x / a) sin(n pi y / b) / (pi^4 D (m^2/a^2 + n^2/b^2)^2)

    for an isotropic plate (``D`` a number), and for a specially orthotropic one (``D`` the 3 x 3
    bending stiffness with D16 = D26 = 0) the denominator is
    pi^4 [D11 (m/a)^4 + 2 (D12 + 2 D66) (m/a)^2 (n/b)^2 + D22 (n/b)^4] (Whitney; Reddy, ch. 5),
    with q_mn = 16 q / (pi^2 m n) for odd m, n (0 otherwise) for the uniform load and
    q_mn = 4 P / (a b) sin(m pi xi / a) sin(n pi eta / b) for the point load. ``terms`` is the
    number of m (and of n) summed. A uniform load's terms fall like (m n)^-1 (m^2 + n^2)^-2 and the
    default is exact to ~1e-12; a point load's tail is O(terms^-2), ~1e-6 relative at the default.
    Why: the series is the exact Kirchhoff solution, finer than any printed table coefficient.
    """
    kind = load[0]
    m = np.arange(1, terms + 1, dtype=float)
    sx = np.sin(m * np.pi * x / a)
    sy = np.sin(m * np.pi * y / b)
    if kind == "uniform":
        q = float(load[1])
        odd = (m % 2 == 1).astype(float)
        cx, cy = odd / m, odd / m
        amp = 16.0 * q / np.pi**2
    elif kind == "point":
        P = float(load[1])
        xi, eta = load[2] if len(load) > 2 else (a / 2.0, b / 2.0)
        cx, cy = np.sin(m * np.pi * xi / a), np.sin(m * np.pi * eta / b)
        amp = 4.0 * P / (a * b)
    else:
        raise ValueError(f"unknown load kind {kind!r} (uniform or point)")
    fx, fy = cx * sx, cy * sy  # separable parts of q_mn and of the mode shape
    matrix = np.ndim(D) == 2
    if matrix and not _orthotropic(np.asarray(D)):
        raise ValueError("Navier's series needs D16 = D26 = 0 (a specially orthotropic plate)")
    total = 0.0
    chunk = 512  # rows of m at a time: bounded memory for many terms
    for i in range(0, terms, chunk):
        mi = m[i:i + chunk, None]
        if matrix:
            p2, q2 = (mi / a) ** 2, (m[None, :] / b) ** 2
            denom = D[0, 0] * p2**2 + 2.0 * (D[0, 1] + 2.0 * D[2, 2]) * p2 * q2 + D[1, 1] * q2**2
        else:
            denom = (mi**2 / a**2 + m[None, :] ** 2 / b**2) ** 2
        total += float(np.sum(fx[i:i + chunk, None] * fy[None, :] / denom))
    return amp * total / (np.pi**4 * (1.0 if matrix else D))


def validation_names() -> list[str]:
    """Catalog cases that carry validation rows."""
    return [n for n in case_names() if load_case_spec(n).validations]


def _load_of(spec: CaseSpec, kinds: tuple[str, ...]):
    for ld in spec.tasks[0].loads:
        if ld.kind in kinds:
            return ld
    raise CaseError(spec.source, "tasks", f"task 0 has no {' or '.join(kinds)} load for the validation")


def _plate_stiffness(spec: CaseSpec, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(A, D) of a plate of one section, refused (naming ``what``) where it has thickness regions."""
    if spec.regions:
        raise CaseError(spec.source, "regions", f"{what} applies to a plate of one thickness and layup")
    A, D, _ = spec.material.stiffness(spec.thickness)
    return A, D


def strip_reference(spec: CaseSpec, v: Validation, points: int = 200_000) -> float:
    """The end displacement of a strip along x (x from 0 to L, y from 0 to b) whose sections may
    change along it, held so that each field is one-dimensional (uy and the slope w_y held along its
    long edges, the end x = 0 clamped), loaded at x = L by a total force (F, 0, P):

        ux(L) = F / b * integral_0^L dx / A11(x),    w(L) = P / b * integral_0^L (L - x)^2 / D11(x) dx

    (a bar in series; a cantilever of bending stiffness b D11(x): cylindrical bending, exact in plate
    theory where A16 = D16 = 0). The integrals are midpoint sums over ``points`` pieces along y = b/2
    (pieces straddling a step in thickness err by under 1 / ``points``).
    """
    L, b = v.lengths["L"], v.lengths["b"]
    x = (np.arange(points) + 0.5) * L / points
    sections = [spec.material.stiffness(spec.thickness), *(r.stiffness() for r in spec.regions)]
    idx = section_index(spec.regions, x, np.full(points, b / 2))
    force = _load_of(spec, ("edge_traction", "patch")).force
    if v.quantity == "ux":
        A11 = np.array([s[0][0, 0] for s in sections])[idx]
        return float(abs(force[0]) / b * np.sum(1.0 / A11) * L / points)
    if v.quantity == "w":
        D11 = np.array([s[1][0, 0] for s in sections])[idx]
        return float(abs(force[2]) / b * np.sum((L - x) ** 2 / D11) * L / points)
    raise CaseError(spec.source, "validation.quantity", "a strip's reference is for ux or w")


def reference(spec: CaseSpec, v: Validation | None = None) -> float:
    """The reference value of validation row ``v`` (default: the case's first).

    q is the pressure of task 0's pressure load, P = |Fz| of its patch (point) load, F = |Fx| of its
    edge traction; a, b, L come from the row; E, t, D, A from the case.
    """
    v = v if v is not None else spec.validations[0]
    L = v.lengths
    if v.scale == "q a^4 / D":
        q = abs(_load_of(spec, ("pressure",)).magnitude)
        scale = q * L["a"] ** 4 / flexural_rigidity(spec)
    elif v.scale == "P a^2 / D":
        P = abs(_load_of(spec, ("patch",)).force[2])
        scale = P * L["a"] ** 2 / flexural_rigidity(spec)
    elif v.scale == "F L / (E b t)":
        E, t = spec.material.E, spec.thickness
        F = abs(_load_of(spec, ("edge_traction", "patch")).force[0])
        scale = F * L["L"] / (E * L["b"] * t)
    elif v.scale == "F L / (b (A11 - A12^2 / A22))":
        A, _ = _plate_stiffness(spec, v.scale)
        if not _orthotropic(A):
            raise CaseError(spec.source, "validation.scale", f"{v.scale} needs A16 = A26 = 0")
        F = abs(_load_of(spec, ("edge_traction", "patch")).force[0])
        scale = F * L["L"] / (L["b"] * (A[0, 0] - A[0, 1] ** 2 / A[1, 1]))
    elif v.scale == "navier":
        scale = series_reference(spec, v)
        if scale is None:
            raise CaseError(spec.source, "validation.scale", "navier needs a simply supported rectangle from "
                            "(0, 0) to (a, b) of one section with D16 = D26 = 0, under one uniform pressure "
                            "or one point force")
    elif v.scale == "strip":
        scale = strip_reference(spec, v)
    elif v.scale == "case":
        other = load_case_spec(v.case)
        twin = Validation(v.quantity, v.case_at, 1.0, "case", {})
        scale = abs(probe_value(other, twin))
    else:  # the spec reader only lets the scales above through
        raise ValueError(f"{spec.source}: unknown validation scale {v.scale!r}")
    return float(v.coefficient * scale)


def series_reference(spec: CaseSpec, v: Validation | None = None, terms: int = 801) -> float | None:
    """Navier's exact deflection where it applies, else None.

    It applies to a rectangle from (0, 0) to (a, b) of one section (isotropic, or with D16 = D26 = 0),
    all of whose outer boundary is simply supported (w held, rotation free) and nothing else, loaded
    in task 0 by one uniform pressure or one point force normal to the plate.
    """
    v = v if v is not None else spec.validations[0]
    if v.quantity != "w" or "a" not in v.lengths or spec.regions:
        return None
    a, b = v.lengths["a"], v.lengths.get("b", v.lengths["a"])
    box = shapely.box(0.0, 0.0, a, b)
    if spec.polygon.symmetric_difference(box).area > 1e-9 * a * b:
        return None
    if len(spec.supports) != 1 or not spec.supports[0].outer or spec.supports[0].holds != ("w",):
        return None
    loads = spec.tasks[0].loads
    if len(loads) != 1:
        return None
    ld = loads[0]
    if isinstance(spec.material, Material):
        D = flexural_rigidity(spec)
    else:
        D = spec.material.stiffness()[1]
        if not _orthotropic(D):
            return None
    x, y = v.at
    if ld.kind == "pressure" and ld.region is None:
        return abs(navier_ss_rectangle(a, b, D, ("uniform", ld.magnitude), x, y, terms))
    if ld.kind == "patch" and ld.radius == 0 and not np.any(ld.force[:2]):
        return abs(navier_ss_rectangle(a, b, D, ("point", ld.force[2], tuple(ld.at)), x, y, terms))
    return None


def probe_value(spec: CaseSpec, v: Validation | None = None, model=None) -> float:
    """Signed quantity of row ``v`` at its point, task 0, no fixtures (direct solve).

    Signs are the code's: w positive along +z (a positive pressure pushes along +z).
    """
    from fixbench.cases.fem import PlateModel  # heavy import only when a model is solved

    v = v if v is not None else spec.validations[0]
    model = model if model is not None else PlateModel(spec)
    fields = model.solve_direct(0, np.zeros((0, 2)))
    field = "bending" if v.quantity == "w" else "membrane"
    if field not in fields:
        return 0.0  # the task does not load this field: its response is zero
    vals = model.component_probes(field, v.at[None, :]) @ fields[field]
    # bending: one row (w); membrane: component-major rows (ux, then uy)
    return float(vals[{"w": 0, "ux": 0, "uy": 1}[v.quantity]])


def row_name(spec: CaseSpec, v: Validation) -> str:
    """The case's name, with the row's label (or quantity) where the case has several rows."""
    if len(spec.validations) == 1 and not v.label:
        return spec.name
    return f"{spec.name}: {v.label or v.quantity}"


def validate_spec(spec: CaseSpec) -> list[dict]:
    """The validation rows of a parsed case (see :func:`validate`)."""
    if not spec.validations:
        raise CaseError(spec.source, "validation", "the case has no validation rows")
    from fixbench.cases.fem import PlateModel

    model = PlateModel(spec)
    rows = []
    for v in spec.validations:
        value = probe_value(spec, v, model)
        comp, ref = abs(value), reference(spec, v)
        row = {"name": row_name(spec, v), "quantity": v.quantity, "computed": comp, "value": value,
               "reference": ref, "rel_error": float(abs(comp - ref) / abs(ref)),
               "coefficient": v.coefficient, "scale": v.scale if v.scale != "case" else f"case {v.case}",
               "mesh_size": spec.mesh.size, "elements": int(model.mesh.t.shape[1])}
        series = series_reference(spec, v)
        row["series"] = series
        row["series_rel_error"] = None if series is None else float(abs(comp - series) / series)
        rows.append(row)
    return rows


def validate(names=None) -> list[dict]:
    """Solve every validation case (or ``names``) and compare with its references.

    Each row: ``name``, ``quantity``, ``computed`` and ``reference`` (metres, magnitudes: w is
    positive along +z in the code while the tables give the deflection along the load), ``value``
    (the signed computed quantity),
    ``rel_error`` = |computed - reference| / reference, and for simply supported rectangles the
    exact Navier value ``series`` with ``series_rel_error``; also mesh size and element count.
    """
    names = validation_names() if names is None else list(names)
    return [row for n in names for row in validate_spec(load_case_spec(n))]
