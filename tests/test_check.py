"""``fixbench check CASE``: the figures of a small catalog case, the warning of a too-thin part, one
line and exit code 2 for a bad file, strict JSON, settings checked."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from fixbench.bench.check import CheckSettings, deflection, random_maxima
from fixbench.bench.cli import main
from fixbench.cases.problem import load_problem
from fixbench.solvers.base import ConfigError

SMALL = "wing_panel_small"


def _refuse(name):
    raise ValueError(f"not JSON: {name}")


def _thin(tmp_path, thickness_mm) -> str:
    path = tmp_path / "thin_panel.toml"
    path.write_text(f'[case]\nextends = "{SMALL}"\n\n[geometry]\nthickness_mm = {thickness_mm}\n')
    return str(path)


def test_small_case_figures_json(capsys, tmp_path):
    png = tmp_path / "small.png"
    rc = main(["check", SMALL, "--json", "--out", str(png)])
    out = capsys.readouterr()
    assert rc == 0, out.err
    res = json.loads(out.out, parse_constant=_refuse)  # strict JSON
    p = load_problem(SMALL)
    mesh = res["mesh"]
    assert [r["mesh_scale"] for r in mesh["rows"]] == [1.0, 0.7, 0.5]
    assert mesh["rows"][0]["elements"] < mesh["rows"][1]["elements"] < mesh["rows"][2]["elements"]
    assert mesh["layout"] == [int(a[0]) for a in p.action_sets]  # each agent's first action
    assert mesh["rows"][0]["max_u_m"] == pytest.approx(p.direct_deformation(mesh["task"], [mesh["layout"]]).max_u[0])
    assert abs(mesh["change"]) < mesh["limit"] == 0.02 and not mesh["flagged"]
    d = res["deflection"]
    assert 0 < d["best_w_over_t"] <= d["median_w_over_t"] <= d["worst_w_over_t"]
    assert d["median_w_over_t"] <= d["limit"] == 0.5 and not d["flagged"]
    ref = res["reference"]
    assert ref["joint_size"] == p.joint_size and ref["evaluations"] == p.joint_size * p.n_tasks
    assert ref["matrix"]["method"] == "enumeration" and ref["matrix"]["samples"] == ref["evaluations"]
    assert ref["portfolio"]["proven"] and ref["layout_batched_s"] > 0 and ref["layout_single_s"] > 0
    r = res["reward"]
    assert r["suggested_degenerate_share"] <= min(r["degenerate_share"], r["limit"])
    assert (r["sigma_x_m"], r["sigma_z_m"]) == p.spec.reward_sigma
    assert res["picture"] == str(png) and png.stat().st_size > 1000
    assert out.err.splitlines() == [f"warning: {w}" for w in res["warnings"]]  # one line each


def test_too_thin_part_warns_with_the_ratio(capsys, tmp_path):
    """A fifth of the thickness: w/t grows 5^4 = 625 times (w ~ 1/t^3), far beyond the limit; warned."""
    rc = main(["check", _thin(tmp_path, 2), "--out", str(tmp_path / "thin.png")])
    out = capsys.readouterr()
    assert rc == 0, out.err
    warned = [w for w in out.err.splitlines() if "geometry.thickness_mm" in w]
    assert len(warned) == 1 and warned[0].startswith("warning: ") and "thin_panel.toml" in warned[0]
    ratio = float(re.search(r"w/t = ([0-9.e+]+)", warned[0]).group(1))
    s = CheckSettings()
    thick = load_problem(SMALL)
    maxima, tasks = random_maxima(thick, s)
    assert ratio == pytest.approx(625 * deflection(thick, maxima, tasks, s)["median_w_over_t"], rel=1e-2)
    assert ratio > 0.5
    assert "median w/t" in out.out and "mesh convergence" in out.out and "portfolio" in out.out


@pytest.mark.parametrize("case, key", [("bad", "geometry.thickness_mm"), ("no_such_case", "")])
def test_bad_file_one_line_exit_2(capsys, tmp_path, monkeypatch, case, key):
    monkeypatch.chdir(tmp_path)
    target = _thin(tmp_path, -2) if case == "bad" else case
    assert main(["check", target, "--json"]) == 2
    out = capsys.readouterr()
    lines = out.err.splitlines()
    assert len(lines) == 1 and out.out == ""
    assert key in lines[0] and ("thin_panel.toml" in lines[0] if case == "bad" else case in lines[0])
    assert "Traceback" not in out.err and not list(tmp_path.glob("*.png"))  # nothing written


def test_settings_are_checked():
    with pytest.raises(ConfigError, match="mesh_scales"):
        CheckSettings(mesh_scales=(0.5, 1.0))
    with pytest.raises(ConfigError, match="layouts"):
        CheckSettings(layouts=0)
    assert np.all(np.diff(CheckSettings().mesh_scales) < 0)
