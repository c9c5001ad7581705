"""Imports every built-in planner so that each registers itself."""

from solvers import random_search  # noqa: F401
from solvers import evolutionary  # noqa: F401
from solvers import exact, greedy  # noqa: F401
from solvers import nashq  # noqa: F401
from solvers import cbr, qp  # noqa: F401
