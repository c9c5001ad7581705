"""Part geometry (shapely) and triangular meshes (Triangle).

Why Triangle rather than gmsh: the parts are flat polygons with holes, which is exactly what
Shewchuk's Triangle meshes (constrained, quality Delaunay), it is a small deterministic wheel with
no GUI or OpenGL libraries, and it remeshes with per-triangle area limits, which is all a graded
size field needs. gmsh would add a large native dependency for features a 2-D plate does not use.

Shapes come from shapely (circles, ellipses, slots, rounded rectangles and offsets are buffers and
affine maps of points, lines and boxes) and outlines drawn in CAD from DXF files through ezdxf
(:func:`read_dxf`); nothing here computes a curve by hand.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import shapely
import shapely.affinity
import shapely.ops
import shapely.validation

from fixbench.cases.errors import CaseError

if TYPE_CHECKING:
    from skfem import MeshTri

#: segments per quarter circle of every round shape and offset (circles are 64-gons)
QUAD_SEGS = 16
#: DXF entities that are curves of an outline; any other entity on the layers read is refused
DXF_CURVES = ("LINE", "ARC", "CIRCLE", "ELLIPSE", "SPLINE", "LWPOLYLINE", "POLYLINE")


class ShapeError(ValueError):
    """A shape that cannot be built; the case reader names the key it came from."""


def circle(cx: float, cy: float, r: float) -> shapely.Polygon:
    return shapely.Point(cx, cy).buffer(r, quad_segs=QUAD_SEGS)


def ellipse(cx: float, cy: float, a: float, b: float, angle: float = 0.0) -> shapely.Polygon:
    """Semi-axes ``a`` (along x before rotation) and ``b``, turned by ``angle`` (rad) about its centre."""
    unit = shapely.Point(0.0, 0.0).buffer(1.0, quad_segs=QUAD_SEGS)
    shape = shapely.affinity.rotate(shapely.affinity.scale(unit, a, b, origin=(0, 0)), angle,
                                    origin=(0, 0), use_radians=True)
    return shapely.affinity.translate(shape, cx, cy)


def slot(x0: float, y0: float, x1: float, y1: float, width: float) -> shapely.Polygon:
    """A slot (stadium): the end arcs centred on (x0, y0) and (x1, y1), ``width`` across."""
    return shapely.LineString([(x0, y0), (x1, y1)]).buffer(width / 2, quad_segs=QUAD_SEGS)


def rectangle(x0: float, y0: float, x1: float, y1: float, corner: float = 0.0,
              angle: float = 0.0) -> shapely.Polygon:
    """A rectangle, its corners rounded to radius ``corner``, turned by ``angle`` (rad) about its centre."""
    box = shapely.box(x0 + corner, y0 + corner, x1 - corner, y1 - corner)
    shape = box.buffer(corner, quad_segs=QUAD_SEGS) if corner else box
    return shapely.affinity.rotate(shape, angle, origin="center", use_radians=True) if angle else shape


def offset(shape: shapely.Polygon, distance: float) -> shapely.Polygon:
    """``shape`` grown by ``distance`` (shrunk where negative), its convex corners rounded."""
    grown = shape.buffer(distance, quad_segs=QUAD_SEGS)
    if not isinstance(grown, shapely.Polygon) or grown.is_empty:
        raise ShapeError(f"an offset of {distance * 1e3:g} mm leaves {_pieces(grown)}, not one shape")
    return grown


def _pieces(geom) -> str:
    return "nothing" if geom.is_empty else f"{len(shapely.get_parts(geom))} separate pieces"


def read_dxf(path: str, unit: float | None, layers: tuple[str, ...], tolerance: float) -> shapely.Polygon:
    """The part drawn in a DXF file's model space: its closed loops, nested even-odd (an outline,
    its holes, islands in the holes), in metres.

    ``unit`` is the drawing unit in metres named by the case file, ``None`` to take the header's
    ``$INSUNITS``; curves are flattened by ezdxf to chords within ``tolerance`` (m) of the curve.
    Lines and arcs meeting end to end close a loop as well as a closed polyline does (shapely nodes
    the linework and builds the area); linework that closes no loop is refused, not dropped.
    """
    import ezdxf
    from ezdxf import path as dxf_path

    try:
        doc = ezdxf.readfile(path)
    except OSError as exc:
        raise ShapeError(f"cannot read {path} ({exc.strerror or exc})") from None
    except ezdxf.DXFStructureError as exc:
        raise ShapeError(f"{path} is not a readable DXF file ({exc})") from None
    scale = _dxf_scale(doc.header.get("$INSUNITS", 0), unit)
    lines = []
    for e in doc.modelspace():
        if layers and e.dxf.layer not in layers:
            continue
        if e.dxftype() not in DXF_CURVES:
            raise ShapeError(f"{path}: a {e.dxftype()} on layer '{e.dxf.layer}' is not a curve "
                             f"({', '.join(DXF_CURVES)}); read only the outline's layers with layers = [...]")
        pts = [(v.x, v.y) for v in dxf_path.make_path(e).flattening(tolerance / scale)]
        lines.append(shapely.LineString(np.array(pts) * scale))
    if not lines:
        raise ShapeError(f"{path}: no curve" + (f" on the layers {', '.join(layers)}" if layers else ""))
    return _area(shapely.set_precision(shapely.union_all(lines), 1e-9), path)


def _dxf_scale(insunits: int, unit: float | None) -> float:
    """Metres per drawing unit: the key's unit, the header's, and both agreeing if both are given."""
    from ezdxf import units

    if insunits == 0:
        if unit is None:
            raise ShapeError("the DXF file declares no units ($INSUNITS = 0): name them in the key, "
                             "e.g. dxf_mm")
        return unit
    try:
        declared = units.conversion_factor(insunits, units.InsertUnits.Meters)
    except ValueError:
        raise ShapeError(f"the DXF file's $INSUNITS = {insunits} is no unit ezdxf knows") from None
    if unit is not None and not np.isclose(unit, declared, rtol=1e-9):
        raise ShapeError(f"the DXF file declares {units.unit_name(insunits).lower()} "
                         f"($INSUNITS = {insunits}), the key another unit; give dxf = \"...\" to "
                         f"take the file's")
    return declared


def _area(linework, path: str) -> shapely.Polygon:
    _, cuts, dangles, _ = shapely.polygonize_full(shapely.get_parts(linework))
    loose = shapely.get_parts(shapely.union_all([cuts, dangles]))
    if len(loose):
        x, y = np.asarray(loose[0].coords[0]) * 1e3
        raise ShapeError(f"{path}: {len(loose)} piece(s) of linework close no loop (the first from "
                         f"({x:.3f}, {y:.3f}) mm)")
    area = shapely.build_area(linework)
    if not isinstance(area, shapely.Polygon) or area.is_empty:
        raise ShapeError(f"{path}: the closed loops make {_pieces(area)}, not one part")
    return shapely.Polygon(_canonical(area.exterior), [_canonical(h) for h in area.interiors])


def _canonical(ring) -> np.ndarray:
    """A ring's vertices counter-clockwise from its lowest-left one (least x, then least y), as a
    hand-written ``rectangle_*`` lists them, so that a drawing and the same part written by hand
    give the same polygon (and mesh)."""
    pts = np.asarray(ring.coords)[:-1]
    if not shapely.LinearRing(pts).is_ccw:
        pts = pts[::-1]
    return np.roll(pts, -int(np.lexsort((pts[:, 1], pts[:, 0]))[0]), axis=0)


def build_polygon(shapes, reader) -> shapely.Polygon:
    """Combine the case's shapes (unions and differences, rotated copies) into one polygon.

    A shape with holes (a DXF part) is its outline, then each hole with the other op: the same steps
    as the outline and its holes written one by one as ``polygon_*`` shapes.
    """
    part = None
    for s in shapes:
        for op, ring in [(s.op, s.polygon)] + [(_OTHER[s.op], h) for h in s.holes]:
            shape = _copies(shapely.Polygon(ring), s, reader)
            part = shape if part is None else (part.union(shape) if op == "union" else part.difference(shape))
    part = shapely.set_precision(part, 1e-9)
    if not isinstance(part, shapely.Polygon) or part.is_empty:
        raise reader.error("shapes", "the shapes do not make one connected part")
    return shapely.Polygon(part.exterior, part.interiors)


_OTHER = {"union": "difference", "difference": "union"}


def _copies(poly: shapely.Polygon, s, reader):
    if not poly.is_valid:
        why = shapely.validation.explain_validity(poly)
        raise reader.error(s.key, f"outline is not a simple polygon ({why})")
    if poly.area <= 0:
        raise reader.error(s.key, "polygon has no area")
    copies = [shapely.affinity.rotate(poly, 360.0 * k / s.copies, origin=s.about) for k in range(s.copies)]
    return shapely.union_all(copies)


def size_field(spec, points: np.ndarray) -> np.ndarray:
    """Target element size at ``points``: the global size, finer within the refinement bands."""
    h = np.full(len(points), spec.mesh.size)
    for ref in spec.mesh.refine:
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(ref.points).query(points)
        local = ref.size + spec.mesh.grading * np.maximum(0.0, dist - ref.width)
        h = np.minimum(h, local)
    return h


def _rings(polygon: shapely.Polygon):
    yield polygon.exterior, None
    for hole in polygon.interiors:
        inner = shapely.Polygon(hole)
        yield hole, np.asarray(inner.representative_point().coords[0])


def _lines(spec):
    """The closed rings the mesh must follow: the part's boundary and, where the case has thickness
    regions, the boundary and the regions' outlines noded together (a step in thickness then lies on
    element edges). Each ring is (coordinates without the closing point, closed?)."""
    if not spec.regions:
        for ring, _ in _rings(spec.polygon):
            yield np.asarray(ring.coords)[:-1], True
        return
    lines = [spec.polygon.boundary] + [r.polygon.boundary for r in spec.regions]
    noded = shapely.line_merge(shapely.union_all(lines))
    for line in getattr(noded, "geoms", [noded]):
        coords = np.asarray(line.coords)
        closed = bool(np.allclose(coords[0], coords[-1]))
        yield (coords[:-1] if closed else coords), closed


def _pslg(spec):
    """Vertices and segments of the boundary (and region outlines), split so that no segment exceeds
    the local size."""
    verts, segs, holes = [], [], []
    for _, hole_point in _rings(spec.polygon):
        if hole_point is not None:
            holes.append(hole_point)
    index: dict[tuple[float, float], int] = {}

    def vertex(p) -> int:  # shared by every line that reaches the same point
        key = (round(float(p[0]), 12), round(float(p[1]), 12))
        if key not in index:
            index[key] = len(verts)
            verts.append(np.asarray(p, dtype=float))
        return index[key]

    for coords, closed in _lines(spec):
        ends = zip(coords, np.roll(coords, -1, axis=0)) if closed else zip(coords[:-1], coords[1:])
        ring_pts = []
        for a, b in ends:
            length = np.linalg.norm(b - a)
            h = size_field(spec, np.array([a, b, (a + b) / 2])).min()
            n = max(1, int(np.ceil(length / h)))
            ring_pts.extend(a + (b - a) * t for t in np.arange(n) / n)
        if not closed:
            ring_pts.append(coords[-1])
        ids = [vertex(p) for p in ring_pts]
        pairs = zip(ids, ids[1:] + ids[:1]) if closed else zip(ids[:-1], ids[1:])
        segs.extend([i, j] for i, j in pairs if i != j)
    pslg = {"vertices": np.array(verts), "segments": np.array(segs, dtype=np.int32)}
    if holes:
        pslg["holes"] = np.array(holes)
    return pslg


def make_mesh(spec, max_passes: int = 8) -> MeshTri:
    """Quality triangulation of the part, graded to :func:`size_field` (deterministic).

    Triangle meshes the boundary with a uniform area bound, then the mesh is refined pass by pass,
    each triangle limited to the area of an equilateral triangle of the local target size, until
    every triangle meets its limit.
    """
    import triangle  # mesh libraries: imported by the commands that mesh, not by every start
    from skfem import MeshTri

    pslg = _pslg(spec)
    q = f"pq{spec.mesh.min_angle_deg:g}"
    area = lambda h: np.sqrt(3.0) / 4.0 * h**2  # noqa: E731 - equilateral triangle of side h
    tri = triangle.triangulate(pslg, f"{q}a{area(spec.mesh.size):.12g}Q")
    for _ in range(max_passes):
        v, t = tri["vertices"], tri["triangles"]
        centroids = v[t].mean(axis=1)
        limit = area(size_field(spec, centroids))
        x, y = v[t][:, :, 0], v[t][:, :, 1]
        actual = 0.5 * np.abs((x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0])
                              - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0]))
        if np.all(actual <= 1.5 * limit):
            break
        tri["triangle_max_area"] = limit
        tri = triangle.triangulate(tri, f"r{q}aQ")
    v, t = tri["vertices"], tri["triangles"]
    if len(t) == 0:
        raise CaseError(spec.source, "mesh", "Triangle produced no elements")
    return MeshTri(np.ascontiguousarray(v.T, dtype=float), np.ascontiguousarray(t.T))


def measurement_points(spec) -> np.ndarray:
    """Where deformation is measured: a grid, the boundary, and the located loads of the tasks.

    The points are physical (independent of the mesh), so refining the mesh does not change what
    "maximum deformation" means; their spacing is the case's ``measure.spacing``.
    """
    s = spec.measure_spacing
    poly = spec.polygon
    x0, y0, x1, y1 = poly.bounds
    gx, gy = np.meshgrid(np.arange(x0 + s / 2, x1, s), np.arange(y0 + s / 2, y1, s), indexing="ij")
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    inner = poly.buffer(-1e-6)
    grid = grid[shapely.contains_xy(inner, grid[:, 0], grid[:, 1])]
    edge = []
    for ring, _ in _rings(poly):
        n = max(8, int(np.ceil(ring.length / s)))
        pts = np.array([ring.interpolate(d).coords[0] for d in np.arange(n) * ring.length / n])
        edge.append(pts)
    loads = [ld.at for t in spec.tasks for ld in t.loads if ld.at is not None]
    pts = np.vstack(edge + [grid] + ([np.array(loads)] if loads else []))
    # keep one point per cell of size s/2 (drill lines are dense) in a stable order
    key = np.round(pts / (s / 2)).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return inward(poly, pts[np.sort(first)])


def inward(poly: shapely.Polygon, pts: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """Move points that lie on (or just outside) the boundary a hair inside, for point location."""
    pts = np.array(pts, dtype=float)
    inner = poly.buffer(-eps)
    out = ~shapely.contains_xy(inner, pts[:, 0], pts[:, 1])
    for i in np.flatnonzero(out):
        p = shapely.Point(pts[i])
        near = shapely.ops.nearest_points(inner, p)[0]
        pts[i] = near.coords[0]
    return pts
