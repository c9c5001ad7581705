"""The results store: one JSON row per finished cell, written atomically, plus Parquet traces.

Layout of a run directory::

    DIR/matrix.toml                 the matrix that was run (copied at the start)
    DIR/rows/<cell id>.json         one flat row per finished cell (bench/records/rows.py)
    DIR/traces/<cell id>.parquet    anytime trace: TRACE_COLUMNS (task, task_samples, samples, best)
    DIR/curves/<cell id>.parquet    training curves of learners: curve, index, value (long form)
    DIR/reference/<key>.json        regret reference per (case, material, agents, tasks)
    DIR/reference/<key>.proof.jsonl its positions as the reference phase proved them (bench/references/prove.py)

A row is written to a temporary file and renamed into place, so a run killed at any moment
leaves only complete rows; rerunning skips the cells that have one.

Rows: what a row holds (its columns and schema version), what makes a row file damaged and how an
older schema is read are :mod:`fixbench.bench.records.rows`, which reads them too (its loader,
:func:`~fixbench.bench.records.rows.load_rows`); this module writes them (as ``SCHEMA_VERSION``, with
their checksums) and :meth:`Store.finished` moves a damaged row aside so that ``fixbench run``
recomputes its cell.
``DIR/.lock`` is held (an OS file lock) by the one ``fixbench run`` writing there.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import time
from pathlib import Path

import pandas as pd

from fixbench.bench.records.rows import (
    CHECKSUM,
    FILE_CHECKSUMS,
    SCHEMA_VERSION,
    cell_files,
    file_sha1,
    read_rows,
    row_checksum,
    row_path,
    warn,
)
from fixbench.cases.errors import CaseError
from fixbench.cases.files import strict_value, write_atomic, write_text_atomic
from fixbench.solvers.base import TRACE_COLUMNS


def write_json_atomic(path: Path, data) -> None:
    """``data`` as strict JSON (non-finite numbers as null: :func:`fixbench.cases.files.strict_value`)."""
    write_text_atomic(path, json.dumps(strict_value(data), indent=1, allow_nan=False), ".json.tmp")


def write_parquet_atomic(path: Path, df: pd.DataFrame) -> None:
    write_atomic(path, lambda tmp: df.to_parquet(tmp, index=False), ".parquet.tmp")


def json_text(value) -> str:
    """The canonical JSON text of a column's value (keys sorted): what a table groups records on and
    a CSV writes."""
    return json.dumps(value, sort_keys=True, default=str)


class Store:
    """A run directory (see module docstring)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.damaged: list[Path] = []  # row files found damaged by the last finished()

    def row_path(self, cell_id: str) -> Path:
        return row_path(self.root, cell_id)

    def cell_files(self, cell_id: str) -> dict[str, Path]:
        """The cell's Parquet files, by folder (they may not exist)."""
        return cell_files(self.root, cell_id)

    def finished(self, move_damaged: bool = False, quiet: bool = False) -> dict[str, dict]:
        """Valid rows already written (decoded: :func:`fixbench.bench.records.rows.decode_row`), by cell
        id. Each damaged row file (:func:`fixbench.bench.records.rows.read_rows`) is reported in one line
        (unless ``quiet``) and, with ``move_damaged``, moved to ``DIR/damaged/`` with its trace and curves
        files (its cell is then to do again); ``self.damaged`` lists their paths."""
        out, damaged = read_rows(self.root)
        self.damaged = list(damaged)
        for p, why in damaged.items():
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
