"""Imports every built-in planner so that each registers itself."""

from solvers import (  # noqa: F401  # noqa: F401
    cbr,
    evolutionary,  # noqa: F401
    exact,
    greedy,
    nashq,  # noqa: F401
    qp,
    random_search,  # noqa: F401
)
