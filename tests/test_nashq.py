"""nashq / iql planners: valid layouts within budget, determinism, held-out tasks, weights."""

from __future__ import annotations

import json

import pytest
import torch

from cases.problem import Problem, load_problem
from solvers.base import PlannerError
from solvers.nashq import load_weights
from solvers.registry import get

SMALL = dict(episodes=3, hidden=32)


@pytest.fixture(scope="module")
def problem():
    p = load_problem("wing_panel_small")
    return Problem(p.spec.with_tasks([0, 1, 3]))


@pytest.mark.parametrize("name", ["nashq", "iql"])
def test_valid_layouts_within_budget(problem, name):
    r = get(name)(**SMALL).solve(problem, budget=10, seed=0)  # 3 full episodes of 3 tasks fit
    assert r.samples == 9 and r.info["episodes_run"] == 3 and r.layouts.shape == (3, problem.n_agents)
    problem.check_layouts(r.layouts)
    json.dumps(r.info)
    i = r.info
    assert len(i["step_reward"]) == 9 and len(i["episode_return"]) == 3 and len(i["td_loss"]) == problem.n_agents
    assert all(x >= -1e-15 for x in i["episode_regret_true"])
    r = get(name)(episodes=100, hidden=32).solve(problem, budget=7, seed=0)  # best effort: 2 episodes
    assert r.samples == 6 and r.info["budget_limited"]
    with pytest.raises(PlannerError):
        get(name)(**SMALL).solve(problem, budget=2, seed=0)
    with pytest.raises(PlannerError):
        get(name)(**SMALL).solve(problem, budget=20, seed=0, mode="shared")


@pytest.mark.parametrize("name", ["nashq", "iql"])
def test_same_seed_same_curves(problem, name):
    a, b, c = (get(name)(**SMALL).solve(problem, None, seed=s) for s in (3, 3, 4))
    for key in ("step_reward", "td_loss", "episode_regret_ref"):
        assert a.info[key] == b.info[key]
    assert (a.layouts == b.layouts).all()
    assert a.info["step_reward"] != c.info["step_reward"]


def test_held_out_tasks_cost_nothing(problem):
    r = get("nashq")(train_tasks=(0, 2), **SMALL).solve(problem, None, seed=0)
    assert r.samples == 3 * 2 and r.info["held_out_tasks"] == [1]
    assert set(r.info["step_task"]) == {0, 2}
    problem.check_layouts(r.layouts)


def test_agent_counts():
    p = load_problem("wing_panel_small", agents=3)
    p = Problem(p.spec.with_tasks([0]))
    for name in ("nashq", "iql"):
        r = get(name)(episodes=2, hidden=16).solve(p, None, seed=0)
        assert r.layouts.shape == (1, 3) and r.info["greedy_converged"] in (True, False)
    p1 = Problem(load_problem("wing_panel_small", agents=1).spec.with_tasks([0]))
    r = get("nashq")(episodes=2, hidden=16).solve(p1, None, seed=0)
    assert r.layouts.shape == (1, 1)


def test_weights_round_trip(problem, tmp_path):
    path = tmp_path / "q.pt"
    get("nashq")(save_path=str(path), **SMALL).solve(problem, None, seed=0)
    net = load_weights(str(path))
    state = torch.load(path, weights_only=True)
    assert all(torch.equal(net.state_dict()[k], v) for k, v in state.items())
    x = torch.rand(problem.n_agents, 4, net.w0.shape[1])
    assert net(x).shape == (problem.n_agents, 4, max(len(s) for s in problem.action_sets))


def test_bad_device(problem):
    if torch.cuda.is_available():
        pytest.skip("CUDA present")
    with pytest.raises(PlannerError, match="CUDA"):
        get("nashq")(device="cuda", **SMALL).solve(problem, None, seed=0)



def test_figure4_panels(problem, tmp_path):
    from bench.marl import figure4

    r = get("iql")(**SMALL).solve(problem, None, seed=0)
    paths = figure4({"iql": r, "iql info": r.info}, tmp_path)
    assert len(paths) == 4 and all(p.stat().st_size > 0 for p in paths)
