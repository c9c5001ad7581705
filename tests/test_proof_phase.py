"""The reference ("proof") phase of ``fixbench run``: visible, kept in the run directory, resumable."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fixbench.bench.cli import main
from fixbench.bench.references import prove as proof_module
from fixbench.bench.references.prove import compute_reference
from fixbench.bench.running.matrix import load_matrix
from fixbench.bench.running.runner import run_matrix

POSITIONS = 6
ADD = proof_module.Proof.add  # before any test wraps it
MATRIX = """
name = "proof"
cases = ["plate.toml"]
planners = ["random"]
seeds = [0]
budget = 12
mode = ["per-task", "shared"]
"""


@pytest.fixture
def matrix(tmp_path, plate_toml):
    """A matrix on the test plate (a case file: no shipped reference) with POSITIONS positions."""
    plate_toml(("count = 3", f"count = {POSITIONS}"))
    path = tmp_path / "m.toml"
    path.write_text(MATRIX)
    return path


def _records(out: Path) -> list[dict]:
    (path,) = (out / "reference").glob("*.proof.jsonl")
    return [json.loads(line) for line in path.read_text().splitlines()]


def _reference(out: Path) -> dict:
    (path,) = (out / "reference").glob("*__tall.json")
    return json.loads(path.read_text())


def _without_times(ref: dict) -> dict:
    return {k: v for k, v in ref.items() if k != "wall_s"}


class _Counted:
    """Counts the positions the driver records (Proof.add); ``stop_after``: a kill after that many."""

    def __init__(self, monkeypatch, stop_after: int | None = None):
        self.positions, self.stop_after = [], stop_after

        def counted(proof, record):
            if self.stop_after is not None and len(self.positions) == self.stop_after:
                raise KeyboardInterrupt  # the run is killed here: the positions so far are on disk
            self.positions.append(record["position"])
            ADD(proof, record)

        monkeypatch.setattr(proof_module.Proof, "add", counted)


def test_every_proven_position_is_recorded_in_the_run_directory(matrix, tmp_path, capsys):
    out = tmp_path / "run"
    run_matrix(matrix, out, workers=1, progress=False, plain_every=1e-9)
    header, *recs = _records(out)
    ref = _reference(out)
    assert header["n_tasks"] == POSITIONS and header["joint_size"] == 9 and header["method"] == "enumeration"
    assert {r["position"] for r in recs} == {*range(POSITIONS), "shared"}
    by_position = {r["position"]: r for r in recs}
    assert ref["per_task"] == [by_position[t]["max_deformation_m"] for t in range(POSITIONS)]
    assert ref["layouts"] == [by_position[t]["layout"] for t in range(POSITIONS)]
    assert ref["proven"] and ref["shared"] == by_position["shared"]["objective_m"]
    assert ref["samples"] == 9 * POSITIONS and ref["proof_records"].endswith(".proof.jsonl")
    proof_lines = [x for x in capsys.readouterr().err.splitlines() if "proof" in x]
    assert proof_lines and all("positions" in x and "layouts" in x and "ETA" in x for x in proof_lines)
    assert f"proof 1/{POSITIONS} positions" in proof_lines[0]


def test_on_a_terminal_the_phase_is_a_bar_of_layouts_with_its_time_left(matrix, tmp_path, capsys):
    run_matrix(matrix, tmp_path / "run", workers=1, progress=True)
    bar = [x for x in capsys.readouterr().err.replace("\r", "\n").splitlines() if x.startswith("proof:")]
    assert any(f"1/{POSITIONS} positions" in x for x in bar)
    last = bar[-1]  # layouts: 9 a position, 9 x 6 more for the shared optimum
    assert f"{2 * 9 * POSITIONS}/{2 * 9 * POSITIONS}" in last and "layout/s" in last
    assert f"{POSITIONS}/{POSITIONS} positions" in last and "<00:00" in last


def test_the_phase_gives_what_one_exact_job_gives(matrix, tmp_path):
    """Position by position, the reference is the one ``exact`` gives on the whole problem at once."""
    out = tmp_path / "run"
    run_matrix(matrix, out, workers=1, progress=False)
    ref = _reference(out)
    whole = compute_reference(ref["case"], None, None, None, ("per-task", "shared"))
    for key in ("per_task", "layouts", "shared", "proven", "gap", "samples", "source", "method", "case_fingerprint"):
        assert ref[key] == whole[key], key


def _killed(matrix, out, monkeypatch, stop_after: int) -> Path:
    """Run the matrix into ``out`` until a kill after ``stop_after`` proven positions (KeyboardInterrupt in
    the proof phase); returns its proof records' file."""
    _Counted(monkeypatch, stop_after=stop_after)
    with pytest.raises(KeyboardInterrupt):
        run_matrix(matrix, out, workers=1, progress=False)
    (path,) = (out / "reference").glob("*.proof.jsonl")
    return path


def test_a_killed_proof_resumes_without_proving_a_position_again(matrix, tmp_path, monkeypatch):
    whole = tmp_path / "whole"
    run_matrix(matrix, whole, workers=1, progress=False)
    out = tmp_path / "run"
    _killed(matrix, out, monkeypatch, stop_after=2)
    assert not (out / "rows").exists() or not any((out / "rows").glob("*.json"))
    kept = [r["position"] for r in _records(out)[1:]]
    assert len(kept) == 2
    rerun = _Counted(monkeypatch)
    assert run_matrix(matrix, out, workers=1, progress=False)["run"] == 2
    assert sorted(rerun.positions, key=str) == sorted(set(range(POSITIONS)) - set(kept) | {"shared"}, key=str)
    assert _without_times(_reference(out)) == _without_times(_reference(whole))
    again = _Counted(monkeypatch)  # a finished reference is read, never proven again
    run_matrix(matrix, out, workers=1, progress=False)
    assert again.positions == []


def test_a_record_cut_short_by_a_kill_is_proven_again(matrix, tmp_path, monkeypatch):
    whole = tmp_path / "whole"
    run_matrix(matrix, whole, workers=1, progress=False)
    out = tmp_path / "run"
    path = _killed(matrix, out, monkeypatch, stop_after=3)
    lines = path.read_text().splitlines()
    cut = json.loads(lines[-1])["position"]
    path.write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:25])  # the last record half written
    rerun = _Counted(monkeypatch)
    run_matrix(matrix, out, workers=1, progress=False)
    assert cut in rerun.positions and len(rerun.positions) == POSITIONS + 1 - 2
    assert all(json.loads(line) for line in path.read_text().splitlines())  # the file is whole again
    assert _without_times(_reference(out)) == _without_times(_reference(whole))


def test_records_of_another_case_definition_are_not_used(matrix, tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    path = _killed(matrix, out, monkeypatch, stop_after=3)
    header, *rest = path.read_text().splitlines()
    path.write_text("\n".join([json.dumps({**json.loads(header), "case_fingerprint": "0"}), *rest]) + "\n")
    rerun = _Counted(monkeypatch)
    run_matrix(matrix, out, workers=1, progress=False)
    assert len(rerun.positions) == POSITIONS + 1
    assert "records of another case definition" in capsys.readouterr().err


def test_proof_limit_skips_the_proof(matrix, tmp_path, monkeypatch):
    matrix.write_text(MATRIX + "proof_limit = 8\n")  # the plate has 9 layouts a position
    out = tmp_path / "run"
    counted = _Counted(monkeypatch)
    run_matrix(matrix, out, workers=1, progress=False)
    ref = _reference(out)
    assert counted.positions == [] and not list((out / "reference").glob("*.proof.jsonl"))
    assert ref["per_task"] is None and "over the matrix's proof_limit" in ref["error"]
    assert "no shipped reference" in ref["error"]
    assert load_matrix(matrix).proof_limit == 8


@pytest.mark.parametrize("value", ["-1", "1e6", '"none"', "true"])
def test_a_bad_proof_limit_is_one_line_before_any_work(matrix, tmp_path, value, capsys):
    matrix.write_text(MATRIX + f"proof_limit = {value}\n")
    assert main(["run", str(matrix), "--out", str(tmp_path / "run"), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "proof_limit" in err and str(matrix) in err, err
    assert not (tmp_path / "run").exists()
