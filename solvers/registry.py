"""The planner registry: built-ins, entry-point plugins, and ``package.module:Class`` specs.

Names are unique: registering a second planner under a taken name is an error (as BenchMARL and
nevergrad do), so a plugin can never silently replace a built-in.

Built-ins and entry points are imported when first asked for by name (:func:`get`), not all at
once: a process that runs only ``greedy`` never imports PyTorch or cvxpy, and the benchmark driver,
which only checks names, stays small. :func:`names` lists every name without importing anything;
:func:`listing` describes every planner (a built-in's description and modes are read from its
source, so ``fixbench solvers`` starts without PyTorch, cvxpy or pymoo; plugins are imported);
:func:`available` imports them all (the registry-wide tests).
"""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import importlib.util

from fixbench.solvers.base import Planner, PlannerError

ENTRY_POINT_GROUP = "fixbench.planners"
#: built-in planner name -> the module that registers it when imported
BUILTIN = {"random": "fixbench.solvers.random_search", "exact": "fixbench.solvers.exact",
           "greedy": "fixbench.solvers.greedy", "local": "fixbench.solvers.local",
           "ga": "fixbench.solvers.evolutionary", "pso": "fixbench.solvers.evolutionary",
           "qp": "fixbench.solvers.qp", "cbr": "fixbench.solvers.cbr",
           "nashq": "fixbench.solvers.nashq", "iql": "fixbench.solvers.nashq",
           "optuna": "fixbench.solvers.optuna_tpe", "rules": "fixbench.solvers.rules",
           "surrogate-ts": "fixbench.solvers.surrogate",
           "vdn": "fixbench.solvers.vdn",
           "mappo": "fixbench.solvers.library_learners", "ippo": "fixbench.solvers.library_learners",
           "qmix": "fixbench.solvers.library_learners",
           "gp-ucb": "fixbench.solvers.gp_bandit"}
_REGISTRY: dict[str, type[Planner]] = {}


def register(cls: type[Planner]) -> type[Planner]:
    """Class decorator adding a planner under ``cls.name``; refuses a name that is taken."""
    if not (isinstance(cls, type) and issubclass(cls, Planner)):
        raise PlannerError(f"{cls!r} is not a Planner subclass")
    if not cls.name:
        raise PlannerError(f"planner class {cls.__qualname__} has no name")
    builtin = BUILTIN.get(cls.name)
    if builtin is not None and cls.__module__ != builtin:  # checked without importing the built-in
        raise PlannerError(f"planner name '{cls.name}' is taken by the built-in planner in {builtin}; "
                           f"{cls.__module__}.{cls.__qualname__} must be renamed")
    other = _REGISTRY.get(cls.name)
    if other is not None and other is not cls:
        raise PlannerError(f"planner name '{cls.name}' is taken by {other.__module__}.{other.__qualname__}; "
                           f"{cls.__module__}.{cls.__qualname__} must be renamed")
    _REGISTRY[cls.name] = cls
    return cls


def _entry_points() -> dict:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def _import(name: str) -> None:
    """Import the built-in module or the entry point that provides planner ``name``."""
    if name in _REGISTRY:
        return
    ep = _entry_points().get(name)
    if name in BUILTIN:
        if ep is not None and not ep.value.startswith(BUILTIN[name]):  # every command, not just `solvers`
            raise PlannerError(f"plugin '{name}' ({ep.value}{_package(ep)}) takes the name of the built-in "
                               f"planner in {BUILTIN[name]}; the plugin must be renamed")
        importlib.import_module(BUILTIN[name])
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
    for module in dict.fromkeys(BUILTIN.values()):
        importlib.import_module(module)
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


def _class_attrs(module: str) -> dict[str, dict]:
    """Per class of ``module`` (read, not imported): its constant class attributes and base names."""
    tree = ast.parse(open(importlib.util.find_spec(module).origin, encoding="utf-8").read())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            attrs = {}
            for stmt in node.body:
                target = stmt.targets[0] if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 else \
                    stmt.target if isinstance(stmt, ast.AnnAssign) and stmt.value is not None else None
                if isinstance(target, ast.Name):
                    try:
                        attrs[target.id] = ast.literal_eval(stmt.value)
                    except ValueError:
                        pass
            out[node.name] = {"attrs": attrs, "bases": [b.id for b in node.bases if isinstance(b, ast.Name)]}
    return out


def _lookup(classes: dict, cls: str, attr: str, default):
    """A class attribute through its bases in the same module, else ``default`` (Planner's)."""
    while cls in classes:
        if attr in classes[cls]["attrs"]:
            return classes[cls]["attrs"][attr]
        cls = next(iter(classes[cls]["bases"]), None)
    return default


def listing() -> list[dict]:
    """Every planner: name, description, family, modes and module, sorted by name. Built-ins are described
    from their source without importing them (a test checks this equals the imported classes);
    plugins and registered planners from their classes (a name clash raises, as in :func:`get`)."""
    rows = {n: _row(n, c) for n, c in _REGISTRY.items()}
    for ep in _entry_points().values():
        _import(ep.name)
        rows[ep.name] = _row(ep.name, _REGISTRY[ep.name])
    for module in dict.fromkeys(BUILTIN.values()):
        classes = _class_attrs(module)
        for cls in classes:
            name = _lookup(classes, cls, "name", "")
            if BUILTIN.get(name) == module and name not in rows:
                rows[name] = {"planner": name, "description": _lookup(classes, cls, "description", ""),
                              "family": _lookup(classes, cls, "family", Planner.family),
                              "modes": list(_lookup(classes, cls, "modes", Planner.modes)), "module": module}
    return [rows[n] for n in sorted(rows)]


def _row(name: str, cls: type[Planner]) -> dict:
    """What :func:`listing` says of an imported planner class."""
    return {"planner": name, "description": cls.description, "family": cls.family, "modes": list(cls.modes),
            "module": cls.__module__}

