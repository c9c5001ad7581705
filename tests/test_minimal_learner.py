"""The minimal learner of docs/planners.md ("Write a learner"), as printed: its module written to a
scratch folder, named ``my_learner:EpsGreedy`` in a tiny matrix on wing_panel_small, run by
``fixbench run`` and reported by ``fixbench report``. Its declared curves are what the run stores and
what Figure 4 reads (``learner_runs``); it declares no regret curve, and Figure 4 is drawn anyway."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from fixbench.bench.cli import main
from fixbench.bench.records.rows import load_results
from fixbench.bench.records.store import load_curves
from fixbench.bench.reporting.figures import FIGURE4_CURVES, draw_figure4, learner_runs, plt
from fixbench.bench.reporting.report import learner_cells

ROOT = Path(__file__).resolve().parents[1]
SPEC = "my_learner:EpsGreedy"
MATRIX = f"""
name = "minimal-learner"
cases = ["wing_panel_small"]
materials = ["aluminium"]
planners = ["{SPEC}", "random"]
seeds = [0, 1]
budget = 24
tasks = 2
proof_limit = 0
"""
EPISODES = 24 // 2  # the budget as whole passes over the 2 tasks


def snippet() -> str:
    """The python block of the page's "Write a learner" section."""
    text = (ROOT / "docs" / "planners.md").read_text(encoding="utf-8")
    section = text[text.index("### Write a learner"):text.index("### The env in TorchRL")]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """The matrix run and reported once (the learner's module on the workers' path)."""
    work = tmp_path_factory.mktemp("minimal")
    (work / "my_learner.py").write_text(snippet())
    (work / "m.toml").write_text(MATRIX)
    mp = pytest.MonkeyPatch()
    mp.setenv("PYTHONPATH", str(work) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    mp.syspath_prepend(str(work))
    try:
        assert main(["run", str(work / "m.toml"), "--out", str(work / "run"), "--workers", "1"]) == 0
        assert main(["report", str(work / "run"), "--no-fields"]) == 0
        yield work / "run"
    finally:
        mp.undo()


def test_its_cells_run_within_the_budget_and_store_the_declared_curves(run_dir):
    rows = load_results(run_dir)
    mine = rows[rows["planner"] == SPEC]
    assert len(mine) == 2 and (mine["error"] == "").all() and (mine["samples"] == 24).all()
    assert mine["policy_objective_m"].notna().all()  # its policy is scored beside its incumbents
    curves = load_curves(run_dir)
    for cell, info in zip(mine["cell"], mine["info"]):
        stored = curves[curves["cell"] == cell]
        assert set(stored["curve"]) == {"step_reward", "step_max_u", "step_task", "episode_return"}
        units = info["curve_units"]  # the row's info, as load_results gives it
        assert units == {"step_reward": "step", "step_max_u": "step", "step_task": "step", "episode_return": "episode"}
        steps = stored[stored["curve"] == "step_max_u"].sort_values("index")
        assert steps["index"].tolist() == list(range(24)) and (steps["value"] > 0).all()
        assert len(stored[stored["curve"] == "episode_return"]) == EPISODES
        assert "step_max_u" not in info and info["eps"] == 0.2  # a curve is not in the row's info; scalars are
    assert set(curves["cell"]) == set(mine["cell"])  # random declares none: no curves file


def test_figure4_reads_its_curves_and_the_report_draws_it(run_dir):
    rows = load_results(run_dir)
    ok = rows[rows["error"] == ""]
    curves = load_curves(run_dir)
    cells = learner_cells(curves, ok)
    assert sorted(cells) == sorted(rows.loc[rows["planner"] == SPEC, "cell"])
    runs = learner_runs(ok, curves, cells, {})
    (label,) = runs
    assert len(runs[label]) == 2
    for run in runs[label]:
        assert set(run) == {*FIGURE4_CURVES, "optimum"}
        assert len(run["step_reward"]) == len(run["step_max_u"]) == 24 and len(run["episode_return"]) == EPISODES
        assert np.allclose(run["episode_return"], run["step_reward"].reshape(EPISODES, -1).sum(axis=1))
        assert len(run["episode_regret_ref"]) == 0  # not declared: its panel is drawn without it
    fig, axes = plt.subplots(1, 5)
    draw_figure4(axes, runs, {label: "C0"})
    drawn = [bool(ax.lines) for ax in axes[:4]]
    plt.close(fig)
    assert drawn == [True, True, False, True]  # (c2) from its steps, against the best it saw; (c) not declared
    report = run_dir / "report"
    assert (report / "figures" / "figure4.png").stat().st_size > 0
    assert "figures/figure4.png" in (report / "report.md").read_text(encoding="utf-8")
