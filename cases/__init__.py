"""fixbench's problem room: parts, plate FEA, the counted oracle and the case catalog.

Nothing here knows a planner exists (dependencies point bench -> solvers -> cases). The names
below are imported on first use (PEP 562), so that ``import fixbench.cases.spec`` does not pull in
the FE code, PyTorch-free commands start fast, and a command imports only what it needs.
"""

from __future__ import annotations

import importlib

#: public name -> the module that defines it
_WHERE = {
    "FixtureEnv": "env", "make_env": "env",
    "BudgetExhausted": "errors", "CaseError": "errors", "FixbenchError": "errors", "NumericalError": "errors",
    "MATERIALS": "materials", "Material": "materials", "PLIES": "materials", "Ply": "materials",
    "Laminate": "materials",
    "Deformation": "problem", "Evaluator": "problem", "Problem": "problem", "load_problem": "problem",
    "CaseSpec": "spec", "case_names": "spec", "load_case_spec": "spec",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
