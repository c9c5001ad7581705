"""Every catalog part within linear plate theory at the layouts planners aim for: w/t is measured at
the optimum (here, on a small case). That every part, bus panel included, deflects less than half its
thickness at its reference layouts, mesh-converged within 2 %, is what `fixbench validate` checks
(cases/linearity.py, cases/part_checks.py), the main job's first step; tests/test_cli.py runs it on the fan."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases.linearity import optimum_layouts, part_rows
from fixbench.cases.problem import load_problem


def test_w_over_t_is_measured_at_the_optimum():
    """part_rows' small-case row is the optimum's own max w: the enumeration agrees with a direct
    solve of the returned layouts, and no other layout of a task has a smaller max |u|."""
    problem = load_problem("fan_small")
    best = optimum_layouts(problem)
    (row,) = part_rows(names=["fan_small"])
    w = [problem.direct_deformation(k, best[k:k + 1]).max_w[0] for k in range(problem.n_tasks)]
    assert row["max_w_m"] == pytest.approx(max(w), rel=1e-9)
    rng = np.random.default_rng(0)
    for k in range(problem.n_tasks):
        others = np.column_stack([rng.choice(s, 500) for s in problem.action_sets])
        assert problem.oracle.evaluate(k, others)[:, 3].min() >= problem.oracle.evaluate(k, best[k:k + 1])[0, 3]
