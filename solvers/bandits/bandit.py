"""The rounds loop of the contextual bandits on a model shared by all tasks (``surrogate-ts``, ``gp-ucb``).

Read top to bottom: the shared hyper-parameters, what every model uses (positions in the action
sets, repeats moved), the run (data, round 0, rounds, held-out
tasks, info), the planner. The models' inputs come from :mod:`fixbench.solvers.encoding`: the
task features scaled by their spread (``BanditRun.features``) and the pad coordinates in [-1, 1].
A planner specialises :class:`BanditRun` with its model: :meth:`~BanditRun.fit` at the start of a
round, :meth:`~BanditRun.propose` a round's layouts task by task, and :meth:`~BanditRun.act_held_out`
on the tasks it may not sample.

The data: every evaluated (task, layout) and y = log(max |u|) of it (deformation varies over orders
of magnitude between a good and a bad layout, hence the log), in the order evaluated, with the rows
of each task and the layouts already evaluated on it. Every evaluation goes through
:meth:`BanditRun.evaluate` (the oracle is counted by the evaluator and timed here).

Rounds, not task by task: round 0 gives every training task ``initial_random`` uniform random
layouts that seed the model; every later round starts with :meth:`~BanditRun.fit` and gives every
training task a batch of ``batch`` samples (larger when the budget is large, so that there are at
most ``max_rounds`` rounds), proposed and evaluated task after task (a proposal may use the samples
of the tasks before it in the round). A proposal starts from the task's incumbent, the best layouts
of the ``transfer`` nearest solved tasks (:func:`fixbench.solvers.transfer.warm_layouts`) and one
uniform random layout (:meth:`BanditRun.starts`). A layout already evaluated on the task is moved to
a random neighbour (:func:`move_repeats`).

Budget: split equally over the training tasks (``split_budget``; ``samples_per_task`` each when
unlimited), spent exactly; at least one sample per training task, else :class:`PlannerError`.
Per-task mode only. Returned layouts: on a training task the best layout evaluated there; on a task
outside the evaluator's tasks (held-out track, zero samples) the model's own, from
:meth:`~BanditRun.act_held_out`, started from the nearest training task's best layout.

Randomness: ``rng`` only, drawn in the order of the loop (a model may seed its own generator from
it); torch's threads are set to ``threads`` and deterministic algorithms are asked for during the
run (both restored after, :func:`fixbench.solvers.torch_run.torch_run`), so the same seed gives the
same bits.
"""

from __future__ import annotations

import contextlib
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.problem import Problem
from fixbench.solvers.base import (
    Planner,
    PlannerConfig,
    TracedEvaluator,
    Training,
    at_least,
    random_layouts,
    require_budget,
    split_budget,
)
from fixbench.solvers.encoding import task_features
from fixbench.solvers.torch_run import torch_run
from fixbench.solvers.transfer import nearest_tasks, warm_layouts


# ---------------------------------------------------------------------------------------------
# hyper-parameters of the loop
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BanditConfig(PlannerConfig):
    """The loop's fields. ``batch``, ``max_rounds``, ``transfer`` and ``max_sweeps`` have no default
    here: each planner declares them again with its own default and says what they bound for it."""

    batch: int
    """Samples per training task per round (raised so that there are at most ``max_rounds`` rounds)."""

    max_rounds: int
    """Most rounds after round 0."""

    transfer: int
    """Proposals also start from the best layouts of this many solved tasks nearest by features."""

    max_sweeps: int
    """Most Gauss-Seidel sweeps over the agents per best response."""

    initial_random: int = 10
    """Uniform random layouts per training task before the model is first used (round 0)."""

    tries: int = 50
    """Random one-agent changes tried to turn a repeated layout into a new one before accepting it."""

    samples_per_task: int = 100
    """Samples per training task when the budget is unlimited."""

    threads: int = 1
    """torch intra-op threads during the run (0: torch's setting); restored afterwards."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "initial_random", "batch", "max_sweeps", "samples_per_task")
        at_least(self, 0, "max_rounds", "transfer", "tries", "threads")


# ---------------------------------------------------------------------------------------------
# positions, repeats
# ---------------------------------------------------------------------------------------------
def set_positions(problem: Problem) -> np.ndarray:
    """Global action -> its position in its agent's set."""
    pos = np.zeros(len(problem.points), dtype=np.int64)
    for a in problem.action_sets:
        pos[a] = np.arange(len(a))
    return pos


def move_repeats(layouts: np.ndarray, done: set, batch: set, sets: list[np.ndarray], rng: np.random.Generator,
                 tries: int) -> tuple[np.ndarray, int]:
    """``layouts`` with every one already in ``done`` (evaluated on the task) or in ``batch`` (proposed in
    this batch) moved to a random neighbour (one agent's action changed at random, up to ``tries`` times,
    then the repeat is accepted: a tiny joint space can be used up); adds the results to ``batch``;
    returns them and how many moved."""
    out, moved = layouts.copy(), 0
    for r in range(len(out)):
        key, k = tuple(out[r].tolist()), 0
        while (key in done or key in batch) and k < tries:
            a = int(rng.integers(len(sets)))
            out[r, a] = sets[a][rng.integers(len(sets[a]))]
            key, k = tuple(out[r].tolist()), k + 1
        moved += k > 0
        batch.add(key)
    return out, moved


# ---------------------------------------------------------------------------------------------
# the run: data, round 0, rounds, held-out tasks, info
# ---------------------------------------------------------------------------------------------
class BanditRun(ABC):
    """One run of a rounds bandit; a planner's subclass adds its model and the hooks below."""

    #: the run's clocks, in the order the info lists them (``time_<name>_s``): ``fit`` (:meth:`fit`),
    #: ``act`` (proposals and held-out layouts), ``oracle`` (:meth:`evaluate`); a subclass may add its own
    clocks: ClassVar[tuple[str, ...]] = ("fit", "act", "oracle")

    def __init__(self, cfg: BanditConfig, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator):
        self.cfg, self.problem, self.ev, self.rng = cfg, problem, ev, rng
        self.n, self.sets, self.ids = problem.n_agents, problem.action_sets, ev.tasks
        self.features = task_features(problem, "spread")
        self.pos = set_positions(problem)
        self.shares = np.array(split_budget(ev.budget, len(self.ids), cfg.samples_per_task))
        cap = int(self.shares.sum())  # the data: each evaluated (task, layout) and its y, in the order evaluated
        self.task = np.zeros(cap, dtype=np.int64)
        self.act = np.zeros((cap, self.n), dtype=np.int64)
        self.y = np.zeros(cap)
        self.size = 0
        self.rows_of = {int(t): [] for t in self.ids}
        self.seen = {int(t): set() for t in self.ids}
        self.time = dict.fromkeys(self.clocks, 0.0)
        self.rounds = self.batch = self.moved = 0
        self.round_samples: list[int] = []  # samples spent by the end of round 0, 1, ...
        self.round_best: list[float] = []  # mean best max |u| (m) over the training tasks sampled by then

    # --- what a model adds ------------------------------------------------------------------
    @abstractmethod
    def fit(self, rnd: int) -> None:
        """Start of round ``rnd`` (0, 1, ...): (re)fit the model on the data so far."""

    @abstractmethod
    def propose(self, tasks: np.ndarray, counts: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """A round's layouts: (task, (count, n_agents) global actions) for each of ``tasks`` in order;
        each task's layouts are evaluated before the next task's are asked for."""

    @abstractmethod
    def act_held_out(self, held: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, int]:
        """Layouts (len(held), n_agents) for tasks with no sample, from ``starts`` (the nearest training
        task's best layout of each); returns them and the best-response sweeps spent."""

    def model_info(self) -> dict:
        """The model's own figures for the info, listed after ``batch``."""
        return {}

    def model_curves(self, training: Training) -> Training:
        """``training`` with the model's own curves declared in it (its fit loss, ...)."""
        return training

    # --- what every model uses ----------------------------------------------------------------
    @contextlib.contextmanager
    def timed(self, clock: str):
        """Add the block's wall time to ``clock``."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.time[clock] += time.perf_counter() - t0

    def evaluate(self, task: int, layouts: np.ndarray) -> None:
        """Evaluate ``layouts`` on ``task`` (counted) and append them to the data (a model that keeps
        more of each sample extends this)."""
        with self.timed("oracle"):
            u = self.ev.evaluate(task, layouts).max_u
        rows = slice(self.size, self.size + len(layouts))
        self.task[rows], self.act[rows], self.y[rows] = task, layouts, np.log(np.maximum(u, 1e-30))
        self.rows_of[task].extend(range(rows.start, rows.stop))
        self.size = rows.stop
        self.seen[task].update(map(tuple, layouts.tolist()))

    def inputs(self, rows: np.ndarray, feats: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
        """Model inputs x = [the task's features, the layout's pad coordinates in agent order] of the
        data ``rows``, from ``feats`` (n_tasks, F) and ``pts`` (n_options, d) as the model scales them."""
        return torch.cat([feats[torch.from_numpy(self.task[rows])],
                          pts[torch.from_numpy(self.act[rows])].reshape(len(rows), -1)], 1)

    def unrepeated(self, task: int, layouts: np.ndarray, taken: set | None = None) -> np.ndarray:
        """:func:`move_repeats` of ``layouts`` on ``task`` (``taken``: already proposed this round)."""
        out, moved = move_repeats(layouts, self.seen[task], set() if taken is None else taken, self.sets,
                                  self.rng, self.cfg.tries)
        self.moved += moved
        return out

    def layouts_of(self, local: np.ndarray) -> np.ndarray:
        """Layouts (global actions) of ``local`` (Q, n_agents): each agent's position in its own set."""
        return np.column_stack([self.sets[i][local[:, i]] for i in range(self.n)])

    def starts(self, task: int) -> np.ndarray:
        """Where a proposal on ``task`` starts: its incumbent (once it has one), the best layouts of the
        ``transfer`` nearest solved tasks and one uniform random layout, each once (first kept)."""
        ev = self.ev
        starts = [ev.best_layout[task][None]] if np.isfinite(ev.best[task]) else []
        starts.append(warm_layouts(self.problem, ev.best, ev.best_layout, task, self.cfg.transfer))
        starts.append(random_layouts(self.problem, self.rng, 1))
        starts = np.vstack(starts)
        _, first = np.unique(starts, axis=0, return_index=True)
        return starts[np.sort(first)]

    # --- the loop -----------------------------------------------------------------------------
    def run(self) -> tuple[np.ndarray, dict, Training]:
        """Round 0, the rounds, the held-out tasks: (layouts, info, training)."""
        t_start = time.perf_counter()
        cfg, ids = self.cfg, self.ids
        for t, s in zip(ids.tolist(), self.shares.tolist()):  # round 0: uniform random layouts seed the model
            if m := min(cfg.initial_random, s):
                self.evaluate(t, self.unrepeated(t, random_layouts(self.problem, self.rng, m)))
        self.end_round()
        left = self.shares - np.minimum(cfg.initial_random, self.shares)
        self.batch = max(cfg.batch, math.ceil(int(left.max(initial=0)) / max(cfg.max_rounds, 1)))
        while left.any():
            counts = np.minimum(left, self.batch)
            self.fit(self.rounds)
            self.rounds += 1
            for task, layouts in self.propose(ids[counts > 0], counts[counts > 0]):
                self.evaluate(task, layouts)
            left -= counts
            self.end_round()
        layouts = self.ev.best_layout.copy()
        held = np.setdiff1d(np.arange(self.problem.n_tasks), ids)
        held_sweeps = 0
        if len(held):
            src = [nearest_tasks(self.problem, ids, int(t), 1, self.features)[0] for t in held]
            layouts[held], held_sweeps = self.act_held_out(held, self.ev.best_layout[src])
        return layouts, self.info(held_sweeps, t_start), self.training()

    def end_round(self) -> None:
        """Record the round just ended: the samples spent and the mean best max |u| so far (NaN before any)."""
        best = self.ev.best[self.ids]
        seen = np.isfinite(best)
        self.round_samples.append(self.ev.samples)
        self.round_best.append(float(best[seen].mean()) if seen.any() else math.nan)

    def training(self) -> Training:
        """The run's curves: ``round_samples`` and ``round_best_mean_u`` (m) a round (round 0 first), then
        the model's own (:meth:`model_curves`)."""
        return self.model_curves(Training().add("round", round_samples=self.round_samples,
                                                round_best_mean_u=self.round_best))

    def info(self, held_sweeps: int, t_start: float) -> dict:
        per_task = self.ev.task_samples[self.ids]
        return {
            "samples_per_task": int(per_task.min()) if per_task.min() == per_task.max() else per_task.tolist(),
            "rounds": self.rounds,
            "batch": int(self.batch),
            **self.model_info(),
            "held_out_sweeps": held_sweeps,
            "repeats_moved": int(self.moved),
            **{f"time_{clock}_s": t for clock, t in self.time.items()},
            "time_total_s": time.perf_counter() - t_start,
            "torch_threads": torch.get_num_threads(),
        }


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class RoundsBandit(Planner):
    """A planner that runs its :class:`BanditRun` subclass ``Run`` under :func:`torch_run`. A subclass
    states ``name``, ``description``, ``family`` and ``modes`` in its own body: ``fixbench solvers``
    reads them from its module's source (:func:`fixbench.solvers.registry.listing`)."""

    Run: ClassVar[type[BanditRun]]
    modes = ("per-task",)
    same_on_every_host = False

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        require_budget(self.name, ev.remaining, len(ev.tasks), "one layout per task")
        with torch_run(self.config.threads):
            return self.Run(self.config, problem, ev, rng).run()
