"""The two tracks of the comparison in matrices: the budget sweep and held-out tasks (tiny case).

Matrix keys and their expansion, the refusals (one line naming the key), and a tiny run of both
tracks end to end: budgets follow the samples per task on the tasks a planner may evaluate,
held-out cells spend nothing on the held-out tasks and are scored on them, and the report draws
the sweep and the held-out comparison.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fixbench.bench.cli import main
from fixbench.bench.records.rows import load_results
from fixbench.bench.running.matrix import load_matrix
from fixbench.bench.running.runner import run_matrix

TRACKS = """
name = "tracks"
cases = ["fan_small"]
seeds = [0, 1]
samples_per_task = [2, 6, 20]
agents = 2
tasks = 6
mode = ["per-task", "held-out"]
heldout_every = 3

[[planners]]
name = "random"
[[planners]]
name = "local"
label = "local+transfer"
config = { transfer = 2 }
[[planners]]
name = "iql"
max_samples_per_task = 6
config = { episodes = 100 }
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "m.toml"
    path.write_text(text)
    return path


def test_expansion(tmp_path):
    cells = load_matrix(write(tmp_path, TRACKS)).cells()
    # 2 modes x (3 + 3 + 2 sweep points) x 2 seeds
    assert len(cells) == 2 * 8 * 2
    assert {c.samples_per_task for c in cells if c.planner == "iql"} == {2, 6}
    held = [c for c in cells if c.mode == "held-out"]
    assert all(c.heldout_every == 3 for c in held)
    c = held[0]
    assert c.train_tasks(6) == [0, 3] and c.budget_for(6) == c.samples_per_task * 2
    per_task = [c for c in cells if c.mode == "per-task"][0]
    assert per_task.train_tasks(6) is None and per_task.budget_for(6) == per_task.samples_per_task * 6
    assert len({c.id for c in cells}) == len(cells)


def test_a_planner_entry_may_name_its_cases(tmp_path):
    """``cases`` in a planner entry keeps it to those of the matrix's cases; the other entries' cells
    and every cell id stay as they were."""
    both = TRACKS.replace('cases = ["fan_small"]', 'cases = ["fan_small", "wing_panel_small"]')
    both = both.replace("tasks = 6", "tasks = 3")
    only = both.replace('name = "random"\n', 'name = "random"\ncases = ["wing_panel_small"]\n', 1)
    assert only != both
    full, kept = load_matrix(write(tmp_path, both)).cells(), load_matrix(write(tmp_path, only)).cells()
    assert {c.case for c in kept if c.planner == "random"} == {"wing_panel_small"}
    assert {c.id for c in kept} == {c.id for c in full if c.planner != "random" or c.case == "wing_panel_small"}
    bad = only.replace('cases = ["wing_panel_small"]\n', 'cases = ["bus_panel_small"]\n')
    with pytest.raises(Exception, match="planners\\[0\\].cases.*not one of the matrix's cases"):
        load_matrix(write(tmp_path, bad))


def test_an_entry_may_be_written_once_a_track(tmp_path):
    """The same planner, config and label twice, with mode lists that do not overlap (per-task on
    fewer cases, held-out on all): together they make the cells of one entry, with the ids the single
    entry gives them."""
    both = TRACKS.replace('cases = ["fan_small"]', 'cases = ["fan_small", "wing_panel_small"]').replace("tasks = 6",
                                                                                                    "tasks = 3")
    entry = '[[planners]]\nname = "local"\nlabel = "local+transfer"\nconfig = { transfer = 2 }\n'
    assert entry in both
    split = both.replace(entry, entry + 'mode = ["per-task"]\ncases = ["fan_small"]\n'
                         + entry + 'mode = ["held-out"]\n')
    full, kept = load_matrix(write(tmp_path, both)).cells(), load_matrix(write(tmp_path, split)).cells()
    local = [c for c in kept if c.label == "local+transfer"]
    assert {(c.case, c.mode) for c in local} == {("fan_small", "per-task"), ("fan_small", "held-out"),
                                                 ("wing_panel_small", "held-out")}
    assert {c.id for c in kept} == {c.id for c in full
                                    if c.label != "local+transfer" or (c.case, c.mode) != ("wing_panel_small",
                                                                                          "per-task")}
    overlap = split.replace('mode = ["held-out"]\n', 'mode = ["held-out", "per-task"]\n')
    with pytest.raises(Exception, match="'local\\+transfer'.*in mode per-task.*do not overlap"):
        load_matrix(write(tmp_path, overlap))
    other = split.replace(entry + 'mode = ["held-out"]', entry.replace("transfer = 2", "transfer = 1")
                          + 'mode = ["held-out"]')
    with pytest.raises(Exception, match="labelled 'local\\+transfer' with different"):
        load_matrix(write(tmp_path, other))


@pytest.mark.parametrize("edit, words", [
    (("samples_per_task = [2, 6, 20]", "samples_per_task = [2, 6, 20]\nbudget = 100"), ["not both"]),
    (("samples_per_task = [2, 6, 20]", "samples_per_task = [2, -1]"), ["samples_per_task", "0 or more"]),
    (("heldout_every = 3", ""), ["heldout_every", "held-out"]),
    (("heldout_every = 3", "heldout_every = 1"), ["heldout_every"]),
    (("[[planners]]\nname = \"random\"", "[[planners]]\nname = \"random\"\n[[planners]]\nname = \"random\""),
     ["planners", "labels"]),
])
def test_bad_track_keys_are_one_line(tmp_path, capsys, edit, words):
    text = TRACKS.replace(*edit)
    assert text != TRACKS
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path, text)), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words), err
    assert not out.exists()


def test_only_runs_a_subset_and_a_plain_rerun_completes(tmp_path, capsys):
    m = write(tmp_path, TRACKS.replace("seeds = [0, 1]", "seeds = [0]").replace(
        'mode = ["per-task", "held-out"]\nheldout_every = 3', 'mode = "per-task"'))
    out = tmp_path / "out"
    assert main(["run", str(m), "--out", str(out), "--only", "nonsense"]) == 2
    assert "--only: nonsense" in capsys.readouterr().err
    first = run_matrix(m, out, workers=1, progress=False, only=("local+transfer",))
    assert first["run"] == 3
    assert set(load_results(out)["planner"]) == {"local"}
    assert main(["run", str(m), "--out", str(out), "--only", "budget=3"]) == 2
    second = run_matrix(m, out, workers=1, progress=False, only=("random", "mode=per-task", "seed=0", "seed=7"))
    assert second["run"] == 3 and set(load_results(out)["planner"]) == {"local", "random"}
    assert second["skipped"] == 3 and second["deferred"] == 2
    third = run_matrix(m, out, workers=1, progress=False)
    assert third["skipped"] == 6 and third["run"] == 2 and "deferred" not in third


def test_tracks_end_to_end(tmp_path):
    out = tmp_path / "out"
    summary = run_matrix(write(tmp_path, TRACKS), out, workers=2, progress=False)
    assert summary["failed"] == 0 and summary["run"] == 32
    rows = load_results(out)
    for _, r in rows.iterrows():
        n_train = 2 if r["mode"] == "held-out" else 6
        assert r["budget"] == r["samples_per_task"] * n_train
        assert r["samples"] <= r["budget"]
        u = np.asarray(r["per_task_m"])
        assert len(u) == 6 and r["reference_source"] == "exact"
        scored = [1, 2, 4, 5] if r["mode"] == "held-out" else list(range(6))
        assert r["n_scored_tasks"] == len(scored)
        assert r["objective_m"] == pytest.approx(u[scored].mean())
        assert np.isfinite(r["relative_regret"]) and r["relative_regret"] >= -1e-9
    held = rows[rows["mode"] == "held-out"]
    for cid in held["cell"]:  # no sample on a held-out task
        trace = pd_read(out / "traces" / f"{cid}.parquet")
        assert set(trace["task"].astype(int)) <= {0, 3}
    assert main(["report", str(out), "--no-fields"]) == 0


def pd_read(path):
    import pandas as pd

    return pd.read_parquet(path)
