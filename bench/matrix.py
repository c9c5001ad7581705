"""Benchmark matrix files (TOML) and their deterministic expansion into cells.

A matrix names cases, materials, planners (optionally with config overrides and their own budget),
seeds, budgets, agent counts, modes and, optionally, how many tasks of each case to use. Every
combination is one *cell*: one planner run, identified by a hash of its settings, so a rerun can
skip what is done. The format is documented in README ("Benchmark matrices").
"""

from __future__ import annotations

import hashlib
import itertools
import json
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from cases.errors import CaseError
from cases.materials import MATERIALS
from cases.spec import resolve_case
from cases.units import Reader

KEYS = ("name", "cases", "materials", "planners", "seeds", "budget", "agents", "mode", "tasks",
        "description")


@dataclass(frozen=True)
class PlannerEntry:
    name: str
    config: tuple[tuple[str, object], ...] = ()
    budget: int | None | str = "matrix"  # "matrix" = use the matrix's budgets; None = unlimited


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

    @property
    def id(self) -> str:
        text = json.dumps(asdict(self), sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

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

    def cells(self) -> list[Cell]:
        """Every cell, in a fixed order (case, material, agents, mode, budget, planner, seed)."""
        out = []
        for case, mat, agents, mode, budget, p, seed in itertools.product(
                self.cases, self.materials, self.agents, self.modes, self.budgets, self.planners,
                self.seeds):
            b = budget if p.budget == "matrix" else p.budget
            out.append(Cell(p.name, p.config, case, mat, agents, mode, b, seed, self.tasks))
        # a planner with its own budget repeats across the matrix budgets: keep the first
        seen, unique = set(), []
        for c in out:
            if c.id not in seen:
                seen.add(c.id)
                unique.append(c)
        return unique


def task_subset(n_tasks: int, wanted: int | None) -> list[int]:
    """``wanted`` tasks spread evenly over ``n_tasks`` (all when None or too many)."""
    if wanted is None or wanted >= n_tasks:
        return list(range(n_tasks))
    return sorted({int(round(x)) for x in np.linspace(0, n_tasks - 1, wanted)})


def _list(r: Reader, key: str, kind, default=...) -> list:
    value = r.raw(key, default)
    values = value if isinstance(value, list) else [value]
    if not values:
        raise r.error(key, "is empty")
    for v in values:
        if not isinstance(v, kind) or isinstance(v, bool):
            raise r.error(key, f"entries must be {getattr(kind, '__name__', kind)}, got {v!r}")
    return values


def load_matrix(path: str | Path) -> Matrix:
    """Read and check a matrix file; every problem is a one-line CaseError (file, key, problem)."""
    from solvers.config import apply_sets
    from solvers.registry import get, names

    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise CaseError(source, "", "no such matrix file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(source, "", f"not valid TOML ({exc})") from None
    r = Reader(data, source)
    for key in data:
        if key not in KEYS:
            raise r.error(key, f"unknown key (known: {', '.join(KEYS)})")
    name = r.text("name", path.stem)
    r.text("description", "")
    cases = _list(r, "cases", str)
    for c in cases:
        try:
            resolve_case(c if not c.endswith(".toml") else str(path.parent / c))
        except CaseError as exc:
            raise r.error("cases", f"'{c}': {exc.problem}") from None
    materials = _list(r, "materials", str, [None]) if "materials" in data else [None]
    for m in materials:
        if m is not None and m not in MATERIALS:
            raise r.error("materials", f"unknown material '{m}' (known: {', '.join(MATERIALS)})")
    seeds = _list(r, "seeds", int)
    budgets = [None if b == "unlimited" else b for b in _list(r, "budget", (int, str))]
    for b in budgets:
        if b is not None and (isinstance(b, str) or b <= 0):
            raise r.error("budget", f"must be positive whole numbers or \"unlimited\", got {b!r}")
    agents = _list(r, "agents", int) if "agents" in data else [None]
    if any(a is not None and a < 1 for a in agents):
        raise r.error("agents", "must be at least 1")
    modes = _list(r, "mode", str, ["per-task"])
    for m in modes:
        if m not in ("per-task", "shared"):
            raise r.error("mode", f"must be per-task or shared, got '{m}'")
    tasks = r.integer("tasks", None, minimum=1)
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
        elif pname not in names():
            raise CaseError(source, f"{key}.name", f"unknown planner '{pname}' (known: {', '.join(names())})")
        budget = pr.raw("budget", "matrix", (int, str))
        if budget == "unlimited":
            budget = None
        elif budget != "matrix" and (isinstance(budget, str) or budget <= 0):
            raise pr.error("budget", f"must be a positive whole number or \"unlimited\", got {budget!r}")
        pr.finish()
        planners.append(PlannerEntry(pname, tuple(sorted(overrides.items())), budget))
    r.used.update(data)
    return Matrix(name, source, tuple(cases), tuple(materials), tuple(planners), tuple(seeds),
                  tuple(budgets), tuple(agents), tuple(modes), tasks)


def _as_text(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return ",".join(map(str, v))
    return str(v)
