"""A fixture-planning problem as a pymoo ``Problem``: run any pymoo algorithm on it, every
evaluation counted.

:class:`LayoutProblem` is the problem behind fixbench's ``ga`` planner (:mod:`fixbench.solvers.evolutionary`)
made public: one integer variable per agent, the position in that agent's own candidate set
(``0 .. len(set) - 1``, the ``ga`` encoding), and a vectorised ``_evaluate`` that decodes the whole
population into layouts and makes one counted call for it through a
:class:`~fixbench.solvers.base.TracedEvaluator`:

- ``mode="per-task"``: the objective of ``task``, one sample a layout;
- ``mode="shared"``: one layout for every task, judged by its worst task, ``n_tasks`` samples a
  layout.

The objective is the max deformation |u| in metres (or the soft max with ``soft_power``, the
fitness ``ga`` and ``pso`` use; the best layout by the true max is kept all the same). Variables
arrive as floats from most pymoo operators and are rounded (``np.rint``) to the nearest index.

Budget: ``budget`` samples at most, never more: an evaluation that would pass it is cut, its
first individuals, up to what fits, are evaluated and the rest get ``F = +inf`` without being
evaluated or charged (what ``ga`` does). Give pymoo a termination at the same number of
evaluations, ``("n_eval", budget)`` (per-task) or ``("n_eval", budget // n_tasks)`` (shared), so
that the run ends there.

After the run: :attr:`LayoutProblem.samples` (spent), :meth:`LayoutProblem.layout` (a variable vector
as global candidate indices), :attr:`LayoutProblem.best` (the best layout evaluated, by the true
max, and its max) and :attr:`LayoutProblem.evaluator` (the trace, as a planner's).
"""

from __future__ import annotations

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.base import MODES, PlannerError, TracedEvaluator, require_budget
from fixbench.solvers.evolutionary import GeneticPlanner, PopulationProblem

UNLIMITED = 2**62  # layouts an unlimited evaluator allows (an int: the allowance is sliced with it)


class LayoutProblem(PopulationProblem):
    """pymoo ``Problem`` of one task (or of the shared layout) of a fixbench problem (see the module
    docstring). ``evaluator``: a :class:`TracedEvaluator` to charge (default: a new one with
    ``budget``), e.g. a planner's own ``ev`` inside :meth:`~fixbench.solvers.base.Planner.plan`."""

    def __init__(self, problem: Problem, task: int = 0, mode: str = "per-task", budget: int | None = None,
                 soft_power: float | None = None, evaluator: TracedEvaluator | None = None):
        if mode not in MODES:
            raise PlannerError(f"LayoutProblem: mode must be one of {', '.join(MODES)}, got '{mode}'")
        ev = evaluator if evaluator is not None else TracedEvaluator(problem, budget)
        xl, xu, vtype, decode, encode = GeneticPlanner().encoding(problem)  # ga's integer genes
        if mode == "shared":
            score = lambda layouts: ev.shared_fitness(layouts, soft_power)  # noqa: E731
            allowance = UNLIMITED if ev.budget is None else int(ev.remaining // problem.n_tasks)
        else:
            task = ev.check_open(task)
            score = lambda layouts: ev.fitness(task, layouts, soft_power)  # noqa: E731
            allowance = UNLIMITED if ev.budget is None else int(ev.remaining)
        require_budget("LayoutProblem", allowance, 1, "one layout" + (" on every task" if mode == "shared" else ""))
        super().__init__(xl, xu, vtype, decode, score, allowance)
        self.fixbench_problem, self.evaluator, self.task, self.mode = problem, ev, task, mode
        self.encode = encode

    @property
    def samples(self) -> int:
        """Samples the evaluator has spent."""
        return self.evaluator.samples

    def layout(self, x) -> np.ndarray:
        """One variable vector (or a population) as layouts: global candidate indices, one per agent."""
        x = np.asarray(x, dtype=float)
        out = self.decode(np.atleast_2d(x))
        return out[0] if x.ndim == 1 else out

    @property
    def best(self) -> tuple[np.ndarray | None, float]:
        """(layout, max |u| in metres) of the best layout evaluated: on the task, or the shared
        layout's worst task; (None, inf) before any evaluation."""
        ev = self.evaluator
        if self.mode == "shared":
            return (None if ev.shared_layout is None else ev.shared_layout.copy()), float(ev.shared_best)
        if not np.isfinite(ev.best[self.task]):
            return None, float("inf")
        return ev.best_layout[self.task].copy(), float(ev.best[self.task])
