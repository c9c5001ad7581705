"""The planner registry: built-ins, entry-point plugins, and ``package.module:Class`` specs.

Names are unique: registering a second planner under a taken name is an error (as BenchMARL and
nevergrad do), so a plugin can never silently replace a built-in.

The built-ins are listed once, in :data:`BUILTIN` (name -> ``module:Class``); their classes carry no
decorator. Built-ins and entry points are imported when first asked for by name (:func:`get`), not all
at once: a process that runs only ``greedy`` never imports PyTorch or cvxpy, and the benchmark driver,
which only checks names, stays small. :func:`names` lists every name without importing anything;
:func:`listing` describes every planner (a built-in's description and modes are read from its
source, and its bases' in fixbench.solvers, so ``fixbench solvers`` starts without PyTorch, cvxpy or
pymoo; plugins are imported); :func:`available` imports them all (the registry-wide tests).
"""

from __future__ import annotations

import ast
import functools
import importlib
import importlib.metadata
import importlib.util

from fixbench.solvers.base import Planner, PlannerError

ENTRY_POINT_GROUP = "fixbench.planners"
#: every built-in planner, once: name -> ``module:Class`` (imported when first asked for), by kind
BUILTIN = {
    # search/: on the budget loop of Planner.drive
    "random": "fixbench.solvers.search.random_search:RandomSearch",
    "greedy": "fixbench.solvers.search.greedy:Greedy",
    "local": "fixbench.solvers.search.local:LocalSearch",
    "ga": "fixbench.solvers.search.ga:GeneticPlanner",
    "pso": "fixbench.solvers.search.pso:SwarmPlanner",
    "optuna": "fixbench.solvers.search.optuna_tpe:OptunaTPE",
    # math_programming/
    "exact": "fixbench.solvers.math_programming.exact:Exact",
    "qp": "fixbench.solvers.math_programming.qp:QPPlanner",
    # knowledge/
    "rules": "fixbench.solvers.knowledge.rules:Rules",
    "cbr": "fixbench.solvers.knowledge.cbr:CaseBasedReasoning",
    # bandits/
    "surrogate-ts": "fixbench.solvers.bandits.surrogate:SurrogateTS",
    "gp-ucb": "fixbench.solvers.bandits.gp_bandit:GPUCB",
    # learners/
    "nashq": "fixbench.solvers.learners.nashq:NashQ",
    "iql": "fixbench.solvers.learners.iql:IQL",
    "vdn": "fixbench.solvers.learners.vdn:VDN",
    "mappo": "fixbench.solvers.learners.mappo:MAPPO",
    "ippo": "fixbench.solvers.learners.ippo:IPPO",
    "qmix": "fixbench.solvers.learners.qmix:QMIX",
}
_REGISTRY: dict[str, type[Planner]] = {}


def register(cls: type[Planner]) -> type[Planner]:
    """Add a planner under ``cls.name`` (a plugin's or a ``module:Class`` spec's; the built-ins are added
    from :data:`BUILTIN` when first asked for); refuses a name that is taken."""
    if not (isinstance(cls, type) and issubclass(cls, Planner)):
        raise PlannerError(f"{cls!r} is not a Planner subclass")
    if not cls.name:
        raise PlannerError(f"planner class {cls.__qualname__} has no name")
    builtin = BUILTIN.get(cls.name)
    if builtin is not None and f"{cls.__module__}:{cls.__qualname__}" != builtin:  # checked without importing it
        raise PlannerError(f"planner name '{cls.name}' is taken by the built-in planner {builtin}; "
                           f"{cls.__module__}.{cls.__qualname__} must be renamed")
    other = _REGISTRY.get(cls.name)
    if other is not None and other is not cls:
        raise PlannerError(f"planner name '{cls.name}' is taken by {other.__module__}.{other.__qualname__}; "
                           f"{cls.__module__}.{cls.__qualname__} must be renamed")
    _REGISTRY[cls.name] = cls
    return cls


def _builtin(name: str) -> type[Planner]:
    """Import the built-in planner ``name`` (its ``module:Class`` in :data:`BUILTIN`) and register it."""
    module, _, attr = BUILTIN[name].partition(":")
    cls = getattr(importlib.import_module(module), attr)
    if getattr(cls, "name", None) != name:
        raise PlannerError(f"BUILTIN names '{name}' for {BUILTIN[name]}, whose name is {getattr(cls, 'name', None)!r}")
    return register(cls)


def _entry_points() -> dict:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def _import(name: str) -> None:
    """Import and register the built-in or the entry point that provides planner ``name``."""
    if name in _REGISTRY:
        return
    ep = _entry_points().get(name)
    if name in BUILTIN:
        if ep is not None and f"{ep.module}:{ep.attr}" != BUILTIN[name]:  # every command, not just `solvers`
            raise PlannerError(f"plugin '{name}' ({ep.value}{_package(ep)}) takes the name of the built-in "
                               f"planner {BUILTIN[name]}; the plugin must be renamed")
        _builtin(name)
        return
    if ep is not None:
        _load_entry_point(ep)


def _package(ep) -> str:
    dist = getattr(ep, "dist", None)
    return f", package {dist.name}" if dist is not None else ""


def _load_entry_point(ep) -> None:
    try:
        cls = ep.load()
    except Exception as exc:  # a broken plugin is reported, never a crash of fixbench
        raise PlannerError(f"plugin '{ep.name}' ({ep.value}) failed to import: "
                           f"{type(exc).__name__}: {exc}") from None
    if _REGISTRY.get(getattr(cls, "name", None)) is not cls:
        register(cls)


def names() -> list[str]:
    """Every planner name, built-in, plugin or registered, without importing any planner module."""
    return sorted(set(BUILTIN) | set(_entry_points()) | set(_REGISTRY))


def available() -> dict[str, type[Planner]]:
    """All planners by name (built-ins and plugins), each imported (a name clash raises)."""
    for name in BUILTIN:
        _builtin(name)
    for ep in _entry_points().values():
        _load_entry_point(ep)
    return dict(sorted(_REGISTRY.items()))


def get(name: str) -> type[Planner]:
    """A planner class by registered name or by ``package.module:Class``."""
    if ":" in name:
        return load_spec(name)
    _import(name)
    if name not in _REGISTRY:
        raise PlannerError(f"unknown planner '{name}' (known: {', '.join(names())})")
    return _REGISTRY[name]


def load_spec(spec: str) -> type[Planner]:
    """Import ``package.module:Class`` and register it."""
    module, _, attr = spec.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except Exception as exc:
        raise PlannerError(f"--planner {spec}: cannot import: {type(exc).__name__}: {exc}") from None
    if _REGISTRY.get(getattr(cls, "name", None)) is not cls:
        register(cls)
    return cls


@functools.cache
def _source(module: str) -> tuple[dict[str, dict], dict[str, str]]:
    """``module`` read, not imported: per class its constant class attributes and base names; and the
    names it imports (``from X import name``: name -> X)."""
    tree = ast.parse(open(importlib.util.find_spec(module).origin, encoding="utf-8").read())
    classes, imported = {}, {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            imported.update({a.asname or a.name: node.module for a in node.names})
        elif isinstance(node, ast.ClassDef):
            attrs = {}
            for stmt in node.body:
                target = stmt.targets[0] if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 else \
                    stmt.target if isinstance(stmt, ast.AnnAssign) and stmt.value is not None else None
                if isinstance(target, ast.Name):
                    try:
                        attrs[target.id] = ast.literal_eval(stmt.value)
                    except ValueError:
                        pass
            classes[node.name] = {"attrs": attrs, "bases": [b.id for b in node.bases if isinstance(b, ast.Name)]}
    return classes, imported


def _lookup(module: str, cls: str | None, attr: str, default):
    """A class attribute read from source through the class's first bases, in its own module or imported
    from another module of fixbench.solvers (``iql``'s from ``nashq``'s planner), else ``default``
    (Planner's)."""
    while cls is not None:
        classes, imported = _source(module)
        if cls in classes:
            if attr in classes[cls]["attrs"]:
                return classes[cls]["attrs"][attr]
            cls = next(iter(classes[cls]["bases"]), None)
        elif imported.get(cls, "").startswith("fixbench.solvers."):
            module = imported[cls]
        else:
            break
    return default


def listing() -> list[dict]:
    """Every planner: name, description, family, modes and module, sorted by name. Built-ins are described
    from their source without importing them (a test checks this equals the imported classes);
    plugins and registered planners from their classes (a name clash raises, as in :func:`get`)."""
    rows = {n: _row(n, c) for n, c in _REGISTRY.items()}
    for ep in _entry_points().values():
        _import(ep.name)
        rows[ep.name] = _row(ep.name, _REGISTRY[ep.name])
    for name, spec in BUILTIN.items():
        if name not in rows:
            module, _, cls = spec.partition(":")
            rows[name] = {"planner": name, "description": _lookup(module, cls, "description", ""),
                          "family": _lookup(module, cls, "family", Planner.family),
                          "modes": list(_lookup(module, cls, "modes", Planner.modes)),
                          "zero_shot": bool(_lookup(module, cls, "zero_shot", Planner.zero_shot)), "module": module}
    return [rows[n] for n in sorted(rows)]


def _row(name: str, cls: type[Planner]) -> dict:
    """What :func:`listing` says of an imported planner class."""
    return {"planner": name, "description": cls.description, "family": cls.family, "modes": list(cls.modes),
            "zero_shot": bool(cls.zero_shot), "module": cls.__module__}

