"""fixbench's planners, behind one interface (:class:`fixbench.solvers.base.Planner`) and a registry."""

from fixbench.solvers.base import MODES, Planner, PlannerConfig, PlannerError, PlanResult, TracedEvaluator
from fixbench.solvers.registry import available, get, register

__all__ = ["MODES", "PlanResult", "Planner", "PlannerConfig", "PlannerError", "TracedEvaluator",
           "available", "get", "register"]
