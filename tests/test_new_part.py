"""docs/new-part.md, the walk-through from an empty file to a ranked table on a part of one's own, run
as it stands: each ``# FILE`` block is written, each ``bash`` block run by bash, in order, in an
empty folder; then what each step promises is checked there."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

#: one xdist worker runs these tests (`make test`: --dist loadgroup), so the walk-through runs once a session
pytestmark = pytest.mark.xdist_group("test_new_part")

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "new-part.md"


def blocks() -> list[tuple[str, str]]:
    """The page's fenced blocks in order: (language, text)."""
    return re.findall(r"^```(\w+)\n(.*?)^```$", PAGE.read_text(encoding="utf-8"), re.S | re.M)


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """Run the page in an empty folder; returns the folder and each bash block's (stdout, stderr)."""
    work = tmp_path_factory.mktemp("new-part")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    out = []
    for lang, text in blocks():
        first = text.splitlines()[0]
        if m := re.fullmatch(r"# (\S+\.(?:toml|py))", first):
            (work / m.group(1)).write_text(text, encoding="utf-8")
        elif lang == "bash":
            proc = subprocess.run(["bash", "-euo", "pipefail", "-c", text], cwd=work, env=env,
                                  capture_output=True, text=True)
            assert proc.returncode == 0, f"{text}\n{proc.stderr[-3000:]}"
            out.append((proc.stdout, proc.stderr))
        else:
            pytest.fail(f"docs/new-part.md: a {lang} block names no file and is not bash: {first!r}")
    return work, out


def test_every_step_runs_and_leaves_what_it_says(walk):
    work, out = walk
    assert (work / "panel.dxf").stat().st_size > 0
    cases = out[1][0]
    assert "access_panel" in cases and "panel" in cases
    assert (work / "panel.png").stat().st_size > 0 and (work / "panel-check.png").stat().st_size > 0
    check = out[2][0]
    assert "mesh convergence" in check and "deflection over thickness" in check
    assert not re.search(r"reward.*0 or 1", out[2][1]), "the walk-through's reward widths are degenerate"


def test_the_run_proves_its_positions_and_ranks_every_planner(walk):
    work, out = walk
    assert list((work / "run" / "reference").glob("*.proof.jsonl")), "no proof records in the run"
    main = pd.read_csv(work / "run" / "report" / "tables" / "main.csv").set_index("planner")
    planners = ["random", "greedy", "local", "pso", "cbr", "vdn", "surrogate-ts"]
    assert sorted(main.index) == sorted(planners)
    assert (main["problems"] == 2).all() and main["mean_rank"].between(1, len(planners)).all()
    assert (main["panel_small"] >= 0).all(), "a regret below the proven optimum"


def test_the_cfrp_variant_is_a_laminate_with_its_pad_up(walk):
    from fixbench.cases.materials import Laminate
    from fixbench.cases.spec import load_case_spec

    work, out = walk
    assert "panel_qi" in out[-1][0], "fixbench cases did not list the layup"
    spec = load_case_spec(work / "panel_cfrp.toml")
    assert isinstance(spec.material, Laminate) and len(spec.material.layers) == 32
    assert spec.thickness == pytest.approx(0.004, rel=1e-12)
    (pad,) = spec.regions
    assert pad.thickness == pytest.approx(0.006, rel=1e-12)
    assert not pad.polygon.intersects(spec.polygon.interiors[0].centroid), "the cut-out is not a hole of the pad"
