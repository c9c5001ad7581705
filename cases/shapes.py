"""The shapes of a case file's ``[[geometry.shapes]]`` and the curves drilling tasks run along.

Every key of a shape table is checked when the case is loaded: a key no shape takes, a second kind
of shape in one table or a key of another kind (``corner_radius_mm`` on a circle) is named as the
file writes it, with the keys that are allowed. The shapes themselves are shapely's (and ezdxf's for
DXF files): :mod:`fixbench.cases.geometry`. The format: docs/cases.md#shapes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import shapely

from fixbench.cases import geometry
from fixbench.cases.errors import CaseError
from fixbench.cases.geometry import ShapeError
from fixbench.cases.units import UNITS, Reader

#: the kinds of shape, as a message lists them
KINDS = {"polygon": "polygon_<unit>", "circle": "circle_<unit>", "rectangle": "rectangle_<unit>",
         "ellipse": "ellipse_<unit>", "slot": "slot_<unit>", "dxf": "dxf or dxf_<unit>"}
#: the other keys of a shape, as a message lists them, and the kinds each is for (None: every kind)
MODIFIERS = {"op": ("op", None), "copies": ("copies", None), "about": ("about_<unit>", None),
             "offset": ("offset_<unit>", None), "corner_radius": ("corner_radius_<unit>", ("rectangle",)),
             "angle": ("angle_<unit>", ("rectangle", "ellipse")), "layers": ("layers", ("dxf",)),
             "tolerance": ("tolerance_<unit>", ("dxf",))}
#: how far (m) a flattened DXF curve may stray from the curve, unless the shape gives tolerance_<unit>
DXF_TOLERANCE = 0.05e-3
#: where the positions of a drilling group come from
DRILL_KEYS = {"points": "points_<unit>", "line": "line_<unit>", "along": "along or along_<unit>"}
_SUFFIXES = sorted({s for table in UNITS.values() for s in table}, key=len, reverse=True)


@dataclass(frozen=True)
class Shape:
    """One shape of the outline: ``op`` is union or difference; ``polygon`` is its outer vertices
    and ``holes`` its inner rings (a DXF part's holes)."""

    op: str
    polygon: np.ndarray  # (n, 2) m
    copies: int = 1
    about: tuple[float, float] = (0.0, 0.0)
    key: str = "outline_mm"  # where it came from in the file, for error messages
    holes: tuple[np.ndarray, ...] = ()


def base_name(key: str) -> str:
    """``key`` without a unit suffix: ``corner_radius_mm`` -> ``corner_radius``; every ``dxf_*`` is
    ``dxf`` (its unit is checked when the file is read)."""
    if key.startswith("dxf_"):
        return "dxf"
    for s in _SUFFIXES:
        if key.endswith("_" + s) and len(key) > len(s) + 1:
            return key[: -len(s) - 1]
    return key


def one_of(r: Reader, names: dict[str, str], what: str) -> tuple[str, str]:
    """The one of ``names`` (name -> how a message lists it) that the table gives, and its key as
    written; none, or two, is refused naming the keys as the file writes them."""
    given = [(base_name(k), k) for k in r.data if base_name(k) in names]
    allowed = ", ".join(names.values())
    if not given:
        raise CaseError(r.source, r.prefix, f"{what}: give one of {allowed}")
    if len(given) > 1:
        raise r.error(given[1][1], f"conflicts with {given[0][1]}: give exactly one of {allowed}")
    return given[0]


def parse_shape(s: Reader) -> Shape:
    """One ``[[geometry.shapes]]`` table, every key checked (see the module docstring)."""
    listing = (f"one of {', '.join(KINDS.values())}; and {', '.join(m for m, _ in MODIFIERS.values())}")
    for k in s.data:
        if base_name(k) not in KINDS and base_name(k) not in MODIFIERS:
            raise s.error(k, f"unknown key; a shape takes {listing}")
    kind, key = one_of(s, KINDS, "no shape")
    for k in s.data:
        only = MODIFIERS.get(base_name(k), ("", None))[1]
        if only is not None and kind not in only:
            raise s.error(k, f"only {' or '.join(KINDS[o] for o in only)} takes it, not {key}")
    op = s.text("op", "union", ("union", "difference"))
    try:
        shape = _BUILDERS[kind](s, key)
    except ShapeError as exc:
        raise s.error(key, str(exc)) from None
    if s.has("offset"):
        distance = s.number("offset", "length")
        try:
            shape = geometry.offset(shapely.Polygon(shape) if isinstance(shape, np.ndarray) else shape, distance)
        except ShapeError as exc:
            raise s.error(written(s, "offset"), str(exc)) from None
    copies = s.integer("copies", 1, minimum=1)
    about = tuple(s.array("about", "length", np.zeros(2), shape=(2,)))
    s.finish()
    where = s.prefix.split(".", 1)[-1]
    if isinstance(shape, np.ndarray):
        return Shape(op, shape, copies, about, key=where)
    holes = tuple(np.asarray(h.coords)[:-1] for h in shape.interiors)
    return Shape(op, np.asarray(shape.exterior.coords)[:-1], copies, about, key=where, holes=holes)


def written(r: Reader, name: str) -> str:
    """The key ``name`` as the file writes it (``name`` or ``name_<unit>``)."""
    return next((k for k in r.data if base_name(k) == name), name)


def _polygon(s: Reader, key: str) -> np.ndarray:
    return s.array("polygon", "length", shape=(-1, 2))


def _circle(s: Reader, key: str) -> shapely.Polygon:
    c = s.array("circle", "length", shape=(3,))
    if c[2] <= 0:
        raise ShapeError("radius (third value) must be positive")
    return geometry.circle(*c)


def _rectangle(s: Reader, key: str) -> np.ndarray | shapely.Polygon:
    x0, y0, x1, y1 = s.array("rectangle", "length", shape=(4,))
    if x1 <= x0 or y1 <= y0:
        raise ShapeError("must be [x0, y0, x1, y1] with x1 > x0 and y1 > y0")
    corner = s.number("corner_radius", "length", 0.0, positive=True)
    angle = s.number("angle", "angle", 0.0)
    if corner >= min(x1 - x0, y1 - y0) / 2:
        raise s.error(written(s, "corner_radius"), f"must be less than half the shorter side "
                      f"({min(x1 - x0, y1 - y0) * 1e3 / 2:g} mm); round ends: slot_<unit>")
    if not corner and not angle:
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return geometry.rectangle(x0, y0, x1, y1, corner, angle)


def _ellipse(s: Reader, key: str) -> shapely.Polygon:
    e = s.array("ellipse", "length", shape=(4,))
    if e[2] <= 0 or e[3] <= 0:
        raise ShapeError("must be [cx, cy, a, b] with positive semi-axes a and b")
    return geometry.ellipse(*e, s.number("angle", "angle", 0.0))


def _slot(s: Reader, key: str) -> shapely.Polygon:
    x0, y0, x1, y1, width = s.array("slot", "length", shape=(5,))
    if width <= 0 or (x0, y0) == (x1, y1):
        raise ShapeError("must be [x0, y0, x1, y1, width]: two distinct end centres and a positive "
                         "width (one centre: circle_<unit>)")
    return geometry.slot(x0, y0, x1, y1, width)


def _dxf(s: Reader, key: str) -> shapely.Polygon:
    """A DXF file (its path relative to the case file): units from the key (``dxf_mm``) or, for
    plain ``dxf``, from the file's ``$INSUNITS``; both given must agree."""
    unit = None if key == "dxf" else key[len("dxf_"):]
    if unit is not None and unit not in UNITS["length"]:
        raise ShapeError(f"unknown unit '{unit}' for a length (use one of: {', '.join(UNITS['length'])}; "
                         "or plain dxf to take the unit the file declares)")
    path = s.raw(key, types=(str,))
    layers = s.raw("layers", [], (list,))
    if not all(isinstance(x, str) for x in layers):
        raise s.error("layers", "must be a list of layer names")
    tolerance = s.number("tolerance", "length", DXF_TOLERANCE, positive=True)
    return geometry.read_dxf(path, None if unit is None else UNITS["length"][unit], tuple(layers), tolerance)


_BUILDERS = {"polygon": _polygon, "circle": _circle, "rectangle": _rectangle, "ellipse": _ellipse,
             "slot": _slot, "dxf": _dxf}


# ---------------------------------------------------------------------------------------------
# drilling positions
# ---------------------------------------------------------------------------------------------
def drill_points(g: Reader, polygon: shapely.Polygon) -> tuple[np.ndarray, str]:
    """The positions of a drilling group (m) and the key, as written, they come from."""
    kind, key = one_of(g, DRILL_KEYS, "no drilling positions")
    if kind == "points":
        return g.array("points", "length", shape=(-1, 2)), key
    if kind == "line":
        a, b = g.array("line", "length", shape=(2, 2))
        count = g.integer("count", minimum=1)
        return a + np.outer(np.linspace(0.0, 1.0, count), b - a), key
    curve = _ring(g, polygon) if key == "along" else _polyline(g, key)
    return _along(g, curve), key


def _ring(g: Reader, polygon: shapely.Polygon) -> shapely.LinearRing:
    """``along = "outer"`` or ``"hole N"``, moved ``offset_<unit>`` into the part."""
    which = g.text("along")
    m = re.fullmatch(r"hole (\d+)", which)
    if which == "outer":
        ring, into = polygon.exterior, -1.0
    elif m and int(m.group(1)) < len(polygon.interiors):
        ring, into = polygon.interiors[int(m.group(1))], 1.0
    else:
        n = len(polygon.interiors)
        holes = "no hole" if not n else "'hole 0'" if n == 1 else f"'hole 0' to 'hole {n - 1}'"
        raise g.error("along", f"must be 'outer' or 'hole N' (the part has {holes}); got '{which}'")
    distance = g.number("offset", "length", 0.0, nonneg=True)
    if distance:
        try:
            ring = geometry.offset(shapely.Polygon(ring), into * distance).exterior
        except ShapeError as exc:
            raise g.error(written(g, "offset"), str(exc)) from None
    return ring


def _polyline(g: Reader, key: str) -> shapely.LineString:
    """``along_<unit> = [[x, y], ...]`` (closed when its ends meet), moved ``offset_<unit>`` to its
    left (to its right where negative)."""
    pts = g.array("along", "length", shape=(-1, 2))
    if len(pts) < 2 or shapely.LineString(pts).length == 0:
        raise g.error(key, "needs at least two distinct points")
    line = shapely.LinearRing(pts) if len(pts) > 3 and np.array_equal(pts[0], pts[-1]) else shapely.LineString(pts)
    distance = g.number("offset", "length", 0.0)
    if distance:
        moved = shapely.offset_curve(line, distance, quad_segs=geometry.QUAD_SEGS)
        if not isinstance(moved, shapely.LineString) or moved.is_empty:
            raise g.error(written(g, "offset"), f"an offset of {distance * 1e3:g} mm breaks the curve apart")
        line = shapely.LinearRing(moved.coords) if line.is_closed and moved.is_closed else moved
    return line


def _along(g: Reader, curve: shapely.LineString) -> np.ndarray:
    """``count`` positions evenly along the curve, or one every ``pitch_<unit>``: from end to end of
    an open curve; around a closed one counter-clockwise from its point nearest ``start_<unit>``
    (default: the lower-left corner of the curve's bounding box), the last pitch no shorter than
    the others."""
    by, key = one_of(g, {"count": "count", "pitch": "pitch_<unit>"}, "how many positions")
    closed, length = curve.is_closed, curve.length
    if closed and not shapely.LinearRing(curve.coords).is_ccw:
        curve = shapely.LinearRing(curve.coords[::-1])
    if by == "count":
        n = g.integer("count", minimum=1)
        step = length / n if closed else length / max(n - 1, 1)
    else:
        step = g.number("pitch", "length", positive=True)
        if step > length:
            raise g.error(key, f"is longer than the curve ({length * 1e3:.1f} mm)")
        n = int(np.floor(length / step * (1 + 1e-12))) + (0 if closed else 1)
    if closed:
        start = g.array("start", "length", np.array(curve.bounds[:2]), shape=(2,))
        d = (curve.project(shapely.Point(start)) + step * np.arange(n)) % length
    else:
        d = step * np.arange(n)
    return shapely.get_coordinates(shapely.line_interpolate_point(curve, d))
