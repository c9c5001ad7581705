"""MAPPO and IPPO from TorchRL's components (solvers/library_learners.py): every env step a counted sample,
the budget spent exactly, the same bits from the same seed, and better than random search with the same
budget on wing_panel_small (100 samples a position)."""

from __future__ import annotations

import functools
import subprocess
import sys
from importlib.util import find_spec

import numpy as np
import pytest

from fixbench.cases.problem import Problem, load_problem
from fixbench.solvers import PlannerError, get

needs_torchrl = pytest.mark.skipif(find_spec("torchrl") is None,
                                   reason="torchrl is not installed (pip install 'fixbench[marl]')")
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore::DeprecationWarning")

LEARNERS = ["mappo", "ippo"]
CASE, PER_TASK, SEEDS = "wing_panel_small", 100, (0, 1, 2)


@functools.cache
def problem() -> Problem:
    p = load_problem(CASE)
    p.oracle.prepare()
    return p


@functools.cache
def run(name: str, seed: int):
    return get(name)().solve(problem(), PER_TASK * problem().n_tasks, seed=seed)


@needs_torchrl
@pytest.mark.parametrize("name", LEARNERS)
def test_spends_exactly_its_budget_and_repeats_bit_for_bit(name):
    first, again = run(name, 0), get(name)().solve(problem(), PER_TASK * problem().n_tasks, seed=0)
    assert first.samples == PER_TASK * problem().n_tasks == first.info["steps"]
    assert first.trace[-1, 2] == first.samples  # every step went through the run's counted evaluator
    np.testing.assert_array_equal(first.policy_layouts, again.policy_layouts)
    np.testing.assert_array_equal(first.trace, again.trace)
    assert first.info["step_max_u"] == again.info["step_max_u"] and first.info["batch_loss"] == again.info["batch_loss"]
    other = run(name, 1)
    assert first.info["step_max_u"] != other.info["step_max_u"]  # the seed matters


@needs_torchrl
@pytest.mark.parametrize("name", LEARNERS)
def test_beats_random_search_with_the_same_budget(name):
    """Mean over seeds of the mean over positions of the best max deformation evaluated (the incumbents)."""
    budget = PER_TASK * problem().n_tasks
    learner = np.mean([run(name, s).objective for s in SEEDS])
    random = np.mean([get("random")().solve(problem(), budget, seed=s).objective for s in SEEDS])
    assert learner < random, (learner, random)


@needs_torchrl
@pytest.mark.parametrize("name", LEARNERS)
def test_a_budget_under_one_episode_is_refused_in_one_line(name):
    with pytest.raises(PlannerError, match=f"^planner '{name}': budget too small: one episode needs 4 samples"):
        get(name)().solve(problem(), problem().n_tasks - 1, seed=0)


@needs_torchrl
def test_a_remainder_under_one_episode_is_left_unspent():
    result = get("mappo")(episodes=3).solve(problem(), 2 * problem().n_tasks + 3, seed=0)
    assert result.samples == 2 * problem().n_tasks and result.info["budget_limited"]


def test_without_torchrl_the_registry_imports_and_the_planner_refuses_in_one_line():
    code = ("import sys\nsys.modules['torchrl'] = None\n"
            "from fixbench.cases.problem import load_problem\nfrom fixbench.solvers import PlannerError, get\n"
            "try:\n    get('mappo')().solve(load_problem('fan_small', agents=2), 100, seed=0)\n"
            "except PlannerError as exc:\n    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out == ("planner 'mappo' needs TorchRL and tensordict, which do not import here: "
                   "pip install 'fixbench[marl]'\n")
