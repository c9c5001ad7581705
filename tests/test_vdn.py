"""vdn planner: exact budget, determinism, the VDN greedy action, held-out tasks, beats random search."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers.base import PlannerError
from fixbench.solvers.encoding import task_features
from fixbench.solvers.learners.vdn import VDN, Actions, SharedQ, greedy, q_tot


@pytest.fixture(scope="module")
def small():
    return Problem(load_case_spec("wing_panel_small"))


def test_spends_exactly_its_budget_and_repeats_bit_for_bit(small):
    budget = 5 * small.n_tasks
    torch_state = torch.get_rng_state()
    first = VDN().solve(small, budget, seed=4)  # 100 episodes asked: the 5 that fit are run
    assert first.samples == budget and first.info["episodes_run"] == 5 and first.info["budget_limited"]
    assert torch.equal(torch_state, torch.get_rng_state())  # torch's global generator is not drawn from
    again = VDN().solve(small, budget, seed=4)
    np.testing.assert_array_equal(first.layouts, again.layouts)
    np.testing.assert_array_equal(first.policy_layouts, again.policy_layouts)
    for curve in ("step_max_u", "episode_loss"):
        assert first.training.values(curve).tobytes() == again.training.values(curve).tobytes()
    unlimited = VDN(episodes=3).solve(small, None, seed=0)
    assert unlimited.samples == 3 * small.n_tasks and not unlimited.info["budget_limited"]
    with pytest.raises(PlannerError, match="budget too small"):
        VDN().solve(small, small.n_tasks - 1, seed=0)


def test_greedy_joint_action_is_the_argmax_of_the_summed_q():
    """VDN's decomposition: the agents' own argmaxes are the joint argmax of Q_tot (brute force)."""
    p = Problem(load_case_spec("fan_small", n_agents=2).with_tasks([0, 5]))
    acts, feats = Actions(p), torch.tensor(task_features(p, "min-max"), dtype=torch.float32)
    q = SharedQ(feats.shape[1] + acts.rows.shape[1], 16, 2, torch.Generator().manual_seed(1))
    joint = torch.tensor(list(itertools.product(*(range(len(s)) for s in p.action_sets))))
    for t in range(p.n_tasks):
        with torch.no_grad():
            best = joint[q_tot(q, acts, feats, torch.full((len(joint),), t), joint).argmax()]
        assert greedy(q, acts, feats, np.array([t]))[0].tolist() == best.tolist()


def test_held_out_tasks_get_the_policy_and_no_sample(small):
    result = VDN(episodes=4).solve(small, 100 * small.n_tasks, seed=1, train_tasks=[0, 2])
    assert result.samples == 4 * 2 and result.info["train_tasks"] == [0, 2]
    assert result.held_out.tolist() == [1, 3] and set(result.trace[:, 0].astype(int)) == {0, 2}
    np.testing.assert_array_equal(result.layouts[[1, 3]], result.policy_layouts[[1, 3]])
