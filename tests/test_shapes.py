"""Shapes beyond polygons: rounded rectangles, ellipses, slots, offsets, DXF drawings (ezdxf), and
drilling positions along a curve; each against what it should be, computed here."""

from __future__ import annotations

import math
from pathlib import Path

import ezdxf
import numpy as np
import pytest
import shapely

from fixbench.cases.errors import CaseError
from fixbench.cases.problem import load_problem
from fixbench.cases.shapes import DXF_TOLERANCE
from fixbench.cases.spec import load_case_spec

DXF = Path(__file__).parent / "data" / "plate_holes.dxf"  # written by tests/data/make_dxf.py
OUTLINE = "outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]\n"
DRILL_LINE = "line_mm = [[350, 100], [380, 100]]\ncount = 3"
PLATE_AREA = 400.0 * 200.0  # mm^2
#: a 64-gon's area over its circle's: the round shapes' discretisation
POLY64 = 64 * math.sin(2 * math.pi / 64) / (2 * math.pi)


def _hole(plate_toml, *lines: str) -> shapely.Polygon:
    path = plate_toml((OUTLINE, OUTLINE + '[[geometry.shapes]]\nop = "difference"\n' + "\n".join(lines) + "\n"))
    return load_case_spec(path).polygon


def _hole_area_mm2(polygon: shapely.Polygon) -> float:
    return PLATE_AREA - polygon.area * 1e6


@pytest.mark.parametrize("lines,area", [
    (["rectangle_mm = [220, 70, 280, 130]", "corner_radius_mm = 10"], 60 * 60 - (4 - math.pi) * 10**2),
    (["ellipse_mm = [250, 100, 40, 20]", "angle_deg = 30"], math.pi * 40 * 20),
    (["slot_mm = [220, 100, 280, 100, 30]"], 60 * 30 + math.pi * 15**2),
    (["slot_mm = [220, 100, 280, 100, 30]", "offset_mm = 5"], 60 * 40 + math.pi * 20**2),
    (["circle_mm = [250, 100, 20]", "offset_mm = -5"], math.pi * 15**2),
], ids=["rounded rectangle", "turned ellipse", "slot", "slot grown", "circle shrunk"])
def test_round_shapes_have_their_area(plate_toml, lines, area):
    """Each hole's area is the exact shape's within the 64-gon's shortfall on its round parts."""
    got = _hole_area_mm2(_hole(plate_toml, *lines))
    assert area * POLY64 * 0.999 <= got <= area * 1.0001, (got, area)


def test_turned_ellipse_lies_along_its_angle(plate_toml):
    """A 30 degree ellipse reaches furthest along 30 degrees: its farthest vertex from the centre."""
    ring = np.asarray(_hole(plate_toml, "ellipse_mm = [250, 100, 40, 20]", "angle_deg = 30").interiors[0].coords)
    d = ring * 1e3 - [250, 100]
    far = d[np.argmax(np.hypot(*d.T))]
    assert np.hypot(*far) == pytest.approx(40, abs=1e-5)  # the part is snapped to a 1 nm grid
    assert abs(math.degrees(math.atan2(far[1], far[0])) % 180 - 30) < 1e-4


def test_existing_shape_keys_give_the_same_vertices(plate_toml):
    """circle_mm and rectangle_mm (no corner, no angle) keep their vertices: shapely's 64-gon of the
    point and the four corners as listed (the catalog's meshes depend on them)."""
    spec = load_case_spec(plate_toml((OUTLINE, OUTLINE + '[[geometry.shapes]]\nop = "difference"\n'
                                      "circle_mm = [250, 100, 20]\n[[geometry.shapes]]\nop = \"difference\"\n"
                                      "rectangle_mm = [50, 80, 90, 120]\n")))
    want = np.asarray(shapely.Point(0.25, 0.1).buffer(0.02, quad_segs=16).exterior.coords)[:-1]
    np.testing.assert_array_equal(spec.shapes[1].polygon, want)
    np.testing.assert_array_equal(spec.shapes[2].polygon, np.array([[50, 80], [90, 80], [90, 120], [50, 120]]) * 1e-3)


# ---------------------------------------------------------------------------------------------
# DXF drawings
# ---------------------------------------------------------------------------------------------
def _dxf_shape(path, key: str = "dxf", layers: str = '["OUTLINE", "WINDOW"]', extra: str = "") -> str:
    return f'[[geometry.shapes]]\n{key} = "{path}"\nlayers = {layers}\n{extra}'


def test_dxf_part_deforms_as_the_same_part_written_by_hand(plate_toml):
    """The shipped drawing (an outline of four LINEs, a window as a closed LWPOLYLINE) against the
    same part written as outline_mm and a rectangle_mm difference: the same polygon, and max |u| of
    every task at a few layouts within 0.5 %."""
    drawn = load_problem(plate_toml((OUTLINE, _dxf_shape(DXF)), name="drawn.toml"))
    typed = load_problem(plate_toml((OUTLINE, OUTLINE + '[[geometry.shapes]]\nop = "difference"\n'
                                     "rectangle_mm = [220, 70, 280, 130]\n"), name="typed.toml"))
    assert drawn.spec.polygon.equals(typed.spec.polygon)
    assert len(drawn.spec.polygon.interiors) == 1
    layouts = np.array([[0, 3], [1, 4], [2, 5]])
    for task in range(drawn.n_tasks):
        a = drawn.direct_deformation(task, layouts).max_u
        b = typed.direct_deformation(task, layouts).max_u
        np.testing.assert_allclose(a, b, rtol=5e-3)


def test_dxf_circle_is_flattened_within_its_tolerance(plate_toml):
    """Every layer read: two holes, the CIRCLE's vertices on its circle within the chord tolerance."""
    spec = load_case_spec(plate_toml((OUTLINE, _dxf_shape(DXF, "dxf", '["OUTLINE", "WINDOW", "HOLES"]'))))
    holes = [np.asarray(h.coords) * 1e3 for h in spec.polygon.interiors]
    assert len(holes) == 2
    bolt = min(holes, key=lambda h: h[:, 0].mean())  # the bolt hole at x = 120
    r = np.hypot(*(bolt - [120, 100]).T)
    assert np.all(np.abs(r - 15) <= DXF_TOLERANCE * 1e3)
    area = PLATE_AREA - 60 * 60 - math.pi * 15**2
    assert spec.polygon.area * 1e6 == pytest.approx(area, abs=2 * math.pi * 15 * DXF_TOLERANCE * 1e3)


def _square(path: Path, insunits: int, side: float = 10.0) -> Path:
    doc = ezdxf.new("R2010", units=insunits)
    doc.modelspace().add_lwpolyline([(0, 0), (side, 0), (side, side / 2), (0, side / 2)], close=True)
    doc.saveas(path)
    return path


@pytest.mark.parametrize("insunits,key,side_m", [
    (1, "dxf", 0.254),  # inches in the header
    (0, "dxf_cm", 0.10),  # no unit in the header: the key's
    (4, "dxf_mm", 0.010),  # both, agreeing
])
def test_dxf_units(tmp_path, plate_toml, insunits, key, side_m):
    dxf = _square(tmp_path / "square.dxf", insunits)
    spec = load_case_spec(plate_toml((OUTLINE, _dxf_shape(dxf, key, '["0"]')), ("radius_mm = 10\n", "radius_mm = 1\n"),
                                     ("points_mm = [[100, 50], [100, 150], [200, 50], [200, 150], [300, 50], "
                                      "[300, 150]]", "points_mm = [[1, 1], [2, 2]]"),
                                     ("segment_mm = [[0, 0], [0, 200]]", "segment_mm = [[0, 0], [0, 1]]"),
                                     (DRILL_LINE, "points_mm = [[3, 3]]")))
    assert spec.polygon.bounds == pytest.approx((0, 0, side_m, side_m / 2))


def test_dxf_without_units_needs_them_in_the_key(tmp_path, plate_toml):
    dxf = _square(tmp_path / "square.dxf", 0)
    with pytest.raises(CaseError, match=r"geometry.shapes\[0\].dxf: .*declares no units.*e.g. dxf_mm"):
        load_case_spec(plate_toml((OUTLINE, _dxf_shape(dxf, "dxf", '["0"]'))))


def test_dxf_linework_that_closes_no_loop_is_refused(tmp_path, plate_toml):
    doc = ezdxf.new("R2010", units=4)
    for a, b in [((0, 0), (400, 0)), ((400, 0), (400, 200)), ((400, 200), (0, 200)), ((0, 200), (0, 5))]:
        doc.modelspace().add_line(a, b)
    doc.saveas(tmp_path / "open.dxf")
    with pytest.raises(CaseError, match=r"dxf: .*open.dxf: 4 piece\(s\) of linework close no loop"):
        load_case_spec(plate_toml((OUTLINE, _dxf_shape(tmp_path / "open.dxf", "dxf", '["0"]'))))


def test_dxf_path_is_relative_to_the_file_naming_it(tmp_path, plate_toml):
    """base/part.toml names "plate_holes.dxf" beside it; other/derived.toml extends it from another
    folder and still gets the drawing."""
    (tmp_path / "base").mkdir()
    (tmp_path / "other").mkdir()
    (tmp_path / "base" / "plate_holes.dxf").write_bytes(DXF.read_bytes())
    base = Path(plate_toml((OUTLINE, _dxf_shape("plate_holes.dxf")), name="base/part.toml"))
    (tmp_path / "other" / "derived.toml").write_text('[case]\nextends = "../base/part.toml"\n[mesh]\nsize_mm = 30\n')
    derived = load_case_spec(tmp_path / "other" / "derived.toml")
    assert derived.polygon.equals(load_case_spec(base).polygon) and derived.mesh.size == pytest.approx(0.03)


# ---------------------------------------------------------------------------------------------
# drilling along a curve
# ---------------------------------------------------------------------------------------------
def _drill_points(plate_toml, along: str, hole: bool = True) -> np.ndarray:
    edits = [(DRILL_LINE, along)]
    if hole:
        edits.append((OUTLINE, OUTLINE + '[[geometry.shapes]]\nop = "difference"\ncircle_mm = [250, 100, 20]\n'))
    spec = load_case_spec(plate_toml(*edits))
    return np.array([t.loads[0].at for t in spec.tasks]) * 1e3


def test_rivet_ring_around_a_hole_by_count(plate_toml):
    """8 positions 15 mm out from a 20 mm hole: on the offset circle (its 64-gon), evenly spaced,
    counter-clockwise from the lower-left of the curve's bounding box."""
    pts = _drill_points(plate_toml, 'along = "hole 0"\noffset_mm = 15\ncount = 8')
    r = np.hypot(*(pts - [250, 100]).T)
    assert len(pts) == 8 and np.all((r <= 35 + 1e-9) & (r >= 35 * math.cos(math.pi / 64) - 1e-9))
    gaps = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
    assert np.ptp(gaps) < 0.01 * gaps.mean()
    angles = np.unwrap(np.arctan2(*(pts - [250, 100]).T[::-1]))
    assert np.all(np.diff(angles) > 0)  # counter-clockwise
    assert np.linalg.norm(pts[0] - [250 - 35 / math.sqrt(2), 100 - 35 / math.sqrt(2)]) < 0.5


def test_rivet_ring_by_pitch_from_a_start(plate_toml):
    pts = _drill_points(plate_toml, 'along = "hole 0"\noffset_mm = 15\npitch_mm = 50\nstart_mm = [250, 200]')
    length = 2 * 64 * 35 * math.sin(math.pi / 64)  # about the offset ring's perimeter
    assert len(pts) == math.floor(length / 50) == 4
    assert pts[0] == pytest.approx([250, 135], abs=0.05)  # the curve's point nearest the start
    assert np.linalg.norm(pts[1] - pts[0]) == pytest.approx(2 * 35 * math.sin(25 / 35), rel=0.01)  # 50 mm of arc


def test_positions_along_the_outer_boundary_and_a_polyline(plate_toml):
    pts = _drill_points(plate_toml, 'along = "outer"\noffset_mm = 10\npitch_mm = 100', hole=False)
    assert len(pts) == 11 and pts[0] == pytest.approx([10, 10]) and pts[1] == pytest.approx([110, 10])
    line = _drill_points(plate_toml, "along_mm = [[340, 20], [340, 180]]\noffset_mm = -10\ncount = 3", hole=False)
    np.testing.assert_allclose(line, [[350, 20], [350, 100], [350, 180]], atol=1e-9)  # right of an upward line


def test_a_changed_drawing_changes_the_reference_fingerprint(tmp_path, plate_toml):
    """A reference's fingerprint covers the DXF's contents, not only its path: a redrawn part is
    another case, whose earlier references no run may reuse."""
    from fixbench.cases.references import case_fingerprint

    (tmp_path / "part").mkdir()
    drawing = tmp_path / "part" / "plate_holes.dxf"
    drawing.write_bytes(DXF.read_bytes())
    case = Path(plate_toml((OUTLINE, _dxf_shape("plate_holes.dxf")), name="part/part.toml"))
    before = case_fingerprint(case, "aluminium", 2)
    assert case_fingerprint(case, "aluminium", 2) == before
    doc = ezdxf.readfile(drawing)
    doc.modelspace().add_circle((100, 100), 10)
    doc.saveas(drawing)
    assert case_fingerprint(case, "aluminium", 2) != before
