"""The greedy planner: person-by-person optima, budgets, determinism, shared mode."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers import PlannerError, get


@pytest.fixture(scope="module")
def fan2():
    """fan_small cut to two tasks: 3 agents of 28 candidates."""
    return Problem(load_case_spec("fan_small").with_tasks([0, 1]))


def single_moves(problem, layout):
    """Every layout differing from ``layout`` in one agent's candidate."""
    out = []
    for a, s in enumerate(problem.action_sets):
        trial = np.tile(layout, (len(s), 1))
        trial[:, a] = s
        out.append(trial)
    return np.vstack(out)


def test_per_task_result_is_a_person_by_person_optimum(fan2):
    """On the max itself (soft_power 0) a converged descent ends where no single move helps."""
    r = get("greedy")(restarts=2, soft_power=0).solve(fan2, budget=None, seed=3)
    assert all(all(c) for c in r.info["converged"])
    check = fan2.evaluator()
    for t in range(fan2.n_tasks):
        moves = check.evaluate(t, single_moves(fan2, r.layouts[t])).max_u
        assert moves.min() >= r.max_deformation[t] * (1 - 1e-12)


def test_shared_result_is_a_person_by_person_optimum(fan2):
    r = get("greedy")(restarts=1, soft_power=0).solve(fan2, budget=None, seed=1, mode="shared")
    assert (r.layouts == r.layouts[0]).all() and r.info["converged"] == [[True]]
    moves = single_moves(fan2, r.layouts[0])
    check = fan2.evaluator()
    worst = np.max([check.evaluate(t, moves).max_u for t in range(fan2.n_tasks)], axis=0)
    assert worst.min() >= r.max_deformation.max() * (1 - 1e-12)


@pytest.mark.parametrize("mode", ["per-task", "shared"])
def test_soft_max_descent_escapes_the_blades_tie(fan2, mode):
    """The fan's blades trade the max; one descent on the soft max reaches the optimum, on the max
    it stops far above it (module doc). Optimum by enumerating all 21,952 layouts of each task."""
    joint = np.stack(np.meshgrid(*fan2.action_sets, indexing="ij"), -1).reshape(-1, fan2.n_agents)
    check = fan2.evaluator()
    per_task = np.array([check.evaluate(t, joint).max_u for t in range(fan2.n_tasks)])
    optimum = per_task.min(axis=1).mean() if mode == "per-task" else per_task.max(axis=0).min()
    soft, plain = (get("greedy")(restarts=1, soft_power=p).solve(fan2, budget=None, seed=0, mode=mode)
                   for p in (4, 0))
    assert soft.objective <= 1.01 * optimum
    assert plain.objective > 1.5 * optimum


@pytest.mark.parametrize("mode,budget", [("per-task", 2), ("per-task", 95), ("shared", 2),
                                         ("shared", 181), ("per-task", 400)])
def test_never_exceeds_the_budget(fan2, mode, budget):
    r = get("greedy")().solve(fan2, budget=budget, seed=0, mode=mode)
    assert 0 < r.samples <= budget


def test_refuses_a_budget_below_one_layout(fan2):
    with pytest.raises(PlannerError, match="budget too small"):
        get("greedy")().solve(fan2, budget=1, mode="shared")


def test_same_seed_same_result(fan2):
    a, b = (get("greedy")().solve(fan2, budget=300, seed=5) for _ in range(2))
    assert (a.layouts == b.layouts).all() and a.samples == b.samples and a.info == b.info


def test_a_budget_too_small_for_one_move_is_spent_on_sampling_not_wasted():
    """Below one complete check of an agent's set, greedy samples (half random layouts, half single-agent
    moves) and lands near random search; it used to spend everything on part of one agent's check.
    So it does up to one complete round of checks (every agent once); from there it best-responds."""
    p = Problem(load_case_spec("wing_panel_small"))
    spt = max(len(a) for a in p.action_sets) // 3
    greedy = [get("greedy")().solve(p, spt * p.n_tasks, seed=s) for s in range(4)]
    rand = [get("random")().solve(p, spt * p.n_tasks, seed=s) for s in range(4)]
    assert all(r.info["sampled"] == p.n_tasks and r.samples == spt * p.n_tasks for r in greedy)
    g = np.mean([r.max_deformation.mean() for r in greedy])
    assert g <= 1.15 * np.mean([r.max_deformation.mean() for r in rand])
    for r in greedy:  # the layout returned is the best it evaluated (by the true max) on each task
        best = {}
        for task, _, _, b in r.trace:
            best[task] = min(best.get(task, np.inf), b)
        assert np.allclose(r.max_deformation, [best[t] for t in range(p.n_tasks)], rtol=1e-12)
    one_round = sum(len(a) for a in p.action_sets)
    assert max(len(a) for a in p.action_sets) < one_round - 1
    below = get("greedy")().solve(p, (one_round - 1) * p.n_tasks, seed=0)  # checks fit, a round does not
    at = get("greedy")().solve(p, one_round * p.n_tasks, seed=0)
    assert below.info["sampled"] == p.n_tasks and at.info["sampled"] == 0
