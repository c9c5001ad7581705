"""The rounds loop of the bandits (solvers/bandits/bandit.py), on a model-free run: exact budget, round 0,
the batch-size rule, task after task within a round, same seed -> same bits, no sample on a held-out
task, refusals. surrogate-ts and gp-ucb run on this loop (their own tests check their models)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers.bandits.bandit import BanditConfig, BanditRun, RoundsBandit
from fixbench.solvers.base import PlannerError, TracedEvaluator, random_layouts
from fixbench.solvers.transfer import nearest_tasks


@dataclass(frozen=True)
class ToyConfig(BanditConfig):
    batch: int = 2
    """Samples per training task per round."""

    max_rounds: int = 3
    """Most rounds after round 0."""

    transfer: int = 1
    """Warm starts from this many nearest solved tasks."""

    max_sweeps: int = 1
    """Unused: no best response."""


class ToyRun(BanditRun):
    """No model: a round proposes the task's starts, then uniform random layouts; a held-out task
    takes its start. Records when it was asked for what."""

    def __init__(self, *args):
        super().__init__(*args)
        self.fitted, self.asked = [], []

    def fit(self, rnd: int) -> None:
        self.fitted.append((rnd, self.size))

    def propose(self, tasks, counts):
        for t, c in zip(tasks.tolist(), counts.tolist()):
            self.asked.append((t, c, self.size))
            layouts = np.vstack([self.starts(t), random_layouts(self.problem, self.rng, c)])[:c]
            yield t, self.unrepeated(t, layouts)

    def act_held_out(self, held, starts):
        return starts, len(held)


class Toy(RoundsBandit):
    name = "toy-bandit"
    Config = ToyConfig
    Run = ToyRun


@pytest.fixture(scope="module")
def problem():
    return Problem(load_case_spec("wing_panel_small"))


def run(problem, budget, seed, tasks=None, **cfg):
    """The run object itself (its data and records), and what it returned (its training curves apart)."""
    ev = TracedEvaluator(problem, budget, tasks)
    r = ToyRun(ToyConfig(initial_random=3, **cfg), problem, ev, np.random.default_rng(seed))
    layouts, info, r.training_record = r.run()
    return r, ev, layouts, info


def test_rounds_spend_the_budget_exactly_in_at_most_max_rounds(problem):
    r, ev, _, info = run(problem, 2 * 13 + 1, seed=0, tasks=[0, 2])  # shares 14 and 13
    assert ev.samples == 27 and ev.task_samples[[0, 2]].tolist() == [14, 13] and info["samples_per_task"] == [14, 13]
    # round 0: 3 random layouts a task; then 11 and 10 left in 3 rounds: batch max(2, ceil(11 / 3)) = 4
    assert r.task[:6].tolist() == [0, 0, 0, 2, 2, 2]
    assert info["batch"] == 4 and info["rounds"] == 3 and [f[0] for f in r.fitted] == [0, 1, 2]
    assert [(t, c) for t, c, _ in r.asked] == [(0, 4), (2, 4), (0, 4), (2, 4), (0, 3), (2, 2)]
    # task after task: each task is asked once the tasks before it in the round are evaluated
    assert [size for _, _, size in r.asked] == [6, 10, 14, 18, 22, 25]
    assert r.size == 27
    curves = r.training_record.curves  # a value a round, round 0 first
    assert {c.unit for c in curves.values()} == {"round"} and curves["round_samples"].values.tolist() == [6, 14, 22, 27]
    assert curves["round_best_mean_u"].values[-1] == pytest.approx(ev.best[[0, 2]].mean())
    assert (np.diff(curves["round_best_mean_u"].values) <= 0).all()  # the best so far only improves
    for t in (0, 2):  # the data holds log max |u| of what the evaluator saw; no layout twice on a task
        rows = r.task[:27] == t
        assert r.y[rows].min() == np.log(ev.best[t])
        assert len(np.unique(r.act[rows], axis=0)) == rows.sum()


def test_a_small_budget_is_round_zero_alone(problem):
    r, ev, _, info = run(problem, 2 * 2, seed=0, tasks=[1, 3])
    assert ev.samples == 4 and info["rounds"] == 0 and r.fitted == [] and info["samples_per_task"] == 2


def test_same_seed_same_bits(problem):
    first = Toy(initial_random=3).solve(problem, 4 * 9 + 2, seed=4)
    again = Toy(initial_random=3).solve(problem, 4 * 9 + 2, seed=4)
    other = Toy(initial_random=3).solve(problem, 4 * 9 + 2, seed=5)
    np.testing.assert_array_equal(first.trace, again.trace)
    np.testing.assert_array_equal(first.layouts, again.layouts)
    np.testing.assert_array_equal(first.max_deformation, again.max_deformation)
    assert not np.array_equal(first.trace, other.trace)


def test_held_out_tasks_get_no_sample_and_the_runs_own_layout(problem):
    train = [0, 3]
    r, ev, layouts, info = run(problem, 2 * 8, seed=2, tasks=train)
    held = [1, 2]
    assert ev.samples == 16 and set(r.task[:r.size].tolist()) == set(train) and ev.task_samples[held].sum() == 0
    assert info["held_out_sweeps"] == len(held)
    np.testing.assert_array_equal(layouts[train], ev.best_layout[train])
    for t in held:  # act_held_out got the best layout of the nearest training task
        np.testing.assert_array_equal(layouts[t], ev.best_layout[nearest_tasks(problem, train, t, 1)[0]])


def test_refusals(problem):
    with pytest.raises(PlannerError, match="budget too small"):
        Toy().solve(problem, problem.n_tasks - 1, seed=0)
    with pytest.raises(PlannerError, match="does not support mode 'shared'"):
        Toy().solve(problem, 100, seed=0, mode="shared")
    with pytest.raises(PlannerError, match="initial_random"):
        Toy(initial_random=0)
