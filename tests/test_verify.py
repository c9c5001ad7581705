"""`fixbench verify`: a tiny real run reproduced here, a tampered value caught, a learner judged by its
group's interval; and the sample, the interval and the code-path note on their own."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from fixbench.bench.cli import main
from fixbench.bench.records.store import Store
from fixbench.bench.reporting.stats import prediction_interval
from fixbench.bench.running.provenance import provenance
from fixbench.bench.verify import code_path_note, sample

#: one xdist worker runs these tests (`make test`: --dist loadgroup), so the tiny run is made once a session
pytestmark = pytest.mark.xdist_group("test_verify")

MATRIX = """name = "tiny"
cases = ["fan_small"]
materials = ["aluminium"]
agents = [2]
tasks = 2
seeds = [0, 1, 2]
budget = 12
[[planners]]
name = "random"
[[planners]]
name = "greedy"
[[planners]]
name = "nashq"
config = { episodes = 2, hidden = 8, batch = 4, threads = 1 }
"""


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A real run of 9 cells (random, greedy and nashq on 2 tasks of fan_small with 2 robots, seeds 0-2)."""
    from fixbench.bench.running.runner import run_matrix

    root = tmp_path_factory.mktemp("verify")
    (root / "m.toml").write_text(MATRIX)
    assert run_matrix(root / "m.toml", root / "run", workers=1, progress=False)["failed"] == 0
    return root


def _objectives(run, planner: str) -> dict[int, float]:
    return {r["seed"]: r["objective_m"] for r in Store(run).finished().values() if r["planner"] == planner}


def _set(run, planner: str, values: dict[int, float]) -> None:
    """Rewrite committed rows' objectives by seed (with valid checksums, as a careful hand would)."""
    store = Store(run)
    for row in store.finished().values():
        if row["planner"] == planner and row["seed"] in values:
            row["objective_m"] = values[row["seed"]]
            store.rewrite(row)


def _verify(root, capsys, *args) -> tuple[int, str]:
    code = main(["verify", str(root / "run"), "--workers", "1", *args])
    return code, capsys.readouterr().out


def test_a_tiny_run_agrees_with_itself(tiny_run, capsys):
    code, out = _verify(tiny_run, capsys, "--cells", "3")
    assert code == 0, out
    assert "3 of 3 cells agree" in out
    for planner in ("random", "greedy", "nashq"):  # one cell of each: the sample spans the planners
        assert out.count(f"| {planner} ") == 1, out
    assert "code path differs" not in out  # rerun on the host that made the rows


def test_a_busy_machine_is_warned_of(tiny_run, capsys, monkeypatch):
    monkeypatch.setattr("os.getloadavg", lambda: (64.0, 64.0, 64.0))
    assert main(["verify", str(tiny_run / "run"), "--workers", "1", "--cells", "1"]) == 0
    assert "fixbench: verify: load average 64.0 on " in capsys.readouterr().err


def test_a_tampered_value_is_caught(tiny_run, capsys):
    run = tiny_run / "run"
    was = _objectives(run, "greedy")
    value = was[1] * (1 + 1e-6)  # beyond 1e-9: a deterministic planner's rerun must not move
    _set(run, "greedy", {1: value})
    try:
        code, out = _verify(tiny_run, capsys, "--cells", "9", "--only", "greedy")
    finally:
        _set(run, "greedy", was)
    assert code == 1
    line = next(x for x in out.splitlines() if "DISAGREES" in x)
    assert f"{value * 1e6:.10g}" in line and "| greedy " in line and "1e-09" in line
    assert "2 of 3 cells agree" in out


def test_a_learner_is_judged_by_its_groups_interval(tiny_run, capsys):
    """A learner's rerun off by more than 1e-9 (as on another host) agrees inside the group's prediction
    interval over seeds (committed values set here: seed 0 off by 1e-6, the others 0.1 % either side
    of a centre) and disagrees outside it."""
    run = tiny_run / "run"
    was = _objectives(run, "nashq")
    for centre, agrees in ((was[0], True), (2 * was[0], False)):
        _set(run, "nashq", {0: centre + 1e-6 * was[0], 1: centre * 1.001, 2: centre * 0.999})
        try:
            code, out = _verify(tiny_run, capsys, "--cells", "1", "--only", "nashq,seed=0")
        finally:
            _set(run, "nashq", was)
        assert (code == 0) == agrees, out
        line = next(x for x in out.splitlines() if "| nashq " in x)
        assert "3 seeds" in line and ("agrees" in line) == agrees, line


def test_sample_spans_planners_and_both_kinds():
    rows = pd.DataFrame({"label": [p for p in "abcdL" for _ in range(5)],
                         "same": [p != "L" for p in "abcdL" for _ in range(5)]})
    for seed in range(6):  # whichever entry comes first, the second is of the other kind
        picked = sample(rows, 2, seed)
        assert rows.loc[picked, "same"].nunique() == 2
        assert rows.loc[sample(rows, 5, seed), "label"].nunique() == 5  # one of each before a second of any
    assert sample(rows, 6, 1) == sample(rows, 6, 1) and sample(rows, 6, 1) != sample(rows, 6, 2)
    assert len(sample(rows, 100, 0)) == 25


def test_prediction_interval():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    lo, hi = prediction_interval(x)
    half = 3.182446305284263 * x.std(ddof=1) * math.sqrt(1.25)  # t(0.975, 3)
    assert (lo, hi) == pytest.approx((2.5 - half, 2.5 + half))
    assert all(math.isnan(v) for v in prediction_interval([1.0, math.nan]))


def test_code_path_note():
    here = dict(provenance(), env={})
    assert code_path_note(None, here) == "the row records no provenance"
    assert code_path_note(here, here) == ""
    there = dict(here, cpu="Other CPU", env={**here["env"], "MKL_CBWR": "AVX2"})
    note = code_path_note(there, here)
    assert "cpu Other CPU -> " in note and "env.MKL_CBWR AVX2 -> -" in note
