"""fixbench's harness: benchmark matrices, executors, the results store, reports and the CLI."""

from fixbench.bench.store import load_results

__all__ = ["load_results"]
