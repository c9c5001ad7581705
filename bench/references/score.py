"""The step *rescore*: a result's regret against its reference, and a run's rows scored again.

:func:`metrics` gives the reference-dependent columns of a row (regret, its certified upper end from
the reference's lower bounds, samples to 1 % and 5 %); a worker calls it on every cell
(:mod:`fixbench.bench.running.cells`). :func:`rescore` brings a run directory's reference snapshots
(``DIR/reference/*.json``) up to the shipped references as they are now and recomputes those columns
of its rows from the stored rows and traces, without running a planner again
(``fixbench references rescore DIR``; the loop :func:`fixbench.bench.references.update.update` calls it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from fixbench.bench.records.keys import split
from fixbench.bench.records.rows import SCHEMA_VERSION, planner_mode, reference_of
from fixbench.bench.records.store import Store, write_json_atomic
from fixbench.bench.references.prove import shipped_reference
from fixbench.cases.rewards import REFERENCE_OPTIMAL_REWARD


def _samples_to(trace: np.ndarray, task: int, target: float) -> float:
    rows = trace[(trace[:, 0] == task) & (trace[:, 3] <= target)]
    return float(rows[0, 1]) if len(rows) else math.nan


def reference_bounds(ref: dict) -> np.ndarray:
    """A regret reference's certified lower bound on each position's optimum (m; NaN: none): its
    ``lower_bounds`` (a shipped reference's ``lower_bound_m``, ``exact``'s proven optima), or, in a
    snapshot written before they were recorded, its optima where it is proven."""
    per_task = np.asarray(ref["per_task"], dtype=float)
    if "lower_bounds" in ref:
        return np.array([math.nan if b is None else float(b) for b in ref["lower_bounds"]])
    return per_task.copy() if ref.get("proven") else np.full(len(per_task), math.nan)


def metrics(result, reference: dict | None) -> dict:
    """Regret and runtime-to-target figures of one result against its reference."""
    n_agents = result.layouts.shape[1]
    bell = result.reward_bell if result.reward_bell is not None else np.zeros(len(result.layouts))
    out = {"reference_regret": float(n_agents * len(result.layouts) * REFERENCE_OPTIMAL_REWARD
                                     - n_agents * bell.sum())}
    nan = {k: math.nan for k in ("reference_objective_m", "true_regret_m", "relative_regret", "bound_objective_m",
                                 "relative_regret_upper", "samples_to_1pct", "samples_to_5pct", "success_1pct",
                                 "success_5pct")}
    out.update(nan, reference_proven=False, reference_source="")
    if not reference or reference.get("per_task") is None:
        return out
    scored = result.scored_tasks  # held-out track: the tasks acted on without samples
    opt = np.asarray(reference["per_task"])
    shared = result.mode == "shared"
    if shared and reference.get("shared") is None:
        return out
    ref_obj = reference["shared"] if shared else float(opt[scored].mean())
    out.update(reference_objective_m=ref_obj, reference_proven=bool(reference["proven"]),
               reference_source=reference.get("source", ""),
               true_regret_m=result.objective - ref_obj, relative_regret=result.objective / ref_obj - 1)
    # the bracket's other end: every position's optimum is at least its bound (0 where none is known), so
    # the objective of the bounds is at most the optimal objective and the regret against it at least the
    # true regret (the regret against the reference, a layout reached, is at most the true regret)
    bounds = np.nan_to_num(reference_bounds(reference)[scored], nan=0.0)
    bound_obj = float(bounds.max() if shared else bounds.mean())
    if shared and reference["proven"]:
        bound_obj = ref_obj
    out.update(bound_objective_m=bound_obj,
               relative_regret_upper=result.objective / bound_obj - 1 if bound_obj > 0 else math.nan)
    for pct, eps in (("1pct", 0.01), ("5pct", 0.05)):
        if shared:
            reach = [_samples_to(result.trace, -1, ref_obj * (1 + eps))]
            success = float(result.objective <= ref_obj * (1 + eps))
        else:
            reach = [_samples_to(result.trace, t, opt[t] * (1 + eps)) for t in scored]
            success = float(np.mean(result.max_deformation[scored] <= opt[scored] * (1 + eps)))
        reached = [r for r in reach if not math.isnan(r)]
        out[f"samples_to_{pct}"] = float(np.mean(reached)) if reached else math.nan
        out[f"success_{pct}"] = success
    return out


def policy_columns(result, reference_objective: float) -> dict:
    """The second figure of a planner that returns a policy (``PlanResult.policy_*``): its layouts'
    objective and regret against ``reference_objective`` (NaN: none), beside the incumbents' (the
    scoring rule: ``fixbench.solvers.base``)."""
    if result.policy_max_deformation is None:
        return {"policy_objective_m": math.nan, "policy_relative_regret": math.nan}
    pol = result.policy_objective
    return {"policy_objective_m": pol, "policy_relative_regret": pol / reference_objective - 1,
            "policy_per_task_m": result.policy_max_deformation.tolist(),
            "policy_layouts": result.policy_layouts.tolist()}


class _Scored:
    """What :func:`metrics` reads of a result, rebuilt from a stored row and trace."""

    def __init__(self, row: dict, trace: np.ndarray):
        self.max_deformation = np.asarray(row["per_task_m"], dtype=float)
        self.mode = planner_mode(row["mode"])
        n, k = len(self.max_deformation), row.get("heldout_every")
        self.layouts = np.empty((n, int(row["agents"])))  # metrics reads only its shape (tasks, agents)
        self.held_out = None
        if row["mode"] == "held-out" and k:
            self.held_out = np.asarray(split(n, int(k))[1], dtype=np.int64)
        self.scored_tasks = np.arange(n) if self.held_out is None else self.held_out
        u = self.max_deformation[self.scored_tasks]
        self.objective = float(u.max() if self.mode == "shared" else u.mean())
        self.trace = trace
        self.reward_bell = None


#: row columns that depend on the regret reference (rewritten by :func:`rescore`)
REFERENCE_COLUMNS = ("reference_objective_m", "reference_proven", "reference_source", "true_regret_m",
                     "relative_regret", "bound_objective_m", "relative_regret_upper", "samples_to_1pct",
                     "samples_to_5pct", "success_1pct", "success_5pct")


def rescore(run_dir, echo=print) -> int:
    """Bring a run directory's shipped-reference snapshots (``DIR/reference/*.json``) up to the
    shipped references as they are now, and recompute the reference-dependent columns of its rows;
    returns the number of rows rewritten. An ``exact`` reference is kept as it is (its rows gain any
    column added since they were written). A row of an older schema is written again as the current
    one (bench/records/store.py), whether its values changed or not."""
    store = Store(run_dir)
    rows = store.finished()
    fresh = {}
    for path in sorted((Path(run_dir) / "reference").glob("*.json")):
        ref = json.loads(path.read_text())
        if ref.get("error") or ref.get("per_task") is None:
            continue
        if str(ref.get("source", "")).startswith("catalog reference"):
            new = shipped_reference(ref["case"], ref["material"], int(ref["agents"]), int(ref["n_tasks"]))
            if new is None:
                continue
            if any(new[k] != ref.get(k) for k in new):  # values, layouts, bounds or the file's content hash
                ref.update(new)
                write_json_atomic(path, ref)
        fresh[reference_of(ref)] = ref  # exact's as it is: its columns are recomputed, to the same values
    n = 0
    for cid, row in rows.items():
        m = {}
        if not row.get("error") and row.get("per_task_m") and (ref := fresh.get(reference_of(row))) is not None:
            tp = Path(run_dir) / "traces" / f"{cid}.parquet"
            trace = pd.read_parquet(tp).to_numpy(float) if tp.exists() else np.empty((0, 4))
            m = {k: v for k, v in metrics(_Scored(row, trace), ref).items() if k in REFERENCE_COLUMNS}
            policy = row.get("policy_objective_m")
            if isinstance(policy, (int, float)) and math.isfinite(policy):  # a learner's policy, scored beside it
                m["policy_relative_regret"] = policy / m["reference_objective_m"] - 1
        changed = {k: v for k, v in m.items() if v != row.get(k) and not (v != v and row.get(k) != row.get(k))}
        if not changed and row.get("schema") == SCHEMA_VERSION:
            continue
        row.update(changed)
        store.rewrite(row)
        n += 1
    echo(f"{Path(run_dir).name}: {n} rows rescored against the shipped references")
    return n
