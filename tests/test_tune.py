"""Tuning parity (bench/tune.py): the same declared number of trials for every planner, on the
*_small cases only, the defaults as the first trial, a matrix entry as the result."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fixbench.bench.cli import main
from fixbench.bench.matrix import load_matrix
from fixbench.bench.tune import matrix_entry, space, tune
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


def test_a_reported_problem_is_refused_in_one_line(capsys):
    assert main(["tune", "rules", "--trials", "2", "--cases", "wing_panel"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not a *_small tuning case" in err


TUNED = sorted((Path(__file__).resolve().parents[1] / "results" / "tune").glob("*.toml"))


@pytest.mark.parametrize("path", TUNED, ids=[p.stem for p in TUNED])
def test_committed_tuned_entries_are_valid_and_within_their_search_space(path, tmp_path):
    """Each results/tune/PLANNER.toml (`fixbench tune PLANNER --out`) loads as a matrix entry labelled
    "PLANNER (tuned)", changes only declared tunable fields, each inside its declared range or choices,
    and says it ended no worse than the defaults on the tuning problems (its first trial)."""
    text = path.read_text(encoding="utf-8")
    m = re.match(r"# (\S+): tuned with (\d+) trials on (.+?) \(.*defaults ([\d.]+), tuned ([\d.]+)\n", text)
    assert m and m[1] == path.stem and int(m[2]) == 20, text.splitlines()[0]
    assert all(c.endswith("_small") for c in m[3].split(", ")) and float(m[5]) <= float(m[4])
    matrix = tmp_path / "m.toml"
    matrix.write_text('name = "t"\ncases = ["fan_small"]\nseeds = [0]\nbudget = 10\n' + text)
    (cell,) = load_matrix(matrix).cells()
    assert cell.planner == path.stem and cell.label == f"{path.stem} (tuned)"
    declared = space(available()[path.stem])
    for key, value in dict(cell.config).items():
        kind, *bounds = declared[key]
        assert value in bounds[0] if kind == "choice" else bounds[0] <= value <= bounds[1], (key, value)


def test_the_tuning_table_quotes_the_committed_entries():
    """docs/results.md#tuning has one line per results/tune/PLANNER.toml with its two objectives."""
    docs = (Path(__file__).resolve().parents[1] / "docs" / "results.md").read_text(encoding="utf-8")
    section = docs.split("\n## Tuning\n", 1)[1].split("\n## ", 1)[0]
    line = re.compile(r"^\| `([^`]+)` \| ([\d.]+) \(.*?\) \| ([\d.]+) \(", re.M)
    quoted = {m[1]: (m[2], m[3]) for m in line.finditer(section)}
    committed = {}
    for path in TUNED:
        m = re.search(r"defaults ([\d.]+), tuned ([\d.]+)", path.read_text(encoding="utf-8"))
        committed[path.stem] = (m[1], m[2])
    assert quoted == committed
