"""The pymoo planners ``ga`` and ``pso``: valid layouts, exact budgets, seeds, shared mode, quality."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import load_case_spec, load_problem
from fixbench.cases.problem import Problem
from fixbench.solvers.base import PlannerError
from fixbench.solvers.search.ga import GeneticPlanner
from fixbench.solvers.search.pso import SwarmPlanner
from fixbench.solvers.search.random_search import RandomSearch

PLANNERS = {"ga": GeneticPlanner, "pso": SwarmPlanner}


def get(name):
    return {"random": RandomSearch, **PLANNERS}[name]


@pytest.fixture(scope="module")
def fan():
    return load_problem("fan_small")


@pytest.fixture(scope="module")
def wing():
    return Problem(load_case_spec("wing_panel_small").with_tasks([0, 1]))


def _valid(problem, layouts):
    assert layouts.shape == (problem.n_tasks, problem.n_agents)
    for a, s in enumerate(problem.action_sets):
        assert np.isin(layouts[:, a], s).all()


@pytest.mark.parametrize("name", PLANNERS)
@pytest.mark.parametrize("budget", [6, 100, 437, 1000])
def test_per_task_valid_and_within_budget(fan, name, budget):
    """Budgets below one population, not a multiple of it, and several generations: spent exactly."""
    r = get(name)().solve(fan, budget, seed=1)
    _valid(fan, r.layouts)
    assert r.samples == budget
    assert sum(r.info["n_eval"]) == budget and len(r.info["generations"]) == fan.n_tasks
    # the returned layout of each task is the best one the planner evaluated on it
    best = [r.trace[r.trace[:, 0] == t, -1].min() for t in range(fan.n_tasks)]
    np.testing.assert_allclose(r.max_deformation, best, rtol=1e-12)


@pytest.mark.parametrize("name", PLANNERS)
def test_shared_mode(wing, name):
    budget = 2 * 123 + 1  # 123 shared layouts fit; the odd sample is left
    r = get(name)(pop_size=40)
    r = r.solve(wing, budget, seed=0, mode="shared")
    _valid(wing, r.layouts)
    assert (r.layouts == r.layouts[0]).all()
    assert r.samples == budget - 1 and r.info["n_eval"] == [budget - 1]
    assert r.trace[r.trace[:, 0] == -1, -1].min() == pytest.approx(r.max_deformation.max(), rel=1e-12)


@pytest.mark.parametrize("name", PLANNERS)
def test_seeds(fan, name):
    runs = [get(name)().solve(fan, 300, seed=s).layouts for s in (3, 3, 4)]
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


@pytest.mark.parametrize("name", PLANNERS)
def test_too_small_budget(fan, name):
    with pytest.raises(PlannerError, match="budget too small"):
        get(name)().solve(fan, fan.n_tasks - 1, seed=0)
    with pytest.raises(PlannerError, match="budget too small"):
        get(name)().solve(fan, fan.n_tasks - 1, seed=0, mode="shared")


def test_unlimited_budget_uses_evals_per_task(fan):
    r = get("ga")(evals_per_task=60, pop_size=20).solve(fan, None, seed=0)
    assert r.info["n_eval"] == [60] * fan.n_tasks


def test_beat_random_search(wing):
    """At 0.2 % of the joint space per task, both beat uniform random search on average."""
    budget = int(0.002 * wing.joint_size * wing.n_tasks)
    mean = {name: np.mean([get(name)().solve(wing, budget, seed=s).objective for s in range(3)])
            for name in ("random", *PLANNERS)}
    assert mean["ga"] < mean["random"] and mean["pso"] < mean["random"], mean
