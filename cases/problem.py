"""The fixture-planning problem and its counted evaluator.

A :class:`Problem` is a part + material + base supports + fixture candidates + agents (disjoint
action sets) + tasks + reward settings. A *layout* is one action per agent, each from the agent's
own set (global action indices, in agent order). An action is an *option*: the pads the robot
places (``Problem.options``, one row of ``m`` candidate indices, -1 for "no pad"). With one pad per
robot (the usual case, :attr:`~fixbench.cases.spec.Effector.simple`) option ``i`` is candidate ``i``;
with pairs, ``m`` pads or idle robots the options are enumerated per robot. ``Problem.points`` gives
each option's place in the plane (its pads' coordinates, 2 m numbers) for planners that search by
geometry. Planners see the problem's structure and evaluate layouts only through an
:class:`Evaluator`, which counts every layout as one sample, charges one sample per compliance
column read, and refuses to pass a hard budget.

>>> problem = load_problem("wing_panel_small")
>>> ev = problem.evaluator(budget=100)
>>> d = ev.evaluate(0, [[a[0] for a in problem.action_sets]])
>>> ev.samples
1
"""

from __future__ import annotations

import hashlib
import itertools
import math
import pickle
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fixbench.cases import cache, rewards
from fixbench.cases.errors import BudgetExhausted, CaseError, HeldOutTask
from fixbench.cases.spec import CaseSpec, Effector, load_case_spec

if TYPE_CHECKING:  # the FE code is imported when a model is first built (fast start of light commands)
    from fixbench.cases.fem import PlateModel
    from fixbench.cases.oracle import Oracle

#: The process's cache, the one place where problems, models and oracles are kept between calls:
#: models and oracles by spec content (problems that differ only in their agents share them), the
#: CACHE_SIZE most recently used of each, and the latest problem asked for by name
#: (:func:`cached_problem`). A benchmark worker moves from problem to problem and its memory must
#: not grow with them: a wing spar's oracle data is 3 GB.
CACHE_SIZE = 3
_MODELS: OrderedDict[str, PlateModel] = OrderedDict()
_ORACLES: OrderedDict[str, Oracle] = OrderedDict()
_LATEST: dict[Hashable, Problem] = {}


def set_cache_size(n: int) -> None:
    """Keep at most ``n`` models and oracles per process (a benchmark worker, which gets its jobs
    grouped by problem, keeps 1: a bus panel model and oracle hold ~115 MB)."""
    global CACHE_SIZE
    CACHE_SIZE = max(1, int(n))
    for kept in (_MODELS, _ORACLES):
        while len(kept) > CACHE_SIZE:
            kept.popitem(last=False)


def _cached(cache: OrderedDict, key: str, build):
    if key in cache:
        cache.move_to_end(key)
    else:
        while len(cache) >= CACHE_SIZE:  # evict first: the old and the new never live together
            cache.popitem(last=False)
        cache[key] = build()
    return cache[key]


def cached_problem(key: Hashable, build: Callable[[], Problem]) -> Problem:
    """The problem the caller names ``key``: the one kept from the previous call if that had the same
    key, else ``build()``, kept in its place.

    Bound: one problem, the latest (a benchmark worker gets its jobs grouped by problem). A problem
    holds its model and oracle once built, so keeping more problems would keep more than CACHE_SIZE
    models and oracles alive; the cache lets the old problem go before it builds the new one, so that
    it never holds both. A problem built again finds its model and oracle in their caches while they
    are kept there.
    """
    if key not in _LATEST:
        _LATEST.clear()
        _LATEST[key] = build()
    return _LATEST[key]


@dataclass(frozen=True)
class Deformation:
    """Deformation over the measurement points of a batch of layouts (metres): maxima and a soft max."""

    max_ux: np.ndarray
    max_uy: np.ndarray
    max_w: np.ndarray
    max_u: np.ndarray  # magnitude sqrt(ux^2 + uy^2 + w^2): the objective planners minimise
    max_uxy: np.ndarray  # in-plane magnitude sqrt(ux^2 + uy^2)
    soft_u: np.ndarray  # power mean of |u| over the points when asked for (Oracle.evaluate), else NaN
    reward_gaussian: np.ndarray
    reward_bell: np.ndarray

    def row(self, i: int) -> dict[str, float]:
        return {k: float(getattr(self, k)[i]) for k in self.__dataclass_fields__}


class Problem:
    """One fixture-planning problem (see module docstring)."""

    def __init__(self, spec: CaseSpec, mesh_scale: float = 1.0):
        self.spec = spec if mesh_scale == 1.0 else spec.with_mesh_scale(mesh_scale)
        self.mesh_scale = mesh_scale
        self.name = spec.name
        self.candidates = spec.candidates
        self.tasks = spec.tasks
        self.n_agents = spec.n_agents
        self.candidate_sets = _candidate_sets(spec)
        self.options, self.action_sets = _options(spec, self.candidate_sets)
        self.features = np.array([t.features for t in spec.tasks])

    @cached_property
    def points(self) -> np.ndarray:
        """(n_options, 2 m) coordinates (m) of each option's pads; a "no pad" sits at its robot's
        candidates' centroid (a place for distances, not a pad)."""
        if self.spec.effector.simple:
            return self.candidates
        out = np.empty((len(self.options), self.options.shape[1], 2))
        for s, acts in zip(self.candidate_sets, self.action_sets):
            opt = self.options[acts]
            out[acts] = np.where(opt[..., None] >= 0, self.candidates[np.maximum(opt, 0)],
                                 self.candidates[s].mean(axis=0))
        return out.reshape(len(self.options), -1)

    def pads(self, layouts) -> np.ndarray:
        """Candidate indices of the pads that ``layouts`` place: (L, n_agents * m), -1 for none.

        With a pad limit the pads are handed out in robot order until it is reached (see
        :class:`~fixbench.cases.spec.Effector`). Layouts are not checked here.
        """
        arr = np.atleast_2d(np.asarray(layouts, dtype=np.int64))
        if self.spec.effector.simple:
            return arr
        out = self.options[arr].reshape(len(arr), -1)
        limit = self.spec.effector.pads
        if limit:
            out = np.where(np.cumsum(out >= 0, axis=1) > limit, -1, out)
        return out

    def pad_xy(self, layout) -> np.ndarray:
        """(k, 2) coordinates (m) of the pads one layout places (for drawing it)."""
        pads = self.pads(np.asarray(layout, dtype=np.int64).reshape(1, -1))[0]
        return self.candidates[pads[pads >= 0]]

    def measure(self, task: int, layouts, soft_power: float | None = None) -> np.ndarray:
        """Uncounted oracle maxima (L, 6) of layouts (analysis and references, never a planner)."""
        return self.oracle.evaluate(task, self.pads(layouts), soft_power)

    @property
    def n_tasks(self) -> int:
        return len(self.tasks)

    @property
    def joint_size(self) -> int:
        """Number of joint layouts (product of the agents' set sizes)."""
        return math.prod(len(a) for a in self.action_sets)

    def _key(self) -> str:
        """Hash of everything the model and oracle depend on (all of the spec but the agents)."""
        content = replace(self.spec, n_agents=1, agent_regions=(), effector=Effector())
        return hashlib.sha1(pickle.dumps((content, self.mesh_scale))).hexdigest()

    @cached_property
    def model(self) -> PlateModel:
        from fixbench.cases.fem import PlateModel

        return _cached(_MODELS, self._key(), lambda: PlateModel(self.spec))

    @cached_property
    def oracle(self) -> Oracle:
        from fixbench.cases.oracle import Oracle

        key = self._key()
        return _cached(_ORACLES, key, lambda: Oracle(self.model, self.candidates, cache_key=cache.key(key)))

    @cached_property
    def _owner(self) -> np.ndarray:
        """Agent owning each action (-1: none)."""
        owner = np.full(len(self.options), -1, dtype=np.int64)
        for a, allowed in enumerate(self.action_sets):
            owner[allowed] = a
        return owner

    def check_layouts(self, layouts) -> np.ndarray:
        """Layouts as an (L, n_agents) int array, each entry from its agent's own set."""
        arr = np.atleast_2d(np.asarray(layouts))
        what = "candidate" if self.spec.effector.simple else "action"
        if arr.ndim != 2 or arr.shape[1] != self.n_agents or not np.issubdtype(arr.dtype, np.integer):
            raise CaseError(self.spec.source, "layout",
                            f"must be {self.n_agents} integer {what} indices per layout")
        arr = arr.astype(np.int64)
        inside = (arr >= 0) & (arr < len(self.options))
        ok = inside & (self._owner[np.where(inside, arr, 0)] == np.arange(self.n_agents))
        if not ok.all():
            a = int(np.flatnonzero((~ok).any(axis=0))[0])
            allowed = self.action_sets[a]
            raise CaseError(self.spec.source, "layout", f"{what} {int(arr[~ok[:, a], a][0])} is not "
                            f"in agent {a}'s set ({allowed[0]}..{allowed[-1]})")
        return arr

    def check_task(self, task: int) -> int:
        if not 0 <= int(task) < self.n_tasks:
            raise CaseError(self.spec.source, "task", f"must be in 0..{self.n_tasks - 1}, got {task}")
        return int(task)

    def deformation(self, maxima: np.ndarray) -> Deformation:
        """Rewards use the in-plane magnitude as the literature's "x" and w as its "z"."""
        sx, sz = self.spec.reward_sigma
        ux, uy, w, u, uxy, soft = maxima.T
        return Deformation(ux, uy, w, u, uxy, soft, rewards.gaussian(uxy, w, sx, sz), rewards.bell(uxy, w))

    def evaluator(self, budget: int | None = None) -> Evaluator:
        return Evaluator(self, budget)

    def solve_direct(self, task: int, layout) -> dict:
        """Reference path, uncounted: full fields by a direct constrained solve (for checks).

        ``layout`` None is the free response: the part on its base supports alone, no fixture pads.
        It always exists: a case whose base supports leave a rigid motion free is refused when its
        model is built, and a stiffness that is still singular raises a one-line NumericalError.
        """
        task = self.check_task(task)
        if layout is None:
            return self.model.solve_direct(task, np.zeros((0, 2)))
        pads = self.pads(self.check_layouts(layout))[0]
        return self.model.solve_direct(task, self.candidates[pads[pads >= 0]])

    def displacement_at(self, task: int, layout, points: np.ndarray) -> np.ndarray:
        """(ux, uy, w) in metres at ``points`` ((n, 2), m) for ``layout`` (None: the free response),
        from a direct solve: the FE field itself, anywhere on the part, not only at the measurement
        points the oracle keeps. A point outside the part (or inside a hole) is a CaseError."""
        import shapely

        pts = np.atleast_2d(np.asarray(points, dtype=float))
        part = self.spec.polygon.buffer(1e-9)
        for x, y in pts:
            if not part.covers(shapely.Point(x, y)):
                raise CaseError(self.spec.source, "--at", f"({x * 1e3:g}, {y * 1e3:g}) mm lies outside "
                                "the part (or inside a hole)")
        fields = self.solve_direct(task, layout)
        out = np.zeros((len(pts), 3))
        for name, u in fields.items():
            vals = (self.model.component_probes(name, pts) @ u).reshape(-1, len(pts))
            cols = {"bending": [2], "membrane": [0, 1]}[name]
            out[:, cols] = vals.T
        return out

    def direct_deformation(self, task: int, layout, soft_power: float | None = None) -> Deformation:
        """Deformation of ``layout`` (None: the free response) from a direct solve."""
        v = self.model.measure(self.solve_direct(task, layout))
        inplane = np.sqrt(v["ux"] ** 2 + v["uy"] ** 2)
        mag = np.sqrt(inplane**2 + v["w"] ** 2)
        soft = np.mean(mag**soft_power) ** (1 / soft_power) if soft_power else np.nan
        m = np.array([[np.abs(v["ux"]).max(), np.abs(v["uy"]).max(), np.abs(v["w"]).max(), mag.max(),
                       inplane.max(), soft]])
        return self.deformation(m)


class Evaluator:
    """The counted door to the oracle: every layout is a sample, every compliance column too.

    ``tasks`` restricts the door to some tasks (the held-out track: a planner trains on these and
    must act on the others without a sample); asking about any other task raises
    :class:`~fixbench.cases.errors.HeldOutTask`.
    """

    def __init__(self, problem: Problem, budget: int | None = None, tasks=None):
        if budget is not None and budget < 0:  # the one check of a budget (every planner, every command)
            raise CaseError("--budget", "", f"must be positive (or 0: no sample at all), got {budget}")
        self.problem = problem
        self.budget = budget
        self.samples = 0
        all_tasks = np.arange(problem.n_tasks)
        self.tasks = all_tasks if tasks is None else np.unique(np.asarray(tasks, dtype=np.int64))
        if len(self.tasks) == 0 or self.tasks[0] < 0 or self.tasks[-1] >= problem.n_tasks:
            raise CaseError(problem.spec.source, "tasks", f"evaluator tasks must be a non-empty subset of "
                            f"0..{problem.n_tasks - 1}")
        self._open = np.isin(all_tasks, self.tasks)

    def check_open(self, task: int) -> int:
        """``task`` as an int, or :class:`HeldOutTask` if this evaluator may not evaluate it."""
        task = self.problem.check_task(task)
        if not self._open[task]:
            raise HeldOutTask(f"{self.problem.name}: task {task} is held out: a planner acts on it "
                              "without evaluating it")
        return task

    @property
    def remaining(self) -> float:
        return math.inf if self.budget is None else self.budget - self.samples

    def afford(self, n: int) -> None:
        """Raise :class:`BudgetExhausted` unless ``n`` more samples fit in the budget."""
        if n > self.remaining:
            raise BudgetExhausted(f"{self.problem.name}: budget of {self.budget} samples exhausted "
                                  f"({self.samples} spent, {n} more asked)")

    def charge(self, n: int) -> None:
        """Spend ``n`` samples, or raise :class:`BudgetExhausted` and spend none."""
        self.afford(n)
        self.samples += n

    def evaluate(self, task: int, layouts, soft_power: float | None = None) -> Deformation:
        """Deformation of each layout for ``task``; costs one sample per layout.

        ``soft_power`` p also fills ``soft_u``, the power mean of |u| (same solve, no extra sample).
        """
        p = self.problem
        task, layouts = self.check_open(task), p.check_layouts(layouts)
        self.charge(len(layouts))
        return p.deformation(p.measure(task, layouts, soft_power))

    def compliance(self, field: str, candidates) -> tuple[np.ndarray, np.ndarray]:
        """Compliance data of candidates (coupling rows C, measurement influence H).

        Charged one sample per column: a candidate holding m components of ``field`` costs m.
        """
        cand = np.unique(np.atleast_1d(candidates))
        fo = self.problem.oracle.fields.get(field)
        if fo is None:
            raise CaseError(self.problem.spec.source, "field", f"'{field}' is not active in this case")
        self.charge(fo.per * len(cand))
        return self.problem.oracle.compliance(field, cand)

    def unconstrained(self, field: str, task: int) -> tuple[np.ndarray, np.ndarray]:
        """Free response of ``task`` in ``field`` (base supports only): (d0, m0).

        d0 = B u0 holds every candidate's constraint rows (the pads' mean held components), m0 = P u0
        the field at the measurement points (membrane: all ux, then all uy). Charged one sample:
        it is one FE solve.
        """
        task = self.check_open(task)
        fo = self.problem.oracle.fields.get(field)
        if fo is None:
            raise CaseError(self.problem.spec.source, "field", f"'{field}' is not active in this case")
        self.charge(1)
        return fo.d0[task].copy(), fo.m0[task].copy()


def decode_layouts(sets: list[np.ndarray], start: int, stop: int) -> np.ndarray:
    """Layouts ``start..stop-1`` of the joint space of the agents' candidate ``sets`` in mixed-radix
    order (agent 0 most significant): how exhaustive enumeration walks the joint space in chunks."""
    idx = np.arange(start, stop, dtype=np.int64)
    out = np.empty((len(idx), len(sets)), dtype=np.int64)
    for a in range(len(sets) - 1, -1, -1):
        idx, digit = np.divmod(idx, len(sets[a]))
        out[:, a] = sets[a][digit]
    return out


#: most options (actions of all robots together) a case may enumerate
MAX_OPTIONS = 10**7


def _options(spec: CaseSpec, sets: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Every robot's options (pads it may place) and the option indices of each robot's set."""
    eff = spec.effector
    if eff.simple:
        return np.arange(len(spec.candidates), dtype=np.int64)[:, None], sets
    rows, acts, start = [], [], 0
    for a, s in enumerate(sets):
        if len(s) < eff.per_agent:
            raise CaseError(spec.source, "agents.fixtures_per_agent", f"agent {a} has {len(s)} candidates, "
                            f"fewer than its {eff.per_agent} pads")
        if math.comb(len(s), eff.per_agent) * len(sets) > MAX_OPTIONS:
            raise CaseError(spec.source, "agents.fixtures_per_agent", f"{len(sets)} robots choosing "
                            f"{eff.per_agent} of {len(s)} candidates each is over {MAX_OPTIONS:,} actions")
        tup = np.array(list(itertools.combinations(s, eff.per_agent)), dtype=np.int64)
        if eff.kind == "pair":
            d = np.linalg.norm(spec.candidates[tup[:, 0]] - spec.candidates[tup[:, 1]], axis=1)
            tup = tup[(d <= eff.span * (1 + 1e-9)) & (d >= 2 * spec.fixture_radius * (1 - 1e-9))]
            if not len(tup):
                raise CaseError(spec.source, "agents.span_mm", f"agent {a} has no two candidates "
                                f"{2 * spec.fixture_radius * 1e3:g} to {eff.span * 1e3:g} mm apart")
        if eff.idle:
            tup = np.vstack([tup, np.full((1, eff.per_agent), -1)])
        rows.append(tup)
        acts.append(np.arange(start, start + len(tup), dtype=np.int64))
        start += len(tup)
    return np.vstack(rows), acts


def _candidate_sets(spec: CaseSpec) -> list[np.ndarray]:
    n = len(spec.candidates)
    if spec.agent_regions:
        import shapely

        sets = []
        for _, ring in spec.agent_regions:
            inside = shapely.contains_xy(shapely.Polygon(ring), spec.candidates[:, 0], spec.candidates[:, 1])
            sets.append(np.flatnonzero(inside))
        return sets
    return [a.astype(np.int64) for a in np.array_split(np.arange(n), spec.n_agents)]


def load_problem(case: str | Path, material: str | None = None, agents: int | None = None,
                 mesh_scale: float = 1.0, fixtures_per_agent: int | None = None) -> Problem:
    """A problem from a catalog name or a TOML path, optionally with another material, agent count
    or number of pads per agent."""
    return Problem(load_case_spec(case, material, agents, fixtures_per_agent), mesh_scale)


def task_subset(n_tasks: int, wanted: int | None) -> list[int]:
    """``wanted`` tasks spread evenly over ``n_tasks`` (all when None or too many): the tasks of a
    problem that a matrix or a regret reference restricts to ``tasks: N``."""
    if wanted is None or wanted >= n_tasks:
        return list(range(n_tasks))
    return sorted({int(round(x)) for x in np.linspace(0, n_tasks - 1, wanted)})


def problem_for(case: str, material: str | None, agents: int | None, tasks: int | None) -> Problem:
    """The problem of a catalog case or TOML path on ``tasks`` of its tasks (:func:`task_subset`; all
    when None), from the process's problem cache (:func:`cached_problem`), which keeps the latest one
    only (a benchmark worker gets its jobs grouped by problem)."""
    def build() -> Problem:
        spec = load_case_spec(case, material, agents)
        return Problem(spec.with_tasks(task_subset(len(spec.tasks), tasks)))

    return cached_problem((case, material, agents, tasks), build)
