"""Row files (docs/rows.md): schema 3 writes strict JSON, the JSON columns as plain JSON values and a
missing number as null; schema-1 files (those columns as JSON text) and schema-2 files (a missing
number as NaN) still read, to the same in-memory row; a damaged row of any schema is refused; a
rewrite upgrades an older row to schema 3. The one loader (``load_rows``) gives an early row's defaults,
and no module of the harness but bench/records/rows.py spells out a key that groups rows."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import strict_json_loads

import fixbench.bench
from fixbench.bench.records.rows import (
    CHECKSUM,
    JSON_COLUMNS,
    NUMBERS,
    REFERENCE,
    ROW_SCHEMA,
    SCHEMA_VERSION,
    TEXT_COLUMNS,
    load_results,
    load_rows,
    row_checksum,
)
from fixbench.bench.records.store import Store, write_json_atomic
from fixbench.bench.reporting.html_report import provenance_html

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


def test_the_loader_gives_an_early_row_its_defaults(tmp_path):
    """A schema-1 row of an early run (no mode, no error, numbers as text) reads through ``load_rows`` as a
    per-task row without error, its numbers as numbers and its label the planner's."""
    store = Store(tmp_path / "run")
    early = {k: v for k, v in _row().items() if k not in ("mode", "error", "label")}
    _write_schema_1(store, dict(early, wall_s="1.5"))
    _write_schema_1(store, dict(_row("c1"), mode="shared", error="Boom: no", label="mine"))
    rows = load_rows(store.root).set_index("cell")
    assert rows.loc["c0", ["mode", "error", "ok", "label"]].tolist() == ["per-task", "", True, "random"]
    assert rows.loc["c1", ["mode", "ok", "label"]].tolist() == ["shared", False, "mine"]
    assert rows["wall_s"].dtype == float and rows.loc["c0", "wall_s"] == 1.5
    assert set(NUMBERS) | set(TEXT_COLUMNS) | set(JSON_COLUMNS) | {"reference_proven"} == set(ROW_SCHEMA)


# one definition of the keys that group rows ---------------------------------------------------------

BENCH = Path(fixbench.bench.__path__[0])
#: the one module that spells out the columns rows group by
ROWS_MODULE = BENCH / "records" / "rows.py"
#: frame methods whose column arguments group, order or pick rows
FRAME_CALLS = {"groupby", "sort_values", "pivot_table", "pivot", "drop_duplicates", "duplicated", "dropna",
               "set_index", "merge", "value_counts"}


def _strings(node) -> list[str] | None:
    """The strings of a literal tuple, list or set of strings (nested ones too), else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if not isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return None
    parts = [_strings(e) for e in node.elts]
    return None if any(p is None for p in parts) else [s for p in parts for s in p]


def _literals(node) -> list[list[str]]:
    """The string literals ``node`` is made of: itself, or each term of a sum (``["case", ...] + more``)."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _literals(node.left) + _literals(node.right)
    names = _strings(node)
    return [] if names is None else [names]


def keys_of_its_own(source: str) -> list[int]:
    """The lines where ``source`` spells out a key of rows itself: a literal of column names with two or
    more of the problem's (case, material, agents, n_tasks) given a name (a constant, a local), or a
    literal with any of them but the case handed to a frame's grouping, sorting or picking call."""
    problem = set(REFERENCE)
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            if any(len(set(names) & problem) >= 2 for names in _literals(node.value)):
                found.append(node.lineno)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in FRAME_CALLS:
            for arg in [*node.args, *(k.value for k in node.keywords)]:
                if any(len(set(names) & problem) >= 2 or set(names) & problem - {"case"}
                       for names in _literals(arg)):
                    found.append(node.lineno)
    return sorted(set(found))


def test_no_module_of_the_harness_defines_a_row_key_of_its_own():
    """Every grouping of rows by their problem comes from bench/records/rows.py (REFERENCE, PROBLEM,
    RANKED, SETTINGS, ...): a module of bench/ that writes its own tuple of those columns, or groups by a
    literal list of them, defines a second key that can drift from the first."""
    wrong = [f"{p.relative_to(BENCH)}:{line}" for p in sorted(BENCH.rglob("*.py")) if p != ROWS_MODULE
             for line in keys_of_its_own(p.read_text(encoding="utf-8"))]
    assert not wrong, "keys of their own (use those of bench/records/rows.py): " + ", ".join(wrong)


def test_the_check_finds_a_key_of_its_own():
    """The check fails on what it is meant to catch: a module constant, a nested (column, name) table, a
    local key and a grouping by a literal list of problem columns; a per-case table is no key."""
    source = """
KEY = ("case", "material", "agents")
NAMED = (("case", "case"), ("n_tasks", "tasks"))
def f(df):
    keys = ["case", "material", "seed"] + [k for k in ("mode",) if df[k].nunique() > 1]
    a = df.groupby(["case", "label"]).size()
    b = df.sort_values(by=["agents", "label"])
    return df.groupby(["case", "n_tasks", "label"], sort=True).size(), a, b, keys
"""
    assert keys_of_its_own(source) == [2, 3, 5, 7, 8]
