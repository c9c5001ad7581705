"""LayoutProblem: any pymoo algorithm on a fixbench problem, every evaluation a counted sample."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
from pymoo.algorithms.soo.nonconvex.ga import GA
from pymoo.algorithms.soo.nonconvex.pattern import PatternSearch
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.pm import PM
from pymoo.operators.repair.rounding import RoundingRepair
from pymoo.operators.sampling.rnd import IntegerRandomSampling
from pymoo.optimize import minimize

from fixbench.cases import load_problem
from fixbench.solvers.base import Planner, PlannerError, TracedEvaluator
from fixbench.solvers.search.pymoo_problem import LayoutProblem

DOC = Path(__file__).resolve().parents[1] / "docs" / "planners.md"


@pytest.fixture(scope="module")
def problem():
    return load_problem("fan_small")


def true_max(problem, task: int, layout) -> float:
    return float(problem.deformation(problem.oracle.evaluate(task, np.atleast_2d(layout))).max_u[0])


def integer_ga(pop_size: int) -> GA:
    return GA(pop_size=pop_size, sampling=IntegerRandomSampling(), eliminate_duplicates=True,
              crossover=SBX(vtype=float, repair=RoundingRepair()), mutation=PM(vtype=float, repair=RoundingRepair()))


def test_readme_example_runs_as_written():
    text = DOC.read_text(encoding="utf-8")
    m = re.search(r"<!-- pymoo-example -->\n```python\n(.*?)```\n<!-- /pymoo-example -->", text, re.S)
    assert m, "docs/planners.md has no pymoo example between its markers"
    ns: dict = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(m.group(1), "docs/planners.md (pymoo example)", "exec"), ns)  # noqa: S102
    lp, res, problem = ns["lp"], ns["res"], ns["problem"]
    assert lp.samples == lp.evaluator.samples == 300, "every evaluation is a sample, none past the budget"
    layout = lp.layout(res.X)
    problem.check_layouts(layout[None])
    assert res.F[0] == pytest.approx(true_max(problem, 0, layout), rel=1e-12)
    assert lp.best[1] == pytest.approx(res.F[0], rel=1e-12) and (lp.best[0] == layout).all()
    assert str(lp.samples) in out.getvalue()


def test_budget_is_never_exceeded(problem):
    lp = LayoutProblem(problem, task=2, budget=50)
    minimize(lp, integer_ga(30), ("n_eval", 50), seed=0)  # the second generation does not fit whole
    assert lp.samples == 50
    assert len(lp.evaluator.trace) == 2 and lp.evaluator.trace[-1][1] == 50


def test_shared_mode_charges_every_task(problem):
    lp = LayoutProblem(problem, mode="shared", budget=20 * problem.n_tasks + 3)
    res = minimize(lp, integer_ga(10), ("n_eval", 20), seed=0)
    assert lp.samples == 20 * problem.n_tasks
    layout = lp.layout(res.X)
    worst = max(true_max(problem, t, layout) for t in range(problem.n_tasks))
    assert res.F[0] == pytest.approx(worst, rel=1e-12) and lp.best[1] == pytest.approx(worst, rel=1e-12)
    with pytest.raises(PlannerError, match="budget too small"):
        LayoutProblem(problem, mode="shared", budget=problem.n_tasks - 1)


def test_same_seed_same_run(problem):
    runs = []
    for seed in (4, 4, 5):
        lp = LayoutProblem(problem, task=1, budget=120)
        res = minimize(lp, integer_ga(20), ("n_eval", 120), seed=seed)
        runs.append((lp.layout(res.X).tolist(), float(res.F[0]), lp.samples))
    assert runs[0] == runs[1] and runs[0][2] <= 120
    assert runs[0][1] == pytest.approx(true_max(problem, 1, runs[0][0]), rel=1e-12)


def test_pattern_search_runs_within_budget(problem):
    # pymoo 0.6.2's PatternSearch draws its exploration order from an unseeded generator
    # (exploration_move is called without the algorithm's random_state), so only the budget
    # and the scoring are asserted here, not that one seed repeats.
    lp = LayoutProblem(problem, task=1, budget=120)
    res = minimize(lp, PatternSearch(), ("n_eval", 120), seed=4)
    assert lp.samples <= 120
    assert float(res.F[0]) == pytest.approx(true_max(problem, 1, lp.layout(res.X)), rel=1e-12)


def test_inside_a_planner_on_its_own_evaluator(problem):
    class PymooGA(Planner):
        name = "pymoo-ga-test"
        description = "pymoo GA through LayoutProblem, one run a task"

        def plan(self, problem, ev: TracedEvaluator, rng, mode):
            for task, share in zip(ev.tasks, (40,) * len(ev.tasks)):
                lp = LayoutProblem(problem, task=int(task), evaluator=ev)
                minimize(lp, integer_ga(10), ("n_eval", share), seed=int(rng.integers(2**31)))
            return ev.best_layout.copy(), {}

    result = PymooGA().solve(problem, budget=40 * problem.n_tasks, seed=0)
    assert result.samples == 40 * problem.n_tasks
    best_seen = [min(r[3] for r in result.trace if r[0] == t) for t in range(problem.n_tasks)]
    assert np.allclose(result.max_deformation, best_seen, rtol=1e-12), "its best layouts, scored on the oracle"
