"""fixbench's problem room: parts, plate FEA, the counted oracle and the case catalog.

Nothing here knows a planner exists (dependencies point bench -> solvers -> cases).
"""

from fixbench.cases.env import FixtureEnv, make_env
from fixbench.cases.errors import BudgetExhausted, CaseError, FixbenchError, NumericalError
from fixbench.cases.materials import MATERIALS, Material
from fixbench.cases.problem import Deformation, Evaluator, Problem, load_problem
from fixbench.cases.spec import CaseSpec, case_names, load_case_spec

__all__ = [
    "BudgetExhausted", "CaseError", "CaseSpec", "Deformation", "Evaluator", "FixbenchError",
    "MATERIALS", "Material", "NumericalError", "Problem", "case_names", "load_case_spec",
    "load_problem", "FixtureEnv", "make_env",
]
