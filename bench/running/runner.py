"""`fixbench run`: expand a matrix, compute regret references, run the cells, store the rows.

Crash-safe and resumable: every finished cell's row is written atomically as it arrives, and a
rerun of the same command skips the cells that have a row (``--retry-failed`` reruns the ones
whose row carries an error). The reference phase before the cells proves each problem's optimum
position by position where it can (:mod:`fixbench.bench.references.prove`), with its progress on stderr and
every proven position kept in the run directory: a rerun proves only the positions missing. A
planner that raises or runs past ``--cell-timeout`` becomes a row with its error; the matrix goes on.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from fixbench.bench.records.rows import ONLY_KEYS, reference_key
from fixbench.bench.records.store import Store, write_json_atomic
from fixbench.bench.references.prove import Proof, enumerates
from fixbench.bench.running.cells import base_row
from fixbench.bench.running.matrix import find_matrix, load_matrix
from fixbench.cases import cache as oracle_cache
from fixbench.cases.errors import CaseError
from fixbench.cases.files import write_text_atomic
from fixbench.cases.problem import problem_for


def make_executor(kind: str, workers: int | None, timeout: float | None, address: str | None,
                  env: dict[str, str] | None = None):
    """The executor of ``kind``; ``env``: extra environment variables of its workers."""
    if kind == "ray":
        try:
            from fixbench.bench.running.executors import RayExecutor
        except ImportError:  # pragma: no cover - ray is an optional extra
            raise CaseError("--executor", "ray", "Ray is not installed (pip install 'fixbench[ray]')") from None
        return RayExecutor(workers, timeout, address, env)
    from fixbench.bench.running.executors import LocalExecutor

    return LocalExecutor(workers, timeout, env=env)


def worker_env(out: Path) -> dict[str, str]:
    """The workers' oracle cache: the folder ``$FIXBENCH_CACHE_DIR`` names (``off``: none), else
    ``OUT/oracle-cache`` inside the run directory (nothing is written outside it)."""
    if oracle_cache.ENV in os.environ:
        return {}
    return {oracle_cache.ENV: str(Path(out).resolve() / "oracle-cache")}


def run_matrix(matrix_path: str | Path, out: str | Path, executor: str = "local", workers: int | None = None,
               address: str | None = None, cell_timeout: float | None = None, retry_failed: bool = False,
               progress: bool = True, only: tuple[str, ...] = (), plain_every: float = 0.0) -> dict:
    """Run (or resume) a matrix into ``out``; returns counts of cells run, skipped (done before),
    failed and, with ``only``, deferred (left for a later run).

    ``only``: run just some cells now: planner names or entry labels, and ``key=value`` filters on
    the cell's ``case``, ``material``, ``mode``, ``seed`` or ``samples_per_task`` (a cell runs if it
    matches one of the names, when any is given, and one value of every key given). The rest stay to
    do: a later run of the same matrix without ``only`` completes it.

    ``progress``: a progress bar (a terminal); else, with ``plain_every`` > 0, one plain line on
    stderr at most every that many seconds (cells done, failed, elapsed, ETA: logs, CI, nohup)."""
    matrix_path = find_matrix(matrix_path)
    matrix = load_matrix(matrix_path)  # every check happens before anything is written
    store = Store(out)
    text = Path(matrix_path).read_text(encoding="utf-8")
    cells = matrix.cells()
    selected = selection(cells, only)
    if not store.root.exists() and not any(selected(c) for c in cells):
        return {"cells": len(cells), "skipped": 0, "run": 0, "failed": 0, "deferred": len(cells)}
    opts = _RunOptions(executor, workers, address, cell_timeout, retry_failed, progress, bool(only), plain_every)
    with store.lock():
        return _run_locked(text, store, cells, selected, opts, matrix.proof_limit)


@dataclass(frozen=True)
class _RunOptions:
    """How :func:`run_matrix` runs the cells (its keyword arguments, once checked)."""

    executor: str
    workers: int | None
    address: str | None
    cell_timeout: float | None
    retry_failed: bool
    progress: bool
    partial: bool  # ``only`` was given: the cells it leaves out are counted as deferred
    plain_every: float


def _check_extends(root: Path, saved: Path, cells: list) -> None:
    """A matrix may extend the one a run directory holds: add planner entries, seeds, cases or any
    cell, so long as every cell of the stored matrix is still one of its cells with the same settings
    (a cell's id hashes them all: planner, config, label, case, material, agents, tasks, mode, budget,
    seed). Otherwise one line naming the first stored cell it drops or changes."""
    try:
        old = load_matrix(saved).cells()
    except CaseError as exc:
        raise CaseError(str(root), "", f"holds the results of a matrix that no longer loads ({exc}); "
                        "choose another --out") from None
    ids = {c.id for c in cells}
    for c in old:
        if c.id not in ids:
            what = (f"{c.label or c.planner} {dict(c.config) or ''} on {c.case}/{c.material}, {c.mode}, seed "
                    f"{c.seed}, budget {c.budget if c.samples_per_task is None else f'{c.samples_per_task} a task'}")
            raise CaseError(str(root), "", f"holds the results of a different matrix: its cell {what} is not in "
                            "this one with the same settings (a matrix may only add cells to a run); choose "
                            "another --out")


def _run_locked(text: str, store: Store, cells: list, selected, opts: _RunOptions, proof_limit: int | None) -> dict:
    """The run itself, with the run directory's lock held: the reference phase, then the cells."""
    saved = store.root / "matrix.toml"
    extends = False
    if saved.exists() and saved.read_text(encoding="utf-8") != text:
        if saved.stat().st_size == 0 and not any((store.root / "rows").glob("*.json")):
            saved.unlink()  # an empty copy left by a failed first write (e.g. a full disk): start again
        else:
            _check_extends(store.root, saved, cells)
            extends = True
    done = store.finished(move_damaged=True)
    pending = [c for c in cells if c.id not in done or (opts.retry_failed and done[c.id].get("error"))]
    todo = [c for c in pending if selected(c)]
    summary = {"cells": len(cells), "skipped": len(cells) - len(pending), "run": 0, "failed": 0}
    if store.damaged:
        summary["damaged_moved"] = len(store.damaged)
    if opts.partial:
        summary["deferred"] = len(pending) - len(todo)  # left for a later run (not selected by ``only``)
    if not todo:
        return summary
    check_shipped_references(todo)
    if not saved.exists() or extends:
        write_text_atomic(saved, text)  # an extended run's matrix is the new one, a superset of the old

    modes = tuple(sorted({c.mode for c in cells}))
    ex = make_executor(opts.executor, opts.workers, opts.cell_timeout, opts.address, env=worker_env(store.root))
    try:
        references = _reference_phase(store, todo, modes, proof_limit, ex, opts)
        bar = tqdm(total=len(todo), disable=not opts.progress, unit="cell", desc="cells")
        plain = _PlainProgress(opts.plain_every if not opts.progress else 0.0)

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
            if summary["run"] < len(todo):  # (the command prints its own summary at the end)
                plain.tick(f"{summary['run']}/{len(todo)} cells done, {summary['failed']} failed",
                           summary["run"] / len(todo))

        jobs = [("cell", (c, references.get(reference_key(*c.problem_key)))) for c in todo]
        try:
            ex.run(jobs, on_cell)  # the same workers: their last problem's model is still built
        finally:
            bar.close()
    except KeyboardInterrupt as exc:  # Ctrl-C: the finished rows and proven positions are on disk
        exc.summary = summary
        raise
    finally:
        ex.close()
    return summary


def _reference_phase(store: Store, todo: list, modes: tuple[str, ...], proof_limit: int | None, ex,
                     opts: _RunOptions) -> dict[str, dict]:
    """The regret reference of every problem of ``todo``: read where ``DIR/reference/KEY.json`` holds
    it; proven position by position where the positions can be enumerated (:mod:`fixbench.bench.references.prove`:
    progress on stderr, records in the run directory, a rerun proves only the positions missing); else
    one job a problem (``exact``'s MILP or the shipped reference). Returns {key: reference}."""
    references: dict[str, dict] = {}
    proofs: dict[str, Proof] = {}
    ref_jobs, whole = [], {}
    for key4 in dict.fromkeys(c.problem_key for c in todo):
        key = reference_key(*key4)
        path = store.reference_path(key)
        if path.exists():
            references[key] = json.loads(path.read_text())
        elif enumerates(problem_for(*key4), proof_limit):
            proofs[key] = Proof(store.root, key4, "shared" in modes)
        else:
            ref_jobs.append(("reference", (*key4, modes, proof_limit)))
            whole[key] = problem_for(*key4).n_tasks

    def keep(key: str, ref: dict) -> None:
        references[key] = ref
        write_json_atomic(store.reference_path(key), ref)

    progress = _ProofProgress(list(proofs.values()), sum(whole.values()), opts)
    left = {key: len(proof.missing()) for key, proof in proofs.items()}

    def on_reference(job, result, error):
        key = reference_key(*job[1][:4])
        keep(key, result["reference"] if result else {"key": key, "error": error, "per_task": None})
        progress.advance(whole[key], 0)

    def on_position(job, result, error):
        pos = job[1][0]
        key = reference_key(*pos.problem_key)
        position = "shared" if pos.task is None else pos.task
        proofs[key].add(result or {"position": position, "error": error})
        progress.advance(int(position != "shared"), proofs[key].layouts_of(position))
        left[key] -= 1
        if not left[key]:
            keep(key, proofs[key].reference())

    for key, proof in proofs.items():
        if not left[key]:  # every position was proven before the run stopped: assemble it now
            keep(key, proof.reference())
    try:
        positions = [("position", (pos,)) for proof in proofs.values() for pos in proof.missing()]
        if positions:
            ex.run(positions, on_position)
        if ref_jobs:
            ex.run(ref_jobs, on_reference)
    finally:
        progress.close()
    return references


def check_shipped_references(cells) -> None:
    """Check the shipped reference of every catalog problem of ``cells`` (format, records, content
    hash); one that fails stops the run before any cell, in one line naming the file and the problem.
    Checked here, in the driver, because a worker records a failing reference in the run's
    ``reference/`` snapshot and goes on: every row of the problem would end with a NaN regret and the
    reason out of sight."""
    from fixbench.cases.references import load_reference
    from fixbench.cases.spec import case_names, load_case_spec

    catalog = set(case_names())
    for case, material, agents in dict.fromkeys((c.case, c.material, c.agents) for c in cells):
        if case in catalog:
            spec = load_case_spec(case, material, agents)
            load_reference(case, spec.material.name, spec.n_agents)  # raises CaseError when it fails


class _PlainProgress:
    """A progress line on stderr at most every ``every`` seconds (0: never)."""

    def __init__(self, every: float):
        self.every = every
        self.start = self.last = time.monotonic()

    def tick(self, what: str, fraction: float) -> None:
        """``what`` is done, ``fraction`` of the work this progress counts (the ETA is read from it)."""
        now = time.monotonic()
        if self.every <= 0 or now - self.last < self.every:
            return
        self.last = now
        elapsed = now - self.start
        eta = elapsed / fraction * (1 - fraction) if fraction > 0 else float("nan")
        print(f"fixbench run: {what}, {_hms(elapsed)} elapsed, ETA {_hms(eta)}", file=sys.stderr, flush=True)


class _ProofProgress:
    """The reference phase on stderr: a bar of the layouts the proof enumerates (its rate and ETA),
    with the positions whose reference is in as its postfix; without a terminal, plain lines
    (:class:`_PlainProgress`). Positions proven before a resumed run count as done from the start."""

    def __init__(self, proofs: list, whole_positions: int, opts: _RunOptions):
        todo = [(proof, pos.task if pos.task is not None else "shared") for proof in proofs for pos in proof.missing()]
        self.layouts = sum(proof.layouts_of(w) for proof, w in todo)
        self.positions = sum(proof.n_tasks for proof in proofs) + whole_positions
        self.proven = sum(proof.n_tasks for proof in proofs) - sum(w != "shared" for _, w in todo)
        self.enumerated = 0
        self.bar = tqdm(total=self.layouts, disable=not opts.progress or not self.positions, unit="layout",
                        unit_scale=True, desc="proof", dynamic_ncols=True)
        self.bar.set_postfix_str(self._positions(), refresh=bool(self.positions))
        self.plain = _PlainProgress(opts.plain_every if not opts.progress else 0.0)

    def _positions(self) -> str:
        return f"{self.proven}/{self.positions} positions"

    def advance(self, positions: int, layouts: int) -> None:
        self.proven += positions
        self.enumerated += layouts
        self.bar.set_postfix_str(self._positions(), refresh=False)
        self.bar.update(layouts)
        if self.proven < self.positions:  # the cells' progress follows the last one
            self.plain.tick(f"proof {self._positions()} ({tqdm.format_sizeof(self.enumerated)} of "
                            f"{tqdm.format_sizeof(self.layouts)} layouts)",
                            self.enumerated / self.layouts if self.layouts else self.proven / self.positions)

    def close(self) -> None:
        self.bar.close()


def _hms(s: float) -> str:
    if s != s:
        return "?"
    s = int(s)
    return f"{s // 3600}h{s // 60 % 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def selection(cells, only: tuple[str, ...]):
    """The predicate of ``--only`` (see :func:`run_matrix`); unknown names or keys are refused."""
    known = {c.planner for c in cells} | {c.label for c in cells if c.label}
    names, values = set(), {}
    for item in only:
        key, eq, value = item.partition("=")
        if eq:
            if key not in ONLY_KEYS:
                raise CaseError("--only", item, f"filters on {', '.join(ONLY_KEYS)} only")
            values.setdefault(key, set()).add(value)
        elif item in known:
            names.add(item)
        else:
            raise CaseError("--only", item, f"no planner or label of the matrix (known: {', '.join(sorted(known))})")

    def selected(c) -> bool:
        if names and c.planner not in names and c.label not in names:
            return False
        return all(str(getattr(c, k)) in v for k, v in values.items())

    return selected


def _frame(records: dict | None) -> pd.DataFrame | None:
    return None if records is None else pd.DataFrame(records)


