"""``fixbench export``: IOHprofiler, marl-eval and CSV read back against the store they came from."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import strict_json_loads

from fixbench.bench.cli import cli, main
from fixbench.bench.records.rows import ROW_SCHEMA, load_results
from fixbench.bench.records.store import load_curves, load_traces
from fixbench.bench.reporting.export import (
    DAT_HEADER,
    FORMATS,
    MARKER,
    cell_curve,
    export_run,
    function_id,
    load_run,
    marl_eval_data,
    read_iohprofiler,
    strict_json,
)
from fixbench.bench.running.runner import run_matrix

#: one xdist worker runs these tests (`make test`: --dist loadgroup), so the run is made once a session
pytestmark = pytest.mark.xdist_group("test_export")

# every mode, a classical planner (small batches: several trace rows a task) and a learner with a
# few episodes; iql has no shared mode, so two of its cells fail (rows with an error)
TINY = """
name = "tiny-export"
cases = ["fan_small"]
seeds = [0, 1]
budget = 60
tasks = 2
agents = 2
mode = ["per-task", "shared", "held-out"]
heldout_every = 2

[[planners]]
name = "random"
config = { batch = 5 }
[[planners]]
name = "iql"
config = { episodes = 4, hidden = 16 }
budget = 8
"""
EPISODES = 4


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    (root / "m.toml").write_text(TINY)
    summary = run_matrix(root / "m.toml", root / "run", workers=1, progress=False)
    assert summary["run"] == 12 and summary["failed"] == 2
    return root / "run"


def test_cli_offers_every_format():
    choice = next(p for p in cli.commands["export"].params if p.name == "fmt").type
    assert tuple(choice.choices) == FORMATS


def test_iohprofiler_round_trip(run, tmp_path):
    out = tmp_path / "ioh"
    res = export_run(run, "iohprofiler", out)
    rows = load_results(run)
    ok = rows[rows["error"] == ""].set_index(["planner", "mode", "seed"])
    assert res["runs"] == len(ok) == 10 and res["skipped"] == {"failed": 2}
    assert res["problems"] == 3 and res["algorithms"] == 2
    runs = read_iohprofiler(out)
    assert len(runs) == len(ok)
    assert set(runs["maximization"]) == {"F"} and set(runs["suite"]) == {"fixbench"}
    assert set(runs["DIM"]) == {2} and runs["funcId"].nunique() == 3
    assert all(f == function_id(n) for f, n in zip(runs["funcId"], runs["funcName"]))  # stable ids
    assert set(runs["reference_proven"]) == {"T"}, "fan_small's references are exact's proven optima"
    assert all("reference_objective_m=" in c for c in runs["comment"])
    traces = load_traces(run)
    for r in runs.itertuples():
        row = ok.loc[(r.algId, r.mode, r.seed)]
        curve = np.array(r.curve)
        evals, best = curve[:, 0], curve[:, 1]
        assert (np.diff(evals) > 0).all(), "evaluations strictly increase"
        assert (np.diff(best) <= 0).all() and (np.diff(best[:-1]) < 0).all(), "one line per improvement"
        assert evals[-1] == r.evaluations == row["samples"] and best[-1] == r.best
        assert r.reference_objective_m == row["reference_objective_m"]
        assert r.funcName.endswith(r.mode + ("-k2" if r.mode == "held-out" else ""))
        if r.algId == "random" or r.mode == "held-out":  # best layouts returned, or no curve at all
            assert r.best == pytest.approx(row["objective_m"], rel=1e-12)
        else:  # a learner's policy: its curve ends at the best layouts seen in training
            assert r.best <= row["objective_m"] * (1 + 1e-12)
            per_task = traces[traces["cell"] == row["cell"]].groupby("task")["best"].min()
            assert r.best == pytest.approx(per_task.mean(), rel=1e-12)
        if r.mode == "held-out":
            assert len(curve) == 1
        else:
            assert len(curve) >= 2, "this run improves after its first batch"
    # the files themselves: one block per run, IOHexperimenter's header line
    for dat in out.rglob("*.dat"):
        lines = dat.read_text().splitlines()
        assert lines[0] == DAT_HEADER
    assert (out / MARKER).is_file()
    assert not list(out.rglob("*.json")) and not list(out.rglob("*.csv")), "IOHanalyzer would read them"


def test_cell_curve_per_mode():
    """Equal effort per task, the shared rows as they are, one line for held-out cells."""
    row = pd.Series({"mode": "per-task", "samples": 9, "n_tasks": 2, "objective_m": 2.5}).to_frame().T
    r = next(row.itertuples(index=False))
    trace = pd.DataFrame({"task": [0, 0, 0, 1, 1], "task_samples": [1, 2, 4, 2, 5],
                          "samples": [1, 2, 4, 6, 9], "best": [4.0, 3.0, 2.0, 5.0, 3.0]})
    # k = 1: task 1 not started; k = 2: (3 + 5) / 2 after 2 + 2; k = 4: (2 + 5) / 2 after 4 + 4;
    # k = 5: (2 + 3) / 2 after 4 + 5
    assert cell_curve(r, trace) == [(4, 4.0), (8, 3.5), (9, 2.5)]
    shared = r._replace(mode="shared", objective_m=3.0)
    tr = pd.DataFrame({"task": [0, 1, -1, 0, 1, -1], "task_samples": [1, 1, 2, 2, 2, 4],
                       "samples": [1, 2, 2, 3, 4, 4], "best": [1.0, 3.0, 3.0, 1.0, 3.0, 3.0]})
    assert cell_curve(shared, tr) == [(2, 3.0), (9, 3.0)]
    assert cell_curve(r._replace(mode="held-out", objective_m=7.0), trace) == [(9, 7.0)]
    # a task never evaluated: no mean over all tasks exists, the row's objective at the end
    assert cell_curve(r, trace[trace["task"] == 0]) == [(9, 2.5)]


def test_marl_eval_layout(run, tmp_path):
    out = tmp_path / "marl"
    res = export_run(run, "marl-eval", out)
    data = strict_json_loads((out / "marl_eval.json").read_text())
    rows = load_results(run)
    ok = rows[rows["error"] == ""]
    assert list(data) == ["fan_small"] and res["runs"] == len(ok)
    tasks = data["fan_small"]
    assert set(tasks) == {"aluminium-a2-t2-per-task", "aluminium-a2-t2-shared", "aluminium-a2-t2-held-out-k2"}
    assert set(tasks["aluminium-a2-t2-shared"]) == {"random"}, "failed cells are left out"
    n = 0
    for task, algs in tasks.items():
        for alg, seeds in algs.items():
            assert set(seeds) == {"seed_0", "seed_1"}
            for seed, entries in seeds.items():
                n += 1
                mode = next(m for m in ("per-task", "shared", "held-out") if m in task)
                row = ok[(ok["planner"] == alg) & (ok["seed"] == int(seed[5:])) & (ok["mode"] == mode)]
                assert len(row) == 1
                row = row.iloc[0]
                assert list(entries)[-1] == "absolute_metrics"
                absolute = entries["absolute_metrics"]
                assert absolute["objective_m"] == [row["objective_m"]]
                assert absolute["relative_regret"] == [pytest.approx(row["relative_regret"], rel=1e-12)]
                assert absolute["mean_max_deformation_m"] == [row["mean_max_deformation_m"]]
                steps = [k for k in entries if k.startswith("step_")]
                if alg == "random":
                    assert steps == []
                    continue
                assert steps == [f"step_{k}" for k in range(EPISODES)]
                counts = [entries[s]["step_count"] for s in steps]
                assert counts[-1] == row["samples"] and np.all(np.diff(counts) > 0)
                curves = load_curves(run)
                ret = curves[(curves["cell"] == row["cell"]) & (curves["curve"] == "episode_return")]
                assert [entries[s]["episode_return"][0] for s in steps] == ret.sort_values("index")["value"].tolist()
    assert n == len(ok)


def test_marl_eval_nan_is_null(run):
    rows = load_run(run)
    rows = rows[rows["error"] == ""].reset_index(drop=True)
    rows.loc[0, "relative_regret"] = math.nan
    data, _ = marl_eval_data(rows, pd.DataFrame())
    text = strict_json(data)
    assert "NaN" not in text
    r = rows.iloc[0]
    task = "aluminium-a2-t2-" + r["mode"] + ("-k2" if r["mode"] == "held-out" else "")
    entry = strict_json_loads(text)["fan_small"][task][r["algorithm"]][f"seed_{r['seed']}"]
    assert entry["absolute_metrics"]["relative_regret"] == [None]


def test_marl_eval_pipeline_reads_it(run, tmp_path):
    """marl-eval's own loader, where it is installed (it is not a dependency of fixbench)."""
    marl = pytest.importorskip("marl_eval.utils.data_processing_utils")
    export_run(run, "marl-eval", tmp_path / "m")
    raw = json.loads((tmp_path / "m" / "marl_eval.json").read_text())
    processed = marl.data_process_pipeline(raw_data=copy.deepcopy(raw), metrics_to_normalize=[])
    assert "extra" in processed, "the pipeline rejected the file"
    run0 = processed["fan_small"]["aluminium-a2-t2-per-task"]["iql"]["seed_0"]
    assert run0["absolute_metrics"]["mean_objective_m"] == raw["fan_small"]["aluminium-a2-t2-per-task"][
        "iql"]["seed_0"]["absolute_metrics"]["objective_m"][0]


def test_csv(run, tmp_path):
    out = tmp_path / "csv"
    res = export_run(run, "csv", out)
    rows, traces = load_results(run), load_traces(run)
    back = pd.read_csv(out / "rows.csv")
    assert list(back.columns) == list(ROW_SCHEMA) and len(back) == len(rows) == res["rows"] == 12
    merged = back.set_index("cell").loc[rows["cell"]]
    assert np.allclose(merged["objective_m"].to_numpy(dtype=float), rows["objective_m"].to_numpy(dtype=float),
                       rtol=1e-15, equal_nan=True)
    assert (merged["samples"].fillna(-1).to_numpy() == rows["samples"].fillna(-1).to_numpy()).all()
    for col in ("config", "per_task_m", "layouts", "provenance"):  # JSON values as their JSON text
        values = [v for v in rows[col] if isinstance(v, (list, dict))]
        assert values and [json.loads(v) for v in merged[col] if isinstance(v, str)] == values, col
    tr = pd.read_csv(out / "traces.csv")
    assert list(tr.columns) == ["cell", "task", "task_samples", "samples", "best"] and len(tr) == len(traces)
    assert tr["samples"].dtype.kind == "i"
    assert set(pd.read_csv(out / "curves.csv")["curve"]) >= {"episode_return"}


def test_same_run_same_files(run, tmp_path):
    for name in ("a", "b"):
        export_run(run, "iohprofiler", tmp_path / name)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*")
                                     if p.is_file())
    for f in files:
        if f.name != MARKER:
            assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_cli_and_bad_input(run, tmp_path, capsys):
    out = tmp_path / "e"
    assert main(["export", str(run), "--format", "csv", "--out", str(out)]) == 0
    assert "12 rows" in capsys.readouterr().out
    assert main(["export", str(run), "--format", "iohprofiler", "--out", str(out)]) == 0, "replaces an export"
    capsys.readouterr()
    assert (out / MARKER).is_file() and not (out / "rows.csv").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "no temporary folder left"

    def fails(*argv, needle):
        assert main(["export", *argv]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err and needle in err, err

    fails(str(tmp_path), "--format", "csv", "--out", str(tmp_path / "x"), needle="not a run directory")
    fails(str(run), "--format", "xls", "--out", str(tmp_path / "x"), needle="--format")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    fails(str(run), "--format", "csv", "--out", str(mine), needle="not an earlier fixbench export")
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    (tmp_path / "empty" / "rows").mkdir(parents=True)
    fails(str(tmp_path / "empty"), "--format", "csv", "--out", str(tmp_path / "x"), needle="no finished cell")
    assert not (tmp_path / "x").exists()
