"""The results store: one JSON row per finished cell, written atomically, plus Parquet traces.

Layout of a run directory::

    DIR/matrix.toml                 the matrix that was run (copied at the start)
    DIR/rows/<cell id>.json         one flat row per finished cell (see ROW_SCHEMA)
    DIR/traces/<cell id>.parquet    anytime trace: TRACE_COLUMNS (task, task_samples, samples, best)
    DIR/curves/<cell id>.parquet    training curves of learners: curve, index, value (long form)
    DIR/reference/<key>.json        regret reference per (case, material, agents, tasks)
    DIR/reference/<key>.proof.jsonl its positions as the reference phase proved them (bench/running/proof.py)

A row is written to a temporary file and renamed into place, so a run killed at any moment
leaves only complete rows; rerunning skips the cells that have one.

Schema: a row is written as ``SCHEMA_VERSION`` 3: strict JSON (RFC 8259), its ``JSON_COLUMNS``
(config, per-task values, layouts, info, provenance) as plain JSON values and a number it has no
value for (NaN) as null. Rows of schema 1 held those columns as JSON text inside the JSON, rows of
schemas 1 and 2 wrote a missing number as ``NaN`` (which Python's ``json`` reads, strict parsers do
not); they are read as they are on disk (their checksum is over that text) and then decoded by
:func:`decode_row`, so every reader sees one in-memory form whichever schema a file has (a missing
number is NaN there); :meth:`Store.rewrite` writes such a row again as schema 3 (``fixbench
references rescore DIR`` rewrites every older row of a run).

Integrity: a row carries its schema version, its cell id (equal to its file name), ``row_sha1``, a
SHA-1 of its own content, and ``trace_sha1`` / ``curves_sha1``, the SHA-1 of the bytes of its trace
and curves files (written before the row). A row file that does not parse, is not a row, belongs
to another cell, has a schema version this fixbench does not read, fails its checksum or holds a
column in the wrong form for its schema, or whose trace or curves file is missing or differs from
its recorded SHA-1, is *damaged*: :meth:`Store.finished` reports it in one
line and (in a run) moves it and its files to ``DIR/damaged/`` (never deletes them), so its cell is
recomputed; ``fixbench report`` skips and counts it, and reads only the traces and curves of valid
rows. Rows written before checksums existed are checked by schema only.
``DIR/.lock`` is held (an OS file lock) by the one ``fixbench run`` writing there.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
import sys
import time
from pathlib import Path

import pandas as pd

from fixbench.cases.errors import CaseError
from fixbench.cases.files import strict_value, write_atomic, write_text_atomic
from fixbench.solvers.base import TRACE_COLUMNS

#: the version every row is written with (``schema``)
SCHEMA_VERSION = 3
#: the versions a row read may have (see the module docstring; a row without ``schema`` is of version 1)
READ_VERSIONS = (1, 2, 3)

#: column -> meaning (README "Results" documents the same table)
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


#: what every row must hold, with its type (rows of any version since the first; rows of early
#: runs have no schema, mode or error key: they read as schema 1, per-task, no error)
REQUIRED = {"cell": str, "planner": str, "case": str}
OPTIONAL = {"schema": int, "mode": str, "error": str}
CHECKSUM = "row_sha1"
#: the columns holding a JSON value (not a flat number or text): schema 1 wrote each as JSON text
JSON_COLUMNS = ("config", "per_task_m", "layouts", "info", "provenance", "policy_per_task_m", "policy_layouts")
#: the row key holding the SHA-1 of each per-cell file, by folder
FILE_CHECKSUMS = {"traces": "trace_sha1", "curves": "curves_sha1"}


def write_json_atomic(path: Path, data) -> None:
    """``data`` as strict JSON (non-finite numbers as null: :func:`fixbench.cases.files.strict_value`)."""
    write_text_atomic(path, json.dumps(strict_value(data), indent=1, allow_nan=False), ".json.tmp")


def write_parquet_atomic(path: Path, df: pd.DataFrame) -> None:
    write_atomic(path, lambda tmp: df.to_parquet(tmp, index=False), ".parquet.tmp")


def json_text(value) -> str:
    """The canonical JSON text of a column's value (keys sorted): what a table groups records on and
    a CSV writes."""
    return json.dumps(value, sort_keys=True, default=str)


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


def warn(msg: str) -> None:
    print(f"fixbench: {msg}", file=sys.stderr)


class Store:
    """A run directory (see module docstring)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.damaged: list[Path] = []  # row files found damaged by the last finished()

    def row_path(self, cell_id: str) -> Path:
        return self.root / "rows" / f"{cell_id}.json"

    def cell_files(self, cell_id: str) -> dict[str, Path]:
        """The cell's Parquet files, by folder (they may not exist)."""
        return {folder: self.root / folder / f"{cell_id}.parquet" for folder in FILE_CHECKSUMS}

    def check_files(self, row: dict) -> str:
        """Why the trace or curves file a valid row names does not match it ('' if they do; a row
        without a recorded SHA-1 is not checked)."""
        for folder, path in self.cell_files(row["cell"]).items():
            want = row.get(FILE_CHECKSUMS[folder])
            if not isinstance(want, str):
                continue
            if not path.is_file():
                return f"its {folder} file {path.name} is missing"
            if file_sha1(path) != want:
                return f"its {folder} file {path.name} differs from the row's {FILE_CHECKSUMS[folder]}"
        return ""

    def read_row(self, path: Path) -> tuple[dict | None, str]:
        """The row in ``path`` (decoded: :func:`decode_row`) and '', or None and why it is damaged."""
        try:
            row = json.loads(path.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            return None, f"not JSON ({str(exc).splitlines()[0]})"
        why = check_row(row, path.stem) or self.check_files(row)
        if why:
            return None, why
        try:
            return decode_row(row), ""
        except ValueError as exc:
            return None, str(exc)

    def finished(self, move_damaged: bool = False, quiet: bool = False) -> dict[str, dict]:
        """Valid rows already written (decoded: :func:`decode_row`), by cell id. Each damaged row file
        (see module docstring) is
        reported in one line (unless ``quiet``) and, with ``move_damaged``, moved to
        ``DIR/damaged/`` with its trace and curves files (its cell is then to do again);
        ``self.damaged`` lists their paths."""
        out, self.damaged = {}, []
        for p in sorted((self.root / "rows").glob("*.json")):
            row, why = self.read_row(p)
            if not why:
                out[p.stem] = row
                continue
            self.damaged.append(p)
            if move_damaged:
                stamp = time.strftime("%Y%m%dT%H%M%S")
                dest = self.root / "damaged" / f"{p.name}.{stamp}"
                dest.parent.mkdir(parents=True, exist_ok=True)
                for folder, f in self.cell_files(p.stem).items():
                    if f.is_file():
                        os.replace(f, dest.parent / f"{folder}-{f.name}.{stamp}")
                os.replace(p, dest)
                warn(f"{p}: damaged ({why}); moved to {dest}, its cell will be recomputed")
            elif not quiet:
                warn(f"{p}: damaged ({why}); skipped")
        return out

    @contextlib.contextmanager
    def lock(self):
        """Hold ``DIR/.lock`` for one writer; a second one is refused with one line (a lock of a
        process that died is released by the OS, so the next run takes it over)."""
        self.root.mkdir(parents=True, exist_ok=True)
        f = open(self.root / ".lock", "a+b", buffering=0)  # unbuffered: nothing left to flush at close
        try:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                f.seek(0)
                holder = f.read().decode(errors="replace").strip() or "another process"
                raise CaseError(str(self.root), "", f"another fixbench run is writing here ({holder}); "
                                "wait for it to finish or choose another --out") from None
            with contextlib.suppress(OSError):  # the holder's name is a courtesy: a full disk skips it
                f.truncate(0)
                f.write(f"pid {os.getpid()}".encode())
            yield
            with contextlib.suppress(OSError):
                f.truncate(0)  # released: no stale holder named
        finally:
            f.close()

    def write(self, row: dict, trace: pd.DataFrame | None, curves: pd.DataFrame | None) -> None:
        """Traces first, the row last (with their SHA-1): a row on disk means the cell is complete."""
        row = {k: v for k, v in row.items() if k != CHECKSUM and k not in FILE_CHECKSUMS.values()}
        paths = self.cell_files(row["cell"])
        for folder, frame in (("traces", trace), ("curves", curves)):
            if frame is not None and len(frame):
                write_parquet_atomic(paths[folder], frame)
                row[FILE_CHECKSUMS[folder]] = file_sha1(paths[folder])
            elif paths[folder].is_file():  # a stale file of an earlier attempt: not this row's
                paths[folder].unlink()
        self._put(row)

    def rewrite(self, row: dict) -> None:
        """Write a finished row (as :meth:`finished` gives it) again after changing columns of its own
        (its trace and curves files untouched), as schema ``SCHEMA_VERSION`` with its checksum
        recomputed: a row rewritten without it would read as damaged."""
        self._put({k: v for k, v in row.items() if k != CHECKSUM})

    def _put(self, row: dict) -> None:
        """Write ``row`` (no checksum yet) as schema ``SCHEMA_VERSION``: its values as strict JSON reads
        them back (tuples as arrays, non-finite numbers as null, other objects as text), then its
        checksum over exactly those."""
        row = strict_value({**row, "schema": SCHEMA_VERSION})
        row[CHECKSUM] = row_checksum(row)
        write_json_atomic(self.row_path(row["cell"]), row)

    def reference_path(self, key: str) -> Path:
        return self.root / "reference" / f"{key}.json"


def load_results(root: str | Path) -> pd.DataFrame:
    """One row per finished cell as a DataFrame (columns: ROW_SCHEMA); damaged rows are skipped
    (each reported on stderr; ``df.attrs["damaged"]`` counts them)."""
    store = Store(root)
    rows = list(store.finished().values())
    df = pd.DataFrame(rows, columns=list(ROW_SCHEMA)) if rows else pd.DataFrame(columns=list(ROW_SCHEMA))
    df = df.sort_values(["case", "material", "planner", "seed"], kind="stable").reset_index(drop=True)
    df.attrs["damaged"] = len(store.damaged)
    return df


def _load_parquets(root: str | Path, folder: str, columns: tuple[str, ...] | None = None) -> pd.DataFrame:
    """The Parquet files in ``DIR/folder`` of every valid row (see :meth:`Store.finished`; a file
    that does not match its row's SHA-1 is skipped with its row) as one frame with a ``cell`` column
    (only ``columns`` when given; a file without them is damaged)."""
    valid = Store(root).finished(quiet=True)
    frames = []
    for p in sorted((Path(root) / folder).glob("*.parquet")):
        if p.stem not in valid:
            continue
        try:
            df = pd.read_parquet(p, columns=None if columns is None else list(columns))
        except Exception as exc:  # pyarrow raises several kinds on a damaged file
            warn(f"{p}: damaged ({type(exc).__name__}); skipped")
            continue
        df["cell"] = p.stem
        frames.append(df)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def load_traces(root: str | Path) -> pd.DataFrame:
    """All anytime traces (``TRACE_COLUMNS``) of valid rows, with their cell id."""
    return _load_parquets(root, "traces", TRACE_COLUMNS)


def load_curves(root: str | Path) -> pd.DataFrame:
    """All learners' training curves (curve, index, value) of valid rows, with their cell id."""
    return _load_parquets(root, "curves")
