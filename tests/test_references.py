"""Shipped regret references: format and checks, the portfolio, the harness's fallback, the update loop.

The portfolio runs here on a tiny problem (fan_small with 2 agents: 42 x 42 layouts, 6 tasks) where
the proven optimum is known by enumeration.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import fixbench.cases.references as refs
from fixbench.bench.records.rows import CHECKSUM, row_checksum
from fixbench.bench.records.store import Store, write_json_atomic
from fixbench.bench.references.bound import bound
from fixbench.bench.references.build import Portfolio, build
from fixbench.bench.references.prove import compute_reference
from fixbench.bench.references.score import rescore
from fixbench.bench.references.update import update
from fixbench.cases.errors import CaseError
from fixbench.cases.problem import Problem
from fixbench.cases.spec import load_case_spec
from fixbench.solvers import PlannerError, get

TINY = Portfolio(samples_per_task=150, seeds=(0,), polish_samples=100, max_rounds=3, prove_limit=0)


@pytest.fixture(scope="module")
def tiny():
    return Problem(load_case_spec("fan_small", n_agents=2))


@pytest.fixture(scope="module")
def built(tiny):
    return build("fan_small", agents=2, effort=TINY, problem=tiny, echo=lambda m: None)


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setattr(refs, "REFERENCE_DIR", tmp_path / "refs")
    return tmp_path / "refs"


def test_portfolio_reaches_the_proven_optimum(tiny, built):
    opt = get("exact")().solve(tiny, None).max_deformation
    got = np.array([t["max_deformation_m"] for t in built["tasks"]])
    assert got == pytest.approx(opt, rel=1e-9)
    for t, rec in enumerate(built["tasks"]):  # the recorded value is the layout's true max
        u = tiny.oracle.evaluate(t, tiny.check_layouts([rec["layout"]]))[0, 3]
        assert u == pytest.approx(rec["max_deformation_m"], rel=1e-12)
    prov = built["provenance"][0]
    assert prov["action"] == "build" and prov["samples"] > 0 and prov["portfolio"]["planners"]
    assert {t["status"] for t in built["tasks"]} == {"best-known"}  # no proof asked for


def test_affordable_proof_labels_tasks_proven(tiny):
    from dataclasses import replace

    ref = build("fan_small", agents=2, effort=replace(TINY, max_rounds=0, prove_limit=1e9), problem=tiny,
                echo=lambda m: None)
    opt = get("exact")().solve(tiny, None).max_deformation
    assert [t["status"] for t in ref["tasks"]] == ["proven"] * tiny.n_tasks
    assert [t["lower_bound_m"] for t in ref["tasks"]] == pytest.approx(opt.tolist(), rel=1e-12)
    assert ref["provenance"][0]["steps"][-1]["phase"] == "proof"


def test_write_load_and_checks(built, folder):
    path = refs.write_reference(built)
    text = path.read_text()
    json.loads(text)  # strict JSON
    assert "NaN" not in text
    loaded = refs.load_reference("fan_small", built["material"], 2)
    assert loaded["tasks"] == built["tasks"] and loaded["content_hash"] == refs.content_hash(built["tasks"])
    damaged = json.loads(text)
    damaged["tasks"][0]["max_deformation_m"] *= 0.5  # edited by hand: the hash no longer matches
    path.write_text(json.dumps(damaged))
    with pytest.raises(CaseError, match="content_hash"):
        refs.load_reference("fan_small", built["material"], 2)
    stale = dict(built, case_fingerprint="0" * 16)
    refs.write_reference(stale)
    assert refs.load_reference("fan_small", built["material"], 2) is None  # the case changed since


def test_harness_uses_the_shipped_reference_where_exact_refuses(built, folder, monkeypatch):
    refs.write_reference(built)

    def refuse(self, problem, ev, rng, mode):
        raise PlannerError("planner 'exact': too large")

    monkeypatch.setattr(get("exact"), "plan", refuse)
    ref = compute_reference("fan_small", None, 2, None, ("per-task",))
    assert ref["error"] == ""
    assert ref["source"].startswith("catalog reference fan_small__")
    assert ref["per_task"] == [t["max_deformation_m"] for t in built["tasks"]]
    assert ref["lower_bounds"] == [t["lower_bound_m"] for t in built["tasks"]] == [None] * 6  # none computed
    assert ref["proven"] is False  # best-known until proven
    monkeypatch.setattr(refs, "REFERENCE_DIR", folder / "empty")
    ref = compute_reference("fan_small", None, 2, None, ("per-task",))
    assert "no shipped reference" in ref["error"]


def test_update_merges_only_verified_improvements_and_rescores(tiny, built, folder, tmp_path):
    worse = json.loads(json.dumps(built))
    bad = [int(a[-1]) for a in tiny.action_sets]
    lower = 0.5 * built["tasks"][1]["max_deformation_m"]  # a certified bound on the optimum: it must stay
    worse["tasks"][1].update(layout=bad, max_deformation_m=float(tiny.oracle.evaluate(1, [bad])[0, 3]),
                             lower_bound_m=lower)
    refs.write_reference(worse)
    run = tmp_path / "run"
    store = Store(run)
    snapshot = {"key": "k", "case": "fan_small", "material": built["material"], "agents": 2, "n_tasks": 6,
                "per_task": [t["max_deformation_m"] for t in worse["tasks"]], "proven": False,
                "source": "catalog reference fan_small__x.json", "shared": None}
    write_json_atomic(run / "reference" / "k.json", snapshot)
    good = [t["layout"] for t in built["tasks"]]
    true = [t["max_deformation_m"] for t in built["tasks"]]
    honest = {"cell": "honest", "planner": "p", "case": "fan_small", "material": built["material"],
              "agents": 2, "n_tasks": 6, "mode": "per-task", "error": "", "layouts": json.dumps(good),
              "per_task_m": json.dumps(true), "relative_regret": np.mean(true) / np.mean(snapshot["per_task"]) - 1}
    liar = dict(honest, cell="liar", layouts=json.dumps([bad] * 6), per_task_m=json.dumps([1e-9] * 6))
    for row in (honest, liar):  # with their checksums, as the store writes rows
        write_json_atomic(store.row_path(row["cell"]), row | {CHECKSUM: row_checksum(row)})
    other = tmp_path / "other"  # another run scored against the same reference: the loop rescores it too
    shutil.copytree(run, other)
    changed = update(run, [other], echo=lambda m: None)
    assert list(changed.values()) == [1]
    assert Store(other).finished()["honest"]["relative_regret"] == pytest.approx(0.0, abs=1e-12)
    now = refs.load_reference("fan_small", built["material"], 2)
    assert now["tasks"][1]["layout"] == good[1] and now["tasks"][0] == built["tasks"][0]
    assert now["tasks"][1]["lower_bound_m"] == lower and now["tasks"][1]["status"] == "best-known"
    assert now["tasks"][2:] == built["tasks"][2:]
    assert now["provenance"][-1]["action"] == "update"
    rows = store.finished()
    assert set(rows) == {"honest", "liar"}  # rescored rows keep valid checksums: none reads as damaged
    raw = json.loads(store.row_path("honest").read_text())  # written by hand as schema 1: rewritten as 3
    assert raw["schema"] == 3 and raw["layouts"] == good and rows["honest"]["per_task_m"] == true
    assert rows["honest"]["relative_regret"] == pytest.approx(0.0, abs=1e-12)  # rescored
    assert rows["honest"]["bound_objective_m"] == pytest.approx(lower / 6, rel=1e-12)  # the one bound, of 6
    assert rows["liar"]["relative_regret"] < 0  # a lying row is not trusted, and stays visible
    assert rescore(run, echo=lambda m: None) == 0  # idempotent
    stale = dict(store.finished()["honest"], policy_objective_m=2 * np.mean(true), policy_relative_regret=0.5)
    store.rewrite(stale)  # a policy's regret left behind while every other column is current
    assert rescore(run, echo=lambda m: None) == 1
    assert store.finished()["honest"]["policy_relative_regret"] == pytest.approx(1.0, rel=1e-12)


def test_bound_to_the_end_proves_every_position(tiny, built, folder):
    """Branch-and-bound run to the end: every position proven at exact's optimum, a worse layout of the
    reference replaced by the optimum the search found, the method and its settings recorded."""
    worse = json.loads(json.dumps(built))
    bad = [int(a[-1]) for a in tiny.action_sets]
    u_bad = float(tiny.measure(1, np.asarray([bad]))[0, 3])
    worse["tasks"][1].update(layout=bad, max_deformation_m=u_bad)
    refs.write_reference(worse)
    opt = get("exact")().solve(tiny, None).max_deformation
    assert u_bad > opt[1] * 1.01  # the damage is real
    res = bound("fan_small", None, 2, time_limit_s=600.0, echo=lambda m: None)
    new = refs.load_reference("fan_small", built["material"], 2)
    assert [t["status"] for t in new["tasks"]] == ["proven"] * tiny.n_tasks
    assert [t["max_deformation_m"] for t in new["tasks"]] == pytest.approx(opt.tolist(), rel=1e-9)
    assert [t["lower_bound_m"] for t in new["tasks"]] == [t["max_deformation_m"] for t in new["tasks"]]
    assert [r["gap"] for r in res["positions"]] == [0.0] * tiny.n_tasks
    prov = new["provenance"][-1]
    assert prov["action"] == "bound" and prov["settings"]["time_limit_s"] == 600.0 and prov["proven"] == 6


def test_a_bound_stopped_early_stays_below_and_is_kept_per_position(built, folder):
    refs.write_reference(built)
    bound("fan_small", None, 2, time_limit_s=1e-9, tasks=[2], echo=lambda m: None)
    new = refs.load_reference("fan_small", built["material"], 2)
    rec = new["tasks"][2]
    assert 0 <= rec["lower_bound_m"] <= rec["max_deformation_m"]  # the root's bound: certified, not closed
    assert [t["lower_bound_m"] for i, t in enumerate(new["tasks"]) if i != 2] == [None] * 5


def test_zone_bounds_from_the_command_line_are_certified_and_kept(tiny, built, folder):
    """`--method zones`: every position gets a bound at most exact's optimum, positive somewhere; the
    method is recorded; a later, smaller bound (the root of a branch-and-bound stopped at once) keeps it."""
    from fixbench.bench.cli import main

    refs.write_reference(built)
    assert main(["references", "bound", "fan_small", "--agents", "2", "--method", "zones"]) == 0
    opt = get("exact")().solve(tiny, None).max_deformation
    new = refs.load_reference("fan_small", built["material"], 2)
    zb = np.array([t["lower_bound_m"] for t in new["tasks"]])
    assert np.all(zb >= 0) and np.all(zb <= opt) and zb.max() > 0
    assert "zone bound" in new["provenance"][-1]["method"] and new["provenance"][-1]["settings"]["safety"] == 1e-6
    bound("fan_small", None, 2, time_limit_s=1e-9, echo=lambda m: None)
    again = np.array([t["lower_bound_m"] for t in refs.load_reference("fan_small", built["material"], 2)["tasks"]])
    assert np.all(again >= zb)


def test_a_bound_above_the_reference_is_refused(built, folder, capsys):
    from fixbench.bench.cli import main

    path = refs.write_reference(built)
    damaged = json.loads(path.read_text())
    damaged["tasks"][3]["lower_bound_m"] = 2 * damaged["tasks"][3]["max_deformation_m"]
    damaged["content_hash"] = refs.content_hash(damaged["tasks"])  # consistent, but not a bound
    path.write_text(json.dumps(damaged))
    with pytest.raises(CaseError, match=r"tasks\[3\].lower_bound_m.*no bound"):
        refs.load_reference("fan_small", built["material"], 2)
    assert main(["references", "bound", "fan_small", "--agents", "2", "--time-limit", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "lower_bound_m" in err and "Traceback" not in err


def test_regret_is_bracketed_by_the_reference_and_its_bound(tiny, built):
    """[regret against the reference, regret against the bounds] holds the true regret (against exact's
    optimum) in every mode: a position without a bound counts as 0, none at all gives no upper end."""
    from fixbench.bench.references.score import _Scored, metrics

    opt = get("exact")().solve(tiny, None).max_deformation
    worse = np.array([t["max_deformation_m"] for t in built["tasks"]]) * (1 + np.arange(6) / 50)  # >= opt
    rng = np.random.default_rng(0)
    u = opt * (1 + rng.uniform(0, 0.3, 6))  # a planner's layouts' values
    bounds = [float(b) for b in opt * rng.uniform(0.2, 1.0, 6)]
    bounds[4] = None
    ref = {"per_task": worse.tolist(), "lower_bounds": bounds, "proven": False, "shared": float(worse.max()),
           "source": "catalog reference x.json (content 0)"}
    for mode, every in (("per-task", None), ("held-out", 3), ("shared", None)):
        row = {"per_task_m": u.tolist(), "mode": mode, "heldout_every": every, "agents": 2}
        m = metrics(_Scored(row, np.empty((0, 4))), ref)
        scored = _Scored(row, np.empty((0, 4))).scored_tasks
        true = (u[scored].max() / opt[scored].max() if mode == "shared" else u[scored].mean() / opt[scored].mean()) - 1
        assert m["relative_regret"] <= true <= m["relative_regret_upper"], mode
        b = np.array([0.0 if x is None else x for x in bounds])[scored]
        assert m["bound_objective_m"] == pytest.approx(b.max() if mode == "shared" else b.mean(), rel=1e-15)
    m = metrics(_Scored({"per_task_m": u.tolist(), "mode": "per-task", "agents": 2}, np.empty((0, 4))),
                dict(ref, lower_bounds=[None] * 6))
    assert m["bound_objective_m"] == 0 and np.isnan(m["relative_regret_upper"])  # no bound: no upper end
    proven = dict(ref, per_task=opt.tolist(), lower_bounds=opt.tolist())
    m = metrics(_Scored({"per_task_m": u.tolist(), "mode": "per-task", "agents": 2}, np.empty((0, 4))), proven)
    assert m["relative_regret_upper"] == pytest.approx(m["relative_regret"], rel=1e-12)  # proven: closed


def test_check_small_counts_tasks_at_the_optimum():
    from fixbench.bench.references.build import check_small

    rows = check_small(cases=("fan_small",), materials=("steel",), effort=TINY, echo=lambda r: None)
    assert len(rows) == 1 and rows[0]["tasks"] == 6
    assert 0 <= rows[0]["reached"] <= 6 and rows[0]["worst_gap_pct"] >= -1e-7
    assert (rows[0]["reached"] == 6) == (rows[0]["worst_gap_pct"] <= 1e-7)


def test_every_shipped_reference_carries_a_certified_bound_on_every_position():
    """docs/references.md#zone-bound: each shipped position has a lower bound (proven ones their optimum),
    the method that made it is recorded, and the bounds say something on every shipped part."""
    files = sorted(refs.REFERENCE_DIR.glob("*.json"))
    assert files
    for path in files:
        ref = json.loads(path.read_text(encoding="utf-8"))
        bounds = [t["lower_bound_m"] for t in ref["tasks"]]
        assert None not in bounds, path.name
        assert all(0 <= b <= t["max_deformation_m"] for b, t in zip(bounds, ref["tasks"])), path.name
        methods = {p["method"].split(" (")[0] for p in ref["provenance"] if p["action"] == "bound"}
        assert methods & {"zone bound", "compliance branch-and-bound"}, path.name
        assert sum(b > 0 for b in bounds) >= len(bounds) / 2, path.name
