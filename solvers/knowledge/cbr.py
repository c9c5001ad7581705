"""Case-based reasoning: retrieve solved (part, material, task) cases, adapt, revise, retain.

**Library.** :func:`build_library` solves source problems offline with another registered planner
(default ``greedy``, else ``random``) and writes one JSON file: for each solved task, its feature
vectors (below) and its fixture *positions* in metres relative to the part's bounding-box corner
(with the box size, so positions can also be mapped in box-normalised coordinates), plus a
``sources`` list with the samples each source solve spent; ``library_samples`` is their sum. These
offline samples are reported apart from the online ones (``info["library_samples"]``).
``Config.library`` names the file; a missing file is built there on first use from
``Config.bootstrap``. Without a path the library is built from ``bootstrap`` (the four ``*_small``
catalog cases, ``bootstrap_budget`` samples per task), kept in memory for the process and, where
the run names a disk cache, stored there for the run's other processes (:func:`bootstrap_library`;
never anywhere else: no state outside the run).

Two honest settings (``exclude``): ``"part"`` (default) leaves the query's part out (transfer
between parts); ``"task"`` leaves out only the query's own task of the same case and material, so
the library may hold other tasks, materials and variants of the same part (what CBR is for:
variations of one product); ``"none"`` uses every entry (a check of the library, not a benchmark). Each entry also keeps
``score_m``, the harness's score of the source layout, for reports only: retrieval never reads it.

**Features** (each a plain number; distances are Euclidean on the concatenation, each block
multiplied by its ``*_weight``):

- part: log10 of the bounding-box width and height (m), area / box area (fill), log10 thickness,
  number of holes, log10 number of candidates, number of agents / 10, mean fraction of the four
  DOFs (ux, uy, w, rot) that the base supports hold, and the supports' centroid in box-normalised
  coordinates (where the part is held). Logs make them scale-aware: a twice-larger part is 0.3 away.
- material: log10 E (Pa), Poisson's ratio, log10 density. Deformation scales with 1/E, but the
  best layout of a linear problem hardly depends on it: the default weight is small.
- task: the case's task feature vector (padded or cut to ``TASK_DIMS``), the box-normalised
  centroid of the task's patch loads (0.5, 0.5 if none), log10 of the total patch force (N), and
  the counts of pressure, centrifugal and edge-traction loads.

**Retrieval** is a k-nearest-neighbour query (``scipy.spatial.cKDTree``) for each task.

**Adaptation** maps a retrieved layout's positions into the current part (box-normalised by
default, ``map_normalised``), assigns positions to agents by a minimum-cost assignment
(``scipy.optimize.linear_sum_assignment``; cost = distance from the position to the agent's
nearest candidate), and gives each assigned agent its candidate nearest to its position. With more
agents than stored positions, the agents left over take, one by one, the candidate of their set
farthest from every pad placed so far (spread); with fewer, the worst-matched positions are dropped.

**Revise** (counted): the k distinct adaptations are evaluated and a local search in the plane
(:func:`fixbench.solvers.search.local.local_search`, the ``local`` planner's defaults) goes on from the best
of them with what is left of the task's share of the budget: a retrieved plan is a start, and a
case-based planner that stopped there would leave most of its samples unspent. ``polish_samples``
caps the samples a task may spend (-1: its whole share; with an unlimited budget,
``samples_per_task``); ``polish_samples=0`` spends no sample at all: the nearest case's
adaptation is returned unevaluated. A task's layout is the one with the lowest max deformation
evaluated on it. Shared mode pools the neighbours of every task, ordered by distance, and judges
layouts on every task (n_tasks samples each).

**Retain** (``retain``, per-task mode): each task revised in this run joins the cases that later
tasks retrieve, with its best evaluated layout: tasks are solved in order, so task t may retrieve
any revised task before it (with the library's cases, nearest first), and on the held-out track,
where only the training tasks are revised, every held-out task may retrieve every training task.
The exclusion (``exclude``) concerns the offline library only: a run's own revised tasks are
experience it paid for with its own counted samples. Retained cases live in memory for the run and
are never written to the library file; ``info["retained"]`` counts them, ``info["neighbours"]``
marks them ``retained:``. They have places of their own (``retained_k``, 3) beside the k library
neighbours, so a long run's own cases never crowd the library out.
"""

from __future__ import annotations

import hashlib
import json
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from fixbench.cases import cache
from fixbench.cases.families.suites import expand_suites
from fixbench.cases.files import write_text_atomic
from fixbench.cases.materials import engineering_constants
from fixbench.cases.problem import Problem, load_problem
from fixbench.solvers.base import Planner, PlannerConfig, PlannerError, TracedEvaluator, at_least, require
from fixbench.solvers.registry import available, get
from fixbench.solvers.search.local import revise, revise_budget

TASK_DIMS = 4
_MEMORY: dict[tuple, dict] = {}  # the in-memory library of this process (one bootstrap setting)
FORMAT = 1
EXCLUDE = ("part", "task", "none")  # CBRConfig.exclude


@dataclass(frozen=True)
class CBRConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "k": ("int", 1, 8),
        "retained_k": ("int", 0, 6),
        "part_weight": ("log", 0.1, 10.0),
        "material_weight": ("log", 0.02, 2.0),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    library: str = ""
    """Path of the case library (JSON from build_library; built there from ``bootstrap`` if missing);
    empty: built from ``bootstrap`` in memory for this process, never written."""

    bootstrap: tuple[str, ...] = ("fan_small", "wing_panel_small", "wing_spar_small", "bus_panel_small")
    """Cases (catalog material) solved into a new library when the library file does not exist; the name
    of a shipped suite (``families-train``) stands for all its generated parts."""

    bootstrap_budget: int = 50
    """Samples per task the library-building planner gets when bootstrapping."""

    k: int = 3
    """Neighbours retrieved per task."""

    part_weight: float = 1.0
    """Weight of the part features in the retrieval distance."""

    material_weight: float = 0.2
    """Weight of the material features in the retrieval distance."""

    task_weight: float = 1.0
    """Weight of the task features in the retrieval distance."""

    map_normalised: bool = True
    """Map positions in box-normalised coordinates (else metres from the box corner)."""

    polish_samples: int = -1
    """Counted evaluations a task may spend revising its adaptations: -1, its whole share of the
    budget; 0, none (the adaptation is returned unevaluated); n, at most n."""

    samples_per_task: int = 200
    """Samples a task revises with when the budget is unlimited and ``polish_samples`` is -1."""

    exclude: str = "part"
    """Which library entries a query may not use: "part" (leave one part out: transfer between
    parts), "task" (only the query's own task of the same case and material) or "none" (everything:
    a library check, not a benchmark setting: the query finds its own offline solutions)."""

    retain: bool = True
    """Retain each revised task of the run as a case that later tasks retrieve (the 4R cycle's fourth
    step; in memory for the run, never written to the library file)."""

    retained_k: int = 3
    """With ``retain``: n > 0, a task's k nearest library cases and, beside them, the n nearest of the
    run's retained cases (which then never crowd the library out); 0, the k nearest of both together
    (on the paper's wing panel the retained cases took every place and mean regret was 10 % higher)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "bootstrap_budget", "k")
        at_least(self, 0, "part_weight", "material_weight", "task_weight", "samples_per_task", "retained_k")
        at_least(self, -1, "polish_samples")
        require(self, "exclude", self.exclude in EXCLUDE, f"one of {', '.join(EXCLUDE)}")
        require(self, "bootstrap", bool(self.library or self.bootstrap), "cases to build the library from when no "
                "library file is named (set library=PATH or bootstrap)")


# ---------------------------------------------------------------------------------------------
# features
# ---------------------------------------------------------------------------------------------
def _box(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    x0, y0, x1, y1 = problem.spec.polygon.bounds
    return np.array([x0, y0]), np.array([x1 - x0, y1 - y0])


def part_features(problem: Problem) -> np.ndarray:
    """Scale-aware numbers describing the part, its supports and its fixture problem."""
    spec = problem.spec
    lo, size = _box(problem)
    held = np.mean([len(s.holds) / 4 for s in spec.supports])
    where = []
    for s in spec.supports:
        if s.segment is not None:
            where.append(np.mean(s.segment, axis=0))
        elif s.point is not None:
            where.append(np.asarray(s.point))
        elif s.hole is not None:
            where.append(np.asarray(spec.polygon.interiors[s.hole].centroid.coords[0]))
        else:
            where.append(np.asarray(spec.polygon.centroid.coords[0]))
    centre = (np.mean(where, axis=0) - lo) / size
    return np.array([np.log10(size[0]), np.log10(size[1]), spec.polygon.area / np.prod(size),
                     np.log10(spec.thickness), len(spec.polygon.interiors), np.log10(len(problem.candidates)),
                     problem.n_agents / 10, held, *centre])


def material_features(problem: Problem) -> np.ndarray:
    """log E, nu, log density (a laminate: its in-plane engineering constants along x)."""
    E, nu, density = engineering_constants(problem.spec.material)
    return np.array([np.log10(E), nu, np.log10(density)])


def task_features(problem: Problem, task: int) -> np.ndarray:
    """The case's task features (padded), where and how hard its patch loads push, load kinds."""
    lo, size = _box(problem)
    f = np.zeros(TASK_DIMS)
    own = np.asarray(problem.features[task], dtype=float).ravel()[:TASK_DIMS]
    f[:len(own)] = own
    loads = problem.tasks[task].loads
    patches = [ld for ld in loads if ld.kind == "patch" and ld.at is not None]
    centre = (np.mean([ld.at for ld in patches], axis=0) - lo) / size if patches else np.full(2, 0.5)
    force = sum(float(np.linalg.norm(ld.force)) for ld in patches)
    spread = {"weight": "pressure"}  # a part's own weight is a uniform pressure of its material
    kinds = [sum(spread.get(ld.kind, ld.kind) == k for ld in loads)
             for k in ("pressure", "centrifugal", "edge_traction")]
    return np.concatenate([f, centre, [np.log10(1.0 + force)], kinds])


def features(problem: Problem, task: int, cfg: CBRConfig) -> np.ndarray:
    """The weighted retrieval vector of one task."""
    return np.concatenate([cfg.part_weight * part_features(problem),
                           cfg.material_weight * material_features(problem),
                           cfg.task_weight * task_features(problem, task)])


# ---------------------------------------------------------------------------------------------
# library
# ---------------------------------------------------------------------------------------------
def build_library(problems: list[Problem], planner: str | None = None, budget: int | None = None,
                  path: str | Path | None = None, seed: int = 0,
                  per_task_budget: int | None = None) -> dict:
    """Solve each problem per task with ``planner`` and save the library.

    Each problem gets ``budget`` samples, or ``per_task_budget`` times its task count when given.

    Default planner: ``greedy`` if registered, else ``random``. Returns the library (also written
    to ``path`` as JSON, parent folders created, when a path is given).
    """
    name = planner or ("greedy" if "greedy" in available() else "random")
    solver = get(name)()
    entries, sources = [], []
    for problem in problems:
        share = budget if per_task_budget is None else per_task_budget * problem.n_tasks
        result = solver.solve(problem, share, seed=seed, mode="per-task")
        sources.append({"case": problem.name, "material": problem.spec.material.name, "planner": name,
                        "budget": share, "seed": seed, "samples": int(result.samples)})
        entries += [entry(problem, t, result.layouts[t], float(result.max_deformation[t]))
                    for t in range(problem.n_tasks)]
    library = {"format": FORMAT, "library_samples": int(sum(s["samples"] for s in sources)),
               "sources": sources, "entries": entries}
    if path is None:
        return library
    write_text_atomic(Path(path).expanduser(), json.dumps(library, indent=1), ".json.tmp")
    return library


def entry(problem: Problem, task: int, layout: np.ndarray, score_m: float) -> dict:
    """One case: a task's features and its layout's positions (metres from the box corner)."""
    lo, size = _box(problem)
    return {"case": problem.name, "part": problem.spec.part, "material": problem.spec.material.name,
            "task": task, "task_name": problem.tasks[task].name,
            "part_features": part_features(problem).tolist(),
            "material_features": material_features(problem).tolist(),
            "task_features": task_features(problem, task).tolist(),
            "positions_m": (problem.points[layout] - np.tile(lo, problem.points.shape[1] // 2)).tolist(),
            "box_m": size.tolist(), "score_m": score_m}


def bootstrap_library(cases: tuple[str, ...], per_task_budget: int) -> dict:
    """The library built from catalog ``cases``, kept in the disk cache where one is named.

    Building it means solving every task of every case (about 20 s for the four ``*_small`` cases),
    and each matrix worker's process would pay it again. Where ``$FIXBENCH_CACHE_DIR`` names a
    folder (``fixbench run`` names ``DIR/oracle-cache``) the library is stored there, checksummed, as
    the oracle's data are (:mod:`fixbench.cases.cache`), under a hash of the cases' full specs, the
    budget and the source of every planner module; elsewhere it is built in memory. The build is
    deterministic (seed 0), so a stored library is the one a build would give.
    """
    problems = [load_problem(c) for c in expand_suites(cases)]
    content = hashlib.sha1(pickle.dumps(([p.spec for p in problems], per_task_budget)))
    for module in sorted(Path(__file__).parent.glob("*.py")):
        content.update(module.read_bytes())
    k = cache.key(f"cbr-library:{content.hexdigest()}")
    saved = cache.load(k)
    if saved is not None:
        return json.loads(saved["library"].tobytes())
    library = build_library(problems, budget=None, per_task_budget=per_task_budget)
    cache.store(k, {"library": np.frombuffer(json.dumps(library).encode(), dtype=np.uint8)},
                description=f"cbr case library: {', '.join(cases)}, {per_task_budget} samples a task")
    return library


def load_library(path: str | Path) -> dict:
    path = Path(path).expanduser()
    if not path.is_file():
        raise PlannerError(f"planner 'cbr': no case library at {path} (build one with "
                           "fixbench.solvers.knowledge.cbr.build_library, or set library=PATH)")
    try:
        library = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise PlannerError(f"planner 'cbr': {path}: not a case library ({exc})") from None
    if library.get("format") != FORMAT or not library.get("entries"):
        raise PlannerError(f"planner 'cbr': {path}: not a case library of format {FORMAT}, or empty")
    return library


def _entry_vector(e: dict, cfg: CBRConfig) -> np.ndarray:
    return np.concatenate([cfg.part_weight * np.asarray(e["part_features"]),
                           cfg.material_weight * np.asarray(e["material_features"]),
                           cfg.task_weight * np.asarray(e["task_features"])])


# ---------------------------------------------------------------------------------------------
# adaptation and planner
# ---------------------------------------------------------------------------------------------
def adapt(problem: Problem, entry: dict, normalised: bool) -> np.ndarray:
    """A library entry's positions mapped onto this problem's agents (see module docstring)."""
    lo, size = _box(problem)
    pos = np.asarray(entry["positions_m"], dtype=float)
    pos = pos.reshape(len(pos), -1)  # a row per stored robot: its pads' (x, y)
    k = pos.shape[1] // 2
    pos = np.tile(lo, k) + (pos * np.tile(size / np.asarray(entry["box_m"]), k) if normalised else pos)
    xy = problem.points
    if pos.shape[1] != xy.shape[1]:  # robots that placed another number of pads: match their centres
        pos = pos.reshape(len(pos), -1, 2).mean(axis=1)
        xy = xy.reshape(len(xy), -1, 2).mean(axis=1)
    sets = problem.action_sets
    cost = np.array([[np.min(np.linalg.norm(xy[s] - p, axis=1)) for p in pos] for s in sets])
    agents, which = linear_sum_assignment(cost)
    layout = np.full(problem.n_agents, -1, dtype=np.int64)
    for a, i in zip(agents, which):
        layout[a] = sets[a][np.argmin(np.linalg.norm(xy[sets[a]] - pos[i], axis=1))]
    for a in np.flatnonzero(layout < 0):  # more agents than stored positions: spread out
        placed = xy[layout[layout >= 0]]
        if len(placed) == 0:
            layout[a] = sets[a][0]
            continue
        gap = np.min(np.linalg.norm(xy[sets[a]][:, None, :] - placed[None, :, :], axis=2), axis=1)
        layout[a] = sets[a][np.argmax(gap)]
    return layout


class CaseBasedReasoning(Planner):
    name = "cbr"
    family = "case-based"
    description = "case-based reasoning: nearest solved cases from a library, adapted, revised by local search"
    Config = CBRConfig
    zero_shot = True  # with no sample, each position takes its nearest case's adaptation, unevaluated

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        library, where = self._library(cfg)
        me = (problem.name, problem.spec.material.name)
        entries = [e for e in library["entries"]
                   if not (e["part"] == problem.spec.part if cfg.exclude == "part" else False)]
        if not entries:
            raise PlannerError(f"planner 'cbr': the library {where} holds no case of another part "
                               "(set exclude=task to use same-part cases)")
        tree = cKDTree(np.array([_entry_vector(e, cfg) for e in entries]))
        k = min(cfg.k, len(entries))
        query = np.array([features(problem, t, cfg) for t in range(problem.n_tasks)])
        dist, idx = tree.query(query, k=min(len(entries), k + 1))
        dist, idx = dist.reshape(problem.n_tasks, -1), idx.reshape(problem.n_tasks, -1)
        if cfg.exclude == "task":  # the query's own task may sit in the library: never retrieve it
            own = np.array([[(entries[i]["case"], entries[i]["material"], entries[i]["task"]) == (*me, t)
                             for i in row] for t, row in enumerate(idx)])
            order = np.argsort(own, axis=1, kind="stable")
            dist, idx = np.take_along_axis(dist, order, 1), np.take_along_axis(idx, order, 1)
            if own[np.arange(problem.n_tasks), order[:, 0]].any():
                raise PlannerError("planner 'cbr': the library holds nothing but the query's own tasks")
        dist, idx = dist[:, :k], idx[:, :k]
        info = {"library_samples": library["library_samples"], "distance": dist[:, 0].tolist(),
                "neighbours": [[_name(entries[i]) for i in row] for row in idx], "retained": 0}
        if mode == "shared":
            order = np.argsort(dist, axis=None, kind="stable")
            options = _unique([adapt(problem, entries[i], cfg.map_normalised) for i in idx.ravel()[order]])
            budget = revise_budget(cfg.polish_samples, ev.remaining // problem.n_tasks, cfg.samples_per_task)
            revise(problem, ev, None, budget, options, rng)
            best = ev.shared_layout if ev.shared_layout is not None else options[0]
            return np.tile(best, (problem.n_tasks, 1)), info
        layouts = np.empty((problem.n_tasks, problem.n_agents), dtype=np.int64)
        training = set(ev.tasks.tolist())
        left = len(training)  # tasks still to revise; held-out tasks get the adaptation, no sample
        kept: list[tuple[np.ndarray, dict]] = []  # retained cases of this run, with their vectors
        # training tasks in order, then the held-out ones (which may retrieve every retained task)
        for t in sorted(range(problem.n_tasks), key=lambda t: (t not in training, t)):
            own = sorted([(float(np.linalg.norm(v - query[t])), e) for v, e in kept], key=lambda x: x[0])
            lib = [(d, entries[i]) for d, i in zip(dist[t], idx[t])]
            if cfg.retained_k:  # k from the library, beside them up to retained_k of the run's own
                near = sorted(lib + own[:cfg.retained_k], key=lambda x: x[0])
            else:  # stable: a library case before an equally near retained one
                near = sorted(lib + own, key=lambda x: x[0])[:k]
            info["distance"][t], info["neighbours"][t] = near[0][0], [_name(e) for _, e in near]
            options = _unique([adapt(problem, e, cfg.map_normalised) for _, e in near])
            if t not in training:
                layouts[t] = options[0]
                continue
            budget = revise_budget(cfg.polish_samples, ev.remaining // left, cfg.samples_per_task)
            left -= 1
            revise(problem, ev, t, budget, options, rng)
            layouts[t] = ev.best_layout[t] if np.isfinite(ev.best[t]) else options[0]
            if cfg.retain and np.isfinite(ev.best[t]):  # revised on this task: a case from now on
                kept.append((query[t], entry(problem, t, layouts[t], float(ev.best[t])) | {"retained": True}))
        info["retained"] = len(kept)
        return layouts, info

    @staticmethod
    def _library(cfg: CBRConfig) -> tuple[dict, str]:
        """(library, where it came from): the named file (built there if missing), else in memory."""
        if cfg.library:
            path = Path(cfg.library).expanduser()
            if not path.exists() and cfg.bootstrap:
                build_library([load_problem(c) for c in expand_suites(cfg.bootstrap)], budget=None, path=path,
                              per_task_budget=cfg.bootstrap_budget)
            return load_library(path), str(path)
        key = (cfg.bootstrap, cfg.bootstrap_budget)
        if key not in _MEMORY:
            _MEMORY.clear()
            _MEMORY[key] = bootstrap_library(cfg.bootstrap, cfg.bootstrap_budget)
        return _MEMORY[key], "built from " + ", ".join(cfg.bootstrap)


def _name(e: dict) -> str:
    """How ``info["neighbours"]`` names a case: a retained one is marked as this run's."""
    return ("retained:" if e.get("retained") else "") + f"{e['case']}/{e['material']}/task{e['task']}"


def _unique(layouts: list[np.ndarray]) -> list[np.ndarray]:
    seen, out = set(), []
    for lay in layouts:
        key = tuple(lay.tolist())
        if key not in seen:
            seen.add(key)
            out.append(lay)
    return out
