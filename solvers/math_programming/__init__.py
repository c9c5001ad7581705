"""Mathematical programming: ``exact`` (enumeration or a HiGHS MILP, the proven optimum) and ``qp`` (a
convex relaxation in cvxpy + OSQP, rounded)."""
