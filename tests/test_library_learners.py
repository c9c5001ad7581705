"""MAPPO, IPPO and QMIX from TorchRL's components (solvers/learners/mappo.py, ippo.py, qmix.py): every env
step a counted sample, the budget spent exactly, the same bits from the same seed, no sample on a held-out
task, and better than random search with the same budget on wing_panel_small (100 samples a position)."""

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
#: one xdist worker runs these tests (`make test`: --dist loadgroup), so each learner's runs (run(), cached) are
#: made once a session
pytestmark = [pytest.mark.filterwarnings("ignore::UserWarning", "ignore::DeprecationWarning"),
              pytest.mark.xdist_group("test_library_learners")]

LEARNERS = ["mappo", "ippo", "qmix"]
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
    for curve in ("step_max_u", "batch_loss"):
        assert first.training.values(curve).tobytes() == again.training.values(curve).tobytes()
    other = run(name, 1)
    assert first.training.values("step_max_u").tobytes() != other.training.values("step_max_u").tobytes()  # seed


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
@pytest.mark.parametrize("name", LEARNERS)
def test_held_out_tasks_get_no_sample_and_the_policys_layouts(name):
    train = [0, 2]
    result = get(name)(episodes=3).solve(problem(), 3 * len(train), seed=1, train_tasks=train)
    assert result.samples == 3 * len(train) and set(result.trace[:, 0].astype(int)) == set(train)
    assert result.info["train_tasks"] == train and result.info["held_out_tasks"] == [1, 3]
    assert set(result.training.values("step_task")) == set(train)
    np.testing.assert_array_equal(result.layouts[[1, 3]], result.policy_layouts[[1, 3]])


@needs_torchrl
def test_qmix_plays_each_robots_argmax_at_epsilon_0_and_random_layouts_at_epsilon_1():
    """Epsilon 0 and fewer steps than a replay minibatch (no update): every episode plays the greedy joint
    action, the layouts returned; epsilon 1: each step a random layout of the robots' own actions."""
    p, episodes = problem(), 5
    greedy = get("qmix")(episodes=episodes, eps_start=0.0, eps_end=0.0, batch=64).solve(
        p, episodes * p.n_tasks, seed=0)
    assert greedy.info["updates"] == 0
    tasks = greedy.training.values("step_task")[:p.n_tasks].astype(int)
    policy_u = [p.measure(t, greedy.policy_layouts[t:t + 1])[0, 3] for t in tasks]
    np.testing.assert_allclose(greedy.training.values("step_max_u").reshape(episodes, -1),
                               np.tile(policy_u, (episodes, 1)), rtol=1e-6)
    explored = get("qmix")(episodes=episodes, eps_start=1.0, eps_end=1.0).solve(p, episodes * p.n_tasks, seed=0)
    assert len(set(explored.training.values("step_max_u").tolist())) > p.n_tasks


@needs_torchrl
def test_a_remainder_under_one_episode_is_left_unspent():
    result = get("mappo")(episodes=3).solve(problem(), 2 * problem().n_tasks + 3, seed=0)
    assert result.samples == 2 * problem().n_tasks and result.info["budget_limited"]


@pytest.mark.parametrize("name", ["mappo", "qmix"])
def test_without_torchrl_the_registry_imports_and_the_planner_refuses_in_one_line(name):
    code = ("import sys\nsys.modules['torchrl'] = None\n"
            "from fixbench.cases.problem import load_problem\nfrom fixbench.solvers import PlannerError, get\n"
            f"try:\n    get('{name}')().solve(load_problem('fan_small', agents=2), 100, seed=0)\n"
            "except PlannerError as exc:\n    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out == (f"planner '{name}' needs TorchRL and tensordict, which do not import here: "
                   "pip install 'fixbench[marl]'\n")
