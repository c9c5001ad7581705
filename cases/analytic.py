"""Analytic checks of the plate FEA (docs/plate.md).

A catalog case with a ``[validation]`` table names a quantity (``w``, ``ux`` or ``uy``), a point,
and a textbook formula ``coefficient * scale``. :func:`validate` solves each such case without
fixtures and compares. The references are exact or tabulated:

- plates (Timoshenko & Woinowsky-Krieger): ``q a^4 / D`` or ``P a^2 / D`` times a coefficient
  for nu = 0.3, printed to 3-4 significant digits, so a converged model agrees to about 0.1 %;
- the membrane strip: ``F L / (E b t)`` is exact (uniform stress).

For a simply supported rectangle the table is not needed: Navier's double sine series
(:func:`navier_ss_rectangle`) is exact to any precision, so :func:`validate` reports it too
(``series``), and the tests use it to show the Morley element converging under mesh refinement.
"""

from __future__ import annotations

import numpy as np
import shapely

from fixbench.cases.errors import CaseError
from fixbench.cases.spec import CaseSpec, case_names, load_case_spec


def flexural_rigidity(spec: CaseSpec) -> float:
    """D = E t^3 / (12 (1 - nu^2)) of the case's material and thickness (N m)."""
    m = spec.material
    return m.E * spec.thickness**3 / (12.0 * (1.0 - m.nu**2))


def navier_ss_rectangle(a: float, b: float, D: float, load, x: float, y: float,
                        terms: int = 801) -> float:
    """Deflection at (x, y) of a simply supported a x b plate (corner at the origin), Navier series.

    ``load`` is ``("uniform", q)`` (pressure q in Pa over the whole plate) or ``("point", P)``
    (force P in N at the centre) or ``("point", P, (xi, eta))`` (at (xi, eta)). Deflection is along
    the load. The series is

        w = sum_{m,n >= 1} q_mn sin(m pi x / a) sin(n pi y / b) / (pi^4 D (m^2/a^2 + n^2/b^2)^2)

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
    total = 0.0
    chunk = 512  # rows of m at a time: bounded memory for many terms
    for i in range(0, terms, chunk):
        mi = m[i:i + chunk, None]
        denom = (mi**2 / a**2 + m[None, :] ** 2 / b**2) ** 2
        total += float(np.sum(fx[i:i + chunk, None] * fy[None, :] / denom))
    return amp * total / (np.pi**4 * D)


def validation_names() -> list[str]:
    """Catalog cases that carry a ``[validation]`` table."""
    return [n for n in case_names() if load_case_spec(n).validation is not None]


def _load_of(spec: CaseSpec, kinds: tuple[str, ...]):
    for ld in spec.tasks[0].loads:
        if ld.kind in kinds:
            return ld
    raise ValueError(f"{spec.source}: task 0 has no {' or '.join(kinds)} load for the validation")


def reference(spec: CaseSpec) -> float:
    """``coefficient * scale`` from the case's own load, material, thickness and [validation] lengths.

    q is the pressure of task 0's pressure load, P = |Fz| of its patch (point) load, F = |Fx| of its
    edge traction; a, b, L come from the [validation] table; E, t, D from the case.
    """
    v = spec.validation
    L = v.lengths
    need = {"q a^4 / D": ("a",), "P a^2 / D": ("a",), "F L / (E b t)": ("L", "b")}.get(v.scale, ())
    for k in need:
        if k not in L:  # the spec reader does not tie the lengths to the scale; say which is missing
            raise CaseError(spec.source, f"validation.{k}_<unit>", f"missing (the scale {v.scale} needs it)")
    E, t = spec.material.E, spec.thickness
    if v.scale == "q a^4 / D":
        q = abs(_load_of(spec, ("pressure",)).magnitude)
        scale = q * L["a"] ** 4 / flexural_rigidity(spec)
    elif v.scale == "P a^2 / D":
        P = abs(_load_of(spec, ("patch",)).force[2])
        scale = P * L["a"] ** 2 / flexural_rigidity(spec)
    elif v.scale == "F L / (E b t)":
        F = abs(_load_of(spec, ("edge_traction", "patch")).force[0])
        scale = F * L["L"] / (E * L["b"] * t)
    else:  # the spec reader only lets the three above through
        raise ValueError(f"{spec.source}: unknown validation scale {v.scale!r}")
    return float(v.coefficient * scale)


def series_reference(spec: CaseSpec, terms: int = 801) -> float | None:
    """Navier's exact deflection where it applies, else None.

    It applies to a rectangle from (0, 0) to (a, b), all of whose outer boundary is simply supported
    (w held, rotation free) and nothing else, loaded in task 0 by one uniform pressure or one point
    force normal to the plate.
    """
    v = spec.validation
    if v.quantity != "w" or "a" not in v.lengths:
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
    D = flexural_rigidity(spec)
    x, y = v.at
    if ld.kind == "pressure" and ld.region is None:
        return abs(navier_ss_rectangle(a, b, D, ("uniform", ld.magnitude), x, y, terms))
    if ld.kind == "patch" and ld.radius == 0 and not np.any(ld.force[:2]):
        return abs(navier_ss_rectangle(a, b, D, ("point", ld.force[2], tuple(ld.at)), x, y, terms))
    return None


def probe_value(spec: CaseSpec, model=None) -> float:
    """Signed quantity at the validation point, task 0, no fixtures (direct solve).

    Signs are the code's: w positive along +z (a positive pressure pushes along +z).
    """
    from fixbench.cases.fem import PlateModel  # heavy import only when a model is solved

    v = spec.validation
    model = model if model is not None else PlateModel(spec)
    fields = model.solve_direct(0, np.zeros((0, 2)))
    field = "bending" if v.quantity == "w" else "membrane"
    if field not in fields:
        return 0.0  # the task does not load this field: its response is zero
    vals = model.component_probes(field, v.at[None, :]) @ fields[field]
    # bending: one row (w); membrane: component-major rows (ux, then uy)
    return float(vals[{"w": 0, "ux": 0, "uy": 1}[v.quantity]])


def computed(spec: CaseSpec, model=None) -> float:
    """|quantity| at the validation point (tables give magnitudes along the load)."""
    return abs(probe_value(spec, model))


def validate_spec(spec: CaseSpec) -> dict:
    """One validation row for a parsed case (see :func:`validate`)."""
    if spec.validation is None:
        raise ValueError(f"{spec.source}: the case has no [validation] table")
    from fixbench.cases.fem import PlateModel

    model = PlateModel(spec)
    value = probe_value(spec, model)
    comp, ref = abs(value), reference(spec)
    row = {"name": spec.name, "quantity": spec.validation.quantity, "computed": comp, "value": value,
           "reference": ref, "rel_error": float(abs(comp - ref) / abs(ref)),
           "coefficient": spec.validation.coefficient, "scale": spec.validation.scale,
           "mesh_size": spec.mesh.size, "elements": int(model.mesh.t.shape[1])}
    series = series_reference(spec)
    row["series"] = series
    row["series_rel_error"] = None if series is None else float(abs(comp - series) / series)
    return row


def validate(names=None) -> list[dict]:
    """Solve every validation case (or ``names``) and compare with its analytic reference.

    Each row: ``name``, ``quantity``, ``computed`` and ``reference`` (metres, magnitudes: w is
    positive along +z in the code while the tables give the deflection along the load), ``value``
    (the signed computed quantity),
    ``rel_error`` = |computed - reference| / reference, and for simply supported rectangles the
    exact Navier value ``series`` with ``series_rel_error``; also mesh size and element count.
    """
    names = validation_names() if names is None else list(names)
    return [validate_spec(load_case_spec(n)) for n in names]
