"""Case files: TOML -> validated, SI-unit dataclasses.

A case describes one part and its fixture problem: geometry, mesh density, material, base supports,
fixture candidates, agents, tasks (load cases) and reward settings. The format is documented in
docs/cases.md#case-files; :func:`load_case_spec` is the only reader. Every problem found in a file is a
one-line :class:`~fixbench.cases.errors.CaseError` naming file, key and problem.
"""

from __future__ import annotations

import hashlib
import os
import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import shapely

from fixbench.cases.errors import CaseError
from fixbench.cases.geometry import build_polygon
from fixbench.cases.materials import MATERIALS, Laminate, Material
from fixbench.cases.sections import Region, read_material, read_regions
from fixbench.cases.shapes import Shape, base_name, drill_points, one_of, parse_shape, written
from fixbench.cases.units import Reader

CATALOG = Path(__file__).parent / "catalog"
#: the shipped suites of generated parts (docs/families.md#suites), each part a case by its name
SUITES = Path(__file__).parent / "suites"
DOF_NAMES = ("ux", "uy", "w", "rot")
SUPPORT_KINDS = {"clamped": ("ux", "uy", "w", "rot"), "pinned": ("ux", "uy", "w"),
                 "simple": ("w",), "membrane": ("ux", "uy")}
#: where a base support holds the part, as a message lists the keys
SUPPORT_PLACES = {"segment": "segment_<unit>", "hole": "hole", "boundary": "boundary", "point": "point_<unit>"}
FIELD_OF = {"ux": "membrane", "uy": "membrane", "w": "bending", "rot": "bending"}
#: standard gravity (m/s^2): the ``weight`` load is rho g t along -z
STANDARD_GRAVITY = 9.80665


# ---------------------------------------------------------------------------------------------
# dataclasses (SI units throughout)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Refine:
    """Mesh refinement: element size ``size`` within ``width`` of the points, graded outside."""

    points: np.ndarray  # (n, 2) m
    size: float
    width: float


@dataclass(frozen=True)
class MeshSpec:
    size: float  # target element edge length away from refinement (m)
    refine: tuple[Refine, ...] = ()
    grading: float = 0.3  # growth of element size per unit distance beyond a refinement band
    min_angle_deg: float = 30.0


@dataclass(frozen=True)
class Support:
    """A base support: which DOFs it holds and where (boundary facets or nodes near a point)."""

    name: str
    holds: tuple[str, ...]
    segment: np.ndarray | None = None  # (2, 2): boundary facets on this segment
    hole: int | None = None  # boundary of hole i
    outer: bool = False  # whole outer boundary
    point: np.ndarray | None = None  # nodes within radius of this point
    radius: float = 0.0


@dataclass(frozen=True)
class Load:
    """One load. ``kind`` is pressure, weight, centrifugal, patch or edge_traction.

    - pressure: ``magnitude`` Pa normal to the plate (+z), over the part or ``region``.
    - weight: the part's own weight lying flat, rho g t along -z (:data:`STANDARD_GRAVITY`), from
      the material of the model (so it follows a ``--material`` override); ``magnitude`` unused.
    - centrifugal: body force rho t omega^2 r about ``at`` (the axis, normal to the plate),
      ``magnitude`` = omega in rad/s.
    - patch: total ``force`` (Fx, Fy, Fz) spread uniformly over a disc of ``radius`` at ``at``
      (``patch_shape='disc'``; radius 0 is a point load, allowed out of plane only) or over the
      boundary within ``radius`` of ``at`` (``'edge'``).
    - edge_traction: total ``force`` spread uniformly over the boundary lying on ``segment``.
    """

    kind: str
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    magnitude: float = 0.0
    at: np.ndarray | None = None
    radius: float = 0.0
    patch_shape: str = "disc"
    segment: np.ndarray | None = None
    region: np.ndarray | None = None


@dataclass(frozen=True)
class Task:
    """A load case the fixtures must hold the part for; ``features`` feed learners."""

    name: str
    loads: tuple[Load, ...]
    features: np.ndarray


#: the references a [validation] row may name (cases/analytic.py computes each; docs/plate.md)
VALIDATION_SCALES = {"q a^4 / D": ("a",), "P a^2 / D": ("a",), "F L / (E b t)": ("L", "b"),
                     "F L / (b (A11 - A12^2 / A22))": ("L", "b"), "navier": ("a",), "strip": ("L", "b"),
                     "case": ()}


@dataclass(frozen=True)
class Validation:
    """An analytic reference: ``coefficient * scale`` against the computed ``quantity`` at ``at``.

    ``scale`` "case" compares with another catalog case (``case``) at its point ``case_at``: a mirror
    image, the plate turned, the same plate written another way.
    """

    quantity: str
    at: np.ndarray
    coefficient: float
    scale: str
    lengths: dict[str, float]
    label: str = ""
    case: str = ""
    case_at: np.ndarray | None = None


@dataclass(frozen=True)
class Effector:
    """What one robot places: ``per_agent`` pads from its own candidate set.

    ``independent``: any ``per_agent`` distinct candidates of the set; ``pair`` (``per_agent`` = 2): a
    two-pad end effector, two candidates at most ``span`` apart (metres) and at least two pad radii
    (its pads do not overlap). ``idle``: each robot
    also has a "no pad" action. ``pads`` (0: no limit): the most pads placed in all; a layout asking for
    more is served in robot order (robot 0's pads first), so the robots that come too late place none:
    n robots sharing fewer pads than they could hold.
    """

    per_agent: int = 1
    kind: str = "independent"
    span: float = 0.0  # pair: most distance between its pads' centres (m); least: two pad radii
    idle: bool = False
    pads: int = 0

    @property
    def simple(self) -> bool:
        """One pad per robot, never idle, no pad limit: an action is a candidate."""
        return self.per_agent == 1 and not self.idle and self.pads == 0


@dataclass(frozen=True)
class CaseSpec:
    name: str
    source: str
    description: str
    part: str
    material: Material | Laminate
    thickness: float  # the plate's, outside its regions (a laminate's: its plies')
    shapes: tuple[Shape, ...]
    polygon: shapely.Polygon
    mesh: MeshSpec
    supports: tuple[Support, ...]
    fixture_radius: float
    fixture_holds: tuple[str, ...]
    candidates: np.ndarray  # (n, 2) m
    n_agents: int
    agent_regions: tuple[tuple[str, np.ndarray], ...]
    tasks: tuple[Task, ...]
    reward_sigma: tuple[float, float]  # (sigma_x, sigma_z) m, Gaussian reward
    measure_spacing: float
    validations: tuple[Validation, ...] = ()
    candidates_dropped: int = 0  # grid points outside the part or inside a hole, left out of candidates
    effector: Effector = Effector()
    regions: tuple[Region, ...] = ()

    @property
    def thinnest(self) -> float:
        """The least thickness anywhere on the part (w/t is judged against it)."""
        return min([self.thickness, *(r.thickness for r in self.regions)])

    def with_material(self, material: Material) -> CaseSpec:
        """The whole part in another (isotropic) material: the plate and each thickness region keep
        their thickness (a laminate's: its plies')."""
        return replace(self, material=material, regions=tuple(replace(r, material=material) for r in self.regions))

    def with_agents(self, n_agents: int) -> CaseSpec:
        if self.agent_regions:
            raise CaseError(self.source, "agents.regions", "the case names its agents' regions; "
                            "their number cannot be changed")
        if n_agents < 1:
            raise CaseError(self.source, "agents.count", f"must be at least 1, got {n_agents}")
        if n_agents > len(self.candidates):
            raise CaseError(self.source, "agents.count", f"{n_agents} agents but only "
                            f"{len(self.candidates)} fixture candidates")
        return replace(self, n_agents=n_agents)

    def with_fixtures_per_agent(self, m: int) -> CaseSpec:
        """Each robot places ``m`` independent pads (a pair effector keeps its 2)."""
        if m < 1:
            raise CaseError(self.source, "agents.fixtures_per_agent", f"must be at least 1, got {m}")
        if self.effector.kind == "pair" and m != 2:
            raise CaseError(self.source, "agents.fixtures_per_agent", f"a pair effector places 2 pads, "
                            f"got {m}")
        return replace(self, effector=replace(self.effector, per_agent=m))

    def check_pad_limit(self, key: str) -> None:
        """Refuse a pad limit (``agents.pads``) that is no limit: as many pads as the robots could
        place or more (``with_agents`` and ``with_fixtures_per_agent`` may make it so)."""
        pads, n, m = self.effector.pads, self.n_agents, self.effector.per_agent
        if pads and pads >= n * m:
            raise CaseError(self.source, key, f"{n} robots of {m} pad(s) place at most {n * m} pads, so the "
                            f"case's limit of {pads} (agents.pads) would be no limit; ask for more than "
                            f"{pads} pads in all")

    def with_mesh_scale(self, factor: float) -> CaseSpec:
        """Every element size multiplied by ``factor`` (0.5 = twice as fine)."""
        mesh = replace(self.mesh, size=self.mesh.size * factor,
                       refine=tuple(replace(r, size=r.size * factor) for r in self.mesh.refine))
        return replace(self, mesh=mesh)

    def with_tasks(self, indices) -> CaseSpec:
        return replace(self, tasks=tuple(self.tasks[i] for i in indices))


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
def case_names() -> list[str]:
    """Names of the catalog cases."""
    return sorted(p.stem for p in CATALOG.glob("*.toml"))


def resolve_case(name_or_path: str | Path) -> Path:
    """A catalog name or a path to a user's TOML file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise CaseError(str(p), "", "no such case file")
        return p
    cat = CATALOG / f"{name_or_path}.toml"
    if cat.is_file():
        return cat
    if part := suite_part(str(name_or_path)):
        return part
    raise CaseError(str(name_or_path), "", f"unknown case (known: {', '.join(case_names())}; or a part of a "
                    "shipped suite, docs/families.md#suites)")


def suite_part(name: str) -> Path | None:
    """The case file of the generated part ``name`` of a shipped suite (``SUITES/SUITE/FAMILY_sSEED/NAME.toml``),
    or None."""
    found = sorted(SUITES.glob(f"*/*/{name}.toml")) if re.fullmatch(r"[\w.-]+", name) else []
    return found[0] if found else None


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path) if path.parent != CATALOG else f"catalog/{path.name}"


def read_toml(path: Path, chain: tuple[Path, ...] = ()) -> tuple[dict, str]:
    """Parse a case file and merge it over the case it ``extends`` (tables merge, arrays replace)."""
    source = _display(path)
    if path.resolve() in chain:
        raise CaseError(source, "case.extends", "cycle of extends")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(source, "", f"not valid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CaseError(source, "", f"cannot read ({exc})") from None
    _anchor_dxf_paths(data, path.parent)
    base = data.get("case", {}).get("extends") if isinstance(data.get("case"), dict) else None
    if base is None:
        return data, source
    if not isinstance(base, str):
        raise CaseError(source, "case.extends", "must be a case name or a path")
    rel = path.parent / base
    try:
        base_path = rel if rel.suffix == ".toml" and rel.is_file() else resolve_case(base)
    except CaseError as exc:
        raise CaseError(source, "case.extends", exc.problem) from None
    base_data, _ = read_toml(base_path, chain + (path.resolve(),))
    base_data.get("case", {}).pop("name", None)
    data["case"].pop("extends")
    return _merge(base_data, data), source


def _anchor_dxf_paths(data: dict, folder: Path) -> None:
    """A shape's DXF path is relative to the file that names it (so a case that ``extends`` one in
    another folder still finds the base's drawing)."""
    geometry = data.get("geometry")
    shapes = geometry.get("shapes") if isinstance(geometry, dict) else None
    for shape in shapes if isinstance(shapes, list) else ():
        for k, v in shape.items() if isinstance(shape, dict) else ():
            if base_name(k) == "dxf" and isinstance(v, str):
                shape[k] = os.path.normpath(folder / v)


def drawing_digests(data: dict) -> dict[str, str]:
    """sha256 of each DXF file a merged case (:func:`read_toml`) draws its shapes from, by path: what a
    reference's fingerprint adds to the case's TOML, so that a changed drawing is a changed case."""
    geometry = data.get("geometry")
    shapes = geometry.get("shapes") if isinstance(geometry, dict) else None
    out = {}
    for shape in shapes if isinstance(shapes, list) else ():
        for k, v in shape.items() if isinstance(shape, dict) else ():
            if base_name(k) == "dxf" and isinstance(v, str) and Path(v).is_file():
                out[v] = hashlib.sha256(Path(v).read_bytes()).hexdigest()
    return out


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_case_spec(name_or_path: str | Path, material: str | None = None,
                   n_agents: int | None = None, fixtures_per_agent: int | None = None) -> CaseSpec:
    """Read and validate a case; ``material`` (a grade, or the case's own material or layup by name),
    ``n_agents`` and ``fixtures_per_agent`` override the file's choice (the overrides together must
    leave a pad limit a limit)."""
    path = resolve_case(name_or_path)
    data, source = read_toml(path)
    spec = parse_case(data, source, default_name=path.stem)
    if material is not None and material != spec.material.name:  # the case's own: nothing to change
        if material not in MATERIALS:
            raise CaseError(source, "--material", f"unknown material '{material}' (known: "
                            f"{', '.join(MATERIALS)}, or the case's own '{spec.material.name}')")
        spec = spec.with_material(MATERIALS[material])
    if fixtures_per_agent is not None:
        spec = spec.with_fixtures_per_agent(fixtures_per_agent)
    if n_agents is not None:
        spec = spec.with_agents(n_agents)
    if n_agents is not None or fixtures_per_agent is not None:
        spec.check_pad_limit("agents.count" if n_agents is not None else "agents.fixtures_per_agent")
    return spec


def parse_case(data: dict, source: str, default_name: str = "case") -> CaseSpec:
    top = Reader(data, source)
    case = top.table("case") or Reader({}, source, "case")
    name = case.text("name", default_name)
    description = case.text("description", "")
    part = case.text("part", name)
    case.finish()

    material = read_material(top.table("material", required=True))
    thickness, shapes, polygon = _geometry(top.table("geometry", required=True), material)
    thickness_regions = read_regions(top, polygon, material, thickness)
    tasks = _tasks(top, polygon)
    mesh = _mesh(top.table("mesh", required=True), tasks)
    supports = tuple(_support(r, polygon) for r in top.tables("supports"))
    radius, holds, candidates, dropped = _fixtures(top.table("fixtures", required=True), polygon)
    n_agents, agent_regions, effector = _agents(top.table("agents", required=True), candidates)

    reward = top.table("reward") or Reader({}, source, "reward")
    sigma = (reward.number("sigma_x", "length", 10e-6, positive=True),
             reward.number("sigma_z", "length", 10e-6, positive=True))
    reward.finish()
    measure = top.table("measure") or Reader({}, source, "measure")
    spacing = measure.number("spacing", "length", mesh.size * 1.5, positive=True)
    measure.finish()
    raw = top.data.get("validation")
    validations = tuple(_validation(v) for v in (top.tables("validation") if isinstance(raw, list) else
                                                  [top.table("validation")] if raw is not None else []))
    top.finish()

    if not tasks:
        raise top.error("tasks", "the case has no tasks")
    if not supports:
        raise top.error("supports", "no base support: the part is free to move rigidly")
    return CaseSpec(name=name, source=source, description=description, part=part,
                    material=material, thickness=thickness, shapes=shapes, polygon=polygon,
                    mesh=mesh, supports=supports, fixture_radius=radius, fixture_holds=holds,
                    candidates=candidates, n_agents=n_agents, agent_regions=agent_regions, tasks=tasks,
                    reward_sigma=sigma, measure_spacing=spacing, validations=validations,
                    candidates_dropped=dropped, effector=effector, regions=thickness_regions)


def _geometry(r: Reader, material: Material | Laminate) -> tuple[float, tuple[Shape, ...], shapely.Polygon]:
    """Thickness, shapes and outline; a laminate's thickness is its plies' (a thickness given beside
    them must agree)."""
    if isinstance(material, Laminate):
        thickness = r.number("thickness", "length", material.thickness, positive=True)
        if abs(thickness - material.thickness) > 1e-9 * material.thickness:
            raise r.error(next(k for k in r.data if k.startswith("thickness")),
                          f"is {thickness * 1e3:g} mm but the plies of [material] add up to "
                          f"{material.thickness * 1e3:g} mm (leave it out, or make them agree)")
    else:
        thickness = r.number("thickness", "length", positive=True)
    shapes: list[Shape] = []
    if r.has("outline"):
        shapes.append(Shape("union", r.array("outline", "length", shape=(-1, 2)),
                            key=r._unit_key("outline", None) or "outline_mm"))
    shapes.extend(parse_shape(s) for s in r.tables("shapes"))
    if not shapes:
        raise r.error("outline_mm", "missing (or give [[geometry.shapes]])")
    if shapes[0].op != "union":
        raise r.error("shapes", "the first shape must be a union")
    polygon = build_polygon(shapes, r)
    r.finish()
    return thickness, tuple(shapes), polygon


def _mesh(r: Reader, tasks: tuple[Task, ...]) -> MeshSpec:
    size = r.number("size", "length", positive=True)
    refine = []
    for s in r.tables("refine"):
        near = s.text("near", "points", ("points", "tasks"))
        if near == "tasks":
            pts = [ld.at for t in tasks for ld in t.loads if ld.at is not None]
            if not pts:
                raise s.error("near", "no task has a located load to refine near")
            points = np.array(pts)
        else:
            points = _densify(s.array("polyline", "length", shape=(-1, 2)), size / 4)
        refine.append(Refine(points, s.number("size", "length", positive=True),
                             s.number("width", "length", 0.0, nonneg=True)))
        s.finish()
    mesh = MeshSpec(size, tuple(refine), r.number("grading", None, 0.3, positive=True),
                    r.number("min_angle", "angle", np.radians(30.0), positive=True))
    mesh = replace(mesh, min_angle_deg=float(np.degrees(mesh.min_angle_deg)))
    if not 10.0 <= mesh.min_angle_deg <= 34.0:
        raise r.error("min_angle_deg", "must lie between 10 and 34 degrees (Triangle's range)")
    r.finish()
    return mesh


def _densify(line: np.ndarray, step: float) -> np.ndarray:
    pts = [line[0]]
    for a, b in zip(line[:-1], line[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        pts.extend(a + (b - a) * t for t in np.linspace(0, 1, n + 1)[1:])
    return np.array(pts)


def _holds(r: Reader, default: tuple[str, ...] | None, allowed: tuple[str, ...]) -> tuple[str, ...]:
    if r.has("kind"):
        kind = r.text("kind", choices=tuple(SUPPORT_KINDS))
        return SUPPORT_KINDS[kind]
    holds = r.raw("holds", default, (list,))
    if holds is ...:
        raise r.error("holds", "missing (or give kind)")
    if not holds or any(h not in allowed for h in holds) or len(set(holds)) != len(holds):
        raise r.error("holds", f"must be a non-empty list of distinct names from {', '.join(allowed)}")
    return tuple(holds)


def _boundary_segment(r: Reader, polygon: shapely.Polygon) -> np.ndarray:
    """A segment (2 x 2, m) that must lie along the part's boundary."""
    seg = r.array("segment", "length", shape=(2, 2))
    line = shapely.LineString(seg)
    tol = 1e-6 * max(1.0, line.length)
    if line.length == 0 or line.difference(polygon.boundary.buffer(tol)).length > tol:
        raise r.error(r._unit_key("segment", None) or "segment_mm",
                      "does not lie along the part's boundary")
    return seg


def _support(r: Reader, polygon: shapely.Polygon) -> Support:
    holds = _holds(r, ..., DOF_NAMES)
    name = r.text("name", "support")
    where = one_of(r, SUPPORT_PLACES, "no place")
    sup: Support
    if where[0] == "segment":
        seg = _boundary_segment(r, polygon)
        sup = Support(name, holds, segment=seg)
    elif where[0] == "hole":
        hole = r.integer("hole", minimum=0)
        if hole >= len(polygon.interiors):
            raise r.error("hole", f"the part has {len(polygon.interiors)} holes")
        sup = Support(name, holds, hole=hole)
    elif where[0] == "boundary":
        r.text("boundary", choices=("outer",))
        sup = Support(name, holds, outer=True)
    else:
        pt = r.array("point", "length", shape=(2,))
        if not polygon.buffer(1e-9).covers(shapely.Point(pt)):
            raise r.error("point_mm", "lies outside the part")
        sup = Support(name, holds, point=pt, radius=r.number("radius", "length", 0.0, nonneg=True))
    r.finish()
    return sup


def _fixtures(r: Reader, polygon: shapely.Polygon):
    """Pad radius, held components, candidates (m) and how many grid points were dropped.

    A grid is laid over the part's bounding box, so its points outside the outline or inside a hole
    are dropped (and counted): a part with holes or a non-convex outline needs no hand-drawn keep
    polygon. Points listed one by one must all lie inside the part (a listed point outside it is a
    mistake in the file, not a grid overhanging the part).
    """
    radius = r.number("radius", "length", positive=True)
    holds = _holds(r, ["ux", "uy", "w"], ("ux", "uy", "w"))
    grid = r.table("grid")
    if grid is not None and r.has("points"):
        raise r.error("points_mm", "give either points_* or [fixtures.grid], not both")
    if grid is not None:
        axes = []
        for ax in ("x", "y"):
            start = grid.number(f"{ax}_start", "length")
            step = grid.number(f"{ax}_step", "length", positive=True)
            axes.append(start + step * np.arange(grid.integer(f"{ax}_count", minimum=1)))
        order = grid.text("order", "x", ("x", "y"))
        xx, yy = np.meshgrid(axes[0], axes[1], indexing="ij" if order == "x" else "xy")
        points = np.column_stack([xx.ravel(), yy.ravel()])
        if grid.has("keep_inside"):
            keep = shapely.Polygon(grid.array("keep_inside", "length", shape=(-1, 2)))
            if not keep.is_valid:
                raise grid.error("keep_inside_mm", "is not a valid (simple) polygon")
            points = points[shapely.contains_xy(keep, points[:, 0], points[:, 1])]
        grid.finish()
    else:
        points = r.array("points", "length", shape=(-1, 2))
    if len(points) == 0:
        raise r.error("grid" if grid is not None else "points_mm", "no fixture candidates")
    inside = shapely.contains_xy(polygon, points[:, 0], points[:, 1])
    dropped = 0
    if grid is not None:
        dropped = int(np.count_nonzero(~inside))
        points = points[inside]
        if len(points) == 0:
            raise r.error("grid", f"no grid point lies inside the part (all {dropped} fall outside "
                                  "its outline or inside its holes)")
    elif not inside.all():
        i = int(np.flatnonzero(~inside)[0])
        x, y = points[i] * 1e3
        raise r.error("points_mm", f"candidate {i} at ({x:.1f}, {y:.1f}) mm lies outside the part")
    r.finish()
    return radius, holds, points, dropped


def _agents(r: Reader, candidates: np.ndarray):
    regions = []
    for s in r.tables("regions"):
        poly = shapely.Polygon(s.array("polygon", "length", shape=(-1, 2)))
        if not poly.is_valid:
            raise s.error("polygon_mm", "is not a valid (simple) polygon")
        regions.append((s.text("name", f"agent{len(regions)}"), np.asarray(poly.exterior.coords)))
        s.finish()
    count = r.integer("count", len(regions) if regions else ..., minimum=1)
    if regions:
        if count != len(regions):
            raise r.error("count", f"is {count} but {len(regions)} regions are named")
        owner = np.full(len(candidates), -1)
        for i, (name, ring) in enumerate(regions):
            inside = shapely.contains_xy(shapely.Polygon(ring), candidates[:, 0], candidates[:, 1])
            both = inside & (owner >= 0)
            if both.any():
                raise r.error(f"regions[{i}]", f"region '{name}' overlaps region "
                              f"'{regions[owner[both][0]][0]}' (shared candidates)")
            if not inside.any():
                raise r.error(f"regions[{i}]", f"region '{name}' holds no fixture candidate")
            owner[inside] = i
        _check_owned(r, candidates, owner < 0)
    elif count > len(candidates):
        raise r.error("count", f"{count} agents but only {len(candidates)} fixture candidates")
    effector = _effector(r, count)
    r.finish()
    return count, tuple(regions), effector


def _check_owned(r: Reader, candidates: np.ndarray, unowned: np.ndarray) -> None:
    """Every candidate must lie in a region (strictly inside: a point on a region's edge is in none)."""
    if not unowned.any():
        return
    pts = candidates[unowned] * 1e3
    (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
    first = ", ".join(f"({x:.1f}, {y:.1f})" for x, y in pts[:3])
    raise r.error("regions", f"{len(pts)} of {len(candidates)} fixture candidates lie in no region "
                  f"(a point on a region's edge is in none), within x {x0:.1f}..{x1:.1f}, "
                  f"y {y0:.1f}..{y1:.1f} mm, first at {first} mm: every candidate needs one robot")


def _effector(r: Reader, n_agents: int) -> Effector:
    """The [agents] keys of what one robot places (see :class:`Effector`)."""
    m = r.integer("fixtures_per_agent", 1, minimum=1)
    kind = r.text("effector", "independent", ("independent", "pair"))
    span = r.number("span", "length", 0.0, positive=True)
    if kind == "pair":
        if m != 2:
            raise r.error("fixtures_per_agent", f"a pair effector places 2 pads, got {m}")
        if not span:
            raise r.error("span_<unit>", "missing: a pair effector needs its span (e.g. span_mm)")
    elif span:
        raise r.error("span_mm", "only a pair effector has a span (effector = \"pair\")")
    idle = r.raw("idle", False, (bool,))
    pads = r.integer("pads", 0, minimum=1)
    if pads and pads >= n_agents * m:
        raise r.error("pads", f"{pads} pads is no limit for {n_agents} robots of {m} pads each "
                              f"(leave it out, or give fewer than {n_agents * m})")
    return Effector(m, kind, span, idle, pads)


def _load(r: Reader, polygon: shapely.Polygon) -> Load:
    kind = r.text("kind", choices=("pressure", "weight", "centrifugal", "patch", "edge_traction"))
    if kind == "weight":
        ld = Load(kind)
    elif kind == "pressure":
        region = r.array("region", "length", None, shape=(-1, 2))
        ld = Load(kind, magnitude=r.number("pressure", "pressure"), region=region)
    elif kind == "centrifugal":
        ld = Load(kind, magnitude=r.number("speed", "angular_speed", nonneg=True),
                  at=r.array("center", "length", shape=(2,)))
    elif kind == "patch":
        ld = _patch(r, r.array("at", "length", shape=(2,)), polygon, written(r, "at"))
    else:
        seg = _boundary_segment(r, polygon)
        ld = Load(kind, force=r.array("force", "force", shape=(3,)), segment=seg)
    r.finish()
    return ld


def _patch(r: Reader, at: np.ndarray, polygon: shapely.Polygon, at_key: str = "at_mm") -> Load:
    force = r.array("force", "force", shape=(3,))
    radius = r.number("radius", "length", nonneg=True)
    shape = r.text("patch", "disc", ("disc", "edge"))
    if shape == "disc" and radius == 0 and np.any(force[:2] != 0):
        raise r.error("radius_mm", "an in-plane point force is singular in plane stress; "
                                   "give the patch a physical radius")
    if shape == "edge" and radius == 0:
        raise r.error("radius_mm", "an edge patch needs a positive radius")
    if not polygon.buffer(1e-9).covers(shapely.Point(at)):
        x, y = at * 1e3
        raise r.error(at_key, f"load point ({x:.1f}, {y:.1f}) mm lies outside the part")
    return Load("patch", force=force, at=at, radius=radius, patch_shape=shape)


def _tasks(top: Reader, polygon: shapely.Polygon) -> tuple[Task, ...]:
    background = tuple(_load(r, polygon) for r in top.tables("loads"))
    lo, hi = np.array(polygon.bounds[:2]), np.array(polygon.bounds[2:])
    tasks: list[Task] = []
    for g in top.tables("tasks"):
        kind = g.text("kind", choices=("drilling", "loads"))
        name = g.text("name", kind)
        if kind == "drilling":
            points, key = drill_points(g, polygon)
            template = {k: v for k, v in g.data.items() if k.split("_")[0] in ("force", "radius", "patch")}
            for i, p in enumerate(points):
                sub = Reader(template, g.source, g.prefix)
                ld = _patch(sub, p, polygon, key)
                tasks.append(Task(f"{name} {i}", (ld,) + background, (p - lo) / (hi - lo)))
            for k in template:
                g.used.add(k)
        else:
            loads = tuple(_load(r, polygon) for r in g.tables("loads"))
            if not loads and not background:
                raise g.error("loads", "a task needs at least one load")
            feats = g.array("features", None, np.array([float(len(tasks))]), shape=(-1,))
            tasks.append(Task(name, loads + background, feats))
        g.finish()
    dims = {len(t.features) for t in tasks}
    if len(dims) > 1:
        raise top.error("tasks", f"tasks have feature vectors of different lengths {sorted(dims)}")
    return tuple(tasks)


def _validation(r: Reader) -> Validation:
    quantity = r.text("quantity", choices=("w", "ux", "uy"))
    at = r.array("at", "length", shape=(2,))
    scale = r.text("scale", choices=tuple(VALIDATION_SCALES))
    coefficient = r.number("coefficient", None, ... if scale.endswith("/ D") else 1.0, positive=True)
    lengths = {k: r.number(k, "length", positive=True) for k in ("a", "b", "L") if r.has(k)}
    for k in VALIDATION_SCALES[scale]:
        if k not in lengths:
            raise r.error(f"{k}_<unit>", f"missing (the scale '{scale}' needs it)")
    label = r.text("label", "")
    case, case_at = "", None
    if scale == "case":
        case = r.text("case")
        case_at = r.array("case_at", "length", shape=(2,))
    r.finish()
    return Validation(quantity, at, coefficient, scale, lengths, label, case, case_at)
