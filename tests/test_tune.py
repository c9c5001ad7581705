"""Tuning parity (bench/tune.py): the same declared number of trials for every planner, on the
*_small cases only, the defaults as the first trial, a matrix entry as the result."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from fixbench.bench.cli import main
from fixbench.bench.running.matrix import load_matrix
from fixbench.bench.tune import matrix_entry, read_entry, space, tune, tuning_table
from fixbench.solvers import available


@pytest.mark.parametrize("name", sorted(available()))
def test_every_declared_search_space_is_well_formed(name):
    spec = space(available()[name])
    assert all(v[0] in ("int", "float", "log", "choice") for v in spec.values())


def test_tuning_starts_from_the_defaults_and_never_ends_worse(tmp_path):
    result = tune("rules", 4, cases=("fan_small",), seeds=(0,), echo=lambda m: None)
    assert len(result["trials"]) == 4 and result["trials"][0]["config"] == {"load_weight": 0.25}
    assert result["tuned"] <= result["default"] == result["trials"][0]["objective"]
    assert set(result["config"]) <= {"load_weight"}
    entry = matrix_entry(result)
    assert tomllib.loads(entry)["planners"][0]["tuning"] == {
        "track": "per-task", "trials": 4, "cases": ["fan_small"], "seeds": [0], "samples_per_task": 100,
        "objective_default": result["default"], "objective_tuned": result["tuned"]}  # full precision
    m = tmp_path / "m.toml"
    m.write_text('name = "t"\ncases = ["fan_small"]\nseeds = [0]\nbudget = 10\n' + entry)
    cells = load_matrix(m).cells()
    assert [c.label for c in cells] == ["rules (tuned)"] and dict(cells[0].config) == result["config"]
    back = read_entry(m)
    assert (back["planner"], back["trials"], back["default"], back["tuned"], back["config"], back["track"]) == (
        "rules", 4, result["default"], result["tuned"], result["config"], "per-task")


def test_the_held_out_track_is_tuned_on_the_positions_never_sampled(tmp_path):
    """--track held-out: each trial trains on every 2nd position of the tuning case and is scored on the
    others alone; the entry runs in the held-out track only, and says so."""
    import math

    import numpy as np

    from fixbench.bench.tune import _tuning_problem
    from fixbench.solvers import get

    result = tune("rules", 2, cases=("fan_small",), seeds=(0,), echo=lambda m: None, track="held-out",
                  heldout_every=2)
    p, optima = _tuning_problem("fan_small")
    train = list(range(0, p.n_tasks, 2))
    res = get("rules")().solve(p, 100 * len(train), seed=0, train_tasks=train)
    held = [t for t in range(p.n_tasks) if t % 2]
    assert list(res.held_out) == held
    assert result["default"] == math.log1p(max(res.objective / np.mean(optima[held]) - 1, 0.0))
    entry = matrix_entry(result)
    written = tomllib.loads(entry)["planners"][0]
    assert written["label"] == "rules (tuned held-out)" and written["mode"] == ["held-out"]
    assert written["tuning"] == {"track": "held-out", "heldout_every": 2, "trials": 2, "cases": ["fan_small"],
                                 "seeds": [0], "samples_per_task": 100, "objective_default": result["default"],
                                 "objective_tuned": result["tuned"]}
    m = tmp_path / "m.toml"
    m.write_text('name = "t"\ncases = ["fan_small"]\nseeds = [0]\nsamples_per_task = [10]\n'
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
    entry = read_entry(path)
    tuning = entry["tuning"]
    assert entry["planner"] == path.stem and tuning["trials"] == 20, tuning
    assert tuning["track"] == ("held-out" if held else "per-task")
    assert tuning.get("heldout_every") == (2 if held else None)
    assert tuning["seeds"] == [0] and tuning["samples_per_task"] == 100
    assert all(c.endswith("_small") for c in tuning["cases"])
    assert tuning["objective_tuned"] <= tuning["objective_default"]
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
    assert "\n" not in err and "odd.toml: planners[0].tuning: missing" in err and "fixbench tune PLANNER --out" in err
    assert (folder / "table.md").read_text(encoding="utf-8") == table  # nothing already written lost


PSO = Path(__file__).resolve().parents[1] / "results" / "tune" / "pso.toml"
GOOD = ('tuning = { track = "per-task", trials = 20, cases = ["fan_small"], seeds = [0], samples_per_task = 100, '
        'objective_default = 0.5, objective_tuned = 0.25 }')


@pytest.mark.parametrize(("tuning", "key", "problem"), [
    (None, "planners[0].tuning", "missing"),
    ('tuning = "20 trials"', "planners[0].tuning", "must be a table"),
    (GOOD.replace("trials = 20", 'trials = "20"'), "planners[0].tuning.trials", "must be a whole number"),
    (GOOD.replace("trials = 20, ", ""), "planners[0].tuning.trials", "missing"),
    (GOOD.replace('cases = ["fan_small"]', "cases = []"), "planners[0].tuning.cases", "non-empty list"),
    (GOOD.replace("0.25", "nan"), "planners[0].tuning.objective_tuned", "must be finite"),
    (GOOD.replace('"per-task"', '"shared"'), "planners[0].tuning.track", "must be one of per-task, held-out"),
    (GOOD.replace('"per-task"', '"held-out"'), "planners[0].tuning.heldout_every", 'needed by track "held-out"'),
    (GOOD.replace(" }", ", wall_s = 3 }"), "planners[0].tuning.wall_s", "unknown key"),
])
def test_an_entry_without_its_tuning_table_or_with_a_malformed_one_is_refused_in_one_line(
        tuning, key, problem, tmp_path, capsys):
    """`fixbench tune-table` reads the figures from the entry's `tuning` table (never from a comment):
    one missing or malformed is refused in one line naming the file and the key; the matrix loader
    checks the same table (a matrix that carries the entry is refused the same way)."""
    folder = tmp_path / "tune"
    folder.mkdir()
    entry = ('# pso: tuned with 20 trials ...; defaults 0.5, tuned 0.25\n'  # a comment is never read
             '[[planners]]\nname = "pso"\nlabel = "pso (tuned)"\n')
    (folder / "pso.toml").write_text(entry + (tuning + "\n" if tuning else ""))
    assert main(["tune-table", str(folder)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"pso.toml: {key}: " in err and problem in err, err
    assert not (folder / "table.md").exists()
    if tuning is None:
        return  # a matrix entry needs no tuning table
    matrix = tmp_path / "m.toml"
    matrix.write_text('name = "t"\ncases = ["fan_small"]\nseeds = [0]\nbudget = 10\n' + entry + tuning + "\n")
    assert main(["run", str(matrix), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"m.toml: {key}: " in err and problem in err, err
    assert not (tmp_path / "out").exists()


def test_the_tuning_table_is_provenance_not_a_setting(tmp_path):
    """A tuned entry's `tuning` table changes no cell: the same entry without it gives the same cells
    (config, label, id), whatever its figures say."""
    text = PSO.read_text(encoding="utf-8")
    bare = "\n".join(line for line in text.splitlines() if not line.startswith("tuning = ")) + "\n"
    head = ('name = "t"\ncases = ["fan_small"]\nseeds = [0, 1]\nbudget = 10\nmode = ["per-task", "held-out"]\n'
            'heldout_every = 2\n')
    cells = {}
    for name, entry in (("with", text), ("without", bare), ("other", text.replace("trials = 20", "trials = 3"))):
        (tmp_path / f"{name}.toml").write_text(head + entry)
        cells[name] = [(c.id, c.config, c.label) for c in load_matrix(tmp_path / f"{name}.toml").cells()]
    assert bare != text and cells["with"] == cells["without"] == cells["other"] and len(cells["with"]) == 4


def test_defaults_that_cannot_run_on_a_tuning_case_are_refused_naming_it(capsys):
    """qp's compliance read alone costs more than one sample a position: nothing to tune against."""
    assert main(["tune", "qp", "--trials", "2", "--cases", "fan_small", "--samples-per-task", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("fixbench: fan_small: qp's defaults cannot run") and "budget too small" in err
