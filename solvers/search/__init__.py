"""Search planners: ``random``, ``greedy``, ``local``, ``ga``, ``pso`` (on pymoo) and ``optuna``, each on
the budget loop of :meth:`fixbench.solvers.base.Planner.drive`."""
