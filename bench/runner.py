"""`fixbench run`: expand a matrix, compute regret references, run the cells, store the rows.

Crash-safe and resumable: every finished cell's row is written atomically as it arrives, and a
rerun of the same command skips the cells that have a row (``--retry-failed`` reruns the ones
whose row carries an error). A planner that raises or runs past ``--cell-timeout`` becomes a row
with its error; the matrix goes on.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from bench.cells import base_row, reference_key
from bench.matrix import load_matrix
from bench.store import Store
from cases.errors import CaseError


def make_executor(kind: str, workers: int | None, timeout: float | None, address: str | None):
    if kind == "ray":
        try:
            from bench.executors import RayExecutor
        except ImportError:  # pragma: no cover - ray is an optional extra
            raise CaseError("--executor", "ray", "Ray is not installed (pip install 'fixbench[ray]')") from None
        return RayExecutor(workers, timeout, address)
    from bench.executors import LocalExecutor

    return LocalExecutor(workers, timeout)


def run_matrix(matrix_path: str | Path, out: str | Path, executor: str = "local", workers: int | None = None,
               address: str | None = None, cell_timeout: float | None = None, retry_failed: bool = False,
               progress: bool = True, only: tuple[str, ...] = ()) -> dict:
    """Run (or resume) a matrix into ``out``; returns counts of cells run, skipped and failed.

    ``only``: run just the cells of these planner names or entry labels now (the rest stay to do: a
    later run of the same matrix without ``only`` completes it)."""
    matrix = load_matrix(matrix_path)  # every check happens before anything is written
    store = Store(out)
    saved = store.root / "matrix.toml"
    text = Path(matrix_path).read_text(encoding="utf-8")
    if saved.exists() and saved.read_text(encoding="utf-8") != text:
        raise CaseError(str(out), "", "holds the results of a different matrix (its matrix.toml differs); "
                        "choose another --out")
    cells = matrix.cells()
    known = {c.planner for c in cells} | {c.label for c in cells if c.label}
    for name in only:
        if name not in known:
            raise CaseError("--only", name, f"no planner or label of the matrix (known: {', '.join(sorted(known))})")
    done = store.finished()
    todo = [c for c in cells if c.id not in done or (retry_failed and done[c.id].get("error"))]
    if only:
        todo = [c for c in todo if c.planner in only or c.label in only]
    summary = {"cells": len(cells), "skipped": len(cells) - len(todo), "run": 0, "failed": 0}
    if not todo:
        return summary
    store.root.mkdir(parents=True, exist_ok=True)
    if not saved.exists():
        shutil.copyfile(matrix_path, saved)

    modes = tuple(sorted({c.mode for c in cells}))
    references: dict[str, dict] = {}
    ref_jobs = []
    for key4 in dict.fromkeys(c.problem_key for c in todo):
        key = reference_key(*key4)
        path = store.reference_path(key)
        if path.exists():
            references[key] = json.loads(path.read_text())
        else:
            ref_jobs.append(("reference", (*key4, modes)))
    ex = make_executor(executor, workers, cell_timeout, address)
    bar = tqdm(total=len(ref_jobs) + len(todo), disable=not progress, unit="job", desc="references")

    def on_reference(job, result, error):
        case, material, agents, tasks, _ = job[1]
        key = reference_key(case, material, agents, tasks)
        ref = result["reference"] if result else {"key": key, "error": error, "per_task": None}
        references[key] = ref
        from bench.store import write_json_atomic

        write_json_atomic(store.reference_path(key), ref)
        bar.update()

    def on_cell(job, result, error):
        cell = job[1][0]
        if result is None:
            row = base_row(cell)
            row["error"] = error
            result = {"row": row, "trace": None, "curves": None}
        row = result["row"]
        store.write(row, _frame(result["trace"]), _frame(result["curves"]))
        summary["run"] += 1
        summary["failed"] += bool(row["error"])
        bar.set_postfix(failed=summary["failed"])
        bar.update()

    try:
        if ref_jobs:
            ex.run(ref_jobs, on_reference)
        bar.set_description("cells")
        jobs = [("cell", (c, references.get(reference_key(*c.problem_key)))) for c in todo]
        ex.run(jobs, on_cell)  # the same workers: their last problem's model is still built
    finally:
        ex.close()
    bar.close()
    return summary


def _frame(records: dict | None) -> pd.DataFrame | None:
    return None if records is None else pd.DataFrame(records)


