"""The exact planner: enumeration equals brute force by direct FE solves; the MILP equals enumeration."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import load_problem
from fixbench.cases.problem import decode_layouts as decode
from fixbench.solvers import PlannerError, get

POINTS = ("points_mm = [[100, 50], [100, 150], [200, 50], [200, 150], [300, 50], [300, 150]]",
          "points_mm = [[100, 50], [100, 150], [150, 100], [200, 50], [200, 150], [250, 100], "
          "[300, 50], [300, 150], [350, 150], [350, 50]]")


@pytest.fixture
def tiny(plate_toml):
    """10 candidates, 2 agents of 5 (25 layouts), 3 drilling tasks, both fields loaded."""
    return load_problem(plate_toml(POINTS, name="tiny.toml"))


@pytest.fixture
def tiny_bending(plate_toml):
    """As tiny, loaded out of plane only: |u| = |w|, so the MILP's norm is exact."""
    return load_problem(plate_toml(POINTS, ("force_N = [10, 0, -100]", "force_N = [0, 0, -100]"),
                                   name="tiny_bending.toml"))


def brute_force(problem):
    """max |u| of every layout of every task, by direct constrained FE solves: (tasks, layouts)."""
    layouts = decode(problem.action_sets, 0, problem.joint_size)
    return layouts, np.array([[problem.direct_deformation(t, [L]).max_u[0] for L in layouts]
                              for t in range(problem.n_tasks)])


def test_decode_covers_the_joint_space(tiny):
    layouts = decode(tiny.action_sets, 0, tiny.joint_size)
    assert len(np.unique(layouts, axis=0)) == tiny.joint_size
    tiny.check_layouts(layouts)
    assert (decode(tiny.action_sets, 7, 12) == layouts[7:12]).all()


def test_enumeration_equals_brute_force(tiny):
    layouts, values = brute_force(tiny)
    n = tiny.joint_size * tiny.n_tasks
    per_task = get("exact")(chunk=7).solve(tiny, budget=n, mode="per-task")
    assert per_task.samples == n
    assert per_task.info == {"method": "enumeration", "proven": True, "gap": 0.0}
    np.testing.assert_allclose(per_task.max_deformation, values.min(axis=1), rtol=1e-9)
    shared = get("exact")(chunk=7).solve(tiny, budget=n, mode="shared")
    assert shared.samples == n
    np.testing.assert_allclose(shared.max_deformation.max(), values.max(axis=0).min(), rtol=1e-9)
    assert (shared.layouts == layouts[np.argmin(values.max(axis=0))]).all()


def test_enumeration_refuses_a_small_budget(tiny):
    with pytest.raises(PlannerError, match="budget too small"):
        get("exact")().solve(tiny, budget=tiny.joint_size * tiny.n_tasks - 1)


@pytest.mark.parametrize("mode", ["per-task", "shared"])
def test_milp_equals_enumeration_when_only_w_is_measured(tiny_bending, mode):
    p = tiny_bending
    truth = get("exact")().solve(p, None, mode=mode)
    milp = get("exact")(max_enumeration=1).solve(p, None, mode=mode)
    assert milp.info["method"] == "milp" and milp.info["proven"] and milp.info["big_m_ok"]
    np.testing.assert_allclose(milp.max_deformation, truth.max_deformation, rtol=1e-7)
    columns = sum(fo.per for fo in p.oracle.fields.values()) * 10
    assert milp.samples == columns + len(p.oracle.fields) * p.n_tasks + p.n_tasks


def test_milp_bound_brackets_the_optimum(tiny):
    """Both fields loaded: the dual bound is below the true optimum, the layout's value above it."""
    truth = get("exact")().solve(tiny, None)
    milp = get("exact")(max_enumeration=1).solve(tiny, None)
    lower = np.array(milp.info["lower_bound"])
    assert (lower <= truth.max_deformation * (1 + 1e-7)).all()
    assert (milp.max_deformation >= truth.max_deformation * (1 - 1e-12)).all()
    assert (milp.max_deformation * (1 - np.array(milp.info["gaps"])) <= lower * (1 + 1e-9)).all()
    assert milp.info["proven"] == (milp.info["gap"] <= get("exact").Config().proven_gap)
    strict = get("exact")(max_enumeration=1, proven_gap=-1.0).solve(tiny, None)  # nothing is proven
    assert not strict.info["proven"] and strict.info["gap"] == milp.info["gap"]


def test_milp_refuses_too_many_columns(tiny):
    with pytest.raises(PlannerError, match="max_milp_columns"):
        get("exact")(max_enumeration=1, max_milp_columns=10).solve(tiny, None)
