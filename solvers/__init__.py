"""fixbench's planners, behind one interface (:class:`fixbench.solvers.base.Planner`) and a registry.

The names below are imported on first use (PEP 562): listing planners or reading a config does
not import the numerical libraries a planner needs to run.
"""

from __future__ import annotations

import importlib

#: public name -> the module that defines it
_WHERE = {
    "MODES": "base", "PlanResult": "base", "Planner": "base", "PlannerConfig": "base", "PlannerError": "base",
    "Share": "base", "TracedEvaluator": "base",
    "available": "registry", "get": "registry", "register": "registry",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
