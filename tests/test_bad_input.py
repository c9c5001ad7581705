"""Bad input: one line naming file, key and problem; exit code 2; no traceback; nothing written."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fixbench.bench.cli import main

# (id, edits to the valid plate, text the message must contain: the key and the problem)
BAD_FILES = [
    ("missing key", [("thickness_mm = 5\n", "")], ["geometry.thickness_<unit>", "missing"]),
    ("unknown material", [('name = "aluminium"', 'name = "unobtainium"')],
     ["material.name", "unknown material"]),
    ("self-intersecting outline", [("[[0, 0], [400, 0], [400, 200], [0, 200]]",
                                    "[[0, 0], [400, 200], [400, 0], [0, 200]]")],
     ["outline_mm", "not a simple polygon"]),
    ("candidate outside the part", [("[300, 150]]", "[500, 150]]")], ["fixtures.points_mm", "outside"]),
    ("overlapping agent sets", [("count = 2\n", 'count = 2\n[[agents.regions]]\nname = "a"\n'
                                 "polygon_mm = [[0, 0], [250, 0], [250, 200], [0, 200]]\n"
                                 '[[agents.regions]]\nname = "b"\n'
                                 "polygon_mm = [[150, 0], [400, 0], [400, 200], [150, 200]]\n")],
     ["agents.regions[1]", "overlaps"]),
    ("fewer candidates than agents", [("count = 2\n", "count = 7\n")], ["agents.count", "only 6"]),
    ("part free to move rigidly", [('kind = "clamped"', 'kind = "simple"')],
     ["supports", "free to move rigidly out of plane"]),
    ("negative thickness", [("thickness_mm = 5", "thickness_mm = -5")],
     ["geometry.thickness_mm", "must be positive, got -5"]),
    ("NaN load", [("force_N = [10, 0, -100]", "force_N = [nan, 0, -100]")], ["force_N", "finite"]),
    ("unknown unit", [("thickness_mm = 5", "thickness_in = 0.2")], ["geometry.thickness_in", "unknown unit"]),
    ("unit missing", [("thickness_mm = 5", "thickness = 5")], ["geometry.thickness", "unit in the key"]),
    ("unknown key", [("[mesh]\n", "[mesh]\nsize_fine_mm = 3\n")], ["mesh.size_fine_mm", "unknown key"]),
    ("not TOML", [("[mesh]\n", "[mesh\n")], ["not valid TOML"]),
    ("wrong type", [("count = 3", 'count = "three"')], ["tasks[0].count", "whole number"]),
    ("in-plane point load", [("radius_mm = 8", "radius_mm = 0")], ["radius_mm", "singular"]),
    ("support off the boundary", [("segment_mm = [[0, 0], [0, 200]]", "segment_mm = [[50, 0], [50, 200]]")],
     ["supports[0].segment_mm", "does not lie along"]),
    ("load outside the part", [("[[350, 100], [380, 100]]", "[[350, 100], [480, 100]]")],
     ["line_mm", "outside the part"]),
    ("no supports", [('[[supports]]\nname = "left"\nsegment_mm = [[0, 0], [0, 200]]\nkind = "clamped"\n', "")],
     ["supports", "free to move rigidly"]),
    ("bad holds", [('kind = "clamped"', 'holds = ["ux", "spin"]')], ["supports[0].holds", "distinct names"]),
    ("Poisson ratio", [('name = "aluminium"', 'name = "aluminium"\nnu = 0.7')], ["material.nu", "(-1, 0.5)"]),
]


def _one_line_error(capsys, argv, code=2) -> str:
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("label,edits,needles", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_case_file(capsys, plate_toml, label, edits, needles):
    path = plate_toml(*edits)
    line = _one_line_error(capsys, ["evaluate", path, "--task", "0", "--layout", "0,3"])
    assert "plate.toml" in line
    for needle in needles:
        assert needle in line, line


BAD_ARGS = [
    (["evaluate", "no_such_case", "--task", "0", "--layout", "0"], ["no_such_case", "unknown case"]),
    (["evaluate", "{plate}", "--material", "wood", "--task", "0", "--layout", "0,3"],
     ["--material", "unknown material"]),
    (["evaluate", "{plate}", "--task", "0", "--layout", "0"], ["layout", "2 integer"]),
    (["evaluate", "{plate}", "--task", "0", "--layout", "0,1"], ["layout", "not in agent 1"]),
    (["evaluate", "{plate}", "--task", "9", "--layout", "0,3"], ["task", "0..2"]),
    (["evaluate", "{plate}", "--task", "0", "--layout", "a,b"], ["--layout", "comma-separated"]),
    (["evaluate", "missing.toml", "--task", "0", "--layout", "0"], ["missing.toml", "no such case file"]),
    (["show", "{plate}", "--bogus"], ["No such option"]),
]


@pytest.mark.parametrize("argv,needles", BAD_ARGS, ids=[" ".join(a[0][:1] + a[0][2:4]) for a in BAD_ARGS])
def test_bad_arguments(capsys, plate_toml, argv, needles):
    path = plate_toml()
    line = _one_line_error(capsys, [a.replace("{plate}", path) for a in argv])
    for needle in needles:
        assert needle in line, line


def test_extends_cycle(capsys, tmp_path):
    (tmp_path / "a.toml").write_text('[case]\nextends = "b.toml"\n')
    (tmp_path / "b.toml").write_text('[case]\nextends = "a.toml"\n')
    line = _one_line_error(capsys, ["show", str(tmp_path / "a.toml")])
    assert "case.extends" in line and "cycle" in line


def test_bad_input_writes_nothing(plate_toml, tmp_path, capsys):
    out = tmp_path / "pic.png"
    out.write_bytes(b"old picture")
    path = plate_toml(("thickness_mm = 5", "thickness_mm = -5"))
    _one_line_error(capsys, ["show", path, "--out", str(out)])
    assert out.read_bytes() == b"old picture"


OUTLINE = "outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]\n"
DXF = Path(__file__).parent / "data" / "plate_holes.dxf"  # written by tests/data/make_dxf.py
DRILL_LINE = "line_mm = [[350, 100], [380, 100]]\ncount = 3"


def _shape(*lines: str) -> tuple[str, str]:
    """An edit of the test plate adding one [[geometry.shapes]] table after its outline."""
    return OUTLINE, OUTLINE + "[[geometry.shapes]]\n" + "".join(line + "\n" for line in lines)


def _regions(*boxes: tuple[int, int]) -> tuple[str, str]:
    """Agents' regions spanning x0..x1 (mm) of the plate's full height, one a box."""
    text = "".join(f'[[agents.regions]]\nname = "r{i}"\npolygon_mm = [[{a}, 0], [{b}, 0], [{b}, 200], [{a}, 200]]\n'
                   for i, (a, b) in enumerate(boxes))
    return "count = 2\n", f"count = {len(boxes)}\n{text}"


def _layup(ply: str = "T300/5208", angles: str = "[0, 90]", thickness: str = "1.25", symmetric: str = "true",
           name: str = "cfrp", angles_key: str = "angles_deg") -> tuple[str, str]:
    """An edit making the test plate a laminate (two plies mirrored: 4 x 1.25 mm = its 5 mm)."""
    return ('[material]\nname = "aluminium"\n',
            f'[material]\nname = "{name}"\nsymmetric = {symmetric}\n[[material.plies]]\nply = "{ply}"\n'
            f'{angles_key} = {angles}\nthickness_mm = {thickness}\n')


def _region(*thickness: str, box: str = "rectangle_mm = [200, 0, 300, 200]", second: str = "") -> tuple[str, str]:
    """An edit adding thickness regions: the first on ``box``, a second (if given) on ``second``."""
    text = f'[[regions]]\nname = "pad 0"\n{box}\n{thickness[0]}\n'
    if second:
        text += f'[[regions]]\nname = "pad 1"\n{second}\n{thickness[1]}\n'
    return OUTLINE, OUTLINE + text


# (id, edits to the valid plate, text the one line must contain: the key as written and the problem)
BAD_SHAPES = [
    ("unknown shape key", [_shape('op = "difference"', "triangle_mm = [1, 2, 3]")],
     ["geometry.shapes[0].triangle_mm: unknown key", "ellipse_<unit>", "slot_<unit>", "dxf or dxf_<unit>"]),
    ("two kinds in one shape", [_shape('op = "difference"', "circle_mm = [250, 100, 20]",
                                       "rectangle_mm = [220, 70, 280, 130]")],
     ["geometry.shapes[0].rectangle_mm: conflicts with circle_mm", "give exactly one of"]),
    ("key of another kind", [_shape('op = "difference"', "circle_mm = [250, 100, 20]", "corner_radius_mm = 5")],
     ["geometry.shapes[0].corner_radius_mm: only rectangle_<unit> takes it, not circle_mm"]),
    ("corner radius too large", [_shape('op = "difference"', "rectangle_mm = [220, 70, 280, 130]",
                                        "corner_radius_mm = 30")],
     ["geometry.shapes[0].corner_radius_mm", "less than half the shorter side (30 mm)"]),
    ("shape of no kind", [_shape('op = "difference"')], ["geometry.shapes[0]: no shape: give one of"]),
    ("offset that erases the shape", [_shape('op = "difference"', "ellipse_mm = [250, 100, 30, 10]",
                                             "offset_mm = -20")],
     ["geometry.shapes[0].offset_mm", "leaves nothing"]),
    ("drill point listed outside", [(DRILL_LINE, "points_mm = [[350, 100], [480, 100]]")],
     ["tasks[0].points_mm: load point (480.0, 100.0) mm lies outside the part"]),
    ("two sources of drill points", [(DRILL_LINE, "points_mm = [[350, 100]]\n" + DRILL_LINE)],
     ["tasks[0].line_mm: conflicts with points_mm"]),
    ("curve of a hole the part lacks", [(DRILL_LINE, 'along = "hole 0"\ncount = 4')],
     ["tasks[0].along", "the part has no hole"]),
    ("pitch longer than the curve", [(DRILL_LINE, 'along = "outer"\noffset_mm = 10\npitch_mm = 2000')],
     ["tasks[0].pitch_mm: is longer than the curve (1120.0 mm)"]),
    ("regions leaving a gap", [_regions((0, 150), (250, 400))],
     ["agents.regions: 2 of 6 fixture candidates lie in no region", "(200.0, 50.0), (200.0, 150.0) mm"]),
    ("region edge on a candidate", [_regions((0, 200), (200, 400))],
     ["agents.regions: 2 of 6 fixture candidates lie in no region", "x 200.0..200.0, y 50.0..150.0 mm"]),
    ("DXF with a note", [(OUTLINE, f'[[geometry.shapes]]\ndxf = "{DXF}"\n')],
     ["geometry.shapes[0].dxf", "a TEXT on layer 'NOTES' is not a curve", "layers = [...]"]),
    ("DXF units in conflict", [(OUTLINE, f'[[geometry.shapes]]\ndxf_cm = "{DXF}"\nlayers = ["OUTLINE"]\n')],
     ["geometry.shapes[0].dxf_cm", "declares millimeters ($INSUNITS = 4)"]),
    ("DXF unit unknown", [(OUTLINE, f'[[geometry.shapes]]\ndxf_in = "{DXF}"\n')],
     ["geometry.shapes[0].dxf_in", "unknown unit 'in'", "plain dxf"]),
    ("DXF missing", [(OUTLINE, '[[geometry.shapes]]\ndxf = "no_such.dxf"\n')],
     ["geometry.shapes[0].dxf", "no_such.dxf", "cannot read"]),
    ("ply of no thickness", [_layup(thickness="0")], ["material.plies[0].thickness_mm", "must be positive, got 0"]),
    ("ply of negative thickness", [_layup(thickness="-0.125")],
     ["material.plies[0].thickness_mm", "must be positive, got -0.125"]),
    ("unknown ply material", [_layup(ply="T1000/unknown")],
     ["material.plies[0].ply", "unknown ply material 'T1000/unknown'", "T300/5208"]),
    ("ply angle not a number", [_layup(angles='[0, "ninety"]')],
     ["material.plies[0].angles_deg", "must be a (nested) list of numbers"]),
    ("ply angle without its unit", [_layup(angles_key="angles")],
     ["material.plies[0].angles", "needs its unit in the key, e.g. angles_rad"]),
    ("unsymmetric layup", [_layup(symmetric="false")], ["material.plies", "not symmetric about its mid-plane"]),
    ("layup named as a grade", [_layup(name="steel")], ["material.name", "a layup's name"]),
    ("plate thickness beside plies", [_layup(), ("thickness_mm = 5", "thickness_mm = 6")],
     ["geometry.thickness_mm", "the plies of [material] add up to 5 mm"]),
    ("region thicker than a plate", [_region("thickness_mm = 30")],
     ["regions[0].thickness_mm", "thicker than the plate model allows", "t / span = 0.15 above 0.1"]),
    ("overlapping regions",
     [_region("thickness_mm = 8", "thickness_mm = 9", second="rectangle_mm = [250, 0, 350, 200]")],
     ["regions[1].thickness_mm", "overlaps region 'pad 0' with a different thickness"]),
    ("region off the part", [_region("thickness_mm = 8", box="rectangle_mm = [500, 0, 600, 200]")],
     ["regions[0].rectangle_mm", "covers no part of the plate"]),
    ("region of a laminate without plies", [_layup(), _region("thickness_mm = 8")],
     ["regions[0].plies", "a region of a laminate gives its own"]),
    ("region of no thickness", [_region("thickness_mm = 0")], ["regions[0].thickness_mm", "must be positive, got 0"]),
]


@pytest.mark.parametrize("label,edits,needles", BAD_SHAPES, ids=[b[0] for b in BAD_SHAPES])
def test_bad_shape_or_placement(capsys, plate_toml, tmp_path, label, edits, needles):
    """Refused when loaded: one line naming the key as the file writes it, exit 2, the picture that
    `fixbench show --out` would have replaced left as it was."""
    out = tmp_path / "pic.png"
    out.write_bytes(b"old picture")
    line = _one_line_error(capsys, ["show", plate_toml(*edits), "--out", str(out)])
    assert "plate.toml" in line
    for needle in needles:
        assert needle in line, line
    assert out.read_bytes() == b"old picture"


def test_cases_refuses_candidates_no_robot_owns(capsys, plate_toml):
    """`fixbench cases FILE` no longer lists a case whose regions leave candidates unowned."""
    line = _one_line_error(capsys, ["cases", plate_toml(_regions((0, 150), (250, 400)))])
    assert "agents.regions: 2 of 6 fixture candidates lie in no region" in line


def test_console_script_exit_code(plate_toml):
    """The installed entry point, in a fresh process: exit 2, one line, no traceback."""
    path = plate_toml(("thickness_mm = 5", "thickness_mm = -5"))
    proc = subprocess.run([sys.executable, "-m", "fixbench", "show", path], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "geometry.thickness_mm: must be positive" in proc.stderr


SOLVE_BAD = [
    (["--planner", "no_such_planner"], ["unknown planner 'no_such_planner'"]),
    (["--planner", "random", "--set", "batch"], ["--set batch", "key=value"]),
    (["--planner", "random", "--set", "colour=red"], ["--set colour=red", "no setting 'colour'"]),
    (["--planner", "random", "--set", "batch=many"], ["--set batch=many", "invalid literal"]),
    (["--planner", "random", "--budget", "0"], ["--budget 0", "cannot act with zero samples"]),
    (["--planner", "random", "--budget", "-5"], ["--budget", "must be positive"]),
    (["--planner", "no_module_here:Planner"], ["no_module_here:Planner", "cannot import"]),
    (["--planner", "random", "--mode", "both"], ["--mode"]),
]


@pytest.mark.parametrize("extra,needles", SOLVE_BAD, ids=[" ".join(s[0]) for s in SOLVE_BAD])
def test_bad_solve_arguments(capsys, plate_toml, extra, needles):
    line = _one_line_error(capsys, ["solve", plate_toml(), *extra])
    for needle in needles:
        assert needle in line, line


def test_plugin_that_raises_on_import(tmp_path):
    """An installed plugin (entry point) whose module raises: one line, exit 2."""
    (tmp_path / "broken_plugin.py").write_text("raise RuntimeError('kaboom at import')\n")
    dist = tmp_path / "broken_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[fixbench.planners]\nbroken = broken_plugin:Broken\n")
    proc = subprocess.run([sys.executable, "-m", "fixbench", "solvers"], capture_output=True, text=True,
                          env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "plugin 'broken'" in proc.stderr and "kaboom at import" in proc.stderr


def test_planner_spec_that_raises_on_import(capsys, plate_toml, tmp_path, monkeypatch):
    (tmp_path / "explodes.py").write_text("raise ImportError('missing dependency xyz')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    line = _one_line_error(capsys, ["solve", plate_toml(), "--planner", "explodes:Planner"])
    assert "explodes:Planner" in line and "missing dependency xyz" in line


@pytest.mark.parametrize("command", [["solvers"], ["solve", "fan_small", "--planner", "greedy", "--budget", "20"]])
def test_a_plugin_taking_a_builtin_name_is_refused_by_every_command(tmp_path, command):
    """A plugin registering 'greedy': refused by `fixbench solvers` and by `fixbench solve --planner greedy`
    alike (one line naming the plugin and its package), never run in place of the built-in or silently
    shadowed by it."""
    (tmp_path / "shadow_plugin.py").write_text(
        "from solvers import Planner\nclass Greedy(Planner):\n    name = 'greedy'\n"
        "    description = 'impostor'\n    def plan(self, problem, ev, rng, mode):\n        raise SystemExit(9)\n")
    dist = tmp_path / "shadow_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: shadow-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[fixbench.planners]\ngreedy = shadow_plugin:Greedy\n")
    proc = subprocess.run([sys.executable, "-m", "fixbench", *command], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "greedy" in proc.stderr and "shadow_plugin" in proc.stderr
