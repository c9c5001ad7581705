"""The qp planner: valid layouts, exact sample accounting, budget, determinism, revision, beats random."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import load_problem
from fixbench.solvers.base import PlannerError
from fixbench.solvers.math_programming.qp import QPPlanner
from fixbench.solvers.search.random_search import RandomSearch

READS = 3 * 84  # fan_small: 84 candidates, bending (1 row) + membrane (2 rows)
FREE = 2 * 6  # one unconstrained response per field and task


@pytest.fixture(scope="module")
def fan():
    return load_problem("fan_small")


def test_rounding_alone_costs_exactly_the_reads(fan):
    r = QPPlanner(polish_samples=0).solve(fan, None, seed=0)
    assert r.samples == READS + FREE
    assert r.info["compliance_samples"] == READS and r.info["unconstrained_samples"] == FREE
    assert set(r.info["qp_status"]) == {"optimal"}
    fan.check_layouts(r.layouts)
    assert len(r.trace) == 0  # nothing evaluated: the harness scores the rounded layouts


def test_polish_is_counted_and_bounded(fan):
    r = QPPlanner(polish_samples=10).solve(fan, None, seed=0)
    polished = r.samples - READS - FREE
    assert 0 < polished <= 6 * 10
    assert r.trace[-1, 2] == r.samples  # the evaluator's total agrees with the trace


def test_budget_never_exceeded_and_too_small_refused(fan):
    r = QPPlanner().solve(fan, 300, seed=0)
    assert r.samples <= 300
    with pytest.raises(PlannerError, match="budget too small"):
        QPPlanner().solve(fan, 15, seed=0)  # one candidate an agent (9 reads) + 12 responses


@pytest.mark.parametrize("budget, kept", [(100, 5), (600, 28)])
def test_reads_take_at_most_their_share_of_the_budget(fan, budget, kept):
    """A budget too small to read every candidate screens the sets further (max_read_share of it,
    half by default) instead of refusing: at 100 samples 5 candidates an agent (45 reads), at 600
    all 28 (252 reads)."""
    r = QPPlanner().solve(fan, budget, seed=0)
    assert r.info["candidates_per_agent"] == [kept] * 3
    assert r.info["compliance_samples"] == 3 * 3 * kept <= budget / 2
    assert r.samples == budget  # what the reads leave is spent on polish and revision
    fan.check_layouts(r.layouts)
    assert QPPlanner(max_read_share=1.0).solve(fan, 300, seed=0).info["candidates_per_agent"] == [28] * 3


def test_same_seed_same_result(fan):
    a, b = (QPPlanner(polish_samples=8).solve(fan, None, seed=3) for _ in range(2))
    assert np.array_equal(a.layouts, b.layouts) and a.samples == b.samples


def test_shared_mode(fan):
    r = QPPlanner(polish_samples=4).solve(fan, None, seed=0, mode="shared")
    assert (r.layouts == r.layouts[0]).all()
    assert r.samples <= READS + FREE + 4 * fan.n_tasks


def test_beats_random_at_equal_budget(fan):
    """On fan_small qp's polished layouts are the proven optima (checked by enumeration in the
    closing benchmark); random search with the same total budget is about 2x worse."""
    q = QPPlanner().solve(fan, None, seed=0)
    rand = np.mean([RandomSearch().solve(fan, q.samples, seed=s).max_deformation.mean() for s in range(3)])
    assert q.max_deformation.mean() < 0.8 * rand


def test_revision_spends_the_budget_and_improves_on_the_pools():
    """What the pools' descent leaves of a task's share goes to local's search from its layout: the
    whole budget is spent and the result is better than stopping at the pools' optimum."""
    spar = load_problem("wing_spar_small")
    full = QPPlanner().solve(spar, 1200, seed=0)
    pools = QPPlanner(polish_samples=40).solve(spar, 1200, seed=0)
    assert full.samples == 1200 and pools.samples < 1200
    assert full.max_deformation.mean() < 0.95 * pools.max_deformation.mean()
    spar.check_layouts(full.layouts)
