"""Writing a case as a new user would, from the README alone: a bracket with a hole, a candidate grid
laid over it, and the checks a user makes against a hand calculation (the free response, the
displacement at given points)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixbench.bench.cli import main
from fixbench.cases.analytic import reference, series_reference
from fixbench.cases.problem import load_problem
from fixbench.cases.spec import load_case_spec

# An L bracket (two 100 mm arms, 300 mm long) with a 25 mm bolt hole, clamped along x = 0, and a
# 20 mm candidate grid over its bounding box: the README's case format and nothing else.
BRACKET = """
[case]
description = "L bracket with a bolt hole"

[material]
name = "aluminium"

[geometry]
thickness_mm = 4
outline_mm = [[0, 0], [300, 0], [300, 100], [100, 100], [100, 300], [0, 300]]
[[geometry.shapes]]
op = "difference"
circle_mm = [60, 60, 25]

[mesh]
size_mm = 20

[[supports]]
name = "wall"
segment_mm = [[0, 0], [0, 300]]
kind = "clamped"

[fixtures]
radius_mm = 8
[fixtures.grid]
x_start_mm = 10
x_step_mm = 20
x_count = 15
y_start_mm = 10
y_step_mm = 20
y_count = 15

[agents]
count = 2

[[tasks]]
kind = "drilling"
points_mm = [[280, 50], [50, 280]]
force_N = [10, 0, -100]
radius_mm = 5
"""


def _expected_grid():
    """The grid points inside the L and outside the hole, counted without shapely: the grid
    (10, 30, ..., 290 mm) never lies within 5 mm of the L's edges or of the hole's circle."""
    g = 10.0 + 20.0 * np.arange(15)
    x, y = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    in_l = ((x < 300) & (y < 100)) | ((x < 100) & (y < 300))
    in_hole = (x - 60) ** 2 + (y - 60) ** 2 < 25**2
    keep = in_l & ~in_hole
    return np.column_stack([x[keep], y[keep]]), int((~keep).sum())


@pytest.fixture
def bracket(tmp_path):
    path = tmp_path / "bracket.toml"
    path.write_text(BRACKET)
    return str(path)


def run_json(capsys, *argv):
    rc = main(list(argv))
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out)


def test_grid_points_off_the_part_are_dropped_and_counted(bracket):
    spec = load_case_spec(bracket)
    kept, dropped = _expected_grid()
    assert dropped == 104 and len(kept) == 121  # 100 outside the L, 4 in the hole
    assert spec.candidates_dropped == dropped
    np.testing.assert_allclose(spec.candidates * 1e3, kept, atol=1e-9)  # same points, same order


def test_show_reports_dropped(capsys, bracket, tmp_path):
    rc = main(["show", bracket, "--out", str(tmp_path / "b.png")])
    out = capsys.readouterr().out
    assert rc == 0
    assert "121 fixture candidates (104 grid points outside the part or inside its holes dropped)" in out


def test_cases_lists_dropped(capsys):
    rows = {r["case"]: r for r in run_json(capsys, "cases", "--json")}
    assert all(isinstance(r["dropped"], int) and r["dropped"] >= 0 for r in rows.values())
    assert rows["wing_panel"]["dropped"] == 0  # its keep polygon lies inside the part


def test_listed_candidate_outside_is_still_an_error(capsys, tmp_path):
    text = BRACKET.replace("[fixtures.grid]\nx_start_mm = 10\nx_step_mm = 20\nx_count = 15\n"
                           "y_start_mm = 10\ny_step_mm = 20\ny_count = 15\n",
                           "points_mm = [[20, 20], [200, 50], [200, 200]]\n")
    path = tmp_path / "listed.toml"
    path.write_text(text)
    rc = main(["evaluate", str(path), "--task", "0", "--free"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1
    assert "listed.toml" in lines[0] and "fixtures.points_mm" in lines[0]
    assert "candidate 2 at (200.0, 200.0) mm lies outside the part" in lines[0]


def test_grid_entirely_off_the_part_is_an_error(capsys, tmp_path):
    path = tmp_path / "off.toml"
    path.write_text(BRACKET.replace("x_start_mm = 10", "x_start_mm = 1000"))
    rc = main(["evaluate", str(path), "--task", "0", "--free"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1
    assert "fixtures.grid" in lines[0] and "no grid point lies inside the part" in lines[0]


def test_at_is_the_fe_field(capsys, bracket):
    """--at reads the FE solution itself: the same numbers as scikit-fem's own point probes of a
    direct solve, zero on the clamped edge's vertices, and the free response exceeds the held one."""
    problem = load_problem(bracket)
    layout = [int(problem.action_sets[0][5]), int(problem.action_sets[1][40])]
    pts_mm = [(280.0, 50.0), (150.0, 80.0), (50.0, 150.0), (0.0, 0.0)]
    argv = ["evaluate", bracket, "--task", "0", "--json"] + [a for p in pts_mm for a in ("--at", f"{p[0]},{p[1]}")]
    held = run_json(capsys, *argv, "--layout", ",".join(map(str, layout)))
    free = run_json(capsys, *argv, "--free")
    assert free["layout"] == "free (no fixtures)" and free["max_u"] > 5 * held["max_u"]

    for res, lay in ((held, [layout]), (free, None)):
        fields = problem.solve_direct(0, lay)
        pts = np.array(pts_mm[:3]) * 1e-3
        w = fields["bending"] @ problem.model.fields["bending"].basis.probes(pts.T).T
        uxy = fields["membrane"] @ problem.model.fields["membrane"].basis.probes(pts.T).T  # ux.., uy..
        got = res["at"]
        assert [(a["x_mm"], a["y_mm"]) for a in got] == pts_mm
        np.testing.assert_allclose([a["w_m"] for a in got[:3]], w, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose([a["ux_m"] for a in got[:3]], uxy[:3], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose([a["uy_m"] for a in got[:3]], uxy[3:], rtol=1e-9, atol=1e-15)
        corner = got[3]  # the clamped edge's end: held at zero (read a hair inside the part)
        assert corner["u_m"] < 1e-6 * res["max_u"]
        # the drill point is a measurement point: the field there cannot exceed the reported maximum
        assert got[0]["u_m"] <= res["max_u"] * (1 + 1e-12)
    # the drill point is where the free bracket deflects most (the arm's tip region)
    assert free["at"][0]["u_m"] > 0.8 * free["max_u"]


def test_free_response_against_a_hand_calculation(capsys):
    """A simply supported square plate under uniform pressure: the centre deflection of the free
    response (no fixtures) equals 0.00406 q a^4 / D (Timoshenko) and Navier's series within 0.5 %."""
    res = run_json(capsys, "evaluate", "plate_ss_uniform", "--task", "0", "--free", "--at", "500,500", "--json")
    spec = load_case_spec("plate_ss_uniform")
    w = abs(res["at"][0]["w_m"])
    assert w == pytest.approx(reference(spec), rel=5e-3)
    assert w == pytest.approx(series_reference(spec), rel=5e-3)
    assert res["max_w"] == pytest.approx(w, rel=5e-3)  # the centre is where it deflects most


@pytest.mark.parametrize("argv,needles", [
    (["--free", "--at", "60,60"], ["--at", "(60, 60) mm lies outside the part (or inside a hole)"]),
    (["--free", "--at", "500,20"], ["--at", "outside the part"]),
    (["--free", "--at", "1,"], ["--at", "not a point x,y in mm"]),
    (["--free", "--layout", "0,120"], ["exactly one of --layout", "--free"]),
    ([], ["exactly one of --layout", "--free"]),
])
def test_bad_evaluate_arguments(capsys, bracket, argv, needles):
    rc = main(["evaluate", bracket, "--task", "0", *argv])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in lines[0]
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_free_response_of_an_unsupported_part_is_refused(capsys, tmp_path):
    """Without a base support the free response would be singular: one line, no number."""
    path = tmp_path / "loose.toml"
    path.write_text(BRACKET.replace('[[supports]]\nname = "wall"\nsegment_mm = [[0, 0], [0, 300]]\n'
                                    'kind = "clamped"\n', ""))
    rc = main(["evaluate", str(path), "--task", "0", "--free"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1
    assert "loose.toml" in lines[0] and "free to move rigidly" in lines[0]
