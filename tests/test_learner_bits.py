"""The Q-learners' shared pieces (solvers/learners/common.py) keep their contracts: the config fields and
defaults committed runs hash, the budget as whole episodes, the two epsilon schedules in their units,
the training split, the replay ring, the nashq engine's inputs from solvers/encoding.py,
and on every run: the same seed gives the same bits, the budget is spent exactly, held-out tasks get
no sample, the info keys every learner emits and the curves it declares (Figure 4's among them) are there."""

from __future__ import annotations

import math
from dataclasses import asdict, fields

import numpy as np
import pytest
import torch

from fixbench.bench.reporting.figures import FIGURE4_CURVES
from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers.base import PlannerError, TracedEvaluator
from fixbench.solvers.encoding import pad_coordinates, task_features
from fixbench.solvers.learners.common import (
    LearnerConfig,
    QLearnerConfig,
    Replay,
    episodes_that_fit,
    epsilon_by_run_fraction,
    epsilon_by_step,
    train_ids,
    train_split,
)
from fixbench.solvers.learners.mappo import PPOConfig
from fixbench.solvers.learners.marl_engine import Learner
from fixbench.solvers.learners.nashq import NashQConfig
from fixbench.solvers.learners.vdn import VDNConfig
from fixbench.solvers.registry import get

LEARNERS = ("nashq", "iql", "vdn")
#: every learner, one position a step and several (the last step of an episode shorter)
RUNS = [pytest.param(name, per_step, id=f"{name}-{per_step}") for name in LEARNERS for per_step in (1, 3)]
#: every key of learners.learner_info, in every learner's info
COMMON_KEYS = {"algorithm", "episodes_run", "budget_limited", "train_tasks", "held_out_tasks", "steps",
               "time_setup_s", "time_select_s", "time_oracle_s", "time_update_s", "time_greedy_s", "time_total_s",
               "torch_threads"}
#: every curve of learners.learner_training, with its unit, in every learner's training record
COMMON_CURVES = {"step_reward": "step", "step_max_u": "step", "step_task": "step", "episode_return": "episode"}
#: the defaults committed runs hash (results/paper/matrix.toml, results/tune/*.toml name these fields)
NASHQ_DEFAULTS = {"episodes": 100, "eps_start": 0.9, "eps_end": 0.05, "eps_decay": 3500.0, "alpha": 0.8,
                  "lr": 1e-4, "batch": 32, "capacity": 1_000_000, "hidden": 256, "grad_clip": 100.0, "tau": 0.005,
                  "reward": "scaled", "scale_samples": 500, "max_sweeps": 10, "shuffle": False, "train_tasks": (),
                  "train_fraction": 1.0, "optima": (), "device": "cpu", "threads": 1, "save_path": "",
                  "positions_per_step": 1}
VDN_DEFAULTS = {"episodes": 100, "hidden": 128, "layers": 2, "lr": 3e-3, "weight_decay": 1e-4, "batch": 64,
                "update_every": 1, "capacity": 1_000_000, "eps_start": 0.9, "eps_end": 0.05, "eps_decay": 0.2,
                "scale_samples": 500, "shuffle": False, "train_tasks": (), "train_fraction": 1.0,
                "greedy_chunk": 32, "threads": 1, "positions_per_step": 1}
#: small networks and batches, so that a few episodes update the networks
QUICK = {"hidden": 16, "batch": 4}


@pytest.fixture(scope="module")
def small():
    return Problem(load_case_spec("wing_panel_small"))




def test_config_fields_and_defaults_are_those_committed_runs_hash():
    assert {f.name: getattr(NashQConfig(), f.name) for f in fields(NashQConfig)} == NASHQ_DEFAULTS
    assert {f.name: getattr(VDNConfig(), f.name) for f in fields(VDNConfig)} == VDN_DEFAULTS
    shared = {f.name for f in fields(QLearnerConfig)}
    assert {f.name for f in fields(LearnerConfig)} <= {f.name for f in fields(PPOConfig)}
    assert shared <= set(NASHQ_DEFAULTS) & set(VDN_DEFAULTS)
    assert all(NASHQ_DEFAULTS[k] == VDN_DEFAULTS[k] for k in shared)
    # the hash covers every field by name, whatever the order the base class puts them in
    assert NashQConfig().hash() == NashQConfig(**asdict(NashQConfig())).hash()
    assert NashQConfig(eps_decay=100.0).hash() != NashQConfig().hash()
    # a field added later is hashed only away from the value that does what the committed runs did
    for cls in (NashQConfig, VDNConfig):
        assert cls.hash_omits == {"positions_per_step": 1}
        assert cls(positions_per_step=2).hash() != cls().hash() == cls(positions_per_step=1).hash()


@pytest.mark.parametrize("cls", [NashQConfig, VDNConfig])
@pytest.mark.parametrize("field, value", [("episodes", 0), ("eps_start", 1.5), ("capacity", 0),
                                          ("scale_samples", 1), ("train_fraction", 0.0), ("train_tasks", (-1,)),
                                          ("eps_decay", 0.0), ("lr", 0.0), ("hidden", 0), ("batch", 0)])
def test_every_learner_refuses_the_same_bad_values(cls, field, value):
    with pytest.raises(PlannerError, match=field):
        cls(**{field: value})


def test_budget_buys_whole_episodes(small):
    t = small.n_tasks
    assert episodes_that_fit("x", 7, TracedEvaluator(small, None), t) == 7  # unlimited: as asked
    assert episodes_that_fit("x", 7, TracedEvaluator(small, 3 * t + t - 1), t) == 3  # the remainder unspent
    assert episodes_that_fit("x", 2, TracedEvaluator(small, 3 * t), t) == 2
    with pytest.raises(PlannerError, match=f"planner 'x': budget too small: one episode needs {t} samples, "
                                           f"{t - 1} available"):
        episodes_that_fit("x", 7, TracedEvaluator(small, t - 1), t)


def test_epsilon_schedules_in_their_units():
    assert epsilon_by_step(0, 0.9, 0.05, 3500.0) == 0.9
    assert epsilon_by_step(3500, 0.9, 0.05, 3500.0) == pytest.approx(0.05 + 0.85 / math.e)
    assert epsilon_by_step(10**6, 0.9, 0.05, 3500.0) == pytest.approx(0.05)
    steps = [epsilon_by_step(s, 0.9, 0.05, 350.0) for s in range(0, 2000, 50)]
    assert all(a > b for a, b in zip(steps, steps[1:]))
    # a fraction of the run: the same curve in any run length, at the same share of it
    for total in (100, 5000):
        assert epsilon_by_run_fraction(total // 5, total, 0.9, 0.05, 0.2) == pytest.approx(0.05 + 0.85 / math.e)
        for s in (0, 7, total - 1):
            assert epsilon_by_run_fraction(s, total, 0.9, 0.05, 0.2) == epsilon_by_step(s, 0.9, 0.05, 0.2 * total)


def test_training_split(small):
    assert train_ids(small, NashQConfig()).tolist() == list(range(small.n_tasks))
    assert train_ids(small, NashQConfig(train_tasks=(2, 0, 2))).tolist() == [0, 2]
    assert train_ids(small, NashQConfig(train_fraction=0.5)).tolist() == [0, small.n_tasks - 1]
    with pytest.raises(PlannerError, match="train_tasks must be in"):
        train_ids(small, VDNConfig(train_tasks=(small.n_tasks,)))
    held_out = TracedEvaluator(small, 10, [1])  # the held-out track's evaluator wins over the config
    assert train_split(small, held_out, NashQConfig(train_tasks=(0, 2))).tolist() == [1]


def test_replay_is_a_ring_of_its_capacity():
    replay = Replay(capacity=3, steps=10, n_agents=2)
    assert replay.cap == 3 and len(replay) == 0
    for k in range(5):
        replay.add(k, np.array([k, 10 + k]), float(k))
    assert len(replay) == 3
    assert replay.task.tolist() == [3, 4, 2] and replay.act[:, 1].tolist() == [13, 14, 12]
    tasks, acts, values = replay.sample(np.random.default_rng(0), (2, 6))
    assert tasks.shape == (2, 6) and acts.shape == (2, 6, 2) and set(tasks.ravel().tolist()) <= {2, 3, 4}
    assert torch.equal(values.long(), tasks) and torch.equal(acts[..., 0], tasks)
    assert Replay(capacity=100, steps=4, n_agents=1).cap == 4  # never more than the run's steps
    many = Replay(capacity=3, steps=10, n_agents=2)  # a batched step's rows go in as one add each would
    many.add_many(np.arange(2), np.array([[0, 10], [1, 11]]), np.arange(2.0))
    many.add_many(np.arange(2, 5), np.array([[2, 12], [3, 13], [4, 14]]), np.arange(2.0, 5.0))
    assert len(many) == 3 and all(torch.equal(getattr(many, k), getattr(replay, k)) for k in ("task", "act", "value"))
    one, once = Replay(capacity=3, steps=10, n_agents=2), Replay(capacity=3, steps=10, n_agents=2)
    for i in range(5):  # a batched step of more rows than the ring holds keeps the last ones, as one by one
        one.add(i, np.array([i, 10 + i]), float(i))
    once.add_many(np.arange(5), np.array([[i, 10 + i] for i in range(5)]), np.arange(5.0))
    assert once.added == one.added == 5
    assert all(torch.equal(getattr(once, k), getattr(one, k)) for k in ("task", "act", "value"))


def test_the_nashq_engine_takes_its_inputs_from_the_encoding_module():
    """The engine's state is the min-max task features and its action inputs the [0, 1] pad coordinates
    (their ranges: tests/test_encoding.py)."""
    p = Problem(load_case_spec("fan_small", n_agents=2))
    engine = Learner(p, 8, 2, True, torch.device("cpu"), torch.Generator().manual_seed(0))
    assert torch.equal(engine.feats, torch.tensor(task_features(p, "min-max"), dtype=torch.float32))
    pos = pad_coordinates(p, interval=(0.0, 1.0))
    for i, s in enumerate(p.action_sets):
        assert torch.equal(engine.pos[i, :len(s)], torch.tensor(pos[s], dtype=torch.float32))


@pytest.mark.parametrize("name, per_step", RUNS)
def test_same_seed_same_bits_and_exact_budget(small, name, per_step):
    budget = 4 * small.n_tasks + small.n_tasks - 1  # four episodes fit, the remainder is left unspent
    runs = [get(name)(**QUICK, positions_per_step=per_step).solve(small, budget, seed=2) for _ in range(2)]
    a, b = runs
    assert a.samples == b.samples == 4 * small.n_tasks and a.info["episodes_run"] == 4
    assert a.info["budget_limited"] and a.info["steps"] == a.samples
    np.testing.assert_array_equal(a.layouts, b.layouts)
    np.testing.assert_array_equal(a.policy_layouts, b.policy_layouts)
    assert a.max_deformation.tobytes() == b.max_deformation.tobytes()
    assert a.trace.tobytes() == b.trace.tobytes()
    untimed = [{k: v for k, v in r.info.items() if not k.startswith("time_")} for r in runs]
    assert untimed[0] == untimed[1]
    assert a.training.curves.keys() == b.training.curves.keys()
    for key, curve in a.training.curves.items():
        if not key.startswith("time_"):
            assert curve.unit == b.training.curves[key].unit
            assert curve.values.tobytes() == b.training.values(key).tobytes(), key
    other = get(name)(**QUICK, positions_per_step=per_step).solve(small, budget, seed=3)
    assert other.training.values("step_max_u").tobytes() != a.training.values("step_max_u").tobytes()  # the seed


@pytest.mark.parametrize("name, per_step", RUNS)
def test_held_out_tasks_get_no_sample_and_the_info_every_learner_emits(small, name, per_step):
    train = [0, 2]
    result = get(name)(**QUICK, positions_per_step=per_step).solve(small, 3 * len(train), seed=1, train_tasks=train)
    info = result.info
    assert result.samples == 3 * len(train) and set(result.trace[:, 0].astype(int)) == set(train)
    assert info["train_tasks"] == train and info["held_out_tasks"] == [1, 3]
    curves = result.training.curves
    assert set(curves["step_task"].values) == set(train)
    np.testing.assert_array_equal(result.layouts[[1, 3]], result.policy_layouts[[1, 3]])
    assert COMMON_KEYS <= set(info) and info["algorithm"] == name
    assert {k: curves[k].unit for k in COMMON_CURVES} == COMMON_CURVES
    assert not {k for k, v in info.items() if isinstance(v, list) and len(v) == result.samples}  # no curve in info
    assert len(curves["step_reward"].values) == len(curves["step_max_u"].values) == info["steps"] == result.samples
    assert len(curves["episode_return"].values) == info["episodes_run"] == 3
    assert np.allclose(curves["episode_return"].values, np.reshape(curves["step_reward"].values, (3, -1)).sum(axis=1))
    if name != "vdn":  # the regret curves of Figure 4 (vdn has no regret reference of its own)
        assert set(FIGURE4_CURVES) <= set(curves)
    else:  # its loss, one value an episode (NaN where no update ran)
        assert curves["episode_loss"].unit == "episode" and len(curves["episode_loss"].values) == 3
