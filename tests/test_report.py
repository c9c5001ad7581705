"""`fixbench report`: tables, figures, failed cells, robustness and determinism.

Most tests write fake rows through the store (fast); one runs a tiny real matrix end to end.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from fixbench.bench.cli import main
from fixbench.bench.records.rows import ROW_SCHEMA, load_results, load_rows
from fixbench.bench.records.store import Store, write_json_atomic
from fixbench.bench.reporting.comparison import heldout_table, improvement_table, main_table, sweep_table
from fixbench.bench.reporting.figures import anytime_figure, ecdf_figure, sweep_figure, violin_figure
from fixbench.bench.reporting.merge import load_references
from fixbench.bench.reporting.report import make_report
from fixbench.bench.reporting.stats import bootstrap_ci, iqm, probability_of_improvement
from fixbench.bench.reporting.tables import summary_table

OPT = {"aluminium": [2e-5, 4e-5], "steel": [1e-5, 2e-5]}
PLANNERS = {"random": 1.5, "greedy": 1.2, "nashq": 1.8}  # final objective / optimum


def _trace(opt: list[float], factor: float, rng) -> pd.DataFrame:
    recs = []
    for t, o in enumerate(opt):
        best = o * (factor + 2.0)
        for s in (1, 3, 10, 30, 100):
            best = min(best, o * (factor + (2.0 if s == 1 else rng.uniform(0, 1.0) * 10 / s)))
            recs.append((t, s, s + 100 * t, best))
    return pd.DataFrame(recs, columns=["task", "task_samples", "samples", "best"])


def _curves(opt: list[float], rng) -> pd.DataFrame:
    episodes, n = 4, len(opt)
    task = np.tile(np.arange(n), episodes)
    u = np.asarray(opt)[task] * rng.uniform(1.0, 3.0, len(task))
    rew = np.exp(-(u * 1e5) ** 2)
    ret = rew.reshape(episodes, n).sum(axis=1)
    frames = [("step_reward", rew), ("step_max_u", u), ("step_task", task), ("episode_return", ret),
              ("episode_regret_ref", 2 * n * 0.7854 - 2 * ret),
              ("episode_regret_true", (u - np.asarray(opt)[task]).reshape(episodes, n).sum(axis=1))]
    return pd.concat([pd.DataFrame({"curve": k, "index": np.arange(len(v)), "value": np.asarray(v, float)})
                      for k, v in frames], ignore_index=True)


def fake_run(root: Path, seeds=(0, 1, 2), failed: dict | None = None, references: bool = True,
             learners: bool = True) -> Path:
    """A run directory with rows, traces, curves and references, written through the store.

    ``failed`` maps (planner, material, seed) to an error; such rows carry a huge objective that
    must never reach the statistics."""
    store = Store(root)
    rng = np.random.default_rng(1)
    failed = failed or {}
    for mat, opt in OPT.items():
        if references:
            key = f"fan_small__{mat}__adefault__t2"
            write_json_atomic(store.reference_path(key), {
                "key": key, "case": "fan_small", "material": mat, "agents": 3, "n_tasks": 2, "error": "",
                "per_task": opt, "shared": None, "proven": True, "gap": 0.0, "samples": 100,
                "layouts": [[18, 46, 74], [18, 46, 74]], "method": "enumeration"})
        for planner, factor in PLANNERS.items():
            for seed in seeds:
                cid = f"{planner}-{mat}-{seed}"
                row = {k: math.nan for k in ROW_SCHEMA}
                row.update(cell=cid, planner=planner, config={}, config_hash="h",
                           case="fan_small", part="fan", material=mat, agents=3, mode="per-task",
                           budget=300, seed=seed, n_tasks=2, version="test", error="", info={},
                           layouts=[[18, 46, 74], [18, 46, 74]])
                err = failed.get((planner, mat, seed))
                if err:
                    row.update(error=err, objective_m=1.0, relative_regret=1e6, wall_s=1e6)
                    store.write(row, None, None)
                    continue
                f = factor * (1 + 0.05 * seed)
                obj = float(np.mean(opt)) * f
                ref = float(np.mean(opt)) if references else math.nan
                row.update(objective_m=obj, mean_max_deformation_m=obj, reference_objective_m=ref,
                           relative_regret=obj / ref - 1, true_regret_m=obj - ref,
                           samples_to_1pct=math.nan, samples_to_5pct=30.0 if f < 1.4 else math.nan,
                           success_1pct=0.0, success_5pct=0.0, samples=300, wall_s=0.1 * (seed + 1),
                           cpu_s=0.1)
                curves = _curves(opt, rng) if planner == "nashq" and learners else None
                store.write(row, _trace(opt, f, rng), curves)
    return root


@pytest.fixture(scope="module")
def reported(tmp_path_factory):
    run = fake_run(tmp_path_factory.mktemp("report") / "run")
    return run, make_report(run, fields=False)


def test_report_tables_and_figures(reported):
    run, res = reported
    md = (run / "report" / "report.md").read_text()
    assert res["report"] == run / "report" / "report.md"
    for needle in ("| case", "max def. (um)", "IQM (um)", "regret (%)", "samples to 1%", "success 5% (%)",
                   "wall (s)", "rank", "failed", "Dolan-More", "COCO"):
        assert needle in md, needle
    for name in ("anytime_fan_small", "ecdf", "profile", "violin", "figure4"):
        png = run / "report" / "figures" / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert png.with_suffix(".pdf").exists()
        assert f"](figures/{name}.png)" in md
    for name in ("summary", "references", "profile"):
        for ext in ("csv", "tex", "md"):
            assert (run / "report" / "tables" / f"{name}.{ext}").exists()
    assert "Deformation fields skipped" in md and res["notes"]
    summ = pd.read_csv(run / "report" / "tables" / "summary.csv")
    assert list(summ["planner"]) == ["greedy", "nashq", "random"]
    assert list(summ["rank"]) == [1, 3, 2]
    # greedy: objective 1.2 * (1, 1.05, 1.1) * mean optimum per material, averaged
    expect = np.mean([1.2 * (1 + 0.05 * s) * np.mean(o) for o in OPT.values() for s in range(3)]) * 1e6
    assert summ.loc[0, "objective_um"] == pytest.approx(expect)
    assert summ.loc[0, "objective_um_lo"] <= expect <= summ.loc[0, "objective_um_hi"]
    assert summ.loc[0, "reached_5pct"] == 6 and summ.loc[1, "reached_5pct"] == 0


def test_csv_round_trips(reported):
    run, _ = reported
    expect = summary_table(load_rows(run))
    back = pd.read_csv(run / "report" / "tables" / "summary.csv")
    pd.testing.assert_frame_equal(back, expect, check_dtype=False)


def test_failed_rows_are_counted_not_averaged(tmp_path):
    failed = {("greedy", "steel", 1): "RuntimeError: planner exploded",
              ("random", "aluminium", 0): "worker died (exit code -9)"}
    run = fake_run(tmp_path / "run", failed=failed)
    make_report(run, fields=False)
    summ = pd.read_csv(run / "report" / "tables" / "summary.csv").set_index("planner")
    assert summ.loc["greedy", "failed"] == 1 and summ.loc["random", "failed"] == 1
    assert summ.loc["nashq", "failed"] == 0 and (summ["cells"] == 6).all()
    ok = [1.2 * (1 + 0.05 * s) * np.mean(o) for m, o in OPT.items() for s in range(3)
          if (m, s) != ("steel", 1)]
    assert summ.loc["greedy", "objective_um"] == pytest.approx(np.mean(ok) * 1e6)
    assert summ["wall_s_hi"].max() < 1  # the failed rows' 1e6 s never got in
    md = (run / "report" / "report.md").read_text()
    assert "planner exploded" in md and (run / "report" / "tables" / "failed.csv").exists()


def test_only_failed_rows(tmp_path):
    failed = {(p, m, s): "RuntimeError: boom" for p in PLANNERS for m in OPT for s in (0, 1, 2)}
    run = fake_run(tmp_path / "run", failed=failed)
    res = make_report(run, tmp_path / "rep")
    md = res["report"].read_text()
    summ = pd.read_csv(res["tables"]["summary"])
    assert (summ["failed"] == 6).all() and summ["objective_um"].isna().all()
    assert "skipped" in md and not res["figures"]


def test_without_references_or_learners(tmp_path):
    run = fake_run(tmp_path / "run", references=False, learners=False)
    res = make_report(run, fields=False)
    md = res["report"].read_text()
    assert "no learner" in md and "no usable regret reference" in md
    assert "best value seen in the run" in md  # anytime curves fall back to the best seen
    assert "anytime_fan_small" in res["figures"] and "figure4" not in res["figures"]
    assert "violin" not in res["figures"]  # no regret without a reference


def test_empty_run_and_not_a_run_dir(tmp_path, capsys):
    (tmp_path / "empty" / "rows").mkdir(parents=True)
    res = make_report(tmp_path / "empty")
    assert "no rows" in res["report"].read_text()
    assert main(["report", str(tmp_path)]) == 2
    assert "not a run directory" in capsys.readouterr().err


def test_deterministic(tmp_path):
    run = fake_run(tmp_path / "run", failed={("nashq", "steel", 2): "boom"})
    make_report(run, tmp_path / "a", fields=False)
    make_report(run, tmp_path / "b", fields=False)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) > 20
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_bootstrap_ci():
    assert bootstrap_ci([3.0, 3.0, 3.0]) == (3.0, 3.0, 3.0)
    assert bootstrap_ci([5.0, math.nan]) == (5.0, 5.0, 5.0)
    assert all(math.isnan(v) for v in bootstrap_ci([]))
    x = np.arange(20.0)
    p, lo, hi = bootstrap_ci(x, strata=[i % 2 for i in range(20)])
    assert lo < p == 9.5 < hi and bootstrap_ci(x) == bootstrap_ci(x)
    assert iqm(np.array([0, 1, 2, 3, 4, 5, 6, 100.0])) == pytest.approx(3.5)


def test_real_run_and_cli(tmp_path, plate_toml, monkeypatch, capsys):
    """A tiny real matrix (a 6-candidate plate), then `fixbench report DIR`."""
    from fixbench.bench.running.runner import run_matrix

    monkeypatch.chdir(tmp_path)
    plate_toml()
    (tmp_path / "m.toml").write_text('name = "tiny"\ncases = ["plate.toml"]\nmaterials = ["aluminium"]\n'
                                     'planners = ["random", "greedy"]\nseeds = [0, 1]\nbudget = 12\n')
    summary = run_matrix(tmp_path / "m.toml", tmp_path / "run", workers=1, progress=False)
    assert summary["failed"] == 0
    rows = load_results(tmp_path / "run")
    assert all(isinstance(x, list) and len(x) == 3 for x in rows["layouts"])  # rows keep their layouts per task
    assert main(["report", str(tmp_path / "run")]) == 0
    assert "wrote" in capsys.readouterr().out
    rep = tmp_path / "run" / "report"
    for name in ("anytime_plate", "ecdf", "profile", "violin", "field_plate"):
        assert (rep / "figures" / f"{name}.png").exists(), name
    summ = pd.read_csv(rep / "tables" / "summary.csv")
    assert set(summ["planner"]) == {"random", "greedy"} and (summ["failed"] == 0).all()
    assert summ["regret_pct"].notna().all()
    shutil.rmtree(rep)
    assert main(["report", str(tmp_path / "run"), "--out", str(tmp_path / "r2"), "--no-fields"]) == 0
    assert (tmp_path / "r2" / "report.md").exists()


# the comparison: budget sweep, held-out track, probability of improvement, main table ---------------

SWEEP_OPT = [2e-5, 4e-5, 3e-5, 5e-5]  # 4 tasks; held out with k = 2: tasks 1 and 3
SWEEP = {"random": ("random", lambda spt: 2.0 / spt ** 0.3),
         "greedy+transfer": ("greedy", lambda spt: 0.0 if spt >= 100 else 0.5 / spt),
         "nashq": ("nashq", lambda spt: 5.0 / spt ** 0.5)}
NASHQ_MAX_SPT = 10  # like a learner's max_samples_per_task: no nashq cell at 100
HELDOUT_GAP = {"random": 1.0, "greedy+transfer": 0.3, "nashq": 0.6}


def _task_gaps(r: float) -> np.ndarray:
    """Gap per task: r on even tasks, 1.5 r on the odd (held-out) ones."""
    return r * np.array([1.0, 1.5, 1.0, 1.5])


def _sweep_row(cid, case, label, planner, mode, seed, spt, per_task, scored, **extra) -> dict:
    opt = np.asarray(SWEEP_OPT)
    obj, ref = float(per_task[scored].mean()), float(opt[scored].mean())
    row = {k: math.nan for k in ROW_SCHEMA}
    row.update(cell=cid, planner=planner, config={}, config_hash="h", label=label, case=case,
               part="plate", material="aluminium", agents=3, mode=mode, seed=seed, n_tasks=4,
               samples_per_task=spt, budget=math.nan if math.isnan(spt) else spt * 4,
               n_scored_tasks=len(scored), per_task_m=per_task.tolist(), objective_m=obj,
               reference_objective_m=ref, relative_regret=obj / ref - 1, samples=0 if math.isnan(spt) else spt * 4,
               reference_source="exact", version="test", error="", info={}, wall_s=0.1, cpu_s=0.1)
    row.update(extra)
    return row


def sweep_run(root: Path, cases=("plate_a", "plate_b"), seeds=(0, 1, 2)) -> Path:
    """A budget sweep (1, 10, 100 samples a task) and a held-out track (k = 2, 10 samples a training
    task) on two cases, plus ``exact`` with its own (unlimited) budget, written through the store."""
    store = Store(root)
    opt = np.asarray(SWEEP_OPT)
    for case in cases:
        key = f"{case}__aluminium__adefault__t4"
        write_json_atomic(store.reference_path(key), {
            "key": key, "case": case, "material": "aluminium", "agents": 3, "n_tasks": 4, "error": "",
            "per_task": SWEEP_OPT, "shared": None, "proven": True, "layouts": [[0, 1, 2]] * 4})
        for seed in seeds:
            store.write(_sweep_row(f"exact-{case}-{seed}", case, "", "exact", "per-task", seed, math.nan,
                                   opt, [0, 1, 2, 3]), None, None)
            for label, (planner, gap) in SWEEP.items():
                for spt in (1, 10, 100):
                    if planner == "nashq" and spt > NASHQ_MAX_SPT:
                        continue
                    u = opt * (1 + _task_gaps(gap(spt) * (1 + 0.1 * seed)))
                    store.write(_sweep_row(f"{label}-{case}-{spt}-{seed}", case, label, planner, "per-task",
                                           seed, spt, u, [0, 1, 2, 3]), None, None)
                u = opt * (1 + _task_gaps(HELDOUT_GAP[label] * (1 + 0.1 * seed)))
                store.write(_sweep_row(f"{label}-{case}-heldout-{seed}", case, label, planner, "held-out", seed,
                                       10, u, [1, 3], heldout_every=2, samples=20), None, None)
    return root


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    run = sweep_run(tmp_path_factory.mktemp("sweep") / "run")
    return run, make_report(run, fields=False)


def _labelled(fig) -> int:
    """Asserts every axes with data has an x and a y label; returns how many axes have data."""
    axes = [ax for ax in fig.axes if ax.has_data()]
    for ax in axes:
        assert ax.get_xlabel().strip() and ax.get_ylabel().strip(), ax.get_title()
    return len(axes)


def test_labels_come_from_rows(swept, tmp_path):
    run, _ = swept
    rows = load_rows(run)
    assert set(rows["label"]) == {"exact", "random", "greedy+transfer", "nashq"}
    store = Store(tmp_path / "labels")
    entries = [("greedy", {}, ""), ("greedy", {"transfer": 3}, "greedy+transfer"),
               ("ga", {}, math.nan), ("ga", {"transfer": 3}, math.nan)]
    for i, (planner, config, label) in enumerate(entries):
        row = {k: math.nan for k in ROW_SCHEMA}
        row.update(cell=f"c{i}", planner=planner, config=config, label=label, case="c", material="m", seed=0,
                   mode="per-task", error="")
        store.write(row, None, None)
    # a labelled entry does not turn its planner's unlabelled entry into "greedy (default)"
    assert sorted(load_rows(store.root)["label"]) == ["ga (default)", "ga (transfer=3)", "greedy", "greedy+transfer"]
    for col in ("samples_per_task", "heldout_every", "n_scored_tasks"):
        assert pd.api.types.is_numeric_dtype(rows[col]), col


def test_sweep_and_heldout_sections(swept):
    run, res = swept
    md = res["report"].read_text()
    for name in ("main", "summary", "sweep", "heldout", "improvement"):
        for ext in ("csv", "tex", "md"):
            assert (run / "report" / "tables" / f"{name}.{ext}").exists(), name
    assert "](figures/sweep.png)" in md and (run / "report" / "figures" / "sweep.pdf").exists()
    assert "pays 10 a task" in md and "| samples_per_task" in md  # the summary splits by the sweep
    sweep = pd.read_csv(res["tables"]["sweep"])
    assert "exact" not in set(sweep["planner"])  # its own budget: not a point of the sweep
    g = sweep[(sweep["case"] == "plate_a") & (sweep["planner"] == "random") & (sweep["samples_per_task"] == 10)]
    full = 2.0 / 10 ** 0.3 * np.mean([1 + 0.1 * s for s in range(3)]) * np.dot(SWEEP_OPT, [1, 1.5, 1, 1.5]) \
        / np.sum(SWEEP_OPT) * 100
    assert g["cells"].item() == 3 and g["regret_pct"].item() == pytest.approx(full)
    assert g["regret_pct_lo"].item() <= full <= g["regret_pct_hi"].item()
    assert set(sweep.loc[sweep["planner"] == "nashq", "samples_per_task"]) == {1, 10}
    held = pd.read_csv(res["tables"]["heldout"])
    a = held[held["case"] == "plate_a"].fillna({"samples_per_task": -1})
    a = a.set_index(["planner", "track", "samples_per_task"])
    # held-out cells: their own regret over tasks 1 and 3, 20 samples (10 on each training task)
    assert a.loc[("nashq", "held-out", 10), "regret_pct"] == pytest.approx(0.6 * 1.5 * 1.1 * 100)
    assert a.loc[("nashq", "held-out", 10), "samples"] == 20
    # per-task cells scored on the same held-out tasks: gap 1.5 r there
    assert a.loc[("random", "per-task", 100), "regret_pct"] == pytest.approx(2.0 / 100 ** 0.3 * 1.5 * 1.1 * 100)
    assert a.loc[("exact", "per-task", -1), "regret_pct"] == pytest.approx(0)


def test_heldout_table_skips_rows_without_per_task_or_reference(swept):
    run, _ = swept
    rows = load_rows(run)
    refs = load_references(run)
    rows.loc[rows["label"] == "random", "per_task_m"] = math.nan
    held = heldout_table(rows, {k: v for k, v in refs.items() if k[0] == "plate_a"})
    per = held[held["track"] == "per-task"]
    assert "random" not in set(per["planner"]) and set(per["case"]) == {"plate_a"}
    assert "random" in set(held.loc[held["track"] == "held-out", "planner"])  # its own regret column


def test_sweep_figure(swept):
    run, _ = swept
    table = sweep_table(load_rows(run))
    colors = {lab: f"C{i}" for i, lab in enumerate(sorted(table["planner"].unique()))}
    fig = sweep_figure(table, colors)
    try:
        assert _labelled(fig) == 2
        assert [ax.get_title() for ax in fig.axes] == ["plate_a", "plate_b"]
        assert all(ax.get_xscale() == "log" and ax.get_yscale() == "log" for ax in fig.axes)
        assert "samples per task" in fig.axes[0].get_xlabel() and "(%)" in fig.axes[0].get_ylabel()
        assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
        assert {t.get_text() for t in fig.legends[0].get_texts()} == set(colors)
        w, h = fig.get_size_inches()
        assert 9 <= w <= 11 and w / h <= 3.2
        # greedy+transfer's regret of 0 at 100 samples a task is drawn at the floor, not dropped
        line = next(ln for ln in fig.axes[0].get_lines() if ln.get_label() == "greedy+transfer")
        assert len(line.get_xdata()) == 3 and np.all(np.asarray(line.get_ydata()) > 0)
    finally:
        plt.close(fig)


def test_probability_of_improvement_matches_pairwise_count():
    x = np.array([1.0, 2.0, 3.0, 5.0])
    y = np.array([2.0, 4.0, 4.0])  # x = 2 ties y = 2
    brute = np.mean([1.0 if a < b else 0.5 if a == b else 0.0 for a in x for b in y])
    assert brute == pytest.approx(7.5 / 12)
    p, lo, hi = probability_of_improvement(x, y)
    assert p == pytest.approx(brute) and lo <= p <= hi and 0 <= lo < hi <= 1
    assert probability_of_improvement(x, y) == (p, lo, hi)  # fixed seed
    rows = pd.DataFrame({"case": "c", "ok": True, "mode": "per-task",
                         "label": ["X"] * len(x) + ["Y"] * len(y), "relative_regret": np.r_[x, y] / 100})
    t = improvement_table(rows).set_index(["X", "Y"])
    assert len(t) == 2 and t.loc[("X", "Y"), "P"] == pytest.approx(brute)
    assert t.loc[("Y", "X"), "P"] == pytest.approx(1 - brute)
    assert t.loc[("Y", "X"), "P_lo"] == pytest.approx(1 - hi) and t.loc[("X", "Y"), "cells_X"] == 4
    assert probability_of_improvement([1.0], [2.0, 3.0]) == (1.0, 1.0, 1.0)


def test_improvement_table_per_group(swept):
    run, res = swept
    imp = pd.read_csv(res["tables"]["improvement"])
    assert {"case", "mode", "samples_per_task", "X", "Y", "P", "P_lo", "P_hi"} <= set(imp.columns)
    g = imp[(imp["case"] == "plate_a") & (imp["mode"] == "per-task") & (imp["samples_per_task"] == 10)]
    assert len(g) == 6  # 3 planners at 10 samples a task: every ordered pair
    assert g.set_index(["X", "Y"]).loc[("greedy+transfer", "random"), "P"] == 1.0
    assert ((imp["P_lo"] <= imp["P"]) & (imp["P"] <= imp["P_hi"])).all()


def test_main_table_ranks(swept, tmp_path):
    run, res = swept
    main_ = pd.read_csv(res["tables"]["main"])
    assert "mean_rank" in main_ and main_["mean_rank"].is_monotonic_increasing
    # the fake sweep has per-task and held-out cells: one column per case and mode
    assert {"plate_a (per-task)", "plate_a (per-task)_lo", "plate_a (per-task)_hi", "plate_b (held-out)"} \
        <= set(main_.columns)
    m = main_.set_index("planner")
    # exact (own budget) competes at each of the 3 sweep levels (2 cases x 3 seeds x 3 levels: 18
    # problems), nashq has no cell at 100 samples a task: every entry is ranked on nashq's 12 problems
    assert (m["problems"] == 2 * 3 * 2).all() and main_["planner"].iloc[0] == "exact"
    assert re.search(r"mean rank over the 12 of \d+ problems every planner ran on",
                     (run / "report" / "report.md").read_text())
    assert "mean rank |" in (run / "report" / "tables" / "main.md").read_text()
    # failed cells rank last: greedy fails on one of the six problems of the fake run
    rows = load_rows(fake_run(tmp_path / "run", failed={("greedy", "steel", 1): "boom"}))
    t = main_table(rows).set_index("planner")
    assert t.loc["greedy", "mean_rank"] == pytest.approx((5 * 1 + 3) / 6)
    assert t.loc["random", "mean_rank"] == pytest.approx((5 * 2 + 1) / 6)
    assert list(main_table(rows)["planner"]) == ["greedy", "random", "nashq"]
    # a failed row keeps the cell's raw settings (no agents or tasks count): still its problem's last
    rows.loc[~rows["ok"], ["agents", "n_tasks"]] = math.nan
    assert main_table(rows).set_index("planner").loc["greedy", "mean_rank"] == pytest.approx((5 * 1 + 3) / 6)


def test_old_run_directory_without_new_columns(tmp_path):
    run = fake_run(tmp_path / "run")
    new = ("label", "samples_per_task", "heldout_every", "n_scored_tasks", "per_task_m", "reference_source",
           "setup_s", "row_sha1")  # rows of older runs had none of these (nor a checksum)
    for p in (run / "rows").glob("*.json"):
        row = json.loads(p.read_text())
        write_json_atomic(p, {k: v for k, v in row.items() if k not in new})
    res = make_report(run, fields=False)
    md = res["report"].read_text()
    assert "no budget sweep" in md and "no held-out cells" in md
    assert {"main", "summary", "improvement"} <= set(res["tables"]) and "sweep" not in res["figures"]
    assert set(load_rows(run)["label"]) == set(PLANNERS)


def _recs(planners: dict[str, float], cases=("a", "b")) -> list[dict]:
    """Gap traces: per case and planner label, two tasks running to ``planners[label]`` samples."""
    return [{"case": c, "label": lab, "planner": lab, "task": t, "cell": f"{c}-{lab}",
             "s": np.geomspace(1, top, 6), "gap": np.geomspace(1, 0.01, 6) * (t + 1)}
            for c in cases for lab, top in planners.items() for t in (0, 1)]


def test_anytime_leaves_out_the_reference():
    recs = _recs({"exact": 4e4, "greedy": 100, "random": 300})
    fig = anytime_figure(recs, "a", {"exact": "k", "greedy": "C0", "random": "C1"})
    try:
        ax = fig.axes[0]
        assert _labelled(fig) == 1 and "reference" in ax.get_ylabel()
        assert 300 <= ax.get_xlim()[1] < 1000  # the largest a planner other than exact spent, plus a margin
        assert not any(ln.get_label().startswith("exact") for ln in ax.get_lines())
    finally:
        plt.close(fig)


def test_ecdf_and_violin_layout(swept):
    recs = _recs({"greedy": 100, "random": 300})
    fig = ecdf_figure(recs, ["a", "b"], {"greedy": "C0", "random": "C1"})
    try:
        assert _labelled(fig) == 2
        assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    finally:
        plt.close(fig)
    run, _ = swept
    rows = load_rows(run)
    for cases in (["plate_a"], ["plate_a", "plate_b"]):
        ok = rows[rows["case"].isin(cases)]
        fig = violin_figure(ok, {lab: f"C{i}" for i, lab in enumerate(sorted(ok["label"].unique()))})
        try:
            assert _labelled(fig) == len(cases)
            assert all(ax.get_xlabel().startswith("difference from reference (%") for ax in fig.axes)
            assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == sorted(ok["label"].unique())
            w, h = fig.get_size_inches()
            assert w / h <= 2.5 + 1e-9 and w <= 11
        finally:
            plt.close(fig)


def test_comparison_sections_deterministic(swept, tmp_path):
    run, _ = swept
    for out in ("a", "b"):
        make_report(run, tmp_path / out, fields=False)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert {"tables/main.csv", "tables/improvement.csv", "tables/heldout.csv", "figures/sweep.pdf"} <= set(
        map(str, files))
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_iqm_table_pools_positions_and_leaves_out_the_tails():
    from scipy.stats import trim_mean

    from fixbench.bench.reporting.comparison import iqm_table
    opt = [1.0, 2.0, 4.0, 8.0, 1.0, 1.0]
    refs = {("c", "m", 2, 6): {"per_task": opt}}
    ratios = {0: [1.1, 1.2, 1.0, 5.0, 1.3, 1.4], 1: [1.2, 1.1, 1.05, 1.0, 9.0, 1.5]}
    recs = []
    for seed, r in ratios.items():
        for mode in ("per-task", "held-out"):
            recs.append(dict(case="c", material="m", agents=2, n_tasks=6, mode=mode, heldout_every=3, seed=seed,
                             label="p", ok=True, relative_regret=0.5,
                             per_task_m=[o * x for o, x in zip(opt, r)]))
    table = iqm_table(pd.DataFrame(recs), refs).set_index("planner")
    pooled = (np.array(ratios[0] + ratios[1]) - 1) * 100
    assert table.loc["p", "c (per-task)"] == pytest.approx(trim_mean(pooled, 0.25))
    assert table.loc["p", "c (per-task) mean"] == pytest.approx(pooled.mean())
    assert table.loc["p", "c (per-task)_lo"] <= trim_mean(pooled, 0.25) <= table.loc["p", "c (per-task)_hi"]
    held = (np.array([ratios[s][t] for s in (0, 1) for t in (1, 2, 4, 5)]) - 1) * 100  # not 0 and 3
    assert table.loc["p", "c (held-out)"] == pytest.approx(trim_mean(held, 0.25))
    assert trim_mean(pooled, 0.25) < pooled.mean()  # the 5x and 9x positions are in the tail, not the IQM


def test_the_reference_table_gives_each_reference_its_own_gap():
    """Positions with a certified bound and (reference - bound) / reference over them; a snapshot
    written before bounds were recorded counts its proven optima as their own bounds."""
    from fixbench.bench.reporting.tables import reference_table

    refs = {("a", "steel", 2, 3): {"per_task": [2e-6, 3e-6, 2e-6], "lower_bounds": [1e-6, None, 2e-6]},
            ("b", "steel", 2, 2): {"per_task": [1e-6, 4e-6], "proven": True},
            ("c", "steel", 2, 2): {"per_task": [1e-6, 4e-6], "proven": False}}
    t = reference_table(refs).set_index("case")
    assert t.loc["a", "bounded"] == 2 and t.loc["a", "gap to bound, median (%)"] == pytest.approx(25.0)
    assert t.loc["a", "worst (%)"] == pytest.approx(50.0)
    assert t.loc["b", "bounded"] == 2 and t.loc["b", "worst (%)"] == 0.0
    assert t.loc["c", "bounded"] == 0 and math.isnan(t.loc["c", "gap to bound, median (%)"])
