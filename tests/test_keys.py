"""The keys that group rows (bench/records/rows.py) and the held-out split (bench/records/keys.py): one
definition each, and every user of the split gets the same positions."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from fixbench.bench.records.keys import split
from fixbench.bench.records.rows import PROBLEM, RANKED, REFERENCE, problem_of, reference_key, reference_of
from fixbench.bench.running.matrix import Cell


@pytest.mark.parametrize("n, every", [(10, 2), (7, 3), (5, 5), (1, 2), (0, 4)])
def test_split_partitions_the_positions(n, every):
    train, held = split(n, every)
    assert sorted(train + held) == list(range(n))
    assert train == [t for t in range(n) if t % every == 0] and not set(train) & set(held)


def test_split_refuses_a_level_below_two():
    with pytest.raises(ValueError, match="heldout_every"):
        split(10, 1)


def test_a_held_out_cell_trains_on_the_split():
    cell = Cell(case="wing_panel_small", material=None, agents=None, tasks=None, planner="random", config=(),
                budget=None, seed=0, mode="held-out", samples_per_task=10, heldout_every=3)
    assert cell.train_tasks(8) == split(8, 3)[0] == [0, 3, 6]
    assert cell.budget_for(8) == 30


def test_reference_of_a_row_and_a_failed_row():
    row = {"case": "fan", "material": "steel", "agents": 3.0, "n_tasks": 6, "mode": "per-task", "seed": 1}
    assert reference_of(row) == ("fan", "steel", 3, 6)
    assert reference_of(pd.Series(row)) == reference_of(row)
    assert reference_of({**row, "agents": math.nan}) is None and reference_of({"case": "fan"}) is None
    assert problem_of(row) == ("fan", "steel", 3.0, 6, "per-task")
    assert REFERENCE == PROBLEM[:4] and set(PROBLEM) < set(RANKED) and "seed" in RANKED


def test_reference_key_is_a_file_name():
    assert reference_key("fan", None, None, None) == "fan__default__adefault__tall"
    key = reference_key("my parts/a plate.toml", "steel", 2, 5)
    assert key.startswith("a_plate-") and key.endswith("__steel__a2__t5") and "/" not in key
