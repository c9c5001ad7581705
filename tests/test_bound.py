"""Certified lower bounds (bench/references/compliance_bound.py): every node's bound is at most every
completion's value, and branch-and-bound run to the end finds exact's proven optimum."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.bench.references.compliance_bound import BoundConfig, ComplianceBound, lower_bound
from fixbench.bench.references.zone_bound import ZoneBound, ZoneConfig
from fixbench.cases.problem import Problem, decode_layouts, load_problem
from fixbench.cases.spec import case_names, load_case_spec
from fixbench.solvers import get

POINTS = ("points_mm = [[100, 50], [100, 150], [200, 50], [200, 150], [300, 50], [300, 150]]",
          "points_mm = [[100, 50], [100, 150], [150, 100], [200, 50], [200, 150], [250, 100], "
          "[300, 50], [300, 150], [350, 150], [350, 50]]")
#: what the bus panel and the pads case bring (window and rail supports, a background pressure; a pad
#: limit) is checked exhaustively on the tiny plates below, so the bounds against exact's optimum run
#: on the other small cases only: bus_panel_small builds its oracle on the bus panel's 307k-DOF mesh
#: and wing_panel_pads_small enumerates 390,625 layouts a task (3.5-5 min a test)
SMALL = [n for n in case_names() if n.endswith("_small") and n not in {"bus_panel_small", "wing_panel_pads_small"}]
#: robots per small case here: two keep enumeration and the search to the end at a second or so
AGENTS = 2
#: no time limit in these tests: the search runs to the end ...
#: ... and on the tiny case branches down to single layouts (no subtree closed by enumeration)
BRANCHING = BoundConfig(time_limit_s=1e9, enumerate_max=1)


@pytest.fixture(scope="module", params=["one pad a robot", "pad limit", "windowed"])
def tiny(request, tmp_path_factory):
    """10 candidates, 3 agents (4 x 3 x 3 = 36 layouts), 3 drilling tasks, both fields loaded; or the
    same robots each free to idle, sharing 2 pads (5 x 4 x 4 = 80 layouts); or the first with a
    simply supported window and rail and a background pressure (conftest.WINDOWED)."""
    from conftest import PLATE, windowed

    agents = "count = 3" + ("\nidle = true\npads = 2" if request.param == "pad limit" else "")
    text = PLATE.replace(*POINTS).replace("count = 2", agents)
    path = tmp_path_factory.mktemp("bound") / "tiny.toml"
    path.write_text(windowed(text) if request.param == "windowed" else text)
    return load_problem(str(path))


def values(problem, task):
    """Every layout of the joint space and its max |u| on the oracle."""
    layouts = decode_layouts(problem.action_sets, 0, problem.joint_size)
    return layouts, problem.measure(task, layouts)[:, 3]


def test_every_node_bound_is_at_most_every_completion(tiny):
    bounder = ComplianceBound(tiny)
    positive = 0
    for task in range(tiny.n_tasks):
        layouts, u = values(tiny, task)
        for depth in range(tiny.n_agents + 1):
            for prefix in np.unique(layouts[:, :depth], axis=0):
                below = (layouts[:, :depth] == prefix).all(axis=1)
                b = bounder.node(task, dict(enumerate(prefix.tolist())))
                assert 0 <= b <= u[below].min(), (task, prefix, b, u[below].min())
                positive += b > 0
    assert positive > 0  # the bound says something somewhere


def test_branch_and_bound_to_the_end_finds_the_optimum(tiny):
    bounder = ComplianceBound(tiny)
    for task in range(tiny.n_tasks):
        layouts, u = values(tiny, task)
        r = lower_bound(tiny, task, BRANCHING, bounder)
        assert r.nodes > 1
        assert r.proven and r.bound == r.best == u.min()
        assert r.root_bound <= r.bound and r.gap == 0.0
        assert tiny.measure(task, r.layout[None])[0, 3] == r.best


def test_a_time_limit_leaves_a_valid_bound(tiny):
    _, u = values(tiny, 0)
    r = lower_bound(tiny, 0, BoundConfig(time_limit_s=1e-9))
    assert not r.proven and 0 <= r.bound <= u.min()


@pytest.mark.parametrize("case", SMALL)
def test_small_cases_bound_at_most_exacts_optimum(case):
    problem = load_problem(case, agents=None if load_case_spec(case).effector.pads else AGENTS)
    exact = get("exact")().solve(problem, budget=problem.joint_size * problem.n_tasks)
    assert exact.info["method"] == "enumeration" and exact.info["proven"]
    bounder = ComplianceBound(problem)
    # the root's children are bounded, and each is closed by enumerating its completions
    one_level = BoundConfig(time_limit_s=1e9, enumerate_max=max(len(a) for a in problem.action_sets))
    for task in range(problem.n_tasks):
        r = lower_bound(problem, task, one_level, bounder)
        assert r.root_bound <= exact.max_deformation[task]
        assert r.proven and r.best == pytest.approx(exact.max_deformation[task], rel=1e-12)


@pytest.mark.parametrize("bad", [dict(time_limit_s=0), dict(safety=1), dict(enumerate_max=0), dict(scale_points=0),
                                 dict(scale_span=0.5)])
def test_config_is_checked(bad):
    with pytest.raises(ValueError, match="BoundConfig"):
        BoundConfig(**bad)


def test_every_zone_node_bound_is_at_most_every_completion(tiny):
    zones = ZoneBound(tiny)
    tasks = np.arange(tiny.n_tasks)
    positive = 0
    for k in range(tiny.n_agents):
        nodes = zones.node_bounds(k, tasks)  # (actions of robot k, tasks)
        assert nodes.shape == (len(tiny.action_sets[k]), tiny.n_tasks)
        for task in tasks:
            layouts, u = values(tiny, task)
            for i, act in enumerate(tiny.action_sets[k]):
                below = layouts[:, k] == act
                assert 0 <= nodes[i, task] <= u[below].min(), (k, act, task)
        positive += (nodes > 0).sum()
    assert positive > 0
    best = np.array([values(tiny, t)[1].min() for t in tasks])
    assert np.all(zones.bounds() <= best) and zones.bounds().max() > 0


@pytest.mark.parametrize("case", SMALL)
def test_small_cases_zone_bound_at_most_exacts_optimum(case):
    """At every case's own robots (the zones are what the robots' sets make them), on its last position
    (the proof enumerates up to 3.2 million layouts a position; every position of the tiny plates is
    checked above)."""
    spec = load_case_spec(case)
    problem = Problem(spec.with_tasks([len(spec.tasks) - 1]))
    exact = get("exact")().solve(problem, budget=problem.joint_size * problem.n_tasks)
    assert exact.info["proven"]
    zb = ZoneBound(problem).bounds()
    assert np.all(zb >= 0) and np.all(zb <= exact.max_deformation)
    assert zb.max() > 0.02 * exact.max_deformation.max()  # it bites somewhere


@pytest.mark.parametrize("bad", [dict(safety=1), dict(pivot=0), dict(scale_points=0), dict(task_chunk=0),
                                 dict(expand_max=0),
                                 dict(scale_span=0.5)])
def test_zone_config_is_checked(bad):
    with pytest.raises(ValueError, match="ZoneConfig"):
        ZoneConfig(**bad)


def test_every_zone_pair_node_bound_is_at_most_every_completion(tiny):
    zones = ZoneBound(tiny)
    positive = 0
    for task in range(tiny.n_tasks):
        layouts, u = values(tiny, task)
        for k in range(tiny.n_agents):
            for j in range(tiny.n_agents):
                if j == k:
                    continue
                nodes = zones.pair_nodes(k, j, task)
                for a, act_k in enumerate(tiny.action_sets[k]):
                    for b, act_j in enumerate(tiny.action_sets[j]):
                        below = (layouts[:, k] == act_k) & (layouts[:, j] == act_j)
                        assert 0 <= nodes[a, b] <= u[below].min(), (task, k, j, act_k, act_j)
                positive += (nodes > 0).sum()
                # a pair node clamps fewer DOFs than the one-robot node above it
                assert np.all(nodes.min(axis=1) >= zones.node_bounds(k, [task])[:, 0] * (1 - 1e-9))
    assert positive > 0
    plain = ZoneBound(tiny, ZoneConfig(pairs=False)).bounds()
    assert np.all(zones.bounds() >= plain)
