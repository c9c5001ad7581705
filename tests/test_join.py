"""Add a planner to the comparison (README "Add your planner to the comparison"): the README's commands
run as they stand on a copy of the committed run results/tiny with the example plugin, and merged
reports refuse runs that are not comparable."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fixbench.bench.cli import main
from fixbench.bench.reporting.merge import load_runs

#: one xdist worker runs these tests (`make test`: --dist loadgroup), so the README's join example runs once a session
pytestmark = pytest.mark.xdist_group("test_join")

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "results" / "tiny"
README = ROOT / "README.md"


def readme_block(marker: str, fence: str = "") -> str:
    """The text between README's ``<!-- marker -->`` lines (inside its ``fence`` code block, if given)."""
    opening, closing = (f"```{fence}\n", "```\n") if fence else ("", "")
    m = re.search(rf"<!-- {marker} -->\n{opening}(.*?){closing}<!-- /{marker} -->",
                  README.read_text(encoding="utf-8"), re.S)
    assert m, f"README has no {marker} block"
    return m.group(1)


def copy_run(src: Path, dest: Path) -> Path:
    """A committed run as a checkout has it (its oracle cache is not committed)."""
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("oracle-cache", ".lock"))
    return dest


def files(run: Path, folder: str = "rows") -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((run / folder).glob("*"))}


@pytest.fixture(scope="module")
def journey(tmp_path_factory):
    """The README block, run by bash in a scratch copy of the checkout's results/tiny and example
    plugin; ``pip`` installs into a scratch folder on PYTHONPATH (never into the project's venv)."""
    work = tmp_path_factory.mktemp("join")
    copy_run(TINY, work / "results" / "tiny")
    shutil.copytree(ROOT / "examples" / "fixbench-plugin-example", work / "examples" / "fixbench-plugin-example")
    committed = {f: files(TINY, f) for f in ("rows", "traces", "curves", "reference")}
    site = work / "site"
    shim = (f'pip() {{ "{sys.executable}" -m pip "$@" -q --no-deps --no-build-isolation --target "{site}"; }}\n'
            "set -euo pipefail\n")
    env = {**os.environ, "PYTHONPATH": str(site), "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    proc = subprocess.run(["bash", "-c", shim + readme_block("join-example", "bash")], cwd=work, env=env,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert {f: files(TINY, f) for f in committed} == committed, "results/tiny was written to"
    return work, proc.stdout, committed


def test_the_readme_commands_rank_a_plugin_beside_a_committed_run(journey):
    work, out, committed = journey
    assert "near-load" in out  # listed by fixbench solvers
    assert "8 cells: 2 run (0 failed), 6 already done; results in mine" in out
    mine = work / "mine"
    assert {k: v for k, v in files(mine).items() if k in committed["rows"]} == committed["rows"]
    new = set(files(mine)) - set(committed["rows"])
    assert len(new) == 2 and {json.loads((mine / "rows" / n).read_text())["planner"] for n in new} == {"near-load"}
    for folder in ("traces", "curves", "reference"):  # the committed cells' files untouched too
        assert {k: v for k, v in files(mine, folder).items() if k in committed[folder]} == committed[folder]
    main_csv = pd.read_csv(mine / "report" / "tables" / "main.csv").set_index("planner")
    assert sorted(main_csv.index) == ["greedy", "local", "near-load", "random"]
    assert (main_csv["problems"] == 2).all() and main_csv["mean_rank"].between(1, 4).all()
    assert sorted(main_csv["mean_rank"]) != [1, 1, 1, 1]  # ranked, not all tied
    assert np.isfinite(main_csv.loc["near-load", "fan_small"])  # its relative regret
    assert "| near-load " in (mine / "report" / "tables" / "main.md").read_text()


def test_the_merged_report_equals_the_extended_copys(journey):
    """`fixbench report alone --with tiny` (the plugin's cells alone, merged at report time) gives the
    extended copy's tables (formatted to the byte; their numbers within 1e-9, for alone/ computed its
    own regret reference), save the planner's own wall times."""
    work, out, _ = journey
    assert "8 cells: 2 run (0 failed), 0 already done, 6 left for a run without --only" in out
    a, b = work / "mine" / "report" / "tables", work / "alone" / "report" / "tables"
    for name in ("main", "versus_best", "improvement", "profile", "references", "summary"):
        x, y = pd.read_csv(a / f"{name}.csv"), pd.read_csv(b / f"{name}.csv")
        wall = [c for c in x.columns if c.startswith("wall_s")]
        pd.testing.assert_frame_equal(x.drop(columns=wall), y.drop(columns=wall), rtol=1e-9, atol=0)
        if not wall:
            assert (a / f"{name}.md").read_bytes() == (b / f"{name}.md").read_bytes(), name
    md = (b.parent / "report.md").read_text()
    assert md.startswith("# fixbench report: tiny + tiny\n") and "merged (one protocol): 8 cells" in md


def _rewrite(run: Path, change) -> None:
    """Change every row of ``run`` with ``change(row)`` and keep its checksum valid."""
    from fixbench.bench.records.store import Store

    store = Store(run)
    for row in store.finished().values():
        change(row)
        store.rewrite(row)


def _refused(capsys, *args) -> str:
    assert main(["report", *map(str, args), "--no-fields"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_runs_that_are_not_comparable_are_refused(tmp_path, capsys):
    base = copy_run(TINY, tmp_path / "base")
    # another budget
    other = copy_run(TINY, tmp_path / "budget")
    _rewrite(other, lambda r: r.update(budget=200))
    err = _refused(capsys, base, other)
    assert "not comparable" in err and "budget 200" in err and "has budget 120" in err
    # another regret reference (a case file changed: its fingerprint and optima)
    ref = copy_run(TINY, tmp_path / "ref")
    path = next((ref / "reference").glob("*.json"))
    snap = json.loads(path.read_text())
    snap["per_task"][1] *= 1.01
    path.write_text(json.dumps(snap))
    err = _refused(capsys, base, ref)
    assert "regret reference of fan_small/aluminium (2 agents, 3 tasks) differs: task 1" in err
    snap["case_fingerprint"] = "0" * 16
    path.write_text(json.dumps(snap))
    assert "case fingerprint 0000000000000000 here" in _refused(capsys, base, ref)
    # a seed the protocol run does not have, for a planner alone there
    seeds = copy_run(TINY, tmp_path / "seeds")
    _rewrite(seeds, lambda r: r.update(seed=7))
    err = _refused(capsys, base, seeds)
    assert "cells at seed 7" in err and "has seed 0, 1" in err
    # a label naming another config
    label = copy_run(TINY, tmp_path / "label")
    _rewrite(label, lambda r: r.update(config={"batch": 5}) if r["planner"] == "random" else None)
    err = _refused(capsys, base, label)
    assert "label 'random' is random (batch=5) here and random (default)" in err and "collide" in err
    # the same cell with another result
    moved = copy_run(TINY, tmp_path / "moved")
    _rewrite(moved, lambda r: r.update(objective_m=r["objective_m"] * 2))
    assert "with another result than" in _refused(capsys, base, moved)
    assert not (base / "report").exists() and not (other / "report").exists(), "a refused merge writes nothing"


def test_a_cell_in_both_runs_is_read_once_and_with_names_committed_runs(tmp_path, capsys):
    copy = copy_run(TINY, tmp_path / "copy")
    runs = load_runs([copy, TINY])
    assert len(runs.rows) == len(load_runs([TINY]).rows) == 6 and runs.cells[1] == set()
    assert main(["report", "--with", "nosuchrun"]) == 2
    assert "--with: nosuchrun: no committed run of that name" in capsys.readouterr().err
    assert main(["report"]) == 2
