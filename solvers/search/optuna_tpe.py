"""``optuna``: Optuna's tree-structured Parzen estimator (TPE) over the agents' candidates.

One categorical parameter per agent, its position in that agent's own candidate set: categorical,
not an integer range, because the candidate order carries no distance (a grid is numbered row by
row, so index i + 1 can be across the part; see :mod:`fixbench.solvers.search.pso`). TPE models the
good and the bad layouts seen so far by per-parameter (``multivariate``: joint) Parzen densities and
proposes the layout that maximises their ratio.

The study is driven by ask-and-tell, one layout a trial, so the budget is honoured exactly: per-task
mode runs one study a task on its share of the budget (``samples_per_task`` each when unlimited; the
budget loop of :meth:`~fixbench.solvers.base.Planner.drive`), the objective the task's max |u| in
metres (the soft max with ``soft_power``, as ``ga`` and ``pso`` may use); shared mode runs one study
on the worst task of one layout, ``n_tasks`` samples a trial. A layout the study proposes again is
told its known value and costs nothing (the oracle is deterministic); a study that has proposed only
known layouts ``stall_asks`` times in a row has converged and stops with its budget left (a
documented best effort, as ``ga`` that can breed nothing new). An allowance that covers the whole
joint space (tiny problems) is spent on every layout once, in batches, instead: TPE would only
rediscover them, one ask at a time (each ask costs more as a study grows: measured on fan_small with
2 agents, 7 ms an ask on average over a study of 100 or 300 layouts, 11 ms over one of 1,000).

Seeding: each study's :class:`optuna.samplers.TPESampler` gets a seed drawn from the planner's
``rng``; nothing global is seeded, so the same seed gives the same layouts. Optuna's logging is
lowered to warnings while the planner runs (and restored after), and its warning that
multivariate TPE is experimental is not shown.

Transfer (``transfer`` k > 0, per-task mode): tasks are solved in order, and each study first
evaluates the best layouts of the k already-solved tasks nearest by task features
(:func:`fixbench.solvers.transfer.warm_layouts`), enqueued as its first trials (each costs its
sample, within the task's share); TPE then starts from what they scored.

Held-out track: the planner searches only the training tasks its evaluator allows and leaves the
others to :meth:`~fixbench.solvers.base.Planner.solve`, which gives each held-out task the best
layout of its nearest training task (zero samples), as for every non-learning planner.

``info``: ``trials`` (asks), ``n_eval`` (samples spent) and ``repeats`` (known layouts proposed
again) per study.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import optuna

from fixbench.cases.problem import Problem
from fixbench.solvers.base import Planner, PlannerConfig, Share, TracedEvaluator, at_least

ENUMERATION_BATCH = 4096  # layouts a counted call when an allowance covers the joint space


@dataclass(frozen=True)
class OptunaConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "n_startup_trials": ("int", 5, 50),
        "multivariate": ("choice", [True, False]),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    samples_per_task: int = 200
    """Layouts per task (per-task) or shared layouts (shared mode) when the budget is unlimited."""

    n_startup_trials: int = 10
    """Random trials before TPE models the results (Optuna's default)."""

    n_ei_candidates: int = 24
    """Layouts TPE draws from its good-layout density to pick the next one (Optuna's default)."""

    multivariate: bool = True
    """Model the agents jointly (multivariate TPE) rather than one agent at a time."""

    soft_power: float = 0.0
    """Objective: the power mean of |u| with this exponent (a soft max, see greedy); 0: the max."""

    stall_asks: int = 200
    """Stop a study after this many proposals in a row of layouts already evaluated (they cost nothing)."""

    transfer: int = 0
    """Warm start: each task's study first evaluates the best layouts of this many solved tasks nearest
    by task features (0: none)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "samples_per_task", "n_ei_candidates", "stall_asks")
        at_least(self, 0, "n_startup_trials", "soft_power", "transfer")


class OptunaTPE(Planner):
    name = "optuna"
    family = "bayesian-optimisation"
    description = "Optuna's TPE sampler, one categorical parameter per agent (index into its set)"
    Config = OptunaConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config

        def search(share: Share) -> tuple[int, int, int]:
            """One study on the share: (asks, samples spent, repeats)."""
            spent = ev.samples
            asks, repeats = self._study(problem, share.score, share.allowance, share.warm, int(rng.integers(2**31)))
            return asks, ev.samples - spent, repeats

        verbosity = optuna.logging.get_verbosity()
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                layouts, studies = self.drive(problem, ev, mode, search, unlimited=cfg.samples_per_task,
                                              soft_power=cfg.soft_power or None, transfer=cfg.transfer)
        finally:
            optuna.logging.set_verbosity(verbosity)
        trials, n_eval, repeats = (list(column) for column in zip(*studies))
        return layouts, {"trials": trials, "n_eval": n_eval, "repeats": repeats}

    def _study(self, problem: Problem, score, allowance: int, warm: np.ndarray, seed: int) -> tuple[int, int]:
        """One ask-and-tell study of ``allowance`` new layouts; returns (asks, repeats)."""
        cfg = self.config
        sets = problem.action_sets
        if allowance >= problem.joint_size:  # every layout once, no study
            grid = np.stack(np.meshgrid(*sets, indexing="ij"), axis=-1).reshape(-1, len(sets))
            for start in range(0, len(grid), ENUMERATION_BATCH):
                score(grid[start:start + ENUMERATION_BATCH])
            return 0, 0
        names = [f"agent_{a}" for a in range(len(sets))]
        space = {n: optuna.distributions.CategoricalDistribution(list(range(len(s)))) for n, s in zip(names, sets)}
        sampler = optuna.samplers.TPESampler(seed=seed, n_startup_trials=cfg.n_startup_trials,
                                             n_ei_candidates=cfg.n_ei_candidates, multivariate=cfg.multivariate)
        study = optuna.create_study(direction="minimize", sampler=sampler)
        for layout in warm[:allowance]:
            study.enqueue_trial({n: int(np.searchsorted(s, g)) for n, s, g in zip(names, sets, layout)})
        seen: dict[tuple[int, ...], float] = {}
        asks = repeats = in_a_row = 0
        while len(seen) < allowance and in_a_row < cfg.stall_asks:
            trial = study.ask(space)
            asks += 1
            key = tuple(int(trial.params[n]) for n in names)
            if key in seen:
                repeats += 1
                in_a_row += 1
            else:
                in_a_row = 0
                layout = np.array([[s[i] for s, i in zip(sets, key)]], dtype=np.int64)
                seen[key] = float(score(layout)[0])
            study.tell(trial, seen[key])
        return asks, repeats
