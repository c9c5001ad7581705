"""The harness: malformed matrices, resume after kill -9, failing and slow cells, Ray = local."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fixbench.bench.cli import main
from fixbench.bench.records.rows import ROW_SCHEMA, load_results
from fixbench.bench.running.matrix import load_matrix
from fixbench.bench.running.runner import run_matrix

TINY = """
name = "tiny"
cases = ["fan_small"]
materials = ["aluminium", "steel"]
planners = ["random", "greedy"]
seeds = [0, 1]
budget = 120
tasks = 2
agents = 2
"""

PLANNERS_THAT_MISBEHAVE = '''
import time
from dataclasses import dataclass
from fixbench.solvers import Planner, PlannerConfig

class Boom(Planner):
    name = "boom"
    description = "raises"
    def plan(self, problem, ev, rng, mode):
        raise RuntimeError("planner exploded")

class Sleepy(Planner):
    name = "sleepy"
    description = "never finishes"
    def plan(self, problem, ev, rng, mode):
        time.sleep(600)
'''


def write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


BAD_MATRICES = [
    ("unknown key", TINY + "colour = 'red'\n", ["colour", "unknown key"]),
    ("unknown planner", TINY.replace('"greedy"', '"telepathy"'), ["planners[1].name", "unknown planner"]),
    ("unknown case", TINY.replace('"fan_small"', '"moon_base"'), ["cases", "moon_base", "unknown case"]),
    ("empty list", TINY.replace("seeds = [0, 1]", "seeds = []"), ["seeds", "is empty"]),
    ("bad budget", TINY.replace("budget = 120", "budget = -3"), ["budget", "must be positive"]),
    ("budget type", TINY.replace("budget = 120", "budget = 1.5"), ["budget"]),
    ("unknown material", TINY.replace('"steel"', '"cheese"'), ["materials", "unknown material 'cheese'"]),
    ("bad config", TINY.replace('planners = ["random", "greedy"]\n', "")
     + '[[planners]]\nname = "random"\nconfig = {bogus = 1}\n',
     ["planners[0].config", "no setting 'bogus'"]),
    ("bad mode", TINY + 'mode = "sometimes"\n', ["mode", "must be one of per-task, shared, held-out"]),
    ("not TOML", TINY + "[[[\n", ["not valid TOML"]),
    ("per_case of another case", TINY + "[per_case.wing_panel_small]\nagents = [3]\n",
     ["per_case.wing_panel_small", "not one of the matrix's cases"]),
    ("per_case material", TINY + "[per_case.fan_small]\nmaterials = [\"cheese\"]\n",
     ["per_case.fan_small.materials", "unknown material 'cheese'"]),
    ("per_case key", TINY + "[per_case.fan_small]\nseeds = [3]\n", ["per_case.fan_small.seeds", "unknown key"]),
]


@pytest.mark.parametrize("label,text,needles", BAD_MATRICES, ids=[b[0] for b in BAD_MATRICES])
def test_malformed_matrix(capsys, tmp_path, label, text, needles):
    out = tmp_path / "out"
    rc = main(["run", str(write(tmp_path, text)), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "m.toml" in err
    for needle in needles:
        assert needle in err, err
    assert not out.exists(), "nothing may be written"


def test_cells_are_deterministic(tmp_path):
    m = load_matrix(write(tmp_path, TINY))
    ids = [c.id for c in m.cells()]
    assert len(ids) == len(set(ids)) == 2 * 2 * 2
    assert ids == [c.id for c in load_matrix(write(tmp_path, TINY, "again.toml")).cells()]


def test_a_case_may_run_with_its_own_materials_and_agents(tmp_path):
    """``per_case`` replaces the matrix's materials or agents for one case; the other cases' cells,
    and their ids, are those of the matrix without it."""
    two = TINY.replace('cases = ["fan_small"]', 'cases = ["fan_small", "wing_panel_small"]')
    plain = load_matrix(write(tmp_path, two)).cells()
    own = load_matrix(write(tmp_path, two + '[per_case.wing_panel_small]\nmaterials = ["titanium"]\nagents = [3]\n',
                            "own.toml")).cells()
    assert {c.id for c in plain if c.case == "fan_small"} == {c.id for c in own if c.case == "fan_small"}
    assert {(c.material, c.agents) for c in own if c.case == "wing_panel_small"} == {("titanium", 3)}
    assert len(plain) == 16 and len(own) == 8 + 4  # wing_panel_small: one material instead of two


def test_run_resume_and_schema(tmp_path):
    out = tmp_path / "run"
    path = write(tmp_path, TINY)
    first = run_matrix(path, out, workers=1, progress=False)
    assert first == {"cells": 8, "skipped": 0, "run": 8, "failed": 0}
    df = load_results(out)
    assert len(df) == 8 and list(df.columns) == list(ROW_SCHEMA)
    assert (df["error"] == "").all() and (df["samples"] <= 120).all()
    assert df["reference_proven"].all() and (df["relative_regret"] >= -1e-12).all()
    again = run_matrix(path, out, workers=1, progress=False)
    assert again["run"] == 0 and again["skipped"] == 8
    for p in df["provenance"]:  # where and with what each row was made
        assert p["fixbench"] and p["python"] and p["libraries"]["numpy"] and p["cpu"] and p["cores"] >= 1
        assert isinstance(p["env"], dict) and "numpy_blas" in p


def test_a_matrix_that_adds_cells_extends_the_run_and_one_that_changes_a_cell_is_refused(tmp_path, capsys):
    """Extend a run: added planner entries and seeds run alone there, the stored rows stay
    byte-identical; a matrix that changes (or drops) a stored cell is refused in one line naming it."""
    out = tmp_path / "run"
    run_matrix(write(tmp_path, TINY), out, workers=1, progress=False)
    before = {p.name: p.read_bytes() for p in (out / "rows").glob("*.json")}
    more = TINY.replace('planners = ["random", "greedy"]', 'planners = ["random", "greedy", "local"]')
    more = more.replace("seeds = [0, 1]", "seeds = [0, 1, 2]")
    extended = run_matrix(write(tmp_path, more, "more.toml"), out, workers=1, progress=False)
    assert extended == {"cells": 18, "skipped": 8, "run": 10, "failed": 0}
    assert {p.name: p.read_bytes() for p in (out / "rows").glob("*.json") if p.name in before} == before
    assert (out / "matrix.toml").read_text() == more
    changed = more.replace("budget = 120", "budget = 100")
    assert main(["run", str(write(tmp_path, changed, "changed.toml")), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "holds the results of a different matrix: its cell random" in err
    assert "budget 120" in err and "only add cells" in err


def test_kill_minus_nine_then_resume(tmp_path):
    """Kill the driver mid-run; the rerun completes and every cell is there exactly once."""
    text = TINY.replace("seeds = [0, 1]", "seeds = [0, 1, 2, 3, 4, 5]")
    path, out = write(tmp_path, text), tmp_path / "run"
    cmd = [sys.executable, "-m", "fixbench", "run", str(path), "--out", str(out), "--workers", "1"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    rows = out / "rows"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and len(list(rows.glob("*.json"))) < 3:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = len(list(rows.glob("*.json")))
    assert 3 <= done_before < 24
    summary = run_matrix(path, out, workers=1, progress=False)
    assert summary["skipped"] == done_before and summary["run"] == 24 - done_before
    df = load_results(out)
    assert len(df) == 24 and df["cell"].is_unique and (df["error"] == "").all()


def test_failing_and_slow_cells_become_rows(tmp_path, monkeypatch):
    (tmp_path / "misbehave.py").write_text(PLANNERS_THAT_MISBEHAVE)
    monkeypatch.setenv("PYTHONPATH", str(tmp_path) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    monkeypatch.syspath_prepend(str(tmp_path))
    text = TINY.replace('planners = ["random", "greedy"]',
                        'planners = ["misbehave:Boom", "misbehave:Sleepy", "random"]')
    text = text.replace("seeds = [0, 1]", "seeds = [0]").replace('"aluminium", "steel"', '"steel"')
    out = tmp_path / "run"
    summary = run_matrix(write(tmp_path, text), out, workers=2, cell_timeout=20, progress=False)
    assert summary["run"] == 3 and summary["failed"] == 2
    df = load_results(out).set_index("planner")
    assert "planner exploded" in df.loc["misbehave:Boom", "error"]
    assert "timeout" in df.loc["misbehave:Sleepy", "error"]
    assert df.loc["random", "error"] == ""


@pytest.mark.slow
def test_ray_gives_the_same_rows_as_local(tmp_path):
    pytest.importorskip("ray")
    path = write(tmp_path, TINY)
    run_matrix(path, tmp_path / "local", workers=2, progress=False)
    run_matrix(path, tmp_path / "ray", executor="ray", workers=2, progress=False)
    cols = ["cell", "planner", "material", "seed", "samples", "objective_m", "mean_reward", "error"]
    local = load_results(tmp_path / "local")[cols]
    ray = load_results(tmp_path / "ray")[cols]
    assert len(local) == 8
    assert local.equals(ray)
