"""Row files (docs/rows.md): schema 3 writes strict JSON, the JSON columns as plain JSON values and a
missing number as null; schema-1 files (those columns as JSON text) and schema-2 files (a missing
number as NaN) still read, to the same in-memory row; a damaged row of any schema is refused; a
rewrite upgrades an older row to schema 3."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import strict_json_loads

from fixbench.bench.reporting.html_report import provenance_html
from fixbench.bench.running.store import (
    CHECKSUM,
    JSON_COLUMNS,
    ROW_SCHEMA,
    SCHEMA_VERSION,
    Store,
    load_results,
    row_checksum,
    write_json_atomic,
)

#: the JSON columns of one cell, as values
VALUES = {"config": {"batch": 5, "shape": [2, 3]}, "per_task_m": [1.25e-5, 2.5e-5, 3.0e-5],
          "layouts": [[18, 46, 74], [18, 47, 74], [0, 46, 74]], "info": {"episodes": 7, "note": "x"},
          "provenance": {"fixbench": "test", "libraries": {"numpy": "2.0", "scipy": "1.14"}, "cpu": "Test CPU"},
          "policy_per_task_m": [1.5e-5, 2.5e-5, 3.5e-5], "policy_layouts": [[1, 2, 3], [4, 5, 6], [7, 8, 9]]}


def _row(cell: str = "c0") -> dict:
    row = {k: math.nan for k in ROW_SCHEMA}
    row.update(cell=cell, planner="random", case="fan_small", material="aluminium", agents=3, mode="per-task",
               seed=0, n_tasks=3, error="", objective_m=float(np.mean(VALUES["per_task_m"])), samples=30, **VALUES)
    return row


def _write_schema_1(store: Store, row: dict) -> None:
    """The row as the code before schema 2 wrote it: the JSON columns as JSON text, schema 1, its
    checksum over that."""
    old = dict(row, schema=1, **{k: json.dumps(row[k]) for k in JSON_COLUMNS})
    write_json_atomic_nan(store.row_path(old["cell"]), old | {CHECKSUM: row_checksum(old)})


def _raw(store: Store, cell: str = "c0") -> dict:
    return json.loads(store.row_path(cell).read_text())


def _same(x, y) -> bool:
    """Equal, NaN equal to NaN."""
    return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))


def _write_schema_2(store: Store, row: dict) -> None:
    """The row as the code before schema 3 wrote it: plain JSON values, a missing number as NaN."""
    old = json.loads(json.dumps(dict(row, schema=2), default=str))
    write_json_atomic_nan(store.row_path(old["cell"]), old | {CHECKSUM: row_checksum(old)})


def write_json_atomic_nan(path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1))  # NaN as Python's json writes it


def test_schema_3_round_trip(tmp_path):
    store = Store(tmp_path / "run")
    store.write(_row(), None, None)
    text = store.row_path("c0").read_text()
    raw = strict_json_loads(text)  # strict JSON: no NaN in the file
    assert raw["schema"] == SCHEMA_VERSION == 3 and raw["relative_regret"] is None
    assert {k: raw[k] for k in JSON_COLUMNS} == VALUES  # plain JSON values in the file, not text
    assert raw[CHECKSUM] == row_checksum(raw)
    row = store.finished()["c0"]
    assert {k: row[k] for k in JSON_COLUMNS} == VALUES and not store.damaged
    assert math.isnan(row["relative_regret"]) and math.isnan(row["budget"])  # a missing number reads as NaN
    df = load_results(store.root)
    assert isinstance(df.loc[0, "per_task_m"], list) and df.loc[0, "layouts"] == VALUES["layouts"]


@pytest.mark.parametrize("schema", [1, 2])
def test_an_older_file_reads_as_its_schema_3_twin(tmp_path, schema):
    old, new = Store(tmp_path / "old"), Store(tmp_path / "new")
    (_write_schema_1 if schema == 1 else _write_schema_2)(old, _row())
    new.write(_row(), None, None)
    assert isinstance(_raw(old)["per_task_m"], str) == (schema == 1)  # the file is left as it is
    a, b = old.finished()["c0"], new.finished()["c0"]
    assert not old.damaged and not new.damaged
    assert (a["schema"], b["schema"]) == (schema, 3)
    drop = ("schema", CHECKSUM)
    assert a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a if k not in drop)
    pd.testing.assert_frame_equal(load_results(old.root).drop(columns="schema"),
                                  load_results(new.root).drop(columns="schema"))


def test_damaged_rows_are_refused(tmp_path, capsys):
    store = Store(tmp_path / "run")
    store.write(_row("c0"), None, None)
    raw = _raw(store, "c0")
    raw["per_task_m"][1] = 1e-9  # a changed value inside an array: the checksum no longer matches
    write_json_atomic(store.row_path("c0"), raw)
    text = dict(_row("c1"), schema=2, per_task_m=json.dumps(VALUES["per_task_m"]))  # schema 2 with text
    write_json_atomic_nan(store.row_path("c1"), text | {CHECKSUM: row_checksum(text)})
    bad = dict(_row("c2"), schema=1, config="{batch=5")  # schema 1 whose text is not JSON
    write_json_atomic_nan(store.row_path("c2"), bad | {CHECKSUM: row_checksum(bad)})
    assert store.finished() == {}
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and "c0.json: damaged (checksum does not match its content)" in err[0]
    assert "c1.json: damaged (key 'per_task_m' is JSON text, not a JSON value (schema 2))" in err[1]
    assert "c2.json: damaged (key 'config' is not JSON text (schema 1))" in err[2]


def test_rewrite_upgrades_a_schema_1_row(tmp_path):
    store = Store(tmp_path / "run")
    _write_schema_1(store, _row())
    before = store.finished()["c0"]
    store.rewrite(dict(before, relative_regret=0.25))
    raw = strict_json_loads(store.row_path("c0").read_text())
    assert raw["schema"] == 3 and raw[CHECKSUM] == row_checksum(raw)
    assert {k: raw[k] for k in JSON_COLUMNS} == VALUES
    after = store.finished()["c0"]
    assert not store.damaged and after["relative_regret"] == 0.25
    drop = ("schema", CHECKSUM, "relative_regret")
    assert after.keys() == before.keys() and all(_same(after[k], before[k]) for k in after if k not in drop)


def test_provenance_records_are_grouped_by_value():
    """Two rows with the same provenance in another key order are one record."""
    rec = VALUES["provenance"]
    same = dict(reversed(list(rec.items())))
    rows = pd.DataFrame({"provenance": [rec, same, dict(rec, cpu="Other CPU"), math.nan]})
    page = provenance_html(rows)
    assert "record 1 (2 cells)" in page and "record 2 (1 cells)" in page and "record 3" not in page
    assert "Not recorded for 1 cells" in page
