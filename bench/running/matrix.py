"""Benchmark matrix files (TOML) and their deterministic expansion into cells.

A matrix names cases, materials, planners (optionally with config overrides, their own budget and the
cases and modes they run in), seeds, budgets, agent counts, modes and, optionally, how many tasks of
each case to use. Every combination is one *cell*: one planner run, identified by a hash of its
settings, so a rerun can skip what is done. The format is documented in docs/matrices.md.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
from dataclasses import asdict, dataclass
from pathlib import Path

from fixbench.bench.records.keys import split
from fixbench.bench.records.rows import DEFAULT_MODE, MODES
from fixbench.cases.errors import CaseError
from fixbench.cases.materials import MATERIALS
from fixbench.cases.spec import load_case_spec, resolve_case
from fixbench.cases.units import Reader, file_reader

KEYS = ("name", "cases", "suites", "materials", "per_case", "planners", "seeds", "budget", "samples_per_task",
        "agents", "mode", "tasks", "heldout_every", "proof_limit", "description")


@dataclass(frozen=True)
class PlannerEntry:
    name: str
    config: tuple[tuple[str, object], ...] = ()
    budget: int | None | str = "matrix"  # "matrix" = use the matrix's budgets; None = unlimited
    max_samples_per_task: int | None = None  # the budget sweep stops here for this planner
    label: str = ""  # how reports name this entry (default: the name and its config)
    cases: tuple[str, ...] = ()  # the matrix's cases this entry runs on (empty: every one)
    modes: tuple[str, ...] = ()  # the matrix's modes (tracks) this entry runs in (empty: every one)
    zero_shot: bool = False  # the planner acts with no sample: it gets the cells of samples_per_task 0


@dataclass(frozen=True)
class Cell:
    """One planner run of the matrix."""

    planner: str
    config: tuple[tuple[str, object], ...]
    case: str
    material: str
    agents: int | None
    mode: str
    budget: int | None
    seed: int
    tasks: int | None
    samples_per_task: int | None = None  # budget sweep: budget = this x the tasks the planner may evaluate
    heldout_every: int | None = None  # held-out mode: train on every k-th task, act on the others
    label: str = ""

    @property
    def id(self) -> str:
        d = asdict(self)
        for k in ("samples_per_task", "heldout_every", "label"):  # absent unless used: older ids stay valid
            if not d[k]:
                del d[k]
        text = json.dumps(d, sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    def train_tasks(self, n_tasks: int) -> list[int] | None:
        """Held-out mode: the training tasks (every ``heldout_every``-th, from the first); else None."""
        return split(n_tasks, self.heldout_every)[0] if self.mode == "held-out" else None

    def budget_for(self, n_tasks: int) -> int | None:
        """The cell's sample budget on a problem of ``n_tasks`` tasks."""
        if self.samples_per_task is None:
            return self.budget
        train = self.train_tasks(n_tasks)
        return self.samples_per_task * (n_tasks if train is None else len(train))

    @property
    def problem_key(self) -> tuple:
        """Cells with the same key share a problem (and its regret reference)."""
        return (self.case, self.material, self.agents, self.tasks)


@dataclass(frozen=True)
class Matrix:
    name: str
    source: str
    cases: tuple[str, ...]
    materials: tuple[str, ...]
    planners: tuple[PlannerEntry, ...]
    seeds: tuple[int, ...]
    budgets: tuple[int | None, ...]
    agents: tuple[int | None, ...]
    modes: tuple[str, ...]
    tasks: int | None
    samples_per_task: tuple[int, ...] = ()
    heldout_every: int | None = None
    #: most layouts a position whose optimum the reference phase proves (None: ``exact``'s own limit)
    proof_limit: int | None = None
    #: (case, key, values): a case's own ``materials`` or ``agents`` instead of the matrix's
    per_case: tuple[tuple[str, str, tuple], ...] = ()

    def of(self, case: str, key: str) -> tuple:
        """The values of ``key`` ("materials" or "agents") ``case`` runs with: its own in ``per_case``,
        else the matrix's."""
        return next((v for c, k, v in self.per_case if c == case and k == key), getattr(self, key))

    def cells(self) -> list[Cell]:
        """Every cell, in a fixed order (case, material, agents, mode, budget, planner, seed).

        With ``samples_per_task`` (the budget sweep) the budgets are those values a task; a planner
        entry's ``max_samples_per_task`` drops the larger ones for it, and its own ``budget`` replaces
        the sweep; a sweep's 0 (k = 0: no sample at all) is a per-task cell of the entries whose planner
        acts without one (``Planner.zero_shot``) only. Held-out cells carry ``heldout_every``."""
        out = []
        sweep = [(None, s) for s in self.samples_per_task] or [(b, None) for b in self.budgets]
        combos = ((case, *rest) for case in self.cases for rest in itertools.product(
            self.of(case, "materials"), self.of(case, "agents"), self.modes, sweep, self.planners, self.seeds))
        for case, mat, agents, mode, (budget, spt), p, seed in combos:
            if spt is not None and p.max_samples_per_task is not None and spt > p.max_samples_per_task:
                continue
            if spt == 0 and not (p.zero_shot and mode == "per-task"):  # k = 0: only who can act without a sample
                continue
            if (p.cases and case not in p.cases) or (p.modes and mode not in p.modes):
                continue
            b, s = (budget, spt) if p.budget == "matrix" else (p.budget, None)
            out.append(Cell(p.name, p.config, case, mat, agents, mode, b, seed, self.tasks, s,
                            self.heldout_every if mode == "held-out" else None, p.label))
        # a planner with its own budget repeats across the matrix budgets: keep the first
        seen, unique = set(), []
        for c in out:
            if c.id not in seen:
                seen.add(c.id)
                unique.append(c)
        return unique


def _beside(matrix: Path, case: str) -> str:
    """A case as the matrix means it: a case file is found beside the matrix (not in the current
    directory); a catalog name stays a name."""
    return str(matrix.parent / case) if case.endswith(".toml") and not Path(case).is_absolute() else case


@functools.cache
def zero_shot_planners() -> dict[str, bool]:
    """Which registered planners act with no sample (``Planner.zero_shot``), read without importing them."""
    from fixbench.solvers.registry import listing

    return {r["planner"]: r["zero_shot"] for r in listing()}


def suite_parts(r: Reader, suite: str) -> list[str]:
    """The case names of a shipped suite's generated parts (``suites = [...]``: docs/families.md#suites)."""
    from fixbench.cases.families.suites import shipped_suites, suite_cases

    names = suite_cases(suite)
    if names is None:
        raise r.error("suites", f"'{suite}' is not a shipped suite with its parts generated (shipped: "
                      f"{', '.join(shipped_suites())})")
    return names


def _list(r: Reader, key: str, kind, default=...) -> list:
    value = r.raw(key, default)
    values = value if isinstance(value, list) else [value]
    if not values:
        raise r.error(key, "is empty")
    for v in values:
        if not isinstance(v, kind) or isinstance(v, bool):
            raise r.error(key, f"entries must be {getattr(kind, '__name__', kind)}, got {v!r}")
    return values


#: the matrices shipped with the package (``fixbench run default`` works from any directory)
SHIPPED = Path(__file__).parents[1] / "matrices"


def shipped_matrices() -> list[str]:
    """Names of the matrices shipped with fixbench (``default``, ``paper``, ``sweep``)."""
    return sorted(p.stem for p in SHIPPED.glob("*.toml"))


def find_matrix(path: str | Path) -> Path:
    """The matrix file ``path`` names: an existing file, else a shipped matrix of that name
    (``default`` or ``default.toml``). A file in the current directory wins over a shipped name."""
    path = Path(path)
    if path.is_file() or path.parent != Path("."):
        return path
    name = path.name if path.suffix == ".toml" else f"{path.name}.toml"
    for candidate in (Path(name), SHIPPED / name):
        if candidate.is_file():
            return candidate
    return path


def _check_labels(r: Reader, planners: list[PlannerEntry], modes: list[str]) -> None:
    """Each label names one entry in each track. The same planner, config and label may be written
    twice with ``mode`` lists that do not overlap (say, on fewer parts in one track: reports show
    them as one entry); anything else that shares a label is refused."""
    seen: dict[str, list[PlannerEntry]] = {}
    for p in planners:
        label = p.label or p.name + (str(p.config) if p.config else "")
        for q in seen.get(label, []):
            if (q.name, q.config, q.budget, q.max_samples_per_task) != (p.name, p.config, p.budget,
                                                                        p.max_samples_per_task):
                raise r.error("planners", f"two entries are labelled '{label}' with different planners, "
                                          "configs or budgets: give them different labels")
            both = set(q.modes or modes) & set(p.modes or modes)
            if both:
                raise r.error("planners", f"two entries are the same planner and config ('{label}') in mode "
                                          f"{', '.join(sorted(both))}: give them different labels or "
                                          "mode lists that do not overlap")
        seen.setdefault(label, []).append(p)


def load_matrix(path: str | Path) -> Matrix:
    """Read and check a matrix file (or a shipped matrix by name, :func:`find_matrix`); every
    problem is a one-line CaseError (file, key, problem)."""
    from fixbench.solvers.base import ConfigError
    from fixbench.solvers.config import apply_sets
    from fixbench.solvers.registry import get, names

    path = find_matrix(path)
    r = file_reader(path, KEYS, f"no such matrix file (shipped matrices: {', '.join(shipped_matrices())})")
    source, data = r.source, r.data
    name = r.text("name", path.stem)
    r.text("description", "")
    cases = []
    for c in _list(r, "cases", str, []) if "cases" in data or "suites" not in data else []:
        where = _beside(path, c)
        try:
            resolve_case(where)
        except CaseError as exc:
            raise r.error("cases", f"'{c}': {exc.problem}") from None
        cases.append(where)
    for s in _list(r, "suites", str) if "suites" in data else []:
        cases += [c for c in suite_parts(r, s) if c not in cases]
    materials = _list(r, "materials", str, [None]) if "materials" in data else [None]
    for m in materials:
        if m is not None and m not in MATERIALS:
            raise r.error("materials", f"unknown material '{m}' (known: {', '.join(MATERIALS)})")
    per_case = []
    for c, table in r.raw("per_case", {}, (dict,)).items():
        where = _beside(path, c)
        if where not in cases:
            raise r.error(f"per_case.{c}", f"'{c}' is not one of the matrix's cases ({', '.join(cases)})")
        cr = Reader(table, source, f"per_case.{c}") if isinstance(table, dict) else None
        if cr is None:
            raise r.error(f"per_case.{c}", "must be a table of materials and/or agents")
        if cr.raw("materials", None) is not None:
            ms = _list(cr, "materials", str)
            own = load_case_spec(where).material.name  # a laminate part runs in its own layup
            for m in ms:
                if m not in MATERIALS and m != own:
                    raise cr.error("materials", f"unknown material '{m}' (known: {', '.join(MATERIALS)}, "
                                                f"or the case's own '{own}')")
            per_case.append((where, "materials", tuple(ms)))
        if cr.raw("agents", None) is not None:
            ns = _list(cr, "agents", int)
            if any(n < 1 for n in ns):
                raise cr.error("agents", "must be at least 1")
            per_case.append((where, "agents", tuple(ns)))
        cr.finish()
    seeds = _list(r, "seeds", int)
    if ("budget" in data) == ("samples_per_task" in data):
        raise r.error("budget", "give either budget (samples a cell) or samples_per_task (a sweep), not both"
                      if "budget" in data else "missing (or samples_per_task)")
    budgets, sweep = [None], []
    if "budget" in data:
        budgets = [None if b == "unlimited" else b for b in _list(r, "budget", (int, str))]
        for b in budgets:
            if b is not None and (isinstance(b, str) or b <= 0):
                raise r.error("budget", f"must be positive whole numbers or \"unlimited\", got {b!r}")
    else:
        sweep = _list(r, "samples_per_task", int)
        if any(v < 0 for v in sweep) or len(set(sweep)) != len(sweep):
            raise r.error("samples_per_task", "must be distinct whole numbers, 0 or more (0: no sample, k = 0)")
    agents = _list(r, "agents", int) if "agents" in data else [None]
    if any(a is not None and a < 1 for a in agents):
        raise r.error("agents", "must be at least 1")
    modes = _list(r, "mode", str, [DEFAULT_MODE])
    for m in modes:
        if m not in MODES:
            raise r.error("mode", f"must be one of {', '.join(MODES)}, got '{m}'")
    tasks = r.integer("tasks", None, minimum=1)
    if tasks is not None:
        for c in cases:
            try:
                n = len(load_case_spec(c).tasks)
            except CaseError as exc:
                raise r.error("cases", f"'{c}': {exc}") from None
            if tasks > n:
                raise r.error("tasks", f"{tasks} tasks asked, but case '{c}' has only {n}")
    heldout_every = r.integer("heldout_every", None, minimum=2)
    proof_limit = r.integer("proof_limit", None, minimum=0)
    if ("held-out" in modes) != (heldout_every is not None):
        raise r.error("heldout_every", "is needed by mode \"held-out\" (train on every k-th task) and only then")
    planners = []
    raw = r.raw("planners")
    if not isinstance(raw, list) or not raw:
        raise r.error("planners", "must be a non-empty list of names or [[planners]] tables")
    for i, item in enumerate(raw):
        key = f"planners[{i}]"
        if isinstance(item, str):
            item = {"name": item}
        pr = Reader(item, source, key)
        pname = pr.text("name")
        label = pr.text("label", "")
        cfg = pr.raw("config", {}, (dict,))
        overrides = {}
        if cfg or ":" in pname:  # the class is needed; a known name alone is checked without importing it
            try:
                cls = get(pname)
            except Exception as exc:  # PlannerError: unknown name or import failure
                raise CaseError(source, f"{key}.name", str(exc)) from None
            sets = [f"{k}={_as_text(v)}" for k, v in cfg.items()]
            try:
                overrides = apply_sets(cls.Config, sets, pname)
            except Exception as exc:
                raise CaseError(source, f"{key}.config", str(exc)) from None
            try:  # the config checks its values when made: a bad one is refused before any cell runs
                cls.Config(**overrides)
            except ConfigError as exc:
                entry = f"planner '{pname}'" + (f", label '{label}'" if label else "")
                raise CaseError(source, f"{key}.config.{exc.field}", f"{exc.problem} ({entry})") from None
            except Exception as exc:  # a plugin's own check, with an exception of its choosing
                raise CaseError(source, f"{key}.config", f"{type(exc).__name__}: {exc} (planner '{pname}')") from None
        elif pname not in names():
            raise CaseError(source, f"{key}.name", f"unknown planner '{pname}' (known: {', '.join(names())})")
        budget = pr.raw("budget", "matrix", (int, str))
        if budget == "unlimited":
            budget = None
        elif budget != "matrix" and (isinstance(budget, str) or budget <= 0):
            raise pr.error("budget", f"must be a positive whole number or \"unlimited\", got {budget!r}")
        cap = pr.integer("max_samples_per_task", None, minimum=1)
        only = tuple(_beside(path, c) for c in _list(pr, "cases", str)) if pr.raw("cases", None) is not None else ()
        for c in only:
            if c not in cases:
                raise pr.error("cases", f"'{c}' is not one of the matrix's cases ({', '.join(cases)})")
        tracks = tuple(_list(pr, "mode", str)) if pr.raw("mode", None) is not None else ()
        for m in tracks:
            if m not in modes:
                raise pr.error("mode", f"'{m}' is not one of the matrix's modes ({', '.join(modes)})")
        if pr.raw("tuning", None) is not None:  # how `fixbench tune` made the entry: checked, kept by no cell
            read_figures(pr.data["tuning"], source, pr.key("tuning"))
        pr.finish()
        zero = cls.zero_shot if cfg or ":" in pname else zero_shot_planners().get(pname, False)
        planners.append(PlannerEntry(pname, tuple(sorted(overrides.items())), budget, cap, label, only, tracks,
                                     bool(zero)))
    _check_labels(r, planners, modes)
    r.used.update(data)
    return Matrix(name, source, tuple(cases), tuple(materials), tuple(planners), tuple(seeds),
                  tuple(budgets), tuple(agents), tuple(modes), tasks, tuple(sweep), heldout_every, proof_limit,
                  tuple(per_case))


def _as_text(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return ",".join(map(str, v))
    return str(v)


#: the tracks a configuration is tuned for (the matrix's modes of the same names)
TRACKS = ("per-task", "held-out")
#: the keys of a tuned entry's ``tuning`` table, in the order ``matrix_entry`` writes them
FIGURES = ("track", "heldout_every", "trials", "cases", "seeds", "samples_per_task", "objective_default",
           "objective_tuned")


def read_figures(table, source: str, key: str = "tuning") -> dict:
    """A ``tuning`` table (:func:`figures`) checked: a table of exactly those keys, each of its kind;
    anything else is a one-line CaseError naming ``source`` and the key. The matrix loader checks a
    ``[[planners]]`` entry's ``tuning`` with this and keeps nothing of it: it is provenance, not a
    setting (no cell's config or id depends on it)."""
    r = Reader(table, source, key)
    track = r.text("track", choices=TRACKS)
    every = r.integer("heldout_every", None, minimum=2)
    if (track == "held-out") != (every is not None):
        raise r.error("heldout_every", "is needed by track \"held-out\" (the split tuned on) and only then")
    out = {"track": track, "heldout_every": every, "trials": r.integer("trials", minimum=1)}
    for name, kind in (("cases", str), ("seeds", int)):
        values = r.raw(name, ..., (list,))
        if not values or any(not isinstance(v, kind) or isinstance(v, bool) for v in values):
            raise r.error(name, f"must be a non-empty list of {kind.__name__}, got {values!r}")
        out[name] = list(values)
    out["samples_per_task"] = r.integer("samples_per_task", minimum=1)
    for name in ("objective_default", "objective_tuned"):
        out[name] = r.number(name, nonneg=True)
    r.finish()
    return {k: out[k] for k in FIGURES if out[k] is not None}
