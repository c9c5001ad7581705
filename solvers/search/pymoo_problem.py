"""A fixture-planning problem as a pymoo ``Problem``: run any pymoo algorithm on it, every
evaluation counted.

The layouts as pymoo variables (:class:`Encoding`; ``ga`` and ``pso``, :mod:`fixbench.solvers.search.ga` and
:mod:`fixbench.solvers.search.pso`, take theirs from here):

- :func:`integer_encoding`: one integer variable per agent, the position in that agent's own
  candidate set (``0 .. len(set) - 1``);
- :func:`plane_encoding`: a point in the plane per pad, snapped to the agent's nearest candidate.

:class:`PopulationProblem` decodes a whole population into layouts and makes one counted call for
it, capped at an allowance of layouts. :class:`LayoutProblem` is that problem on a task of a fixbench
problem, in the integer encoding, through a :class:`~fixbench.solvers.base.TracedEvaluator`:

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

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from pymoo.core.problem import Problem as PymooProblem
from scipy.spatial import cKDTree

from fixbench.cases.problem import Problem
from fixbench.solvers.base import MODES, PlannerError, TracedEvaluator, require_budget

UNLIMITED = 2**62  # layouts an unlimited evaluator allows (an int: the allowance is sliced with it)


class Encoding(NamedTuple):
    """Layouts as pymoo variables: bounds, variable type, a population -> layouts and back."""

    xl: np.ndarray
    xu: np.ndarray
    vtype: type
    decode: Callable[[np.ndarray], np.ndarray]
    encode: Callable[[np.ndarray], np.ndarray]


def integer_encoding(problem: Problem) -> Encoding:
    """One integer variable per agent, the position in its own action set; a float variable (what
    most pymoo operators give) is rounded to the nearest index."""
    sets = problem.action_sets
    xu = np.array([len(s) - 1 for s in sets], dtype=float)

    def decode(X: np.ndarray) -> np.ndarray:
        genes = np.rint(X).astype(np.int64)
        return np.column_stack([s[genes[:, a]] for a, s in enumerate(sets)])

    def encode(layouts: np.ndarray) -> np.ndarray:
        return np.column_stack([np.searchsorted(s, layouts[:, a]) for a, s in enumerate(sets)]).astype(float)

    return Encoding(np.zeros(len(sets)), xu, int, decode, encode)


def plane_encoding(problem: Problem) -> Encoding:
    """A point per action in the plane (:func:`_centre_and_spread`), bounded by the agent's box padded
    by half the median nearest-neighbour spacing of all candidates, snapped to the agent's nearest
    action with a KD-tree (why the plane and not an index: :mod:`fixbench.solvers.search.pso`)."""
    sets = problem.action_sets
    where = _centre_and_spread(problem.points)
    points = [where[s] for s in sets]  # an action as 2 m numbers (one pad: its (x, y))
    d = where.shape[1]
    trees = [cKDTree(p) for p in points]
    pad = 0.5 * float(np.median(cKDTree(problem.candidates).query(problem.candidates, k=2)[0][:, 1]))
    xl = np.concatenate([p.min(axis=0) - pad for p in points])
    xu = np.concatenate([p.max(axis=0) + pad for p in points])

    def decode(X: np.ndarray) -> np.ndarray:
        return np.column_stack([s[t.query(X[:, d * a:d * a + d])[1]] for a, (s, t) in enumerate(zip(sets, trees))])

    def encode(layouts: np.ndarray) -> np.ndarray:
        return where[np.asarray(layouts, dtype=np.int64)].reshape(len(layouts), -1)

    return Encoding(xl, xu, float, decode, encode)


def _centre_and_spread(points: np.ndarray) -> np.ndarray:
    """Actions as plane coordinates: one pad, its (x, y); m pads, their centre and each other pad's
    offset from the first, ``(cx, cy, x2 - x1, y2 - y1, ...)``. In the pads' own coordinates most of
    the box around a robot's pairs is no pair at all (two pads at most ``span`` apart fill a thin
    shell of the 4-D box), and a particle there snaps to whichever pair is nearest: the swarm's
    first population and its moves crowd onto a few pairs. Centre and offset fill their box
    (offsets within a disc of radius ``span``), so a point snaps near where it is."""
    m = points.shape[1] // 2
    if m == 1:
        return points
    xy = points.reshape(len(points), m, 2)
    return np.concatenate([xy.mean(axis=1), (xy[:, 1:] - xy[:, :1]).reshape(len(points), -1)], axis=1)


class PopulationProblem(PymooProblem):
    """A population -> layouts (``encoding``) -> one counted call (``score``) per generation, capped at
    ``allowance`` layouts: the tail of a generation past it gets ``F = +inf``, never evaluated or
    charged (the pymoo problem behind ``ga`` and ``pso``)."""

    def __init__(self, encoding: Encoding, score: Callable[[np.ndarray], np.ndarray], allowance: int):
        super().__init__(n_var=len(encoding.xl), n_obj=1, xl=encoding.xl, xu=encoding.xu, vtype=encoding.vtype)
        self.decode, self.encode, self.score, self.left = encoding.decode, encoding.encode, score, allowance

    def _evaluate(self, X, out, *args, **kwargs):
        k = min(len(X), self.left)
        F = np.full(len(X), np.inf)  # the cut tail of the last generation: never evaluated
        if k:
            F[:k] = self.score(self.decode(np.asarray(X[:k])))
            self.left -= k
        out["F"] = F


class LayoutProblem(PopulationProblem):
    """pymoo ``Problem`` of one task (or of the shared layout) of a fixbench problem (see the module
    docstring). ``evaluator``: a :class:`TracedEvaluator` to charge (default: a new one with
    ``budget``), e.g. a planner's own ``ev`` inside :meth:`~fixbench.solvers.base.Planner.plan`."""

    def __init__(self, problem: Problem, task: int = 0, mode: str = "per-task", budget: int | None = None,
                 soft_power: float | None = None, evaluator: TracedEvaluator | None = None):
        if mode not in MODES:
            raise PlannerError(f"LayoutProblem: mode must be one of {', '.join(MODES)}, got '{mode}'")
        ev = evaluator if evaluator is not None else TracedEvaluator(problem, budget)
        if mode == "shared":
            score = lambda layouts: ev.shared_fitness(layouts, soft_power)  # noqa: E731
            allowance = UNLIMITED if ev.budget is None else int(ev.remaining // problem.n_tasks)
        else:
            task = ev.check_open(task)
            score = lambda layouts: ev.fitness(task, layouts, soft_power)  # noqa: E731
            allowance = UNLIMITED if ev.budget is None else int(ev.remaining)
        require_budget("LayoutProblem", allowance, 1, "one layout" + (" on every task" if mode == "shared" else ""))
        super().__init__(integer_encoding(problem), score, allowance)
        self.fixbench_problem, self.evaluator, self.task, self.mode = problem, ev, task, mode

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
