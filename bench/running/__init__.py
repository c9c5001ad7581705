"""Running a benchmark: matrix files and their cells, what a worker runs, the executors (local
processes, Ray), the driver and each row's provenance. It calls :mod:`fixbench.bench.references` for
each problem's regret reference and writes through :mod:`fixbench.bench.records`.

Imports nothing from the rooms above it (:mod:`fixbench.bench.reporting`, :mod:`fixbench.bench.analysis`)."""
