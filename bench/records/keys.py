"""The held-out split: which positions a held-out cell trains on, defined once for ``fixbench solve
--heldout-every``, the matrix's cells, the reports, ``fixbench tune`` and the reference tools.

The keys that group rows (problem, regret reference, ranked problem, entry label) are in
:mod:`fixbench.bench.records.rows`. The learners' own ``train_tasks`` / ``train_fraction`` choice (their
``train_ids``: positions spread evenly over a per-task run, or those listed) is another rule, not this
one (10 positions, every 2nd: 0, 2, 4, 6, 8 here, 0, 2, 4, 7, 9 there at ``train_fraction`` 0.5); a
held-out cell hands this split to the planner (``Planner.solve(train_tasks=...)``), so the solvers never
need it.
"""

from __future__ import annotations


def split(n_tasks: int, every: int) -> tuple[list[int], list[int]]:
    """The held-out track's split of ``n_tasks`` positions: (trained on: 0, every, 2 every, ...; acted
    on with no sample: the others)."""
    if every < 2:
        raise ValueError(f"heldout_every must be 2 or more, got {every}")
    train = list(range(0, n_tasks, every))
    return train, [t for t in range(n_tasks) if t % every]
