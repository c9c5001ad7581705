"""The ``optuna`` planner: TPE over the agents' candidates, counted, seeded, in every track."""

from __future__ import annotations

import logging
import warnings

import numpy as np
import optuna
import pytest

from fixbench.cases import load_case_spec, load_problem
from fixbench.cases.problem import Problem
from fixbench.solvers import PlannerError, TracedEvaluator, get
from fixbench.solvers.transfer import nearest_tasks


@pytest.fixture(scope="module")
def problem():
    return load_problem("fan_small")  # 6 tasks, 3 agents of 28 candidates


def per_task_best(result, n_tasks: int) -> list[float]:
    return [min(r[3] for r in result.trace if r[0] == t) for t in range(n_tasks)]


def test_budget_spent_exactly_and_best_layouts_returned(problem):
    budget = 30 * problem.n_tasks + 4  # shares of 31 and 30
    r = get("optuna")().solve(problem, budget, seed=0)
    assert r.samples == budget == sum(r.info["n_eval"])
    assert r.info["n_eval"] == [31] * 4 + [30] * 2
    assert (r.trace[:, 2] <= budget).all()
    problem.check_layouts(r.layouts)
    assert np.allclose(r.max_deformation, per_task_best(r, problem.n_tasks), rtol=1e-12)
    with pytest.raises(PlannerError, match="budget too small"):
        get("optuna")().solve(problem, problem.n_tasks - 1, seed=0)


def test_same_seed_same_result(problem):
    a, b, c = (get("optuna")().solve(problem, 12 * problem.n_tasks, seed=s) for s in (3, 3, 4))
    np.testing.assert_array_equal(a.layouts, b.layouts)
    np.testing.assert_array_equal(a.trace, b.trace)
    assert a.info == b.info
    assert not np.array_equal(a.trace[:, 3], c.trace[:, 3]), "another seed, another search"


def test_shared_mode(problem):
    budget = 25 * problem.n_tasks + 5
    r = get("optuna")().solve(problem, budget, seed=1, mode="shared")
    assert r.samples == 25 * problem.n_tasks and r.info["n_eval"] == [r.samples]
    assert (r.layouts == r.layouts[0]).all()
    shared = r.trace[r.trace[:, 0] == -1]
    assert r.objective == pytest.approx(shared[:, 3].min(), rel=1e-12) == r.max_deformation.max()


def test_held_out_track(problem):
    train = [0, 2, 4]
    r = get("optuna")().solve(problem, 20 * len(train), seed=0, train_tasks=train)
    assert r.samples == 60 and set(r.trace[:, 0].astype(int)) == set(train)
    assert r.info["held_out_from"] and list(r.scored_tasks) == [1, 3, 5]
    for t in (1, 3, 5):
        src = int(nearest_tasks(problem, np.array(train), t, 1)[0])
        assert (r.layouts[t] == r.layouts[src]).all()


def test_transfer_starts_each_task_from_its_nearest_solved_tasks(problem, monkeypatch):
    calls = []
    evaluate = TracedEvaluator.evaluate

    def spy(self, task, layouts, soft_power=None):
        calls.append((int(task), np.atleast_2d(layouts).copy(), self.best_layout.copy(), self.best.copy()))
        return evaluate(self, task, layouts, soft_power)

    monkeypatch.setattr(TracedEvaluator, "evaluate", spy)
    r = get("optuna")(transfer=1).solve(problem, 15 * problem.n_tasks, seed=0)
    assert r.samples == 15 * problem.n_tasks
    for t in range(1, problem.n_tasks):
        task, layout, best_layout, best = next(c for c in calls if c[0] == t)  # the task's first trial
        solved = np.flatnonzero(np.isfinite(best))
        src = int(nearest_tasks(problem, solved, t, 1)[0])
        assert (layout[0] == best_layout[src]).all(), t


def test_allowance_covering_the_space_evaluates_every_layout_once():
    p = Problem(load_case_spec("fan_small", n_agents=2).with_tasks([0]))
    r = get("optuna")().solve(p, p.joint_size + 100, seed=0)
    assert r.samples == p.joint_size and r.info["trials"] == [0]
    every = np.stack(np.meshgrid(*p.action_sets, indexing="ij"), axis=-1).reshape(-1, 2)
    assert r.max_deformation[0] == pytest.approx(p.deformation(p.oracle.evaluate(0, every)).max_u.min(), rel=1e-12)


def test_optuna_logging_is_quiet_and_restored(problem):
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append
    logger = logging.getLogger("optuna")  # optuna's library logger (it does not propagate)
    logger.addHandler(handler)
    optuna.logging.set_verbosity(optuna.logging.INFO)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            get("optuna")().solve(problem, 3 * problem.n_tasks, seed=0)
        assert optuna.logging.get_verbosity() == optuna.logging.INFO, "the user's verbosity is restored"
        optuna.create_study()  # what the planner silenced: one INFO line a study
    finally:
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        logger.removeHandler(handler)
    assert [r.levelno for r in records] == [logging.INFO], [r.getMessage() for r in records]
    assert not [w for w in caught if issubclass(w.category, optuna.exceptions.ExperimentalWarning)]
