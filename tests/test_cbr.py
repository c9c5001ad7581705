"""The cbr planner: library building, zero-sample retrieval, counted revision, retention, degradation far away."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixbench.cases import load_problem
from fixbench.cases.problem import Problem
from fixbench.cases.spec import load_case_spec
from fixbench.solvers.base import PlannerError
from fixbench.solvers.knowledge.cbr import CaseBasedReasoning, build_library
from fixbench.solvers.registry import get

BUILD_BUDGET = 100  # samples per task when building the library (and for the reference solves)


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """Wing panel (aluminium), tasks 0, 4, 8, solved by the default planner (greedy)."""
    source = Problem(load_case_spec("wing_panel_small").with_tasks([0, 3]))
    path = tmp_path_factory.mktemp("cbr") / "library.json"
    lib = build_library([source], budget=BUILD_BUDGET * source.n_tasks, path=path)
    return source, path, lib


def test_library_file_records_positions_and_offline_samples(library):
    source, path, lib = library
    stored = json.loads(path.read_text())
    assert stored["library_samples"] == lib["library_samples"] > 0
    assert stored["sources"][0]["planner"] == "greedy"
    assert len(stored["entries"]) == source.n_tasks
    pos = np.array(stored["entries"][0]["positions_m"])
    assert pos.shape == (source.n_agents, 2) and (pos >= 0).all()  # metres from the box corner


def test_zero_samples_returns_the_stored_layouts(library):
    source, path, lib = library
    r = CaseBasedReasoning(library=str(path), polish_samples=0, exclude="none").solve(source, None, seed=0)
    assert r.samples == 0 and len(r.trace) == 0
    assert r.info["library_samples"] == lib["library_samples"]
    assert np.allclose(r.info["distance"], 0.0)
    stored = np.array([e["positions_m"] for e in lib["entries"]])
    lo = np.array(source.spec.polygon.bounds[:2])
    assert np.allclose(source.candidates[r.layouts] - lo, stored)  # positions map back exactly


def test_polish_is_counted_and_within_budget(library):
    source, path, _ = library
    r = CaseBasedReasoning(library=str(path), polish_samples=6, exclude="none").solve(source, 10, seed=0)
    assert 0 < r.samples <= 10
    assert r.trace[-1, 2] == r.samples
    s = CaseBasedReasoning(library=str(path), polish_samples=2, exclude="none").solve(
        source, None, seed=0, mode="shared")
    assert (s.layouts == s.layouts[0]).all() and s.samples <= 2 * source.n_tasks
    z = CaseBasedReasoning(library=str(path), polish_samples=0, exclude="none").solve(
        source, None, seed=0, mode="shared")  # no sample: the nearest adaptation, on every task
    assert z.samples == 0 and (z.layouts == z.layouts[0]).all() and (z.layouts >= 0).all()


def test_missing_library_is_a_clear_error(tmp_path):
    with pytest.raises(PlannerError, match="no case library"):
        cbr = CaseBasedReasoning(library=str(tmp_path / "none.json"), bootstrap=())
        cbr.solve(load_problem("fan_small"), None)


def test_degrades_with_distance_from_the_library(library):
    """(a) close: same part, titanium, tasks between the library's; (b) far: fan_small.

    Ratio = cbr's mean max deformation (no online sample) / greedy's with BUILD_BUDGET per task on
    the query itself. Within the library the ratio is 1 (the stored layouts come back).
    """
    source, path, _ = library
    queries = {"within": source,
               "close": Problem(load_case_spec("wing_panel_small", "titanium").with_tasks([1, 2])),
               "far": load_problem("fan_small")}
    dist, ratio = {}, {}
    for name, q in queries.items():
        r = CaseBasedReasoning(library=str(path), polish_samples=0, exclude="none").solve(q, None, seed=0)
        ref = get("greedy")().solve(q, BUILD_BUDGET * q.n_tasks, seed=0)
        dist[name] = float(np.mean(r.info["distance"]))
        ratio[name] = float(r.max_deformation.mean() / ref.max_deformation.mean())
    print("retrieval distance", dist, "deformation ratio vs greedy", ratio)
    assert dist["within"] == pytest.approx(0.0, abs=1e-12) and ratio["within"] == pytest.approx(1.0)
    assert dist["within"] < dist["close"] < dist["far"]
    assert ratio["far"] > ratio["within"]


def test_revise_spends_the_budget_and_never_ends_worse_than_the_adaptation(library):
    """On a query the library does not hold (titanium, tasks between the stored ones) cbr spends its
    whole budget revising and ends, task by task, no worse than the adaptation it started from."""
    _, path, _ = library
    query = Problem(load_case_spec("wing_panel_small", "titanium").with_tasks([1, 2]))
    start = CaseBasedReasoning(library=str(path), polish_samples=0, exclude="none").solve(query, None, seed=0)
    revised = CaseBasedReasoning(library=str(path), exclude="none").solve(query, 40 * query.n_tasks, seed=0)
    assert revised.samples == 40 * query.n_tasks
    assert (revised.max_deformation <= start.max_deformation).all()
    assert revised.max_deformation.mean() < start.max_deformation.mean()
    capped = CaseBasedReasoning(library=str(path), polish_samples=5, exclude="none").solve(query, 400, seed=0)
    assert capped.samples <= 5 * query.n_tasks


def test_retained_training_tasks_serve_the_held_out_ones(tmp_path):
    """Retain: a revised training task becomes a case; a held-out task whose nearest case it is acts
    with that task's revised layout (mapped back exactly), at zero samples. Without retain, or with
    nothing revised (polish_samples=0), only library cases are retrieved."""
    path = tmp_path / "fan.json"
    build_library([Problem(load_case_spec("fan_small").with_tasks([0, 3]))], budget=100, path=path)
    query = load_problem("wing_panel_small")
    train = [0, 2]
    on = CaseBasedReasoning(library=str(path)).solve(query, 20 * len(train), seed=0, train_tasks=train)
    assert on.info["retained"] == len(train) and on.samples == 20 * len(train)
    firsts = {t: on.info["neighbours"][t][0] for t in on.held_out.tolist()}
    assert all(name.startswith("retained:") for name in firsts.values()), firsts
    for t, name in firsts.items():
        source = int(name.rsplit("task", 1)[1])
        assert source in train and np.array_equal(on.layouts[t], on.layouts[source])
    for cfg in ({"retain": False}, {"polish_samples": 0}):
        off = CaseBasedReasoning(library=str(path), **cfg).solve(query, 20 * len(train), seed=0, train_tasks=train)
        assert off.info["retained"] == 0
        assert not any(n.startswith("retained:") for row in off.info["neighbours"] for n in row)


def test_retained_quota_keeps_the_library_neighbours(tmp_path):
    """retained_k = n: every task retrieves its k nearest library cases and, beside them, at most n of the
    run's retained cases (task t has t of them); merged (0), k neighbours in all; a negative quota is refused."""
    path = tmp_path / "fan.json"
    build_library([Problem(load_case_spec("fan_small").with_tasks([0, 3]))], budget=100, path=path)
    query = load_problem("wing_panel_small")
    k = 2
    for quota in (1, 3):
        r = CaseBasedReasoning(library=str(path), k=k, retained_k=quota).solve(query, 10 * query.n_tasks, seed=0)
        for t, names in enumerate(r.info["neighbours"]):
            own = [n for n in names if n.startswith("retained:")]
            assert len(names) - len(own) == k and len(own) == min(t, quota), (t, names)
    merged = CaseBasedReasoning(library=str(path), k=k, retained_k=0).solve(query, 10 * query.n_tasks, seed=0)
    assert all(len(names) == k for names in merged.info["neighbours"])
    with pytest.raises(PlannerError, match="retained_k"):
        CaseBasedReasoning(library=str(path), retained_k=-1).solve(query, 40, seed=0)


def test_bootstrap_library_is_built_once_into_the_runs_cache(tmp_path, monkeypatch):
    """Where a disk cache is named, the bootstrap library is stored there and a later process loads it
    instead of solving every task again (the same library); a damaged entry is rebuilt, not trusted;
    without a cache nothing is written."""
    from fixbench.cases import cache
    from fixbench.solvers.knowledge import cbr

    monkeypatch.setenv(cache.ENV, "off")
    plain = cbr.bootstrap_library(("fan_small",), 3)
    monkeypatch.setenv(cache.ENV, str(tmp_path))
    built = cbr.bootstrap_library(("fan_small",), 3)
    assert built == plain
    [stored] = cache.entries()
    assert "cbr case library" in stored["description"]

    def no_build(*args, **kwargs):
        raise AssertionError("built again")
    monkeypatch.setattr(cbr, "build_library", no_build)
    assert cbr.bootstrap_library(("fan_small",), 3) == built  # loaded, not built
    with pytest.raises(AssertionError, match="built again"):
        cbr.bootstrap_library(("fan_small",), 4)  # another budget: another library
    npy = next(p for p in (tmp_path / stored["key"]).iterdir() if p.suffix == ".npy")
    npy.write_bytes(npy.read_bytes()[:-3] + b"xyz")
    with pytest.raises(AssertionError, match="built again"):  # damaged: not trusted
        cbr.bootstrap_library(("fan_small",), 3)
