"""Tuning parity (bench/tune.py): the same declared number of trials for every planner, on the
*_small cases only, the defaults as the first trial, a matrix entry as the result."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fixbench.bench.cli import main
from fixbench.bench.running.matrix import load_matrix
from fixbench.bench.tune import matrix_entry, space, tune, tuning_table
from fixbench.solvers import available


@pytest.mark.parametrize("name", sorted(available()))
def test_every_declared_search_space_is_well_formed(name):
    spec = space(available()[name])
    assert all(v[0] in ("int", "float", "log", "choice") for v in spec.values())


def test_tuning_starts_from_the_defaults_and_never_ends_worse(tmp_path):
    result = tune("rules", 4, cases=("wing_panel_small",), seeds=(0,), echo=lambda m: None)
    assert len(result["trials"]) == 4 and result["trials"][0]["config"] == {"load_weight": 0.25}
    assert result["tuned"] <= result["default"] == result["trials"][0]["objective"]
    assert set(result["config"]) <= {"load_weight"}
    entry = matrix_entry(result)
    m = tmp_path / "m.toml"
    m.write_text('name = "t"\ncases = ["wing_panel_small"]\nseeds = [0]\nbudget = 10\n' + entry)
    cells = load_matrix(m).cells()
    assert [c.label for c in cells] == ["rules (tuned)"] and dict(cells[0].config) == result["config"]


def test_the_held_out_track_is_tuned_on_the_positions_never_sampled(tmp_path):
    """--track held-out: each trial trains on every 2nd position of the tuning case and is scored on the
    others alone; the entry runs in the held-out track only, and says so."""
    import math

    import numpy as np

    from fixbench.bench.tune import _tuning_problem
    from fixbench.solvers import get

    result = tune("rules", 2, cases=("wing_panel_small",), seeds=(0,), echo=lambda m: None, track="held-out",
                  heldout_every=2)
    p, optima = _tuning_problem("wing_panel_small")
    res = get("rules")().solve(p, 100 * 2, seed=0, train_tasks=[0, 2])
    held = [t for t in range(p.n_tasks) if t % 2]
    assert list(res.held_out) == held
    assert result["default"] == math.log1p(max(res.objective / np.mean(optima[held]) - 1, 0.0))
    entry = matrix_entry(result)
    assert 'label = "rules (tuned held-out)"' in entry and 'mode = ["held-out"]' in entry
    assert "# track held-out: tuned on the held-out split (k = 2: trained on positions 0, k, 2k, ..." in entry
    m = tmp_path / "m.toml"
    m.write_text('name = "t"\ncases = ["wing_panel_small"]\nseeds = [0]\nsamples_per_task = [10]\n'
                 'mode = ["per-task", "held-out"]\nheldout_every = 2\n[[planners]]\nname = "random"\n' + entry)
    cells = load_matrix(m).cells()
    assert sorted((c.label, c.mode) for c in cells) == [("", "held-out"), ("", "per-task"),
                                                        ("rules (tuned held-out)", "held-out")]


def test_an_entry_restricted_to_a_mode_the_matrix_lacks_is_refused(tmp_path, capsys):
    m = tmp_path / "m.toml"
    m.write_text('name = "t"\ncases = ["wing_panel_small"]\nseeds = [0]\nbudget = 10\n'
                 '[[planners]]\nname = "random"\nmode = ["held-out"]\n')
    assert main(["run", str(m), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "planners[0].mode" in err and "not one of the matrix's modes" in err
    assert not (tmp_path / "out").exists()


def test_a_reported_problem_is_refused_in_one_line(capsys):
    assert main(["tune", "rules", "--trials", "2", "--cases", "wing_panel"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not a *_small tuning case" in err


TUNED = sorted((Path(__file__).resolve().parents[1] / "results" / "tune").glob("*.toml"))
#: the entries tuned for the held-out track (`fixbench tune PLANNER --track held-out`)
HELD = sorted((Path(__file__).resolve().parents[1] / "results" / "tune" / "held-out").glob("*.toml"))


@pytest.mark.parametrize("path", TUNED + HELD, ids=[f"{p.parent.name}/{p.stem}" for p in TUNED + HELD])
def test_committed_tuned_entries_are_valid_and_within_their_search_space(path, tmp_path):
    """Each results/tune/PLANNER.toml (`fixbench tune PLANNER --out`) loads as a matrix entry labelled
    "PLANNER (tuned)" (in held-out/: "PLANNER (tuned held-out)", held-out cells only), changes only
    declared tunable fields, each inside its declared range or choices, and says it ended no worse than
    the defaults on the tuning problems (its first trial)."""
    held = path.parent.name == "held-out"
    text = path.read_text(encoding="utf-8")
    m = re.match(r"# (\S+): tuned with (\d+) trials on (.+?) \(.*defaults ([\d.]+), tuned ([\d.]+)\n", text)
    assert m and m[1] == path.stem and int(m[2]) == 20, text.splitlines()[0]
    assert all(c.endswith("_small") for c in m[3].split(", ")) and float(m[5]) <= float(m[4])
    matrix = tmp_path / "m.toml"
    modes = 'mode = ["per-task", "held-out"]\nheldout_every = 2\n'
    matrix.write_text('name = "t"\ncases = ["fan_small"]\nseeds = [0]\nbudget = 10\n' + modes + text)
    cells = load_matrix(matrix).cells()
    assert [c.mode for c in cells] == (["held-out"] if held else ["per-task", "held-out"])
    cell = cells[0]
    assert cell.planner == path.stem and cell.label == f"{path.stem} (tuned{' held-out' if held else ''})"
    declared = space(available()[path.stem])
    for key, value in dict(cell.config).items():
        kind, *bounds = declared[key]
        assert value in bounds[0] if kind == "choice" else bounds[0] <= value <= bounds[1], (key, value)


@pytest.mark.parametrize("entries", [TUNED, HELD], ids=["per-task", "held-out"])
def test_the_tuning_table_is_made_from_the_committed_entries(entries):
    """results/tune/table.md and results/tune/held-out/table.md (which docs/results.md#tuning mirrors,
    test_committed_results) are `fixbench tune-table FOLDER` of the committed entries, one line per planner."""
    if not entries:
        pytest.skip("no entry tuned for this track is committed")
    folder = entries[0].parent
    table = (folder / "table.md").read_text(encoding="utf-8")
    assert table == tuning_table(folder)
    assert [line.split("`")[1] for line in table.splitlines()[2:]] == [p.stem for p in entries]


def test_tune_table_writes_refreshes_and_refuses_a_broken_entry(tmp_path, capsys):
    folder = tmp_path / "tune"
    folder.mkdir()
    (folder / "pso.toml").write_text(TUNED[0].parent.joinpath("pso.toml").read_text(encoding="utf-8"))
    doc = tmp_path / "doc.md"
    doc.write_text("# t\n<!-- table: tune/table.md -->\nstale\n<!-- /table -->\n")
    assert main(["tune-table", str(folder), "--readme", str(doc)]) == 0
    table = (folder / "table.md").read_text(encoding="utf-8")
    assert "| `pso` | both (tuned per-task) | 20 | 0.5516 (74 %) | 0.1436 (15 %) | c1 = 2.73," in table
    assert doc.read_text() == "# t\n<!-- table: tune/table.md -->\n" + table + "<!-- /table -->\n"
    capsys.readouterr()
    (folder / "odd.toml").write_text("[[planners]]\nname = 'odd'\n")
    assert main(["tune-table", str(folder)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "odd.toml" in err and "tuned with N trials" in err
    assert (folder / "table.md").read_text(encoding="utf-8") == table  # nothing already written lost


def test_defaults_that_cannot_run_on_a_tuning_case_are_refused_naming_it(capsys):
    """qp's compliance read alone costs more than one sample a position: nothing to tune against."""
    assert main(["tune", "qp", "--trials", "2", "--cases", "wing_panel_small", "--samples-per-task", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("fixbench: wing_panel_small: qp's defaults cannot run") and "budget too small" in err
