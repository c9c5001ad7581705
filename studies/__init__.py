"""Studies beside the benchmark, not part of the installed package: each module is a command line of
its own, run from the repository root (``python -m studies.NAME``), that measures or draws something
the docs and results cite, on the oracle or the planners directly rather than through a matrix run.

- :mod:`studies.analysis`: the committed analyses of ``results/analysis/`` (the seed's Figure 3, the
  equilibrium landscape of the small cases, the robots a job needs);
- :mod:`studies.marl`: the learners with the seed's reward (nashq, iql): Figure 4, the speed of the
  published protocol, the small-case optima, held-out tasks, the cost floor of one network update;
- :mod:`studies.gpu_check`: the published protocol on CUDA beside the CPU;
- :mod:`studies.small_benchmark`: exact optima of the ``*_small`` cases and the search planners' gaps
  at 2 % of the enumeration;
- :mod:`studies.startup`: start-up time of the everyday ``fixbench`` commands.

They import the library (:mod:`fixbench`) as any user code does; nothing in the library imports them.
"""
