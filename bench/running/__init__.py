"""Running a benchmark: matrix files and their cells, the regret references (shipped, built, proven),
what a worker runs, the executors (local processes, Ray), the results store and each row's provenance.

Imports nothing from the other rooms (:mod:`fixbench.bench.reporting`, :mod:`fixbench.bench.analysis`)."""
