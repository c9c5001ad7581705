"""A damaged shipped reference is said, not hidden: it stops `fixbench run` before any cell, and
`fixbench report` / `verify` refuse rows scored against a reference other than the one shipped.

The shipped references are copied to a temporary folder (the catalog is never touched) and one value
of the wing panel's is halved by hand, as a user's edit would."""

from __future__ import annotations

import json
import math
import shutil

import pytest

import fixbench.cases.references as refs
from fixbench.bench.cli import main
from fixbench.bench.records.rows import ROW_SCHEMA
from fixbench.bench.records.store import Store
from fixbench.cases.errors import CaseError

FILE = "wing_panel__aluminium__a5.json"


@pytest.fixture
def catalog(tmp_path, monkeypatch):
    """A copy of the shipped references in use in place of the catalog's; returns its folder."""
    folder = tmp_path / "references"
    shutil.copytree(refs.REFERENCE_DIR, folder)
    monkeypatch.setattr(refs, "REFERENCE_DIR", folder)
    return folder


def _halve_one_value(folder) -> None:
    path = folder / FILE
    ref = json.loads(path.read_text())
    ref["tasks"][7]["max_deformation_m"] /= 2
    path.write_text(json.dumps(ref))


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_a_damaged_reference_stops_the_run_before_any_cell(catalog, tmp_path, capsys):
    matrix = tmp_path / "one.toml"
    matrix.write_text('cases = ["wing_panel"]\nmaterials = ["aluminium"]\nplanners = ["rules"]\nseeds = [0]\n'
                      "budget = 100\ntasks = 2\n")
    _halve_one_value(catalog)
    assert main(["run", str(matrix), "--out", str(tmp_path / "run")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert str(catalog / FILE) in line and "content_hash: does not match the tasks" in line
    assert not list((tmp_path / "run").rglob("*.json"))  # no row, no reference snapshot
    assert not (tmp_path / "run" / "matrix.toml").exists()


def _scored_run(root, source: str):
    """A run directory of one fake row scored against ``source``."""
    row = {k: math.nan for k in ROW_SCHEMA}
    row.update(cell="c0", planner="random", config={}, case="wing_panel", material="aluminium",
               agents=5, mode="per-task", seed=0, n_tasks=2, error="", objective_m=2e-5, relative_regret=0.5,
               reference_objective_m=1.33e-5, reference_source=source)
    Store(root).write(row, None, None)
    (root / "matrix.toml").write_text("")
    return root


@pytest.mark.parametrize("command", ["report", "verify"])
def test_rows_scored_against_another_reference_are_refused(catalog, tmp_path, capsys, monkeypatch, command):
    monkeypatch.setattr("os.getloadavg", lambda: (64.0, 64.0, 64.0))  # a busy machine: still one line
    shipped = json.loads((catalog / FILE).read_text())["content_hash"]
    run = _scored_run(tmp_path / "run", f"catalog reference {FILE} (content {'0' * 16})")
    assert main([command, str(run)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"{run}: reference_source: 1 rows were scored against {FILE} of content {'0' * 16}" in line
    assert f"the shipped one is {shipped}" in line and "fixbench references rescore" in line

    good = _scored_run(tmp_path / "good", f"catalog reference {FILE} (content {shipped})")
    refs.check_sources(["exact", "", math.nan, f"catalog reference {FILE} (content {shipped})"], str(good))
    _halve_one_value(catalog)  # the rows' hash is the file's own, but the file no longer matches it
    assert main([command, str(good)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert str(catalog / FILE) in line and "content_hash" in line


def test_a_source_without_hash_or_file_is_refused(catalog):
    with pytest.raises(CaseError, match="without a content hash"):
        refs.check_sources([f"catalog reference {FILE}"], "run")
    with pytest.raises(CaseError, match="no longer shipped"):
        refs.check_sources(["catalog reference gone__aluminium__a5.json (content 0123456789abcdef)"], "run")


def test_the_source_a_row_records_is_read_back(catalog):
    ref = refs.load_reference("wing_panel", "aluminium", 5)
    m = refs.SOURCE.fullmatch(refs.source_text(ref))
    assert (m["file"], m["hash"]) == (FILE, ref["content_hash"])
