"""The planner registry: built-ins, entry-point plugins, and ``package.module:Class`` specs.

Names are unique: registering a second planner under a taken name is an error (as BenchMARL and
nevergrad do), so a plugin can never silently replace a built-in.
"""

from __future__ import annotations

import importlib
import importlib.metadata

from solvers.base import Planner, PlannerError

ENTRY_POINT_GROUP = "fixbench.planners"
_REGISTRY: dict[str, type[Planner]] = {}
_LOADED = False


def register(cls: type[Planner]) -> type[Planner]:
    """Class decorator adding a planner under ``cls.name``; refuses a name that is taken."""
    if not (isinstance(cls, type) and issubclass(cls, Planner)):
        raise PlannerError(f"{cls!r} is not a Planner subclass")
    if not cls.name:
        raise PlannerError(f"planner class {cls.__qualname__} has no name")
    other = _REGISTRY.get(cls.name)
    if other is not None and other is not cls:
        raise PlannerError(f"planner name '{cls.name}' is taken by {other.__module__}.{other.__qualname__}")
    _REGISTRY[cls.name] = cls
    return cls


def _load() -> None:
    """Import the built-in planners and the installed plugins (once)."""
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    importlib.import_module("solvers.builtin")
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            cls = ep.load()
        except Exception as exc:  # a broken plugin is reported, never a crash of fixbench
            raise PlannerError(f"plugin '{ep.name}' ({ep.value}) failed to import: "
                               f"{type(exc).__name__}: {exc}") from None
        if _REGISTRY.get(getattr(cls, "name", None)) is not cls:
            register(cls)


def available() -> dict[str, type[Planner]]:
    """All registered planners by name (built-ins and plugins)."""
    _load()
    return dict(sorted(_REGISTRY.items()))


def get(name: str) -> type[Planner]:
    """A planner class by registered name or by ``package.module:Class``."""
    if ":" in name:
        return load_spec(name)
    planners = available()
    if name not in planners:
        raise PlannerError(f"unknown planner '{name}' (known: {', '.join(planners)})")
    return planners[name]


def load_spec(spec: str) -> type[Planner]:
    """Import ``package.module:Class`` and register it."""
    module, _, attr = spec.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except Exception as exc:
        raise PlannerError(f"--planner {spec}: cannot import: {type(exc).__name__}: {exc}") from None
    _load()
    if _REGISTRY.get(getattr(cls, "name", None)) is not cls:
        register(cls)
    return cls
