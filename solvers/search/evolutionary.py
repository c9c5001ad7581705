"""What the evolutionary planners on pymoo share: a genetic algorithm (``ga``,
:mod:`fixbench.solvers.search.ga`) and particle swarm (``pso``, :mod:`fixbench.solvers.search.pso`).

Both wrap a vectorised pymoo :class:`~pymoo.core.problem.Problem`
(:class:`~fixbench.solvers.search.pymoo_problem.PopulationProblem`) whose ``_evaluate`` decodes a whole
population into layouts and makes one counted oracle call for it, so every generation is one
batched call: ``ev.evaluate(task, layouts)`` in per-task mode (one sample a
layout), ``ev.evaluate_shared(layouts)`` in shared mode (objective: the worst task; ``n_tasks``
samples a layout).

Encodings (:mod:`fixbench.solvers.search.pymoo_problem` owns them; each planner's module says why its
own): ``ga``, one integer gene per agent; ``pso``, a point in the plane per agent.

Fitness: by default the *soft max* of |u|, the power mean over the measurement points with
``soft_power`` (same solve, no extra sample; why: see :mod:`fixbench.solvers.search.greedy`), the max itself with
``soft_power = 0``. What is returned and scored is still the layout with the lowest true max.
Measured at 2 % of the joint space (3 seeds): on fan_small the max as fitness left GA +6.7 % and
PSO +35 % above the optimum, the soft max (p = 4) +0.4 % and +0.1 %.

Restarts: a run that has not improved its best fitness for ``stall_generations`` generations
(pymoo's ``RobustTermination`` over ``SingleObjectiveSpaceTermination``) starts again with a fresh
population on what is left of its allowance. A swarm collapses onto one layout long before a
large allowance is spent (PSO on bus_panel_small stopped improving after ~15 of 210 generations
and ended 2-12 % above the optimum; with restarts, 0-1 %).

Budget: a run gets an allowance of layouts (:meth:`~fixbench.solvers.base.Planner.drive`; per-task
mode: each task's ``split_budget`` share; shared mode: the budget divided by ``n_tasks``) and
pymoo's ``MaximumFunctionCallTermination``. A generation that would pass the allowance is cut: its
first individuals, up to what fits, are evaluated and the rest get ``F = +inf`` without being
evaluated or charged; pymoo's counter then reaches the allowance and the run ends. So the samples
spent never exceed the budget. A small allowance shrinks the population to
``allowance // min_generations`` (2 at least) so that a run still evolves; below 2 layouts a run is a documented
best effort: the first (random) population is evaluated only as far as it fits, a uniform random
sample. A budget with less than one layout per task (per task, or for the shared layout) raises
:class:`~fixbench.solvers.base.PlannerError`. A GA that can breed no new individual (a tiny space,
all seen) stops early and leaves the rest unspent.

Transfer (``transfer`` k > 0, per-task mode): tasks are solved in order, and the first population
of each task holds the best layouts of the k already-solved tasks nearest by task features
(:mod:`fixbench.solvers.transfer`), encoded, beside random individuals; restarts start fresh.

Per-task mode returns ``ev.best_layout``, the best layout ever evaluated on each task (not the
final population); shared mode returns ``ev.shared_layout``. ``info`` has ``generations``,
``restarts`` and ``n_eval`` (samples spent) per optimisation run: one run per task, or one run in
shared mode.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.sampling import Sampling
from pymoo.core.termination import TerminateIfAny
from pymoo.optimize import minimize
from pymoo.termination.ftol import SingleObjectiveSpaceTermination
from pymoo.termination.max_eval import MaximumFunctionCallTermination
from pymoo.termination.robust import RobustTermination

from fixbench.cases.problem import Problem
from fixbench.solvers.base import Planner, PlannerConfig, Share, TracedEvaluator, at_least
from fixbench.solvers.search.pymoo_problem import Encoding, PopulationProblem


class EvolutionaryPlanner(Planner):
    """One pymoo run on each share of the budget (:meth:`~fixbench.solvers.base.Planner.drive`): per
    task, or one on the worst task (shared)."""

    family = "evolutionary"
    #: the layouts as this algorithm's variables (:mod:`fixbench.solvers.search.pymoo_problem`)
    encoding: ClassVar[Callable[[Problem], Encoding]]

    @abstractmethod
    def _algorithm(self, size: int, seeds: np.ndarray | None) -> Algorithm:
        """The configured pymoo algorithm with population ``size`` (a fresh one per run); ``seeds``
        (encoded layouts) go into the first population, the rest is sampled as usual."""

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        encoding = self.encoding(problem)

        def search(share: Share) -> tuple[int, int, int]:
            """One run on the share, restarted while it stalls: (generations, samples spent, restarts)."""
            spent, left, gens, starts = ev.samples, share.allowance, 0, 0
            while left > 0:
                size = max(2, min(cfg.pop_size, left // cfg.min_generations))
                seeds = encoding.encode(share.warm[:size]) if starts == 0 and len(share.warm) else None
                problem_ = PopulationProblem(encoding, share.score, left)
                stall = RobustTermination(SingleObjectiveSpaceTermination(0.0, only_feas=False),
                                          period=cfg.stall_generations or 1)
                budget_end = MaximumFunctionCallTermination(left)
                termination = TerminateIfAny(budget_end, stall) if cfg.stall_generations else budget_end
                res = minimize(problem_, self._algorithm(size, seeds), termination, seed=int(rng.integers(2**31)),
                               verbose=False, copy_termination=False)
                gens, starts, left = gens + int(res.algorithm.n_gen), starts + 1, problem_.left
                if not (cfg.stall_generations and stall.has_terminated()):
                    break  # the budget is spent, or the algorithm stopped itself (nothing new to breed)
            return gens, ev.samples - spent, starts - 1

        layouts, runs = self.drive(problem, ev, mode, search, unlimited=cfg.evals_per_task,
                                   soft_power=cfg.soft_power or None, transfer=cfg.transfer)
        generations, n_eval, restarts = (list(column) for column in zip(*runs))
        return layouts, {"generations": generations, "n_eval": n_eval, "restarts": restarts}


@dataclass(frozen=True)
class EvolutionConfig(PlannerConfig):
    """Budget handling shared by the population-based planners."""

    min_generations: int = 10
    """A small budget shrinks the population to at most allowance / min_generations (2 at least)."""

    evals_per_task: int = 2000
    """Layouts per run (per task, or shared layouts) when the budget is unlimited."""

    soft_power: float = 4.0
    """Fitness: the power mean of |u| with this exponent (a soft max, see greedy); 0: the max."""

    stall_generations: int = 30
    """Restart with a fresh population after this many generations without a better best (0: never)."""

    transfer: int = 0
    """Warm start: the first population of a task holds the best layouts of this many solved tasks
    nearest by task features (0: random populations only)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "min_generations", "evals_per_task")
        at_least(self, 0, "soft_power", "stall_generations", "transfer")


class Seeded(Sampling):
    """A sampling whose first individuals are given (warm starts) and the rest drawn by ``base``."""

    def __init__(self, base: Sampling, seeds: np.ndarray | None):
        super().__init__()
        self.base, self.seeds = base, seeds

    def _do(self, problem, n_samples, **kwargs):
        X = np.asarray(self.base._do(problem, n_samples, **kwargs), dtype=float)
        if self.seeds is not None and len(self.seeds):
            k = min(len(self.seeds), n_samples)
            X[:k] = self.seeds[:k]
        return X
