"""The PettingZoo fixture environment: API compliance on the four parts (action sets as they are and
padded with an action mask), the same info keys at reset and step, sample counting, rewards."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test
from pettingzoo.utils.conversions import parallel_to_aec

from fixbench.cases import make_env
from fixbench.cases.env import INFO_KEYS, MEASURED, UNMEASURED, PositionBatchEnv
from fixbench.cases.errors import BudgetExhausted, CaseError

TASKS = [0, 1, 2]
UNEQUAL = ["wing_panel_pairs_small", "wing_panel_small"]  # robots with action sets of different sizes


@pytest.mark.parametrize("part", ["wing_panel", "wing_spar", "bus_panel", "fan", "wing_panel_pairs_small",
                                  "wing_panel_pads_small"])
def test_pettingzoo_api_seed_and_performance_tests(part):
    """PettingZoo's own tests on every part (the real part, three of its tasks: a cheap oracle): the
    parallel API test, the seed test (same seed, same observations, rewards and infos) and the
    performance benchmark (on the AEC view of the env). One test a part, so that the part's FE model is
    built once (the process keeps it: fixbench.cases.problem's cache)."""
    from pettingzoo.test import performance_benchmark

    env = make_env(part, tasks=TASKS)
    assert env.problem.name == part and env.problem.n_tasks == 3
    parallel_api_test(env, num_cycles=20)
    assert env.samples > 0
    parallel_seed_test(lambda: make_env(part, tasks=TASKS), num_cycles=20)
    performance_benchmark(parallel_to_aec(make_env(part, tasks=TASKS)))


@pytest.mark.parametrize("part", UNEQUAL)
def test_padded_action_sets_pass_the_api_and_seed_tests(part):
    """``pad_actions=True``: one action size for all robots, PettingZoo's tests sample inside the mask."""
    env = make_env(part, tasks=TASKS, pad_actions=True)
    sizes = [len(s) for s in env.problem.action_sets]
    assert len(set(sizes)) > 1
    assert {env.action_space(a).n for a in env.possible_agents} == {max(sizes)}
    obs, _ = env.reset(seed=0)
    assert [int(obs[a]["action_mask"].sum()) for a in env.possible_agents] == sizes
    assert all(env.observation_space(a).contains(o) for a, o in obs.items())
    parallel_api_test(env, num_cycles=20)
    parallel_seed_test(lambda: make_env(part, tasks=TASKS, pad_actions=True), num_cycles=20)


def test_a_padded_action_is_refused_and_costs_nothing():
    env = make_env("wing_panel_pairs_small", tasks=TASKS, pad_actions=True)
    obs, _ = env.reset(seed=0)
    last = env.possible_agents[-1]
    masked = int(np.flatnonzero(obs[last]["action_mask"] == 0)[0])
    with pytest.raises(CaseError) as err:
        env.step({a: (masked if a == last else 0) for a in env.agents})
    assert "\n" not in str(err.value) and f"actions['{last}']" in str(err.value)
    assert env.samples == 0


def test_default_spaces_are_each_robots_own():
    env = make_env("wing_panel_pairs_small", tasks=TASKS)
    assert [env.action_space(a).n for a in env.possible_agents] == [len(s) for s in env.problem.action_sets]
    obs, _ = env.reset(seed=0)
    assert all(isinstance(o, np.ndarray) and env.observation_space(a).contains(o) for a, o in obs.items())


@pytest.mark.parametrize("pad", [False, True])
def test_reset_and_step_infos_carry_the_same_numeric_keys(pad):
    env = make_env("wing_panel_pairs_small", tasks=TASKS, pad_actions=pad)
    _, infos = env.reset(seed=0)
    seen = [infos]
    while env.agents:
        seen.append(env.step({a: 0 for a in env.agents})[-1])
    n_pads = len(seen[-1][env.possible_agents[0]]["pads"])  # 2 a robot: a fixture pair
    assert n_pads == 2 * env.problem.n_agents
    for step, infos in enumerate(seen):
        assert set(infos) == set(env.possible_agents)
        for info in infos.values():
            assert tuple(info) == INFO_KEYS
            values = [info[k] for k in MEASURED] + [info["task"], *info["layout"], *info["pads"]]
            assert all(isinstance(v, (int, float)) and np.isfinite(v) for v in values)
            assert len(info["layout"]) == env.problem.n_agents and len(info["pads"]) == n_pads
            if step == 0:  # reset: nothing evaluated yet
                assert all(info[m] == UNMEASURED for m in MEASURED) and set(info["layout"] + info["pads"]) == {-1}
                assert info["task"] == TASKS[0]
            else:
                assert all(info[m] >= 0 for m in MEASURED) and min(info["layout"]) >= 0
                assert info["task"] == TASKS[step - 1]
    a, b = env.possible_agents[:2]
    assert seen[1][a] is not seen[1][b]  # a dict each: a wrapper that pops a key from one leaves the others


@pytest.mark.parametrize("bad", [-1, 3, 2.7, "1", None, True, np.array([1, 2]), 1.0])
def test_an_action_that_is_not_an_own_index_is_refused_and_costs_nothing(bad):
    env = make_env("fan_small", tasks=TASKS)
    env.reset(seed=0)
    n = len(env.problem.action_sets[0])
    actions = {a: 0 for a in env.possible_agents}
    actions[env.possible_agents[0]] = n if isinstance(bad, int) and bad == 3 else bad
    with pytest.raises(CaseError) as err:
        env.step(actions)
    assert "\n" not in str(err.value) and "actions" in str(err.value)
    assert env.samples == 0
    ok = {a: np.int64(0) for a in env.possible_agents}  # numpy integers are fine
    env.step(ok)
    assert env.samples == 1


@pytest.fixture(scope="module")
def env():
    return make_env("wing_panel_small", tasks=TASKS, budget=4)


def test_one_sample_per_step_and_episode(env):
    obs, infos = env.reset(seed=0)
    start = env.samples
    assert set(obs) == set(env.possible_agents)
    assert all(o.dtype == np.float32 and env.observation_space(a).contains(o) for a, o in obs.items())
    steps = 0
    while env.agents:
        acts = {a: env.action_space(a).sample() for a in env.agents}
        obs, rew, term, trunc, infos = env.step(acts)
        steps += 1
        assert env.samples == start + steps
        r = set(rew.values())
        assert len(r) == 1 and 0 <= r.pop() <= 1  # one shared reward
        info = infos[env.possible_agents[0]]
        assert info["max_u"] > 0 and {"max_uxy", "max_w", "reward_bell", "layout", "task"} <= set(info)
        assert info["reward_gaussian"] == rew[env.possible_agents[0]]
    assert steps == 3 and all(term.values()) and env.agents == []
    with pytest.raises(CaseError):
        env.step(acts)
    env.reset()
    env.step({a: 0 for a in env.agents})
    with pytest.raises(BudgetExhausted):  # 4 = 3 + 1 spent; the 5th refuses and spends nothing
        env.step({a: 0 for a in env.agents})
    assert env.samples == 4


def test_shuffle_and_bell():
    env = make_env("wing_panel_small", tasks=TASKS, reward="bell", shuffle=True)
    orders = []
    for seed in (1, 1, 2):
        env.reset(seed=seed)
        order = []
        while env.agents:
            order.append(env.task)
            _, rew, _, _, infos = env.step({a: 0 for a in env.agents})
            assert rew[env.possible_agents[0]] == infos[env.possible_agents[0]]["reward_bell"]
        orders.append(order)
    assert orders[0] == orders[1] and sorted(orders[2]) == TASKS
    with pytest.raises(CaseError):
        make_env(env.problem, reward="nope")


@pytest.mark.parametrize("per_step", [1, 2, 5])
def test_the_env_batched_over_positions_sees_what_one_position_a_step_sees(per_step):
    """PositionBatchEnv: the shuffled order of FixtureEnv for the same seed, one sample an answer,
    the same measured values, the last step shorter, and the episode's end."""
    one = make_env("wing_panel_small", shuffle=True)
    batched = PositionBatchEnv(one.problem, per_step, shuffle=True)
    rng = np.random.default_rng(3)
    for seed in (7, 8):
        one.reset(seed=seed)
        first = batched.reset(seed=seed)
        assert len(first) == min(per_step, one.problem.n_tasks) and first[0] == one.task
        while not batched.done:
            tasks = batched.tasks
            acts = np.column_stack([rng.integers(0, len(s), len(tasks)) for s in one.problem.action_sets])
            out = batched.step(acts)
            for k, t in enumerate(tasks):
                assert one.task == t
                _, rew, _, _, infos = one.step({a: acts[k, i] for i, a in enumerate(one.possible_agents)})
                info = infos[one.possible_agents[0]]
                assert all(out[key][k] == info[key] for key in MEASURED)
                assert out["reward_gaussian"][k] == rew[one.possible_agents[0]]
        assert one.agents == [] and batched.samples == one.samples
    with pytest.raises(CaseError, match="episode is over"):
        batched.step(acts)


@pytest.mark.parametrize("bad", [np.array([[0, 99]]), np.array([[-1, 0]]), np.array([[0.0, 0.0]]),
                                 np.zeros((2, 2), dtype=np.int64)])
def test_the_batched_env_refuses_bad_answers_and_spends_all_or_nothing(bad):
    p = make_env("fan_small", agents=2).problem
    env = PositionBatchEnv(p, 1, budget=3)
    env.reset()
    with pytest.raises(CaseError) as err:
        env.step(bad)
    assert "\n" not in str(err.value) and "actions" in str(err.value) and env.samples == 0
    env = PositionBatchEnv(p, 4, budget=3)  # a step of 4 answers on a budget of 3: refused whole
    env.reset()
    with pytest.raises(BudgetExhausted):
        env.step(np.zeros((4, 2), dtype=np.int64))
    assert env.samples == 0
    with pytest.raises(CaseError, match="per_step"):
        PositionBatchEnv(p, 0)
