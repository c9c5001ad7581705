"""The local planner at small budgets: where descent gets about one round of moves, it must not lose
to random search at the same budget, and what it returns is the best layout it evaluated."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers import get


@pytest.fixture(scope="module")
def panel():
    return Problem(load_case_spec("wing_panel_small"))


def test_one_round_of_budget_is_no_worse_than_random_search(panel):
    cfg = get("local").Config()
    spt = panel.n_agents * (cfg.neighbours + cfg.explore)  # one check of every agent
    local = [get("local")().solve(panel, spt * panel.n_tasks, seed=s) for s in range(4)]
    rand = [get("random")().solve(panel, spt * panel.n_tasks, seed=s) for s in range(4)]
    assert all(r.samples == spt * panel.n_tasks for r in local)
    m_local = np.mean([r.max_deformation.mean() for r in local])
    assert m_local <= np.mean([r.max_deformation.mean() for r in rand])
    for r in local:
        best = {}
        for task, _, _, b in r.trace:
            best[task] = min(best.get(task, np.inf), b)
        assert np.allclose(r.max_deformation, [best[t] for t in range(panel.n_tasks)], rtol=1e-12)
