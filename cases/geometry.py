"""Part geometry (shapely) and triangular meshes (Triangle).

Why Triangle rather than gmsh: the parts are flat polygons with holes, which is exactly what
Shewchuk's Triangle meshes (constrained, quality Delaunay), it is a small deterministic wheel with
no GUI or OpenGL libraries, and it remeshes with per-triangle area limits, which is all a graded
size field needs. gmsh would add a large native dependency for features a 2-D plate does not use.
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


def build_polygon(shapes, reader) -> shapely.Polygon:
    """Combine the case's shapes (unions and differences, rotated copies) into one polygon."""
    part = None
    for s in shapes:
        poly = shapely.Polygon(s.polygon)
        key = s.key
        if not poly.is_valid:
            why = shapely.validation.explain_validity(poly)
            raise reader.error(key, f"outline is not a simple polygon ({why})")
        if poly.area <= 0:
            raise reader.error(key, "polygon has no area")
        copies = [shapely.affinity.rotate(poly, 360.0 * k / s.copies, origin=s.about)
                  for k in range(s.copies)]
        shape = shapely.union_all(copies)
        part = shape if part is None else (part.union(shape) if s.op == "union"
                                           else part.difference(shape))
    part = shapely.set_precision(part, 1e-9)
    if not isinstance(part, shapely.Polygon) or part.is_empty:
        raise reader.error("shapes", "the shapes do not make one connected part")
    return shapely.Polygon(part.exterior, part.interiors)


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


def _pslg(spec):
    """Vertices and segments of the boundary, split so that no segment exceeds the local size."""
    verts, segs, holes = [], [], []
    for ring, hole_point in _rings(spec.polygon):
        coords = np.asarray(ring.coords)[:-1]
        ring_pts = []
        for a, b in zip(coords, np.roll(coords, -1, axis=0)):
            length = np.linalg.norm(b - a)
            h = size_field(spec, np.array([a, b, (a + b) / 2])).min()
            n = max(1, int(np.ceil(length / h)))
            ring_pts.extend(a + (b - a) * t for t in np.arange(n) / n)
        start = len(verts)
        verts.extend(ring_pts)
        m = len(ring_pts)
        segs.extend([start + i, start + (i + 1) % m] for i in range(m))
        if hole_point is not None:
            holes.append(hole_point)
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
