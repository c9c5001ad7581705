"""`fixbench report`: tables, figures, failed cells, robustness and determinism.

Most tests write fake rows through the store (fast); one runs a tiny real matrix end to end.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.cli import main
from bench.report import bootstrap_ci, iqm, load_rows, make_report, summary_table
from bench.store import ROW_SCHEMA, Store, load_results, write_json_atomic

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
                row.update(schema=1, cell=cid, planner=planner, config="{}", config_hash="h",
                           case="fan_small", part="fan", material=mat, agents=3, mode="per-task",
                           budget=300, seed=seed, n_tasks=2, version="test", error="", info="{}",
                           layouts=json.dumps([[18, 46, 74], [18, 46, 74]]))
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
    from bench.runner import run_matrix

    monkeypatch.chdir(tmp_path)
    plate_toml()
    (tmp_path / "m.toml").write_text('name = "tiny"\ncases = ["plate.toml"]\nmaterials = ["aluminium"]\n'
                                     'planners = ["random", "greedy"]\nseeds = [0, 1]\nbudget = 12\n')
    summary = run_matrix(tmp_path / "m.toml", tmp_path / "run", workers=1, progress=False)
    assert summary["failed"] == 0
    rows = load_results(tmp_path / "run")
    assert all(len(json.loads(x)) == 3 for x in rows["layouts"])  # rows keep their layouts per task
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
