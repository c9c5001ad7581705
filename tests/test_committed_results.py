"""The committed runs against their references: no layout any planner found beats its reference.

A reference that a planner beats is not a reference; when a run finds a better layout,
``fixbench references update DIR`` must merge it (and rescore the run) before the run is committed.
Also: every successful cell of the paper matrix has a finite relative regret against a labelled
reference.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from fixbench.bench.records.rows import load_results
from fixbench.bench.reporting.merge import load_references
from fixbench.cases.problem import task_subset
from fixbench.cases.references import load_reference

ROOT = Path(__file__).resolve().parents[1] / "results"
RUNS = ["reference", "paper", "tiny", "cfrp_paper", "families"]


def _rows(run: str):
    root = ROOT / run
    assert (root / "rows").is_dir(), f"results/{run} is not committed"
    rows = load_results(root)
    return root, rows[(rows["error"].fillna("") == "") & rows["per_task_m"].notna()]


@pytest.mark.parametrize("run", RUNS)
def test_no_committed_layout_beats_its_reference(run):
    root, rows = _rows(run)
    assert len(rows), f"results/{run} has no successful row with per-task deformations"
    refs = load_references(root)
    for _, row in rows.iterrows():
        u = np.asarray(row["per_task_m"])
        ref = refs[(row["case"], row["material"], int(row["agents"]), int(row["n_tasks"]))]
        bound = np.asarray(ref["per_task"]) * (1 - 1e-9)
        assert (u >= bound).all(), (run, row["cell"], row["planner"], np.flatnonzero(u < bound))
        if str(row["reference_source"]).startswith("catalog reference"):  # and the shipped one, as it is now
            shipped = load_reference(row["case"], row["material"], int(row["agents"]))
            assert shipped is not None, (row["case"], row["material"])
            ids = task_subset(shipped["n_tasks"], len(u))
            now = np.array([shipped["tasks"][i]["max_deformation_m"] for i in ids]) * (1 - 1e-9)
            assert (u >= now).all(), (run, row["cell"], row["planner"])


def test_every_paper_cell_has_a_finite_regret_against_a_labelled_reference():
    _, rows = _rows("paper")
    assert np.isfinite(rows["relative_regret"].astype(float)).all()
    assert rows["reference_source"].str.len().gt(0).all()


@pytest.mark.parametrize("run", RUNS + ["sweep"])
def test_every_committed_json_file_is_strict_json(run):
    """Rows and reference snapshots parse under RFC 8259 (no NaN or Infinity): schema 3."""
    from conftest import strict_json_loads

    for path in sorted((ROOT / run).glob("*/*.json")):
        try:
            strict_json_loads(path.read_text(encoding="utf-8"))
        except ValueError as exc:
            raise AssertionError(f"{path.relative_to(ROOT)}: {exc}") from None


@pytest.mark.parametrize("run", RUNS)
def test_every_committed_regret_is_bracketed(run):
    """Every scored row carries both ends of its regret's bracket, in order; against a proven reference
    they meet, and against one with no bound the upper end is NaN (docs/protocol.md#true-regret)."""
    _, rows = _rows(run)
    rows = rows[np.isfinite(rows["relative_regret"].astype(float))]
    assert {"bound_objective_m", "relative_regret_upper"} <= set(rows.columns), f"results/{run} is not rescored"
    low, high = rows["relative_regret"].astype(float), rows["relative_regret_upper"].astype(float)
    bounded = np.isfinite(high)
    assert (low[bounded] <= high[bounded] * (1 + 1e-12) + 1e-12).all()
    assert (rows["bound_objective_m"].astype(float)[~bounded] == 0).all()
    proven = rows["reference_proven"].astype(bool)
    assert np.allclose(low[proven], high[proven], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("doc", ["README.md", "docs/results.md"])
def test_readme_tables_are_the_committed_reports(doc):
    """Every table of the README and docs/results.md that mirrors a committed table (``<!-- table:
    PATH -->`` blocks) is that table as committed: `fixbench report DIR --readme FILE` and `fixbench
    tune-table DIR --readme FILE` refresh them."""
    from fixbench.bench.reporting.tables import TABLE_BLOCK

    readme = ROOT.parent / doc
    blocks = list(TABLE_BLOCK.finditer(readme.read_text(encoding="utf-8")))
    assert blocks, f"{doc} mirrors no committed table"
    for m in blocks:
        path = readme.parent / m["path"]
        assert path.is_file(), m["path"]
        assert m["body"] == path.read_text(encoding="utf-8").rstrip("\n") + "\n", f"{m['path']}: README is stale"


def test_the_readme_states_no_result_by_hand():
    """The README is at most 300 lines, and every result figure in it (a percentage, a probability's
    interval) sits in a table `fixbench report --readme` writes: outside those blocks only the bootstrap
    interval's "95 %" is a percentage, and the answer is a generated table, never prose to keep in step."""
    from fixbench.bench.reporting.tables import TABLE_BLOCK

    text = (ROOT.parent / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 300
    assert "<!-- table: results/paper/report/tables/verdict.md -->" in text
    prose = TABLE_BLOCK.sub("", text)
    assert set(re.findall(r"\d[\d.,]*\s?%", prose)) <= {"95 %"}, re.findall(r".*\d[\d.,]*\s?%.*", prose)
    assert not re.search(r"P = \d|\[\d[\d.]*, \d[\d.]*\]", prose)


def test_refresh_readme_copies_only_this_reports_tables(tmp_path):
    from fixbench.bench.reporting.tables import refresh_readme
    from fixbench.cases.errors import CaseError

    (tmp_path / "run" / "report" / "tables").mkdir(parents=True)
    (tmp_path / "run" / "report" / "tables" / "main.md").write_text("| a |\n|---|\n| 1 |\n")
    readme = tmp_path / "README.md"
    other = "<!-- table: elsewhere/main.md -->\nold\n<!-- /table -->\n"
    readme.write_text("# x\n<!-- table: run/report/tables/main.md -->\nstale\n<!-- /table -->\ntext\n" + other)
    assert refresh_readme(readme, tmp_path / "run" / "report") == 1
    assert readme.read_text() == ("# x\n<!-- table: run/report/tables/main.md -->\n| a |\n|---|\n| 1 |\n"
                                  "<!-- /table -->\ntext\n" + other)
    readme.write_text("<!-- table: run/report/tables/gone.md -->\n<!-- /table -->\n")
    with pytest.raises(CaseError, match="no such table"):
        refresh_readme(readme, tmp_path / "run" / "report")
