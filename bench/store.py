"""The results store: one JSON row per finished cell, written atomically, plus Parquet traces.

Layout of a run directory::

    DIR/matrix.toml                 the matrix that was run (copied at the start)
    DIR/rows/<cell id>.json         one flat row per finished cell (see ROW_SCHEMA)
    DIR/traces/<cell id>.parquet    anytime trace: task, task_samples, samples, best
    DIR/curves/<cell id>.parquet    training curves of learners: curve, index, value (long form)
    DIR/reference/<key>.json        regret reference per (case, material, agents, tasks)

A row is written to a temporary file and renamed into place, so a run killed at any moment
leaves only complete rows; rerunning skips the cells that have one.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pandas as pd

SCHEMA_VERSION = 1

#: column -> meaning (README "Results" documents the same table)
ROW_SCHEMA = {
    "schema": "schema version of this row",
    "cell": "cell id (hash of the cell's settings)",
    "planner": "planner name", "config": "planner config overrides (JSON)",
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
    "per_task_m": "max |u| of the planner's layout on each task (JSON list, metres)",
    "mean_reward": "mean Gaussian reward of the layouts (seed paper)",
    "mean_reward_bell": "mean bell reward (reference code)",
    "reference_objective_m": "the regret reference's objective (optimum or best known)",
    "reference_proven": "whether the reference is a proven optimum",
    "reference_source": "exact, or the shipped catalog reference file and its content hash",
    "true_regret_m": "objective_m - reference_objective_m",
    "relative_regret": "objective_m / reference_objective_m - 1",
    "reference_regret": "N T pi/4 - N sum of bell rewards (the reference code's regret)",
    "samples_to_1pct": "mean over tasks of task samples until within 1 % of the optimum (NaN if never)",
    "samples_to_5pct": "same, within 5 %",
    "success_1pct": "fraction of tasks whose final layout is within 1 % of the optimum",
    "success_5pct": "same, within 5 %",
    "samples": "samples the planner spent",
    "setup_s": "problem set-up before the planner ran: model, factorisation, compliance data (no samples)",
    "wall_s": "wall time of the planner's run (set-up excluded)", "cpu_s": "CPU time of the planner's run",
    "layouts": "the planner's layout per task (JSON)",
    "version": "fixbench version", "error": "empty, or why the cell failed", "info": "planner info (JSON)",
}


def write_json_atomic(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=".json.tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(data, f, default=str, indent=1)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_parquet_atomic(path: Path, df: pd.DataFrame) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=".parquet.tmp")
    os.close(fd)
    df.to_parquet(tmp, index=False)
    os.replace(tmp, path)


class Store:
    """A run directory (see module docstring)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def row_path(self, cell_id: str) -> Path:
        return self.root / "rows" / f"{cell_id}.json"

    def finished(self) -> dict[str, dict]:
        """Rows already written, by cell id."""
        out = {}
        for p in sorted((self.root / "rows").glob("*.json")):
            out[p.stem] = json.loads(p.read_text())
        return out

    def write(self, row: dict, trace: pd.DataFrame | None, curves: pd.DataFrame | None) -> None:
        """Traces first, the row last: a row on disk means the cell is complete."""
        cid = row["cell"]
        if trace is not None:
            write_parquet_atomic(self.root / "traces" / f"{cid}.parquet", trace)
        if curves is not None and len(curves):
            write_parquet_atomic(self.root / "curves" / f"{cid}.parquet", curves)
        write_json_atomic(self.row_path(cid), row)

    def reference_path(self, key: str) -> Path:
        return self.root / "reference" / f"{key}.json"


def load_results(root: str | Path) -> pd.DataFrame:
    """One row per finished cell as a DataFrame (columns: ROW_SCHEMA)."""
    rows = list(Store(root).finished().values())
    df = pd.DataFrame(rows, columns=list(ROW_SCHEMA)) if rows else pd.DataFrame(columns=list(ROW_SCHEMA))
    return df.sort_values(["case", "material", "planner", "seed"], kind="stable").reset_index(drop=True)


def _load_parquets(root: str | Path, folder: str) -> pd.DataFrame:
    """Every cell's Parquet file in ``DIR/folder`` as one frame with a ``cell`` column."""
    frames = []
    for p in sorted((Path(root) / folder).glob("*.parquet")):
        df = pd.read_parquet(p)
        df["cell"] = p.stem
        frames.append(df)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def load_traces(root: str | Path) -> pd.DataFrame:
    """All anytime traces (task, task_samples, samples, best) with their cell id."""
    return _load_parquets(root, "traces")


def load_curves(root: str | Path) -> pd.DataFrame:
    """All learners' training curves (curve, index, value) with their cell id."""
    return _load_parquets(root, "curves")
