"""fixbench's problem room: parts, plate FEA, the counted oracle and the case catalog.

Nothing here knows a planner exists (dependencies point bench -> solvers -> cases).
"""

from cases.env import FixtureEnv, make_env
from cases.errors import BudgetExhausted, CaseError, FixbenchError, NumericalError
from cases.materials import MATERIALS, Material
from cases.problem import Deformation, Evaluator, Problem, load_problem
from cases.spec import CaseSpec, case_names, load_case_spec

__all__ = [
    "BudgetExhausted", "CaseError", "CaseSpec", "Deformation", "Evaluator", "FixbenchError",
    "MATERIALS", "Material", "NumericalError", "Problem", "case_names", "load_case_spec",
    "load_problem", "FixtureEnv", "make_env",
]
