"""``fixbench verify RUN``: rerun a sample of a run's cells on this host and compare with its rows.

A published run is only as good as its rows: ``verify`` reruns ``K`` of its cells here, exactly as
``fixbench run`` ran them (the run's ``matrix.toml``, its regret reference snapshot, the same
executor and worker settings, the run's oracle cache ``RUN/oracle-cache``; nothing else is written)
and prints, per cell, the committed and the new scored value (``objective_m``):

- a planner that gives the same bits on every host (``Planner.same_on_every_host``, the default)
  must agree within the relative tolerance ``TOLERANCE`` (1e-9, the margin by which a layout counts
  as better than a reference: ``fixbench references update``);
- a learner whose results follow the host's floating-point code paths (PyTorch training:
  ``same_on_every_host = False``) agrees when it does so to 1e-9 (the same code path), else when the
  new value falls within its group's 95 % prediction interval over seeds
  (:func:`fixbench.bench.reporting.stats.prediction_interval`; the group: the row's replicates, its planner
  entry on the same settings with every seed, :data:`fixbench.bench.records.rows.REPLICATES`);

and, for every cell, where this host's code path (CPU, BLAS, threads, switches, library versions;
:mod:`fixbench.bench.running.provenance`) differs from the one the row records. The command exits 1 when a
cell disagrees.

The sample (:func:`sample`) is drawn with a seed across planners: one cell of each planner entry in
a random order, then a second of each, and so on; the order puts an entry of the other kind second,
so that a sample of two or more holds both kinds where the run has both.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from fixbench.bench.records.rows import REPLICATES, load_rows, reference_key
from fixbench.bench.records.store import Store
from fixbench.bench.reporting.merge import load_references
from fixbench.bench.reporting.report import check_scored_references
from fixbench.bench.reporting.stats import LEVEL, prediction_interval
from fixbench.bench.running.matrix import load_matrix
from fixbench.bench.running.provenance import provenance
from fixbench.bench.running.runner import make_executor, selection, worker_env
from fixbench.cases.errors import CaseError

#: relative tolerance of an agreement to the bit (references count a layout better by this margin)
TOLERANCE = 1e-9
#: provenance entries that choose the floating-point code path (the host name does not)
CODE_PATH = ("machine", "cpu", "numpy_blas", "torch_blas", "torch_cpu_capability", "torch_threads",
             "numba_threads", "env", "libraries", "python")


def sample(rows: pd.DataFrame, k: int, seed: int) -> list:
    """Index labels of ``k`` rows of ``rows`` (its ``same`` column: the planner's kind), drawn with ``seed``
    (see the module docstring)."""
    rng = np.random.default_rng(seed)
    labels = sorted(rows["label"].unique())
    cells = {lab: list(rng.permutation(rows.index[rows["label"] == lab].to_numpy())) for lab in labels}
    order = [labels[i] for i in rng.permutation(len(labels))]
    kind = rows.groupby("label")["same"].first()
    other = next((lab for lab in order[1:] if kind[lab] != kind[order[0]]), None)
    if other is not None:
        order.remove(other)
        order.insert(1, other)
    out = []
    while len(out) < k and any(cells.values()):
        out += [cells[lab].pop(0) for lab in order if cells[lab]]
    return out[:k]


def verify(run_dir: str | Path, k: int = 10, seed: int = 0, only: tuple[str, ...] = (),
           workers: int | None = None, echo=print) -> list[dict]:
    """Rerun ``k`` sampled cells of ``run_dir`` (``only``: among those ``fixbench run --only`` would
    select) and judge each; returns one record per cell, in the sample's order. ``echo`` gets a line
    as each cell finishes."""
    from fixbench.solvers.registry import get

    run_dir = Path(run_dir)
    if not (run_dir / "rows").is_dir() or not (run_dir / "matrix.toml").is_file():
        raise CaseError(str(run_dir), "", "is not a run directory (it needs rows/ and matrix.toml)")
    rows = load_rows(run_dir)
    refs = load_references(run_dir)
    check_scored_references(run_dir, rows, refs)
    cells = {c.id: c for c in load_matrix(run_dir / "matrix.toml").cells()}
    chosen = selection(list(cells.values()), only)
    done = rows[rows["ok"]].copy()
    done["same"] = [get(p).same_on_every_host for p in done["planner"]]
    ok = done[done["cell"].isin([cid for cid, c in cells.items() if chosen(c)])]
    if ok.empty:
        raise CaseError(str(run_dir), "", "has no successful cell of its matrix to rerun"
                        + (f" among --only {','.join(only)}" if only else ""))
    picked = ok.loc[sample(ok, k, seed)]
    store = Store(run_dir)
    jobs = []
    for cid in picked["cell"]:
        path = store.reference_path(reference_key(*cells[cid].problem_key))
        jobs.append(("cell", (cells[cid], json.loads(path.read_text()) if path.is_file() else None)))
    jobs.sort(key=lambda j: j[1][0].problem_key)  # grouped by problem: a worker builds each model once
    records: dict[str, dict] = {}

    def on_cell(job, result, error):
        cid = job[1][0].id
        records[cid] = rec = judge(picked.loc[picked["cell"] == cid].iloc[0],
                                   result["row"] if result else {"error": error}, done)
        echo(f"{len(records)}/{len(jobs)} {rec['planner']} on {rec['case']}/{rec['material']} ({rec['mode']}, "
             f"seed {rec['seed']}): {rec['verdict']}")

    busy = busy_warning()
    if busy:
        echo(busy)
    ex = make_executor("local", workers, None, None, env=worker_env(run_dir))
    try:
        ex.run(jobs, on_cell)
    finally:
        ex.close()
    return [records[cid] for cid in picked["cell"]]


def busy_warning() -> str | None:
    """The warning for a busy machine (load average at least half the cores, and at least 1), given
    only once the run has passed its checks, so that a refusal stays one line."""
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    if load < max(1.0, cores / 2):
        return None
    return (f"fixbench: verify: load average {load:.1f} on {cores} cores: the cells will take longer than "
            "their committed times, multi-threaded learners longest; an idle machine is best")


def judge(old: pd.Series, new: dict, done: pd.DataFrame) -> dict:
    """One cell's record: the committed row ``old`` and the rerun's row ``new``, the check applied, the
    verdict and a note on the code paths; ``done``: the run's successful rows (the learners' groups)."""
    rec = {"planner": old["label"], "case": old["case"], "material": old["material"], "mode": old["mode"],
           "seed": int(old["seed"]), "committed_m": float(old["objective_m"]), "new_m": math.nan,
           "relative_difference": math.nan, "check": f"{TOLERANCE:g}", "agrees": False,
           "note": code_path_note(old.get("provenance"), new.get("provenance"))}
    if new.get("error"):
        rec.update(verdict="DISAGREES: the rerun failed", note="; ".join(filter(None, [new["error"], rec["note"]])))
        return rec
    rec["new_m"] = value = float(new["objective_m"])
    rec["relative_difference"] = diff = value / rec["committed_m"] - 1
    rec["agrees"] = abs(diff) <= TOLERANCE
    if not old["same"] and not rec["agrees"]:
        group = done[np.logical_and.reduce([_same(done[c], old[c]) for c in REPLICATES])]
        lo, hi = prediction_interval(group["objective_m"])
        if math.isnan(lo):
            rec["check"] = f"{TOLERANCE:g} (one seed: no interval)"
        else:
            rec["check"] = f"[{lo * 1e6:.4g}, {hi * 1e6:.4g}] um ({len(group)} seeds)"
            rec["agrees"] = lo <= value <= hi
    rec["verdict"] = "agrees" if rec["agrees"] else "DISAGREES"
    return rec


def _same(column: pd.Series, value) -> pd.Series:
    """Rows of ``column`` equal to ``value`` (NaN equals NaN: a setting the run leaves unset)."""
    return column.isna() if isinstance(value, float) and math.isnan(value) else column == value


def code_path_note(old: dict | None, new: dict | None) -> str:
    """Where this host's code path differs from the one a row records (``CODE_PATH``; rows' provenance
    records), or why it is unknown; '' when they are the same."""
    if not isinstance(old, dict):
        return "the row records no provenance"
    a, b = old, (new if isinstance(new, dict) else provenance())
    diffs = []
    for key in CODE_PATH:
        x, y = a.get(key), b.get(key)
        if isinstance(x, dict) or isinstance(y, dict):
            x, y = x or {}, y or {}
            diffs += [f"{key}.{s} {x.get(s, '-')} -> {y.get(s, '-')}" for s in sorted(set(x) | set(y))
                      if x.get(s) != y.get(s)]
        elif x != y:
            diffs.append(f"{key} {x if x is not None else '-'} -> {y if y is not None else '-'}")
    return ("code path differs: " + "; ".join(diffs)) if diffs else ""


def show(records: list[dict]) -> str:
    """The records as a Markdown table (values in um to 10 digits: a difference in the last bits shows)."""
    table = pd.DataFrame([{
        "planner": r["planner"], "case": r["case"], "material": r["material"], "mode": r["mode"],
        "seed": r["seed"], "committed (um)": f"{r['committed_m'] * 1e6:.10g}",
        "new (um)": "-" if math.isnan(r["new_m"]) else f"{r['new_m'] * 1e6:.10g}",
        "rel. difference": "-" if math.isnan(r["relative_difference"]) else f"{r['relative_difference']:+.2e}",
        "check": r["check"], "verdict": r["verdict"], "note": r["note"]} for r in records])
    agree = sum(r["agrees"] for r in records)
    return (table.to_markdown(index=False, disable_numparse=True) + f"\n\n{agree} of {len(records)} cells agree "
            f"(same-on-every-host planners within {TOLERANCE:g} relative; learners to {TOLERANCE:g} or within "
            f"their group's {LEVEL:.0%} prediction interval over seeds).")
