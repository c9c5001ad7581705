"""fixbench's harness: benchmark matrices, executors, the results store, reports and the CLI.

``load_results`` is imported on first use (PEP 562): the CLI starts without pandas.
"""

from __future__ import annotations

__all__ = ["load_results"]


def __getattr__(name: str):
    if name == "load_results":
        from fixbench.bench.running.store import load_results

        return load_results
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
