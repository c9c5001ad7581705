"""Studies beside the benchmark: each module is a command line of its own (``python -m
fixbench.bench.studies.NAME``) that measures or draws something the docs and results cite, on the
oracle or the planners directly rather than through a matrix run.

- :mod:`~fixbench.bench.studies.analysis`: the committed analyses of ``results/analysis/`` (the
  seed's Figure 3, the equilibrium landscape of the small cases, the robots a job needs);
- :mod:`~fixbench.bench.studies.marl`: the learners: Figure 4, the speed of the published
  protocol, the small-case optima, held-out tasks, the cost floor of one network update;
- :mod:`~fixbench.bench.studies.gpu_check`: the published protocol on CUDA beside the CPU;
- :mod:`~fixbench.bench.studies.small_benchmark`: exact optima of the ``*_small`` cases and the
  search planners' gaps at 2 % of the enumeration;
- :mod:`~fixbench.bench.studies.startup`: start-up time of the everyday ``fixbench`` commands.

They use the harness (:mod:`fixbench.bench`); nothing in the harness imports them.
"""
