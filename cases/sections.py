"""What a case's plate is made of: its material or layup, and its thickness regions (docs/cases.md).

A part is one material (an isotropic grade, or a laminate of plies from :data:`PLIES`) of one
thickness, except inside its ``[[regions]]``: pad-ups, lands and doublers drawn with the same shape
keys as the outline, each with its own thickness (an isotropic part) or its own plies. The FE model
takes the stiffness element by element (fixbench.cases.fem); the mesh follows the regions' outlines
(fixbench.cases.geometry), so a step in thickness lies on element edges.

Every problem is a one-line :class:`~fixbench.cases.errors.CaseError` naming the key as written.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import shapely

from fixbench.cases.materials import MATERIALS, PLIES, SYMMETRY_TOLERANCE, Laminate, Layer, Material, Ply
from fixbench.cases.shapes import KINDS, MODIFIERS, base_name, parse_shape
from fixbench.cases.units import Reader

#: thin-plate limit: thickness over the part's span (the shorter side of its smallest enclosing
#: rectangle) at most this; beyond it transverse shear, which Kirchhoff theory leaves out, matters
THIN_LIMIT = 0.1


@dataclass(frozen=True)
class Region:
    """A part of the plate with its own thickness or layup (``polygon`` clipped to the part)."""

    name: str
    polygon: shapely.Polygon | shapely.MultiPolygon
    material: Material | Laminate
    thickness: float

    def stiffness(self) -> tuple[np.ndarray, np.ndarray, float]:
        return self.material.stiffness(self.thickness)


def section_index(regions: tuple[Region, ...], x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The section at each point: 0 the plate, i + 1 region i (a later region over an earlier one:
    overlapping regions carry the same section)."""
    section = np.zeros(np.shape(x), dtype=np.int64)
    for i, region in enumerate(regions):
        section[shapely.contains_xy(region.polygon, x, y)] = i + 1
    return section


def read_material(r: Reader) -> Material | Laminate:
    """``[material]``: a grade (with any of E, nu, density overridden) or a layup of plies."""
    if r.has("plies"):
        name = r.text("name")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or name in MATERIALS:
            raise r.error("name", f"a layup's name is a label of letters, digits, '_', '.' or '-' that is not "
                                  f"a grade's ({', '.join(MATERIALS)}); got '{name}'")
        lam = read_layup(r, name)
        r.finish()
        return lam
    name = r.text("name")
    if name not in MATERIALS:
        raise r.error("name", f"unknown material '{name}' (known: {', '.join(MATERIALS)}; or give "
                              "[[material.plies]] for a laminate)")
    base = MATERIALS[name]
    mat = Material(name, r.number("E", "pressure", base.E, positive=True),
                   r.number("nu", None, base.nu), r.number("density", "density", base.density,
                                                           positive=True))
    if not -1.0 < mat.nu < 0.5:
        raise r.error("nu", f"Poisson's ratio must lie in (-1, 0.5), got {mat.nu:g}")
    r.finish()
    return mat


def read_layup(r: Reader, name: str) -> Laminate:
    """``[[<table>.plies]]`` groups (bottom to top; a group is its ``angles_<unit>`` in order, ``repeat``
    times, each ply of one ply material and thickness) and ``symmetric`` (the list is the lower half,
    mirrored above the mid-plane); refuses an unsymmetric stack."""
    layers: list[Layer] = []
    for g in r.tables("plies"):
        ply = _ply(g)
        angles = g.array("angles", "angle", shape=(-1,))
        if len(angles) == 0:
            raise g.error(next(k for k in g.data if base_name(k) == "angles"), "lists no ply")
        thickness = g.number("thickness", "length", positive=True)
        layers.extend(Layer(ply, float(a), thickness) for _ in range(g.integer("repeat", 1, minimum=1))
                      for a in angles)
        g.finish()
    if not layers:
        raise r.error("plies", "lists no ply")
    if r.raw("symmetric", False, (bool,)):
        layers = layers + layers[::-1]
    lam = Laminate(name, tuple(layers))
    coupling = lam.coupling()
    if coupling > SYMMETRY_TOLERANCE:
        raise r.error("plies", f"the layup is not symmetric about its mid-plane (|B| / (|A| t) = {coupling:.2g}): "
                               "fixbench models symmetric layups, whose membrane and bending stay apart; list "
                               "both halves, or the lower half with symmetric = true")
    return lam


def _ply(g: Reader) -> Ply:
    name = g.text("ply")
    if name not in PLIES:
        raise g.error("ply", f"unknown ply material '{name}' (known: {', '.join(PLIES)})")
    b = PLIES[name]
    ply = Ply(name, g.number("E1", "pressure", b.E1, positive=True), g.number("E2", "pressure", b.E2, positive=True),
              g.number("G12", "pressure", b.G12, positive=True), g.number("nu12", None, b.nu12),
              g.number("density", "density", b.density, positive=True))
    if not 0.0 <= ply.nu12 < np.sqrt(ply.E1 / ply.E2):  # Q positive definite: nu12 nu21 < 1
        raise g.error("nu12", f"must lie in [0, sqrt(E1 / E2)) = [0, {np.sqrt(ply.E1 / ply.E2):.3g}), got {ply.nu12:g}")
    return ply


def span(polygon: shapely.Polygon) -> float:
    """The shorter side of the part's smallest enclosing rectangle (m)."""
    ring = np.asarray(shapely.minimum_rotated_rectangle(polygon).exterior.coords)
    sides = np.linalg.norm(np.diff(ring[:3], axis=0), axis=1)
    return float(sides.min())


def check_thin(r: Reader, key: str, thickness: float, polygon: shapely.Polygon) -> None:
    """Refuse a thickness beyond thin-plate theory (:data:`THIN_LIMIT` of the part's span)."""
    s = span(polygon)
    if thickness > THIN_LIMIT * s:
        raise r.error(key, f"{thickness * 1e3:g} mm is thicker than the plate model allows: t / span = "
                           f"{thickness / s:.3g} above {THIN_LIMIT:g} (span {s * 1e3:.4g} mm, the part's narrower "
                           "side), where Kirchhoff theory leaves out transverse shear")


def read_regions(top: Reader, polygon: shapely.Polygon, material: Material | Laminate,
                 thickness: float) -> tuple[Region, ...]:
    """``[[regions]]``: each a shape, a name, and its own ``thickness_<unit>`` or plies."""
    regions: list[Region] = []
    for i, r in enumerate(top.tables("regions")):
        name = r.text("name", f"region {i}")
        shape_keys = {k: v for k, v in r.data.items()
                      if k != "op" and (base_name(k) in KINDS or base_name(k) in MODIFIERS)}
        shape = parse_shape(Reader(shape_keys, r.source, r.prefix))
        r.used.update(shape_keys)
        drawn = shapely.union_all([shapely.affinity.rotate(shapely.Polygon(shape.polygon, shape.holes),
                                                           360.0 * k / shape.copies, origin=shape.about)
                                   for k in range(shape.copies)])
        clipped = drawn.intersection(polygon)
        if clipped.area <= 1e-9 * polygon.area:
            drawn_key = next(k for k in shape_keys if base_name(k) in KINDS)
            raise r.error(drawn_key, f"region '{name}' covers no part of the plate")
        if r.has("plies"):
            if r.has("thickness"):
                raise r.error(next(k for k in r.data if base_name(k) == "thickness"),
                              "a region with plies takes its thickness from them")
            mat: Material | Laminate = read_layup(r, f"{material.name}.{name}")
            t, key = mat.thickness, "plies"
        else:
            if isinstance(material, Laminate):
                raise r.error("plies", "missing: a region of a laminate gives its own [[regions.plies]]")
            mat = material
            t = r.number("thickness", "length", positive=True)
            key = next(k for k in r.data if base_name(k) == "thickness")
        check_thin(r, key, t, polygon)
        region = Region(name, clipped, mat, t)
        for other in regions:
            if (other.material, other.thickness) != (mat, t) and \
                    other.polygon.intersection(clipped).area > 1e-9 * polygon.area:
                raise r.error(key, f"region '{name}' overlaps region '{other.name}' with a different "
                                   "thickness or layup: which one holds there is not said")
        regions.append(region)
        r.finish()
    return tuple(regions)
