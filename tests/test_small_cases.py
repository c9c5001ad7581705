"""Every ``*_small`` case separates planners: random search at 1 % of the joint space stays at least
10 % above the proven optimum (issue 14). A case where it does not (the fixtures barely matter, so
almost any layout is near-optimal) cannot rank planners.

Measured as the default matrix runs the small cases (bench/matrices/default.toml: its agent count,
each case's own material; a case with a pad limit at its own robots), on every task of the case:
the budget is 1 % of the joint space a task, the gap is the mean over seeds 0-4 of random's mean
max deformation over the optimum's, minus 1.
"""

from __future__ import annotations

import pytest

from fixbench.bench.running.matrix import find_matrix, load_matrix
from fixbench.cases.problem import load_problem
from fixbench.cases.spec import case_names, load_case_spec
from fixbench.solvers import get

SMALL = [n for n in case_names() if n.endswith("_small")]
#: the bus panel's oracle set-up (92 candidates x 3 components on 307k DOFs) takes about a minute
SLOW = {"bus_panel_small"}
SHARE = 0.01
MIN_GAP = 0.10
SEEDS = range(5)


def test_every_part_has_a_small_case():
    assert sorted(SMALL) == ["bus_panel_small", "cfrp_wing_panel_small", "fan_small", "wing_panel_pads_small",
                             "wing_panel_pairs_small", "wing_panel_small", "wing_spar_small"]


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW else c for c in SMALL])
def test_random_search_stays_well_above_the_optimum(case):
    # the default matrix's agent count; a case with a pad limit keeps its own robots (the limit is
    # what makes it: 4 robots sharing 3 pads)
    agents = None if load_case_spec(case).effector.pads else load_matrix(find_matrix("default")).agents[0]
    problem = load_problem(case, agents=agents)
    per_task = int(SHARE * problem.joint_size)
    exact = get("exact")().solve(problem, budget=problem.joint_size * problem.n_tasks)
    assert exact.info["method"] == "enumeration" and exact.info["proven"]
    gaps = [get("random")().solve(problem, budget=per_task * problem.n_tasks, seed=s).objective
            / exact.objective - 1 for s in SEEDS]
    mean = sum(gaps) / len(gaps)
    assert mean >= MIN_GAP, f"{case}: random at {per_task} samples a task ends {100 * mean:.2f} % above the optimum"
