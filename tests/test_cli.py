"""The CLI end to end: every command has --help, JSON outputs carry their documented keys."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import meshio
import pytest

from fixbench.bench.cli import cli, main

ROOT = Path(__file__).resolve().parents[1]


def run(capsys, *argv) -> str:
    rc = main(list(argv))
    out = capsys.readouterr()
    assert rc == 0, out.err
    return out.out


@pytest.mark.parametrize("command", sorted(cli.commands))
def test_help(capsys, command):
    assert "Usage" in run(capsys, command, "--help")


def test_evaluate_json_plot_vtk(capsys, tmp_path):
    out = run(capsys, "evaluate", "fan_small", "--task", "1", "--layout", "0,28,56", "--json",
              "--plot", str(tmp_path / "f.png"), "--vtk", str(tmp_path / "f.vtu"))
    res = json.loads(out)
    for key in ("max_ux", "max_uy", "max_w", "max_u", "reward_gaussian", "reward_bell"):
        assert key in res
    assert res["samples"] == 1 and res["max_u"] > 0
    assert (tmp_path / "f.png").stat().st_size > 1000
    mesh = meshio.read(tmp_path / "f.vtu")
    assert mesh.point_data["displacement"].shape[1] == 3


def test_validate_json(capsys):
    checks = json.loads(run(capsys, "validate", "--json", "--no-parts"))
    assert len(checks) >= 6
    for c in checks:
        assert {"name", "computed", "reference", "rel_error"} <= set(c)
        assert c["rel_error"] <= 0.01


def _refuse(name):
    raise ValueError(f"not JSON: {name}")


def test_validate_parts(capsys, monkeypatch):
    """The parts' lines of `fixbench validate` for the cases --part names (the main job, `make bench`,
    runs them on every part: minutes to solve the full parts directly): w/t on a small case and a
    full one, then the full part's oracle and mesh rows; a row beyond its limit exits 1."""
    argv = ("validate", "--json", "--part", "fan_small", "--part", "fan")
    rows = json.loads(run(capsys, *argv), parse_constant=_refuse)  # strict JSON
    parts = {r["name"]: r for r in rows if r.get("check") == "w/t"}
    assert set(parts) == {"fan", "fan_small"}
    for r in parts.values():
        assert 0 < r["w_over_t"] <= r["limit"] == 0.5 and not r["flagged"]
    assert parts["fan"]["layouts"] == "shipped reference" and parts["fan_small"]["layouts"] == "proven optimum"
    whole = {r["check"]: r for r in rows if r.get("check") in ("oracle", "mesh")}
    assert [r["name"] for r in whole.values()] == ["fan", "fan"]
    assert whole["oracle"]["worst_rel_difference"] <= whole["oracle"]["limit"] == 1e-9
    assert 0 < abs(whole["mesh"]["change"]) <= whole["mesh"]["limit"] == 0.02
    assert not any(r["flagged"] for r in whole.values())
    from fixbench.cases import analytic, part_checks

    monkeypatch.setattr(analytic, "validate", lambda: [])  # the analytic plates: test_validate_json
    monkeypatch.setattr(part_checks, "MESH_TOL", abs(whole["mesh"]["change"]) / 2)
    with pytest.raises(SystemExit) as stop:
        main(list(argv))
    assert stop.value.code == 1 and json.loads(capsys.readouterr().out)[-1]["flagged"]


def test_validate_names_every_full_part_and_refuses_an_unknown_one(capsys):
    from fixbench.cases.part_checks import full_parts

    assert full_parts() == ["bus_panel", "cfrp_wing_panel", "fan", "wing_panel", "wing_panel_pairs", "wing_spar"]
    assert main(["validate", "--part", "wing_panel_tiny"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--part: wing_panel_tiny: is not a catalog case with fixtures" in err


def test_cases_json(capsys):
    rows = {r["case"]: r for r in json.loads(run(capsys, "cases", "--json"))}
    assert rows["wing_panel"]["candidates"] == 3333
    assert rows["wing_panel_small"]["joint_size"] <= 10**7
    assert all(r["dofs"] > 0 for r in rows.values())


def test_show(capsys, tmp_path):
    run(capsys, "show", "fan", "--out", str(tmp_path / "fan.png"))
    assert (tmp_path / "fan.png").stat().st_size > 5000


def test_perf_json(capsys):
    res = json.loads(run(capsys, "perf", "--case", "fan_small", "--batch", "2000", "--json"))
    for key in ("single_speedup", "batched_layouts_per_s", "precompute_s", "peak_rss_mb"):
        assert res[key] > 0


def test_perf_of_a_planner_at_several_values_of_a_setting(capsys):
    """Side by side on one problem and seed: the same budget spent by each, the same layouts where
    the setting changes no bit (positions_per_step 1 twice), the first run the ratios' base."""
    rows = json.loads(run(capsys, "perf", "--case", "fan_small", "--planner", "vdn", "--vary",
                          "positions_per_step=1,1,3", "--set", "hidden=8", "--samples-per-task", "4", "--json"))
    assert [r["positions_per_step"] for r in rows] == ["1", "1", "3"]
    assert all(r["samples"] == 24 and r["cpu_s"] > 0 and r["time_select_s"] >= 0 for r in rows)
    assert rows[0]["cpu_ratio"] == 1 and rows[0]["objective_m"] == rows[1]["objective_m"]
    assert main(["perf", "--planner", "vdn", "--vary", "positions_per_step=1,0"]) == 2
    assert "positions_per_step" in capsys.readouterr().err
    assert main(["perf", "--planner", "vdn"]) == 2


def test_solve_json(capsys):
    res = json.loads(run(capsys, "solve", "fan_small", "--planner", "random", "--budget", "60",
                         "--seed", "3", "--json"))
    assert res["samples"] == 60 and res["planner"] == "random" and res["case"] == "fan_small"
    assert len(res["per_task"]) == 6
    assert {"task", "layout", "max_deformation_m", "reward"} <= set(res["per_task"][0])
    assert res["mean_max_deformation_m"] > 0


def test_example_plugin_installs_and_runs(tmp_path):
    """README's plugin example: a separate package, found through its entry point."""
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--target", str(target), str(ROOT / "examples" / "fixbench-plugin-example")],
                   check=True, capture_output=True)
    env = {"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"}
    listed = subprocess.run([sys.executable, "-m", "fixbench", "solvers"], capture_output=True,
                            text=True, env=env, cwd=ROOT)
    assert "near-load" in listed.stdout, listed.stderr
    proc = subprocess.run([sys.executable, "-m", "fixbench", "solve", "fan_small", "--planner", "near-load",
                           "--set", "nearest=2", "--budget", "30", "--json"], capture_output=True, text=True,
                          env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["planner"] == "near-load" and res["samples"] == 30  # the driver spent the budget, 5 a task
