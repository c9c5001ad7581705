"""The planner interface: a config dataclass, a ``plan`` hook, and a scored, traced result.

In the spirit of pymoo's Algorithm and BenchMARL's AlgorithmConfig: a planner is a class with a
``name``, a one-line ``description`` and a frozen ``Config`` dataclass (one docstring per field).
:meth:`Planner.solve` reads like the maths::

    result = Planner(config).solve(problem, budget=2000, seed=0, mode="per-task")

It hands the planner a :class:`TracedEvaluator` (the counted oracle plus an anytime trace) and a
seeded generator, calls :meth:`Planner.plan`, checks the layouts it returns, and scores them. The
score (true max deformation of each returned layout) is the benchmark's measurement, taken on the
uncounted oracle after the planner has finished: the planner never sees it.

One scoring rule (docs/protocol.md#scoring): on every task it evaluated, a planner is scored by its
*incumbent*, the best layout it evaluated there (what an engineer would use: the best layout the FEA
already confirmed), whatever layout it returns; on a task it never evaluated (a held-out task, a
zero-sample planner) by the layout it returns. A learner returns its greedy policy's layouts: they
are scored beside the incumbents as a second figure (``PlanResult.policy_*``), never in the objective.

Modes: ``per-task`` (reconfigurable fixtures: one layout per task, each judged on its task) and
``shared`` (one layout for every task, judged by its worst task).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import numbers
import types
import typing
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np

from fixbench.cases.errors import FixbenchError
from fixbench.cases.problem import Deformation, Evaluator, Problem
from fixbench.solvers.transfer import fill_held_out, warm_layouts

MODES = ("per-task", "shared")
#: columns of an anytime trace (:class:`TracedEvaluator`; stored by the harness as they are): after the
#: planner had spent ``task_samples`` on ``task`` (``samples`` in all), the best max deformation it had
#: seen there was ``best``
TRACE_COLUMNS = ("task", "task_samples", "samples", "best")


class PlannerError(FixbenchError):
    """A planner cannot run as asked (bad config, budget too small for the method, ...)."""


class ConfigError(PlannerError):
    """A config field holds a value its planner cannot use: ``field`` names it, ``problem`` says why
    (a matrix names its entry and the field)."""

    def __init__(self, field: str, problem: str):
        self.field, self.problem = field, problem
        super().__init__(f"{field} {problem}")


@dataclass(frozen=True)
class PlannerConfig:
    """Base of every planner's configuration; subclasses add documented fields.

    ``tunable`` declares the fields ``fixbench tune`` may search and how: field -> ("int", lo, hi),
    ("float", lo, hi), ("log", lo, hi) or ("choice", [values]) (bench/tune.py).

    A config checks itself when it is made (as BenchMARL's dataclasses do), so that a bad value is
    refused before a run starts: here every field against its annotation; a subclass's
    ``__post_init__`` calls this one, then checks its ranges and choices (:func:`at_least`,
    :func:`require`)."""

    tunable: ClassVar[dict[str, tuple]] = {
    }

    hash_omits: ClassVar[dict[str, Any]] = {}
    """Fields added after runs were committed, with the value that does what those runs did: at that
    value a field is left out of :meth:`hash`, so that those runs keep the hash of the config they ran
    (the same planner); at any other value it is hashed like every field."""

    def __post_init__(self) -> None:
        for name, kind in _field_types(type(self)).items():
            value = getattr(self, name)
            if not _fits(value, kind):
                raise ConfigError(name, f"must be of type {_type_name(kind)}, got {value!r}")

    def hash(self) -> str:
        """Short stable hash of the config (for result rows): every field, but those of ``hash_omits`` at
        their listed value."""
        d = {k: v for k, v in asdict(self).items() if k not in self.hash_omits or v != self.hash_omits[k]}
        text = json.dumps(d, sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:10]


@functools.cache
def _field_types(cls: type[PlannerConfig]) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in fields(cls)}


def _fits(value, kind) -> bool:
    """Whether ``value`` is of the annotated ``kind``: an int is a float, a bool is no number, NaN no
    float; ``tuple[X, ...]`` and ``X | None`` look inside; another generic checks its container."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, a) for a in args)
    if origin is tuple:
        inner = [args[0]] * len(value) if args[-1:] == (Ellipsis,) and isinstance(value, tuple) else args
        return isinstance(value, tuple) and len(inner) == len(value) and all(map(_fits, value, inner))
    if kind is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool) and value == value
    if kind is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    return isinstance(value, origin or kind) if isinstance(origin or kind, type) else True


def _type_name(kind) -> str:
    return kind.__name__ if isinstance(kind, type) else str(kind)


def at_least(config: PlannerConfig, low: float, *names: str) -> None:
    """Refuse (:class:`ConfigError`) the first of the fields ``names`` whose value is below ``low``."""
    for name in names:
        value = getattr(config, name)
        if not value >= low:
            raise ConfigError(name, f"must be at least {low}, got {value!r}")


def require(config: PlannerConfig, name: str, ok: bool, want: str) -> None:
    """Refuse (:class:`ConfigError`) the field ``name`` unless ``ok``; ``want`` says what it must be."""
    if not ok:
        raise ConfigError(name, f"must be {want}, got {getattr(config, name)!r}")


class TracedEvaluator(Evaluator):
    """A counted evaluator that also records the anytime trace and the best layout per task.

    Trace rows are ``(task, task_samples, samples, best)``: after the planner had spent
    ``task_samples`` on ``task`` (``samples`` in total), the best max deformation it had seen on
    ``task`` was ``best``. Shared mode adds rows with task -1 and the worst-over-tasks objective.
    """

    TRACE_COLUMNS = TRACE_COLUMNS

    def __init__(self, problem: Problem, budget: int | None, tasks=None):
        super().__init__(problem, budget, tasks)
        self.task_samples = np.zeros(problem.n_tasks, dtype=np.int64)
        self.best = np.full(problem.n_tasks, np.inf)
        self.best_layout = np.full((problem.n_tasks, problem.n_agents), -1, dtype=np.int64)
        self.shared_best, self.shared_layout = np.inf, None
        self.trace: list[tuple[int, int, int, float]] = []

    def evaluate(self, task: int, layouts, soft_power: float | None = None) -> Deformation:
        d = super().evaluate(task, layouts, soft_power)
        self.task_samples[task] += len(d.max_u)
        i = int(np.argmin(d.max_u))
        if d.max_u[i] < self.best[task]:
            self.best[task] = d.max_u[i]
            self.best_layout[task] = np.atleast_2d(layouts)[i]
        self.trace.append((int(task), int(self.task_samples[task]), self.samples, float(self.best[task])))
        return d

    def fitness(self, task: int, layouts, soft_power: float | None = None) -> np.ndarray:
        """What a search minimises on ``task``: the soft max with ``soft_power``, else the max."""
        d = self.evaluate(task, layouts, soft_power)
        return d.soft_u if soft_power else d.max_u

    def shared_fitness(self, layouts, soft_power: float | None = None) -> np.ndarray:
        """The same over all tasks (``evaluate_shared_soft``): soft worst with ``soft_power``, else worst."""
        worst, soft = self.evaluate_shared_soft(layouts, soft_power)
        return soft if soft_power else worst

    def evaluate_shared(self, layouts) -> np.ndarray:
        """Worst max deformation over all tasks of each layout; costs n_tasks samples per layout."""
        return self.evaluate_shared_soft(layouts)[0]

    def evaluate_shared_soft(self, layouts, soft_power: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(worst max over tasks, soft worst) of each layout; costs n_tasks samples per layout.

        The soft worst is the power mean over tasks and points, (mean_t soft_u_t^p)^(1/p), from the
        same solves (NaN without ``soft_power``).
        """
        layouts = self.problem.check_layouts(layouts)
        if len(self.tasks) < self.problem.n_tasks:
            self.check_open(int(np.setdiff1d(np.arange(self.problem.n_tasks), self.tasks)[0]))
        self.afford(len(layouts) * self.problem.n_tasks)  # all or nothing; charged task by task
        per_task = [self.evaluate(t, layouts, soft_power) for t in range(self.problem.n_tasks)]
        worst = np.max([d.max_u for d in per_task], axis=0)
        soft = np.full(len(layouts), np.nan)
        if soft_power:
            s = np.array([d.soft_u for d in per_task])
            top = np.where(worst > 0, worst, 1.0)  # scale by the max so that no power overflows
            soft = top * np.mean((s / top) ** soft_power, axis=0) ** (1 / soft_power)
        i = int(np.argmin(worst))
        if worst[i] < self.shared_best:
            self.shared_best, self.shared_layout = float(worst[i]), layouts[i].copy()
        self.trace.append((-1, self.samples, self.samples, self.shared_best))
        return worst, soft


#: what a training curve's index counts (:class:`Curve`): env steps (one counted sample each), episodes
#: (passes over the training tasks), rounds (a bandit's), fits (of a bandit's model), batches (a rollout
#: and its updates), updates (gradient steps)
CURVE_UNITS = ("step", "episode", "round", "fit", "batch", "update")


@dataclass(frozen=True)
class Curve:
    """One training curve as its learner declares it: ``values[i]`` after the (i + 1)-th ``unit`` of the
    run (:data:`CURVE_UNITS`); NaN where there is no value (an episode without an update)."""

    unit: str
    values: np.ndarray

    def __post_init__(self) -> None:
        if self.unit not in CURVE_UNITS:
            raise PlannerError(f"curve unit '{self.unit}' is not one of {', '.join(CURVE_UNITS)}")
        raw = np.asarray(self.values, dtype=object)
        if raw.ndim != 1:
            raise PlannerError(f"a curve is one value a {self.unit}; got shape {raw.shape}")
        object.__setattr__(self, "values", np.array([math.nan if v is None else v for v in raw], dtype=float))


@dataclass
class Training:
    """A learner's training record (``PlanResult.training``): its curves by name, each with its unit,
    declared by the learner, never guessed from ``info``; a per-agent curve names its agent
    (``td_loss/agent0``). The harness stores every curve (bench/running/cells.py); Figure 4 draws those
    it knows by name (bench/reporting/figures.py ``FIGURE4_CURVES``)."""

    curves: dict[str, Curve] = field(default_factory=dict)

    def add(self, unit: str, **curves) -> Training:
        """Declare ``curves`` (name=values), all indexed by ``unit``; returns the record, to chain."""
        for name, values in curves.items():
            if name in self.curves:
                raise PlannerError(f"curve '{name}' declared twice")
            self.curves[name] = Curve(unit, values)
        return self

    def values(self, name: str) -> np.ndarray:
        return self.curves[name].values


@dataclass
class PlanResult:
    """What a planner run produced, scored on the true (uncounted) oracle afterwards."""

    planner: str
    config: dict
    config_hash: str
    case: str
    material: str
    mode: str
    seed: int
    budget: int | None
    samples: int  # samples the planner spent online
    layouts: np.ndarray  # (n_tasks, n_agents) global action indices (= candidates, one pad a robot)
    max_deformation: np.ndarray  # (n_tasks,) metres, max |u| of each task's layout
    reward: np.ndarray  # (n_tasks,) Gaussian reward of each task's layout
    trace: np.ndarray  # (rows, 4): TracedEvaluator.TRACE_COLUMNS
    info: dict = field(default_factory=dict)  # planner-specific figures (gaps, iterations, ...)
    reward_bell: np.ndarray | None = None  # (n_tasks,) the reference code's bell reward
    held_out: np.ndarray | None = None  # held-out track: the tasks acted on without samples
    pads: np.ndarray | None = None  # (n_tasks, n_agents * m) candidates the layouts place (-1: none)
    policy_layouts: np.ndarray | None = None  # (n_tasks, n_agents) what the planner returned, where that
    #: is not its incumbent (a learner's greedy policy); scored beside it, never in the objective
    policy_max_deformation: np.ndarray | None = None  # (n_tasks,) metres, of policy_layouts
    training: Training | None = None  # a learner's training curves (None: a planner that does not learn)

    @property
    def scored_tasks(self) -> np.ndarray:
        """The tasks the objective is taken over: the held-out ones in that track, else all."""
        return np.arange(len(self.layouts)) if self.held_out is None else self.held_out

    @property
    def objective(self) -> float:
        """Mean over tasks (per-task; over the held-out tasks in that track) or worst task (shared)."""
        return self._objective(self.max_deformation)

    @property
    def policy_objective(self) -> float | None:
        """The objective of the returned (policy) layouts, where they are not the incumbents."""
        return None if self.policy_max_deformation is None else self._objective(self.policy_max_deformation)

    def _objective(self, per_task: np.ndarray) -> float:
        u = per_task[self.scored_tasks]
        return float(u.max() if self.mode == "shared" else u.mean())

    def summary(self) -> dict[str, Any]:
        return {"planner": self.planner, "case": self.case, "material": self.material,
                "mode": self.mode, "seed": self.seed, "budget": self.budget, "samples": self.samples,
                "held_out_tasks": None if self.held_out is None else self.held_out.tolist(),
                "objective_m": self.objective,
                "mean_max_deformation_m": float(self.max_deformation.mean()),
                "worst_max_deformation_m": float(self.max_deformation.max()),
                "mean_reward": float(self.reward.mean()), "policy_objective_m": self.policy_objective,
                "config": self.config, "info": self.info,
                "curves": None if self.training is None else {
                    name: {"unit": c.unit, "values": c.values.tolist()} for name, c in self.training.curves.items()},
                "per_task": [{"task": t, "layout": self.layouts[t].tolist(),
                              **({} if self.pads is None else {"pads": self.pads[t].tolist()}),
                              "max_deformation_m": float(self.max_deformation[t]),
                              "reward": float(self.reward[t])} for t in range(len(self.layouts))]}


@dataclass(frozen=True)
class Share:
    """One search's share of a planner's budget, as :meth:`Planner.drive` hands it to the search."""

    task: int | None
    """The task searched; None: the shared layout, one layout for every task judged by its worst."""

    score: Callable[[np.ndarray], np.ndarray]
    """(L, n_agents) layouts -> one value each to minimise (the max |u|, or the soft max with the
    driver's ``soft_power``; the worst task for the shared layout): counted, and the evaluator keeps
    the best layout by the true max."""

    allowance: int | float
    """Layouts the search may evaluate: its share of the budget (a shared layout costs n_tasks
    samples), or the planner's own number when the budget is unlimited."""

    warm: np.ndarray
    """(k, n_agents) layouts to start from: the best layouts of the solved tasks nearest this one
    (``transfer``; empty without it, and for the shared layout)."""


class Planner(ABC):
    """Base class of every planner (see the module docstring and README, "Write your own planner")."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: the kind of method, as the README groups the planners: marl, bandit, evolutionary, local-search,
    #: case-based, qp, bayesian-optimisation, rules, random, exact (a plugin may name its own)
    family: ClassVar[str] = "other"
    Config: ClassVar[type[PlannerConfig]] = PlannerConfig
    modes: ClassVar[tuple[str, ...]] = MODES
    #: True for a learner whose returned layouts are its greedy policy's (not its incumbents): the
    #: policy is then always scored as the second figure ``policy``
    returns_policy: ClassVar[bool] = False
    #: True for a planner that acts with no sample at all (k = 0, a budget of 0): a layout for every
    #: position from what it brings to the problem (hand rules, a case library), none evaluated
    zero_shot: ClassVar[bool] = False
    #: False for a planner whose results follow the host's floating-point code paths (PyTorch training:
    #: the BLAS kernels a CPU type gets, the thread count): the same bits on the same machine only, so
    #: ``fixbench verify`` judges a rerun elsewhere by its group's spread over seeds, not to 1e-9
    same_on_every_host: ClassVar[bool] = True

    def __init__(self, config: PlannerConfig | None = None, **overrides: Any):
        try:  # the config checks itself when made (PlannerConfig)
            config = config if config is not None else self.Config()
            self.config = replace(config, **overrides) if overrides else config
        except (TypeError, ConfigError) as exc:
            raise PlannerError(f"planner '{self.name}': {exc}") from None

    @abstractmethod
    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator,
             mode: str) -> tuple[np.ndarray, dict] | tuple[np.ndarray, dict, Training]:
        """Return (layouts, info): layouts is (n_tasks, n_agents), all rows equal in shared mode; info the
        run's own figures (scalars and short lists). A learner returns (layouts, info, training), its
        curves declared in a :class:`Training`.

        Learn only through ``ev`` (every evaluation is counted); draw randomness only from ``rng``.
        """

    def drive(self, problem: Problem, ev: TracedEvaluator, mode: str, search: Callable[[Share], Any],
              unlimited: int | float, soft_power: float | None = None, transfer: int = 0) -> tuple[np.ndarray, list]:
        """The budget loop of a search planner: ``search`` once a task, or once on the shared layout.

        Per-task mode: the tasks ``ev`` allows, in order, each with an equal share of the budget
        (:func:`split_budget`; ``unlimited`` layouts each when the budget is unlimited) and, with
        ``transfer`` k > 0, the best layouts of the k solved tasks nearest it (read when its turn
        comes, :func:`~fixbench.solvers.transfer.warm_layouts`); the layouts are each task's best
        evaluated. Shared mode: one search on the worst task, the budget divided by n_tasks (a
        layout costs n_tasks samples); the layouts are the best shared layout, on every task. A
        budget that pays for no layout on some task (no shared layout) is a :class:`PlannerError`.

        Returns (layouts, what ``search`` returned, one entry a search)."""
        if mode == "shared":
            require_budget(self.name, ev.remaining, problem.n_tasks, "one shared layout on every task")
            allowance = unlimited if ev.budget is None else int(ev.remaining // problem.n_tasks)
            no_warm = np.empty((0, problem.n_agents), dtype=np.int64)
            stats = [search(Share(None, functools.partial(ev.shared_fitness, soft_power=soft_power), allowance,
                                  no_warm))]
            return np.tile(ev.shared_layout, (problem.n_tasks, 1)), stats
        require_budget(self.name, ev.remaining, len(ev.tasks), "one layout per task")
        stats = []
        for task, allowance in zip(ev.tasks.tolist(), split_budget(ev.budget, len(ev.tasks), unlimited)):
            warm = warm_layouts(problem, ev.best, ev.best_layout, task, transfer)
            score = functools.partial(ev.fitness, task, soft_power=soft_power)
            stats.append(search(Share(task, score, allowance, warm)))
        return ev.best_layout.copy(), stats

    def solve(self, problem: Problem, budget: int | None, seed: int = 0,
              mode: str = "per-task", train_tasks=None) -> PlanResult:
        """Plan, check and score. ``train_tasks`` (held-out track, per-task mode): the planner may
        evaluate only these tasks and acts on the others with zero samples; a layout it leaves at -1
        on a held-out task becomes the best layout of the nearest training task
        (:func:`fixbench.solvers.transfer.fill_held_out`), and the objective is taken over the held-out tasks."""
        if mode not in self.modes:
            raise PlannerError(f"planner '{self.name}' does not support mode '{mode}' "
                               f"(supports: {', '.join(self.modes)})")
        held = None
        if train_tasks is not None:
            if mode != "per-task":
                raise PlannerError("the held-out track is per-task: each task gets its own layout")
            held = np.setdiff1d(np.arange(problem.n_tasks), np.asarray(train_tasks, dtype=np.int64))
            if len(held) == 0:
                raise PlannerError("the held-out track needs at least one task outside the training tasks")
        if budget == 0 and not self.zero_shot:
            raise PlannerError(f"--budget 0: planner '{self.name}' cannot act with zero samples (k = 0): it has "
                               "nothing to place pads by before it samples")
        ev = TracedEvaluator(problem, budget, train_tasks)  # refuses a negative budget; 0 evaluates nothing
        layouts, info, training = (*self.plan(problem, ev, np.random.default_rng(seed), mode), None)[:3]
        layouts = np.asarray(layouts).reshape(problem.n_tasks, problem.n_agents)
        if held is not None:
            layouts, filled = fill_held_out(problem, layouts, ev.tasks)
            if filled:
                info = {**info, "held_out_from": "nearest training task's best layout"}
        returned = problem.check_layouts(layouts)
        if mode == "shared" and not (returned == returned[0]).all():
            raise PlannerError(f"planner '{self.name}' returned different layouts in shared mode")
        layouts = incumbent_layouts(ev, returned, mode)
        scored = _measure(problem, layouts)
        policy = policy_u = None
        if self.returns_policy or not np.array_equal(layouts, returned):
            policy, policy_u = returned, _measure(problem, returned).max_u
        return PlanResult(self.name, _config_dict(self.config), self.config.hash(), problem.name,
                          problem.spec.material.name, mode, seed, budget, ev.samples, layouts,
                          scored.max_u, scored.reward_gaussian,
                          np.array(ev.trace, dtype=float).reshape(-1, 4), info, scored.reward_bell, held,
                          None if problem.spec.effector.simple else problem.pads(layouts), policy, policy_u,
                          training)


def incumbent_layouts(ev: TracedEvaluator, returned: np.ndarray, mode: str) -> np.ndarray:
    """The layouts a run is scored by (the scoring rule of the module docstring): per task, the best
    layout evaluated there, else the returned one; in shared mode the best shared layout evaluated, else
    the returned one."""
    if mode == "shared":
        return returned if ev.shared_layout is None else np.tile(ev.shared_layout, (len(returned), 1))
    seen = np.isfinite(ev.best)
    return np.where(seen[:, None], ev.best_layout, returned)


def _measure(problem: Problem, layouts: np.ndarray) -> Deformation:
    """Deformation of each task's layout on the uncounted oracle (the benchmark's measurement)."""
    return problem.deformation(np.vstack([problem.measure(t, layouts[t:t + 1]) for t in range(problem.n_tasks)]))


def _config_dict(config: PlannerConfig) -> dict:
    return {f.name: getattr(config, f.name) for f in fields(config)}


def split_budget(budget: int | None, parts: int, default: int) -> list[int]:
    """Split a total budget into ``parts`` near-equal shares (``default`` each when unlimited)."""
    if budget is None:
        return [default] * parts
    base, extra = divmod(budget, parts)
    return [base + (i < extra) for i in range(parts)]


def random_layouts(problem: Problem, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` uniform random layouts, one candidate per agent from its own set."""
    return np.column_stack([rng.choice(a, size=n) for a in problem.action_sets]).astype(np.int64)


def require_budget(name: str, have: float, need: int, what: str) -> None:
    """Clear error when a budget is too small for a method."""
    if have < need:
        raise PlannerError(f"planner '{name}': budget too small: {what} needs {need} samples, "
                           f"{'unlimited' if math.isinf(have) else int(have)} available")
