"""m fixtures per robot (issue 14, item 1): pair end effectors, m independent pads, idle robots and a
pad limit (n robots for m != n fixtures), through the case format, the oracle, every planner, the
MILP and the learners' factored heads."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
import torch

from fixbench.cases import FixbenchError
from fixbench.cases.problem import Problem, load_problem
from fixbench.cases.spec import parse_case
from fixbench.solvers import available, get
from fixbench.solvers.learners.marl_engine import Learner, _q_row

PAIR = 'fixtures_per_agent = 2\neffector = "pair"\nspan_mm = 150\n'
IDLE = "idle = true\npads = 1\n"
THREE = "fixtures_per_agent = 3\n"


def _plate(extra: str, count: int = 2) -> Problem:
    from conftest import PLATE

    text = PLATE.replace("[agents]\ncount = 2\n", f"[agents]\ncount = {count}\n" + extra)
    return Problem(parse_case(tomllib.loads(text), "plate.toml"))


def test_pair_options_are_the_pairs_within_the_span_and_apart_by_two_radii():
    p = _plate(PAIR)
    # agent 0 holds (100,50), (100,150), (200,50) mm: all three pairs are 100-141 mm apart
    assert p.options.tolist() == [[0, 1], [0, 2], [1, 2], [3, 4], [3, 5], [4, 5]]
    short = _plate(PAIR.replace("150", "110"))  # the 141 mm diagonal is out of reach
    assert short.options.tolist() == [[0, 1], [0, 2], [3, 5], [4, 5]]
    assert p.points.shape == (6, 4)
    np.testing.assert_allclose(p.points[1], [0.1, 0.05, 0.2, 0.05])


@pytest.mark.parametrize("extra, problem", [
    ('effector = "pair"\nspan_mm = 100\n', "a pair effector places 2 pads"),
    ('fixtures_per_agent = 2\neffector = "pair"\n', "needs its span"),
    ("span_mm = 100\n", "only a pair effector has a span"),
    ("pads = 2\n", "is no limit"),
    ("fixtures_per_agent = 4\n", "fewer than its 4 pads"),
    ('fixtures_per_agent = 2\neffector = "pair"\nspan_mm = 15\n', "no two candidates"),
    ('idle = "yes"\n', "must be bool"),
])
def test_bad_effector_keys_are_refused_in_one_line(extra, problem):
    with pytest.raises(FixbenchError, match=problem) as exc:
        _plate(extra)
    assert "\n" not in str(exc.value) and "agents" in str(exc.value)


def test_pads_are_handed_out_in_robot_order_up_to_the_limit():
    p = _plate(IDLE)  # 2 robots, 1 pad; actions 0-2 / 4-6 candidates, 3 / 7 idle
    assert p.pads([[0, 4], [3, 4], [0, 7], [3, 7]]).tolist() == [[0, -1], [-1, 3], [0, -1], [-1, -1]]
    # the oracle leaves a pad out exactly as the direct solve without it
    for lay in ([0, 4], [3, 4], [3, 7]):
        np.testing.assert_allclose(p.measure(0, [lay])[0, 3], p.direct_deformation(0, lay).max_u[0], rtol=1e-9)


def test_three_pads_a_robot_match_the_direct_solve():
    p = _plate(THREE)
    assert p.options.tolist() == [[0, 1, 2], [3, 4, 5]] and p.joint_size == 1
    np.testing.assert_allclose(p.measure(1, [[0, 1]])[0, 3], p.direct_deformation(1, [0, 1]).max_u[0], rtol=1e-9)


@pytest.mark.parametrize("extra", [PAIR, IDLE])
@pytest.mark.parametrize("name", sorted(available()))
def test_every_planner_places_feasible_pads_within_its_budget(extra, name):
    p = _plate(extra)
    quick = {"nashq": {"episodes": 3}, "iql": {"episodes": 3}}.get(name, {})
    first = get(name)(**quick).solve(p, 200, seed=3)
    for a, allowed in enumerate(p.action_sets):
        assert np.isin(first.layouts[:, a], allowed).all()
    zero_sample = name == "rules"  # acts from fixturing rules alone
    assert (first.samples == 0 if zero_sample else 0 < first.samples <= 200) and np.all(first.max_deformation > 0)
    again = get(name)(**quick).solve(p, 200, seed=3)
    np.testing.assert_array_equal(first.layouts, again.layouts)


@pytest.mark.parametrize("extra", [PAIR, IDLE, ""])
def test_milp_over_actions_equals_enumeration(extra):
    p = _plate(extra)
    enum = get("exact")().solve(p, None, seed=0)
    milp = get("exact")(max_enumeration=0).solve(p, None, seed=0)
    assert enum.info["method"] == "enumeration" and milp.info["method"] == "milp"
    np.testing.assert_allclose(milp.max_deformation, enum.max_deformation, rtol=1e-7)
    assert milp.info["gap"] < 1e-7 and milp.info["big_m_ok"]


@pytest.mark.parametrize("joint", [False, True])
def test_factored_best_response_equals_brute_force_over_pad_tuples(joint):
    """An action's Q is the sum of its pads' heads; the compiled best response must pick, for each
    agent given the others, the tuple a brute force over every feasible tuple picks."""
    p = _plate('fixtures_per_agent = 2\neffector = "pair"\nspan_mm = 300\nidle = true\n', count=2)
    L = Learner(p, 16, 1, joint, torch.device("cpu"), torch.Generator().manual_seed(4))  # hidden 16, 1 sweep
    w, b = L._host_weights()
    n_tasks = p.n_tasks
    for t in range(n_tasks):
        fixed = np.array([[False, True]])
        for other in range(len(p.action_sets[1])):
            a, _, _ = L.greedy(np.array([t]), fixed, np.array([[0, other]]))
            x = L.feats_np[t]
            if L.joint:
                x = np.concatenate([x, L.pos_np[1, other]])
            q = _q_row(tuple(w + b), 0, np.ascontiguousarray(x, dtype=np.float32))
            brute = [sum(q[c] for c in L.cols_np[0, o]) for o in range(len(p.action_sets[0]))]
            assert a[0, 0] == int(np.argmax(brute))
    # the heads: one per pad, each over the robot's 3 candidates and "no pad"
    assert L.q.dims[-1].item() == 2 * 4


def test_factored_update_gradient_equals_autograd():
    p = _plate(PAIR)
    L = Learner(p, 8, 1, True, torch.device("cpu"), torch.Generator().manual_seed(0))  # hidden 8, 1 sweep
    rng = np.random.default_rng(0)
    tasks = torch.from_numpy(rng.integers(0, p.n_tasks, (2, 5)))
    acts = torch.from_numpy(rng.integers(0, 3, (2, 5, 2)))
    rew = torch.rand(2, 5, generator=torch.Generator().manual_seed(1))
    L.td_grad(tasks, acts, rew, 0.8)
    mine = L.q.flat.grad.clone()
    # autograd through the plain forward pass: Q(s, a) = sum over pads of the head outputs
    w, b = [], []
    for k, v in enumerate(L.q._views(L.q.flat.detach())):
        (w if k % 2 == 0 else b).append(v.clone().requires_grad_(True))
    x = L.inputs(L.feats[tasks], L.joint_pos(acts))
    own = L.cols[L.agent_idx[:, None], acts.gather(2, L.agent_idx[:, None, None].expand(2, 5, 1))[..., 0]]
    with torch.enable_grad():
        h = x
        for k in range(3):
            h = torch.relu(torch.baddbmm(b[k], h, w[k]))
        q = torch.baddbmm(b[3], h, w[3]).gather(2, own).sum(2)
        target = 0.2 * L.target(x).gather(2, own).sum(2) + 0.8 * rew
        torch.nn.functional.smooth_l1_loss(q, target, reduction="none").mean(dim=1).sum().backward()
    ref = torch.cat([t.grad.reshape(-1) for pair in zip(w, b) for t in pair])
    assert (ref != 0).sum() > 0.1 * ref.numel()
    torch.testing.assert_close(mine, ref, rtol=1e-5, atol=1e-7)


def test_catalog_pairs_cases():
    pairs = load_problem("wing_panel_pairs_small")
    assert pairs.n_agents == 3 and pairs.options.shape[1] == 2
    d = np.linalg.norm(pairs.candidates[pairs.options[:, 0]] - pairs.candidates[pairs.options[:, 1]], axis=1)
    assert d.max() <= 0.060 + 1e-9 and d.min() >= 0.020 - 1e-9
    assert pairs.joint_size <= 10**7  # exhaustively solvable
    shared = load_problem("wing_panel_pads_small")
    assert shared.spec.effector.pads == 3 and shared.n_agents == 4
    assert all(shared.options[s[-1]].tolist() == [-1] for s in shared.action_sets)  # every robot may idle
    more = load_problem("wing_panel_small", fixtures_per_agent=2, agents=8)
    assert more.options.shape[1] == 2 and more.n_agents == 8


@pytest.mark.parametrize("override", [{"agents": 3}, {"agents": 1, "fixtures_per_agent": 3}])
def test_fewer_robots_than_the_pad_limit_is_refused_in_one_line(override):
    """--agents (or fixtures_per_agent) that leaves the case's pad limit no limit is an error, as the
    same numbers written in the case file are, not a limit kept silently."""
    with pytest.raises(FixbenchError, match="would be no limit") as exc:
        load_problem("wing_panel_pads_small", **override)
    assert "\n" not in str(exc.value) and "wing_panel_pads_small.toml" in str(exc.value)
    assert load_problem("wing_panel_pads_small", agents=5).n_agents == 5  # still a limit: accepted
    two = load_problem("wing_panel_pads_small", agents=2, fixtures_per_agent=2)  # 4 pads > 3: accepted
    assert two.n_agents == 2 and two.spec.effector.per_agent == 2


def test_pso_on_pairs_beats_random_search():
    """pso codes a pair by its centre and the offset between its pads: its swarm spreads over the
    robot's pairs (in the pads' own coordinates most of the box is no pair, and the first population
    crowded onto the few pairs at its edge: 45.5 um against random's 40.7 um, 5 seeds). At the
    default matrix's budget, 3 seeds, it now ends below random search."""
    p = Problem(load_problem("wing_panel_pairs_small").spec.with_tasks([0, 1, 2]))
    mean = {name: np.mean([get(name)().solve(p, 600, seed=s).max_deformation.mean() for s in range(3)])
            for name in ("pso", "random")}
    assert mean["pso"] < 0.8 * mean["random"], mean
