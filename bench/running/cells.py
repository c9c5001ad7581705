"""What a worker runs for a matrix cell: its problem from the process cache, the planner, the row's metrics
(no file I/O; results go back to the driver). The regret references are in
:mod:`fixbench.bench.running.references`; the executors' entry point is
:func:`fixbench.bench.running.executors.execute`.

A worker asks the process's problem cache for each cell's problem
(:func:`fixbench.cases.problem.cached_problem`), so that one running many cells of one case builds its FE
model and oracle once.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import time
import traceback

import numpy as np
import pandas as pd

from fixbench.bench.running.matrix import Cell, task_subset
from fixbench.bench.running.provenance import provenance
from fixbench.bench.running.rows import SCHEMA_VERSION, planner_mode
from fixbench.bench.running.store import TRACE_COLUMNS
from fixbench.cases.problem import Problem, cached_problem
from fixbench.cases.rewards import REFERENCE_OPTIMAL_REWARD
from fixbench.cases.spec import load_case_spec


def fixbench_version() -> str:
    try:
        return importlib.metadata.version("fixbench")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - running from a checkout
        return "unknown"


def problem_for(case: str, material: str | None, agents: int | None, tasks: int | None) -> Problem:
    """The cell's problem (``tasks`` of the case's tasks, spread evenly; all when None) from the process's
    problem cache, which keeps the latest one only (jobs arrive grouped by problem)."""
    def build() -> Problem:
        spec = load_case_spec(case, material, agents)
        return Problem(spec.with_tasks(task_subset(len(spec.tasks), tasks)))

    return cached_problem((case, material, agents, tasks), build)


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


def base_row(cell: Cell) -> dict:
    return {"schema": SCHEMA_VERSION, "cell": cell.id, "planner": cell.planner, "config": dict(cell.config),
            "label": cell.label, "case": cell.case, "agents": cell.agents, "mode": cell.mode,
            "budget": math.nan if cell.budget is None else cell.budget, "seed": cell.seed,
            "samples_per_task": math.nan if cell.samples_per_task is None else cell.samples_per_task,
            "heldout_every": math.nan if cell.heldout_every is None else cell.heldout_every,
            "material": cell.material, "version": fixbench_version(), "error": ""}


def run_cell(cell: Cell, reference: dict | None) -> dict:
    """Run one cell; returns {"row": ..., "trace": records, "curves": records}. Never raises."""
    from fixbench.solvers.registry import get

    row = base_row(cell)
    t0, c0 = time.perf_counter(), time.process_time()
    trace = curves = None
    try:
        p = problem_for(cell.case, cell.material, cell.agents, cell.tasks)
        p.oracle.prepare()  # set-up, shared by every planner on the problem: outside the planner's time
        row["setup_s"] = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        planner = get(cell.planner)(**dict(cell.config))
        budget = cell.budget_for(p.n_tasks)
        res = planner.solve(p, budget, seed=cell.seed, mode=planner_mode(cell.mode),
                            train_tasks=cell.train_tasks(p.n_tasks))
        scores = metrics(res, reference)
        row.update(config_hash=res.config_hash, part=p.spec.part, material=res.material,
                   agents=p.n_agents, n_tasks=p.n_tasks, samples=res.samples,
                   budget=math.nan if budget is None else budget, n_scored_tasks=len(res.scored_tasks),
                   per_task_m=res.max_deformation.tolist(),
                   mean_max_deformation_m=float(res.max_deformation.mean()),
                   worst_max_deformation_m=float(res.max_deformation.max()),
                   best_max_deformation_m=float(res.max_deformation.min()),
                   objective_m=res.objective, mean_reward=float(res.reward.mean()),
                   mean_reward_bell=float(res.reward_bell.mean()),
                   layouts=res.layouts.tolist(),
                   **policy_columns(res, scores["reference_objective_m"]),
                   info=json.loads(json.dumps(row_info(res), default=_plain)),
                   **scores)
        trace = pd.DataFrame(res.trace, columns=list(TRACE_COLUMNS)).to_dict("list")
        curves = curve_records(res.training)
    except Exception as exc:  # a failing run is a row with its error, not a crash of the matrix
        row["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0]
        row["info"] = {"traceback": traceback.format_exc(limit=4)}
    row["wall_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0
    row["provenance"] = provenance()
    return {"row": row, "trace": trace, "curves": curves}


def row_info(res) -> dict:
    """The row's ``info``: the planner's own figures as it returned them and, for a learner, the unit of
    each curve it declared (``curve_units``: name -> step, episode, ...; the curves file holds the values)."""
    if res.training is None:
        return res.info
    return {**res.info, "curve_units": {name: c.unit for name, c in res.training.curves.items()}}


def _plain(v):
    """A numpy array or number in ``info`` as JSON's list or number (anything else as its text)."""
    return v.tolist() if isinstance(v, (np.ndarray, np.generic)) else str(v)


def curve_records(training) -> dict | None:
    """A learner's declared curves (``PlanResult.training``) in the curves file's long form: ``curve``,
    ``index`` (the count of the curve's unit, from 0), ``value`` (NaN: none); None without a training
    record or curves."""
    if training is None or not training.curves:
        return None
    frames = [pd.DataFrame({"curve": name, "index": np.arange(len(c.values)), "value": c.values})
              for name, c in training.curves.items()]
    return pd.concat(frames, ignore_index=True).to_dict("list")


