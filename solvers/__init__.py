"""fixbench's planners, behind one interface (:class:`solvers.base.Planner`) and a registry."""

from solvers.base import MODES, Planner, PlannerConfig, PlannerError, PlanResult, TracedEvaluator
from solvers.registry import available, get, register

__all__ = ["MODES", "PlanResult", "Planner", "PlannerConfig", "PlannerError", "TracedEvaluator",
           "available", "get", "register"]
