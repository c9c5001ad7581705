"""fixbench's harness: benchmark matrices, executors, the results store, reports and the CLI.

``load_results`` (a run's rows as stored) and ``load_rows`` (the table the reports read: labels, ``ok``,
defaults; :mod:`fixbench.bench.records.rows`) are imported on first use (PEP 562): the CLI starts
without pandas.
"""

from __future__ import annotations

__all__ = ["load_results", "load_rows"]


def __getattr__(name: str):
    if name in __all__:
        from fixbench.bench.running import rows

        return getattr(rows, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
