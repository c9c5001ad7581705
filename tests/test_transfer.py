"""Transfer between tasks (warm starts) and the held-out track (issue: the comparison).

A warm-started planner solves tasks in order and starts each from the best layouts of the nearest
solved tasks; on a drilling job whose positions are close it must never end worse, on average over
seeds, than the same planner started cold at the same budget. The held-out track lets a planner
evaluate only its training tasks: the others get layouts with zero samples.
"""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases.errors import HeldOutTask
from fixbench.cases.problem import load_problem
from fixbench.solvers import Planner, get
from fixbench.solvers.transfer import fill_held_out, nearest_tasks

CLOSE = """
[case]
extends = "wing_panel_small"
description = "test: 8 close drilling positions on the wing panel's rivet line"

[agents]
count = 3

[[tasks]]
kind = "drilling"
name = "rivet"
line_mm = [[500, 516.855], [520, 403.477]]
count = 8
force_N = [25, 0, -250]
radius_mm = 5
"""


@pytest.fixture(scope="module")
def close(tmp_path_factory):
    path = tmp_path_factory.mktemp("case") / "close.toml"
    path.write_text(CLOSE)
    return load_problem(path)


@pytest.mark.parametrize("name", ["greedy", "ga", "pso", "local"])
@pytest.mark.parametrize("per_task", [10, 40])
def test_warm_start_never_worse_than_cold(close, name, per_task):
    """Mean over seeds 0-4 of the mean max deformation on tasks 2..8, same budget."""
    def later(transfer):
        return np.mean([get(name)(transfer=transfer).solve(close, per_task * close.n_tasks, seed=s)
                        .max_deformation[1:].mean() for s in range(5)])

    cold, warm = later(0), later(3)
    assert warm <= cold, (name, per_task, cold, warm)


def test_nearest_tasks_by_features(close):
    assert nearest_tasks(close, [0, 2, 5, 7], 4, 2).tolist() == [5, 2]
    assert nearest_tasks(close, [0, 1, 7], 4, 3).tolist() == [1, 7, 0]
    assert nearest_tasks(close, [], 4, 3).tolist() == []


@pytest.mark.parametrize("name", ["random", "greedy", "ga", "pso", "local"])
def test_held_out_tasks_cost_nothing(close, name):
    train = [0, 4]
    res = get(name)().solve(close, 60, seed=1, train_tasks=train)
    assert res.samples <= 60
    assert set(np.unique(res.trace[:, 0]).astype(int)) <= set(train)
    assert res.held_out.tolist() == [1, 2, 3, 5, 6, 7]
    for t in res.held_out:  # the nearest training task's layout
        src = int(nearest_tasks(close, train, int(t), 1)[0])
        assert (res.layouts[t] == res.layouts[src]).all()
    assert res.objective == pytest.approx(res.max_deformation[res.held_out].mean())


def test_a_planner_that_peeks_at_a_held_out_task_is_refused(close):
    class Peek(Planner):
        name = "peek-test"

        def plan(self, problem, ev, rng, mode):
            ev.evaluate(3, [[a[0] for a in problem.action_sets]])
            return np.zeros((problem.n_tasks, problem.n_agents), dtype=int), {}

    with pytest.raises(HeldOutTask, match="task 3 is held out"):
        Peek().solve(close, 10, train_tasks=[0, 1])


def test_fill_held_out_keeps_filled_rows(close):
    layouts = np.full((close.n_tasks, close.n_agents), -1)
    layouts[[0, 7]] = [[a[0] for a in close.action_sets], [a[1] for a in close.action_sets]]
    layouts[3] = [a[2] for a in close.action_sets]  # a planner's own choice on a held-out task stays
    out, filled = fill_held_out(close, layouts, [0, 7])
    assert 3 not in filled and (out[3] == layouts[3]).all()
    assert (out[1] == layouts[0]).all() and (out[6] == layouts[7]).all()
