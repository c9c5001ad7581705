"""Result rows, the one definition: what a row holds, how rows group, and the one loader.

A run directory holds a row file per finished cell, ``DIR/rows/<cell id>.json``
(:mod:`fixbench.bench.records.store` writes them and keeps the run directory). This module is what
every reader of rows goes by (the reports, the exports, merged runs, ``fixbench verify`` and the
reference tools):

- the schema: the columns and their meaning (:data:`ROW_SCHEMA`, docs/rows.md), the schema version a
  row is written with (:data:`SCHEMA_VERSION`), the older ones still read and their upgrade
  (:func:`decode_row`), and what makes a row file damaged (:func:`read_row`);
- the keys that group rows (below) and the matrix entry a row belongs to (:func:`entry_labels`);
- the one loader, :func:`load_rows`: a run's valid rows as a table, upgraded to the current schema,
  numbers as numbers, ``error`` '' where none, ``ok`` (no error), ``mode`` with its default
  (:data:`DEFAULT_MODE`) and ``label`` the entry's label, in the matrix's case order.
  :func:`load_results` is its first step, the valid rows as stored (``fixbench.bench.load_results``).

Schema: a row is written as ``SCHEMA_VERSION`` 3: strict JSON (RFC 8259), its ``JSON_COLUMNS``
(config, per-task values, layouts, info, provenance) as plain JSON values and a number it has no
value for (NaN) as null. Rows of schema 1 held those columns as JSON text inside the JSON, rows of
schemas 1 and 2 wrote a missing number as ``NaN`` (which Python's ``json`` reads, strict parsers do
not); they are read as they are on disk (their checksum is over that text) and then decoded by
:func:`decode_row`, so every reader sees one in-memory form whichever schema a file has (a missing
number is NaN there); :meth:`fixbench.bench.records.store.Store.rewrite` writes such a row again as
schema 3 (``fixbench references rescore DIR`` rewrites every older row of a run).

Integrity: a row carries its schema version, its cell id (equal to its file name), ``row_sha1``, a
SHA-1 of its own content, and ``trace_sha1`` / ``curves_sha1``, the SHA-1 of the bytes of its trace
and curves files (written before the row). A row file that does not parse, is not a row, belongs
to another cell, has a schema version this fixbench does not read, fails its checksum or holds a
column in the wrong form for its schema, or whose trace or curves file is missing or differs from
its recorded SHA-1, is *damaged* (:func:`read_rows`): the loaders skip it with one line on stderr,
``fixbench run`` moves it aside and recomputes its cell (:meth:`fixbench.bench.records.store.Store.finished`).
Rows written before checksums existed are checked by schema only.

Keys. A cell names its problem as its matrix does, ``(case, material, agents, tasks)`` with None for
the case's own material, robot count and every position
(:attr:`fixbench.bench.running.matrix.Cell.problem_key`; its regret reference's file name:
:func:`reference_key`). A row, and a regret reference, records the values those resolve to, and
these column tuples group rows:

- :data:`REFERENCE` pairs a row with its regret reference: the per-position optima depend on the part,
  material, robots and positions, never on the track (:data:`SHIPPED`: a shipped reference holds every
  position of a part, material and robot count);
- :data:`PROBLEM` adds the mode: each position's optimum is shared by the per-task and held-out tracks,
  the shared mode has its own (one layout for every position); :func:`track_of` adds the held-out
  spacing (other tools cannot tell the tracks apart by mode alone);
- :data:`RANKED` adds the seed: the ranks of the comparison are taken over the entries that ran one
  problem with one seed (one "problem" of rliable's score matrix), at one :func:`budget_level`;
- :data:`SETTINGS`: a cell's settings as its row records them; :data:`REPLICATES`: an entry's cells that
  differ only in their seed; :data:`VARIED_SETTINGS`: those a run's summary tables split on when the run
  varies them; :data:`PROFILE_PROBLEM`: a problem of the performance profile; :data:`ONLY_KEYS`: those
  ``--only`` selects cells by; :data:`ORDER`: the order rows are read in.

The held-out split (which positions a held-out cell trains on) is
:func:`fixbench.bench.records.keys.split`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import sys
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

# the schema ---------------------------------------------------------------------------------------

#: the version every row is written with (``schema``)
SCHEMA_VERSION = 3
#: the versions a row read may have (see the module docstring; a row without ``schema`` is of version 1)
READ_VERSIONS = (1, 2, 3)

#: column -> meaning (docs/rows.md documents the same table)
ROW_SCHEMA = {
    "schema": "schema version of this row",
    "cell": "cell id (hash of the cell's settings)",
    "planner": "planner name", "config": "planner config overrides (JSON object)",
    "config_hash": "hash of the planner's full config",
    "case": "case name", "part": "physical part", "material": "material name",
    "label": "the matrix entry's label (empty: planner name and config)",
    "agents": "number of agents", "mode": "per-task, shared or held-out",
    "budget": "sample budget (NaN = unlimited)",
    "samples_per_task": "budget sweep: samples a task (budget = this x tasks the planner may evaluate)",
    "heldout_every": "held-out mode: the planner trained on every k-th task and acted on the others",
    "seed": "seed", "n_tasks": "tasks in the problem",
    "n_scored_tasks": "tasks the objective is taken over (the held-out ones in held-out mode)",
    "mean_max_deformation_m": "mean over tasks of the max |u| of the planner's layout",
    "worst_max_deformation_m": "worst task's max |u|",
    "best_max_deformation_m": "best task's max |u|",
    "objective_m": "mean (per-task; over held-out tasks in held-out mode) or worst (shared) max |u|",
    "per_task_m": "max |u| of the layout each task is scored by (JSON array, metres; the scoring rule: "
                  "docs/protocol.md#scoring)",
    "mean_reward": "mean Gaussian reward of the layouts (seed paper)",
    "mean_reward_bell": "mean bell reward (reference code)",
    "reference_objective_m": "the regret reference's objective (optimum or best known)",
    "reference_proven": "whether the reference is a proven optimum",
    "reference_source": "exact, or the shipped catalog reference file and its content hash",
    "true_regret_m": "objective_m - reference_objective_m",
    "relative_regret": "objective_m / reference_objective_m - 1: at most the true regret (the reference is a "
                       "layout reached, so at least the optimum)",
    "bound_objective_m": "the same objective of the reference's certified lower bounds on each position's optimum "
                         "(0 for a position without one): at most the optimal objective",
    "relative_regret_upper": "objective_m / bound_objective_m - 1: at least the true regret, so that "
                             "[relative_regret, relative_regret_upper] brackets it (NaN: no positive bound)",
    "reference_regret": "N T pi/4 - N sum of bell rewards (the reference code's regret)",
    "samples_to_1pct": "mean over tasks of task samples until within 1 % of the optimum (NaN if never)",
    "samples_to_5pct": "same, within 5 %",
    "success_1pct": "fraction of tasks whose final layout is within 1 % of the optimum",
    "success_5pct": "same, within 5 %",
    "samples": "samples the planner spent",
    "setup_s": "problem set-up before the planner ran: model, factorisation, compliance data (no samples)",
    "wall_s": "wall time of the planner's run (set-up excluded)", "cpu_s": "CPU time of the planner's run",
    "layouts": "the layout each task is scored by (JSON array of arrays of action indices: the candidates, "
               "with one pad a robot): "
               "the planner's incumbent, the best layout it evaluated there, else the layout it returned; "
               "null in a row made before incumbents were recorded and rescored from its trace",
    "policy_objective_m": "a learner's second figure: the objective of its greedy policy's layouts (NaN: none)",
    "policy_relative_regret": "policy_objective_m / reference_objective_m - 1",
    "policy_per_task_m": "max |u| of the policy's layout on each task (JSON array, metres)",
    "policy_layouts": "the policy's layout per task (JSON array of arrays)",
    "version": "fixbench version", "error": "empty, or why the cell failed", "info": "planner info (JSON object)",
    "provenance": "where and with what the row was made (JSON object): fixbench version and source commit, Python, "
                  "library versions, numpy's BLAS, CPU model and cores, threads, environment switches "
                  "(bench/running/provenance.py)",
}

#: the columns holding a JSON value (not a flat number or text): schema 1 wrote each as JSON text
JSON_COLUMNS = ("config", "per_task_m", "layouts", "info", "provenance", "policy_per_task_m", "policy_layouts")
#: the columns holding text; ``reference_proven`` holds a truth value; every other column a number
TEXT_COLUMNS = ("cell", "planner", "config_hash", "case", "part", "material", "label", "mode", "reference_source",
                "version", "error")
#: the columns holding a number (NaN: none), as :func:`load_rows` reads them
NUMBERS = tuple(c for c in ROW_SCHEMA if c not in (*JSON_COLUMNS, *TEXT_COLUMNS, "reference_proven"))

#: what every row must hold, with its type (rows of any version since the first; rows of early
#: runs have no schema, mode or error key: they read as schema 1, per-task, no error)
REQUIRED = {"cell": str, "planner": str, "case": str}
OPTIONAL = {"schema": int, "mode": str, "error": str}
CHECKSUM = "row_sha1"
#: the row key holding the SHA-1 of each per-cell file, by folder
FILE_CHECKSUMS = {"traces": "trace_sha1", "curves": "curves_sha1"}

#: the modes (tracks) a cell runs in, and the one a row without a mode ran in (rows of early runs)
MODES = ("per-task", "shared", "held-out")
DEFAULT_MODE = "per-task"


def planner_mode(mode: str) -> str:
    """The mode a planner solves a cell of ``mode`` in (``Planner.solve``; the planners know two): a
    held-out cell runs per-task on its training positions."""
    return "per-task" if mode == "held-out" else mode


# the keys -----------------------------------------------------------------------------------------

#: a row's regret reference (resolved values)
REFERENCE = ("case", "material", "agents", "n_tasks")
#: a shipped (catalog) reference: one file a part, material and robot count, every position of the part
SHIPPED = REFERENCE[:3]
#: a problem instance: rows with the same key share each position's optimum
PROBLEM = (*REFERENCE, "mode")
#: one problem of the comparison's ranks, with the budget level (order: how the tables group)
RANKED = ("case", "material", "seed", "agents", "n_tasks", "mode")
#: a cell's settings as its row records them: the problem, its track, its effort, its seed
SETTINGS = (*REFERENCE, "mode", "heldout_every", "budget", "samples_per_task", "seed")
#: the rows of one matrix entry (``label``) that differ only in their seed (``fixbench verify``'s interval)
REPLICATES = ("label", *(c for c in SETTINGS if c != "seed"))
#: the settings a run's summary tables and performance profile split on when the run varies them
VARIED_SETTINGS = ("agents", "mode", "budget", "samples_per_task")
#: a problem of the performance profile (with each of :data:`VARIED_SETTINGS` the run varies)
PROFILE_PROBLEM = ("case", "material", "seed")
#: the settings ``fixbench run --only KEY=VALUE`` (and ``fixbench verify --only``) select cells by
ONLY_KEYS = ("case", "material", "mode", "seed", "samples_per_task")
#: the order rows are read in (:func:`load_results`; :func:`load_rows` then puts the cases in matrix order)
ORDER = ("case", "material", "planner", "seed")


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


def track_of(rec) -> tuple:
    """:data:`PROBLEM` of a row and its held-out spacing (0: not a held-out row, or none recorded)."""
    k = rec["heldout_every"]
    held = rec["mode"] == "held-out" and not (k is None or (isinstance(k, float) and math.isnan(k)))
    return (*problem_of(rec), int(k) if held else 0)


def reference_key(case: str, material: str | None, agents: int | None, tasks: int | None) -> str:
    """The file-name-safe key of a cell's problem as the matrix names it (its regret reference's file
    ``DIR/reference/KEY.json``); a case given as a path becomes its stem plus a hash of the path."""
    name = case
    if case.endswith(".toml") or "/" in case or os.sep in case:
        digest = hashlib.sha1(str(Path(case).resolve()).encode()).hexdigest()[:8]
        name = f"{Path(case).stem}-{digest}"
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
    return f"{name}__{material or 'default'}__a{agents or 'default'}__t{tasks or 'all'}"


def budget_level(rows: pd.DataFrame) -> pd.Series:
    """The budget part of a ranked problem: samples a task in a sweep run, else the cell's budget (NaN: a
    planner's own budget)."""
    return rows["samples_per_task"] if rows["samples_per_task"].notna().any() else rows["budget"]


def with_case_defaults(rows: pd.DataFrame) -> pd.DataFrame:
    """Rows whose :data:`REFERENCE` columns are missing get their case's value where the case has one: a
    failed cell's row keeps the matrix's raw settings (no tasks count; no agents or material where the
    case's default was meant), so without this it would sit alone on a problem of its own."""
    out = rows.copy()
    for col in REFERENCE[1:]:
        values = out.dropna(subset=[col]).groupby("case")[col].unique()
        single = {case: v[0] for case, v in values.items() if len(v) == 1}
        out[col] = out[col].fillna(out["case"].map(single))
    return out


def config_text(config) -> str:
    """A row's planner config (a JSON object) as ``key=value,...`` in key order ('' for none): the
    canonical text tables group and name planners by."""
    return ",".join(f"{k}={v}" for k, v in sorted(config.items())) if isinstance(config, dict) else ""


def entry_labels(rows: pd.DataFrame) -> list[str]:
    """The matrix entry of each row as reports name it: its label where the row has one, else the
    planner, with its config when the rows hold that planner unlabelled under several configs (rows of
    older runs have no label)."""
    cfg = rows["config"].map(config_text)
    given = rows["label"].map(lambda v: v if isinstance(v, str) else "")
    several = rows[given == ""].assign(cfg=cfg).groupby("planner")["cfg"].nunique()
    return [g or (f"{p} ({c or 'default'})" if several.get(p, 1) > 1 else p)
            for g, p, c in zip(given, rows["planner"], cfg)]


# a row file ---------------------------------------------------------------------------------------

def warn(msg: str) -> None:
    print(f"fixbench: {msg}", file=sys.stderr)


def row_path(root: str | Path, cell_id: str) -> Path:
    """The row file of cell ``cell_id`` in run directory ``root``."""
    return Path(root) / "rows" / f"{cell_id}.json"


def cell_files(root: str | Path, cell_id: str) -> dict[str, Path]:
    """The cell's Parquet files a row vouches for, by folder (they may not exist)."""
    return {folder: Path(root) / folder / f"{cell_id}.parquet" for folder in FILE_CHECKSUMS}


def row_checksum(row: dict) -> str:
    """SHA-1 of a row's content without its checksum (keys sorted; NaN written as JSON's NaN)."""
    body = {k: v for k, v in row.items() if k != CHECKSUM}
    return hashlib.sha1(json.dumps(body, sort_keys=True, default=str).encode()).hexdigest()


def file_sha1(path: Path) -> str:
    return hashlib.sha1(path.read_bytes()).hexdigest()


def check_row(row, cell_id: str) -> str:
    """Why a parsed row file is not a valid row of cell ``cell_id`` ('' if it is)."""
    if not isinstance(row, dict):
        return "not a JSON object"
    for key, kind in REQUIRED.items():
        if not isinstance(row.get(key), kind):
            return f"key '{key}' missing or not a {kind.__name__}"
    for key, kind in OPTIONAL.items():
        v = row.get(key)
        if v is None or (isinstance(v, float) and math.isnan(v)):  # missing (null or NaN): an early row
            continue
        if isinstance(v, bool) or not isinstance(v, kind):
            return f"key '{key}' is not a {kind.__name__}"
    if isinstance(row.get("schema"), int) and row["schema"] not in READ_VERSIONS:
        return f"schema {row['schema']}, this fixbench reads {', '.join(map(str, READ_VERSIONS))}"
    if row["cell"] != cell_id:
        return f"holds cell {row['cell']!r}, not {cell_id!r}"
    if CHECKSUM in row and row[CHECKSUM] != row_checksum(row):
        return "checksum does not match its content"
    if row.get("schema") in (2, 3):
        text = [k for k in JSON_COLUMNS if isinstance(row.get(k), str)]
        if text:
            return f"key '{text[0]}' is JSON text, not a JSON value (schema {row['schema']})"
    for key in ("objective_m", "mean_max_deformation_m", "samples"):
        v = row.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
            return f"key '{key}' is not a number"
    v = row.get("objective_m")
    if isinstance(v, (int, float)) and v < 0:
        return f"objective_m is {v} (a deformation cannot be negative)"
    return ""


def check_files(root: str | Path, row: dict) -> str:
    """Why the trace or curves file a valid row names does not match it ('' if they do; a row
    without a recorded SHA-1 is not checked)."""
    for folder, path in cell_files(root, row["cell"]).items():
        want = row.get(FILE_CHECKSUMS[folder])
        if not isinstance(want, str):
            continue
        if not path.is_file():
            return f"its {folder} file {path.name} is missing"
        if file_sha1(path) != want:
            return f"its {folder} file {path.name} differs from the row's {FILE_CHECKSUMS[folder]}"
    return ""


def decode_row(row: dict) -> dict:
    """A valid row (checked by :func:`check_row`, its checksum over the file as it is) in its in-memory
    form: a schema-1 row's ``JSON_COLUMNS`` held as JSON text are decoded to their values (arrays,
    objects); a schema-3 row's nulls outside them read as NaN (as schemas 1 and 2 wrote them); a schema-2
    row is returned as it is. The only place rows of the schemas meet. Raises ValueError naming a
    column whose text is not JSON."""
    if row.get("schema") == 3:
        return {k: math.nan if v is None and k in ROW_SCHEMA and k not in JSON_COLUMNS else v
                for k, v in row.items()}
    if row.get("schema") == 2:
        return row
    out = dict(row)
    for key in JSON_COLUMNS:
        if isinstance(out.get(key), str):
            try:
                out[key] = json.loads(out[key])
            except ValueError:
                raise ValueError(f"key '{key}' is not JSON text (schema 1)") from None
    return out


def read_row(path: Path) -> tuple[dict | None, str]:
    """The row in the row file ``path`` (``DIR/rows/<cell id>.json``; decoded: :func:`decode_row`) and '',
    or None and why it is damaged."""
    try:
        row = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        return None, f"not JSON ({str(exc).splitlines()[0]})"
    why = check_row(row, path.stem) or check_files(path.parent.parent, row)
    if why:
        return None, why
    try:
        return decode_row(row), ""
    except ValueError as exc:
        return None, str(exc)


def read_rows(root: str | Path) -> tuple[dict[str, dict], dict[Path, str]]:
    """The valid rows of run directory ``root`` (decoded), by cell id in file order, and each damaged
    row file with why."""
    valid, damaged = {}, {}
    for p in sorted((Path(root) / "rows").glob("*.json")):
        row, why = read_row(p)
        if why:
            damaged[p] = why
        else:
            valid[p.stem] = row
    return valid, damaged


# the loader ---------------------------------------------------------------------------------------

def load_results(root: str | Path) -> pd.DataFrame:
    """One row per finished cell as stored (upgraded to the current schema) as a DataFrame (columns:
    ROW_SCHEMA, in :data:`ORDER`); damaged rows are skipped (each reported on stderr;
    ``df.attrs["damaged"]`` counts them). :func:`load_rows` is what reads a run for its tables."""
    import pandas as pd

    rows, damaged = read_rows(root)
    for p, why in damaged.items():
        warn(f"{p}: damaged ({why}); skipped")
    df = pd.DataFrame(list(rows.values()), columns=list(ROW_SCHEMA)) if rows else pd.DataFrame(columns=list(ROW_SCHEMA))
    df = df.sort_values(list(ORDER), kind="stable").reset_index(drop=True)
    df.attrs["damaged"] = len(damaged)
    return df


def in_matrix_order(rows: pd.DataFrame, run_dir: str | Path) -> pd.DataFrame:
    """``rows`` with the cases in the order the run's matrix lists them (tables and figures show the parts
    as the matrix does), a stable sort; cases the matrix does not name (or no readable matrix) after."""
    try:
        listed = tomllib.loads((Path(run_dir) / "matrix.toml").read_text()).get("cases", [])
    except (OSError, ValueError):
        listed = []
    order = {c: i for i, c in enumerate(listed) if isinstance(c, str)}
    if rows.empty or not order:
        return rows
    rank = rows["case"].map(lambda c: order.get(c, len(order)))
    return rows.iloc[rank.argsort(kind="stable")].reset_index(drop=True)


def load_rows(run_dir: str | Path) -> pd.DataFrame:
    """The one loader: a run's valid rows (:func:`load_results`) in the matrix's case order, with
    :data:`NUMBERS` as numbers, ``error`` '' where there is none, ``ok`` (no error), ``mode`` where a
    row has none :data:`DEFAULT_MODE`, and ``label`` the matrix entry's (:func:`entry_labels`)."""
    import pandas as pd

    rows = in_matrix_order(load_results(run_dir), run_dir)
    for c in NUMBERS:
        rows[c] = pd.to_numeric(rows[c], errors="coerce")
    rows["error"] = rows["error"].fillna("").astype(str)
    rows["ok"] = rows["error"] == ""
    rows["mode"] = rows["mode"].fillna(DEFAULT_MODE)
    rows["label"] = entry_labels(rows)
    return rows
