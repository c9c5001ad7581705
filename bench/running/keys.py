"""What groups cells, rows and references, and the held-out split: each defined once, used by the
runner, the reports, the exports and the reference tools alike.

A cell names its problem as its matrix does, ``(case, material, agents, tasks)`` with None for the
case's own material, robot count and every position (:attr:`fixbench.bench.running.matrix.Cell.problem_key`;
the regret reference's file name: :func:`reference_key`). A row, and a regret reference, records the
values those resolve to, and these column tuples group rows:

- :data:`REFERENCE` pairs a row with its regret reference: the per-position optima depend on the part,
  material, robots and positions, never on the track;
- :data:`PROBLEM` adds the mode: each position's optimum is shared by the per-task and held-out tracks,
  the shared mode has its own (one layout for every position);
- :data:`RANKED` adds the seed: the ranks of the comparison are taken over the entries that ran one
  problem with one seed (one "problem" of rliable's score matrix).

The held-out track (:func:`split`) trains on positions 0, k, 2k, ... and acts on the others with no
sample; ``fixbench solve --heldout-every``, the cells, the reports and the reference tools all call it.
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path

#: a row's regret reference (resolved values)
REFERENCE = ("case", "material", "agents", "n_tasks")
#: a problem instance: rows with the same key share each position's optimum
PROBLEM = (*REFERENCE, "mode")
#: one problem of the comparison's ranks (order: how the tables group)
RANKED = ("case", "material", "seed", "agents", "n_tasks", "mode")


def reference_of(rec) -> tuple | None:
    """:data:`REFERENCE` of a row or a reference snapshot (a dict or a pandas row), agents and positions as
    ints; None when it lacks them (a failed cell)."""
    try:
        return (rec["case"], rec["material"], int(rec["agents"]), int(rec["n_tasks"]))
    except (KeyError, TypeError, ValueError):
        return None


def problem_of(rec) -> tuple:
    """:data:`PROBLEM` of a row."""
    return tuple(rec[c] for c in PROBLEM)


def reference_key(case: str, material: str | None, agents: int | None, tasks: int | None) -> str:
    """The file-name-safe key of a cell's problem as the matrix names it (its regret reference's file
    ``DIR/reference/KEY.json``); a case given as a path becomes its stem plus a hash of the path."""
    name = case
    if case.endswith(".toml") or "/" in case or os.sep in case:
        digest = hashlib.sha1(str(Path(case).resolve()).encode()).hexdigest()[:8]
        name = f"{Path(case).stem}-{digest}"
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
    return f"{name}__{material or 'default'}__a{agents or 'default'}__t{tasks or 'all'}"


def split(n_tasks: int, every: int) -> tuple[list[int], list[int]]:
    """The held-out track's split of ``n_tasks`` positions: (trained on: 0, every, 2 every, ...; acted
    on with no sample: the others)."""
    if every < 2:
        raise ValueError(f"heldout_every must be 2 or more, got {every}")
    train = list(range(0, n_tasks, every))
    return train, [t for t in range(n_tasks) if t % every]
