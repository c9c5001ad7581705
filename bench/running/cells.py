"""What a worker runs for a matrix cell: its problem from the process cache, the planner, the row's metrics
(no file I/O; results go back to the driver). The row is scored against its regret reference by
:mod:`fixbench.bench.references.score`; the executors' entry point is
:func:`fixbench.bench.running.executors.execute`.

A worker asks the process's problem cache for each cell's problem
(:func:`fixbench.cases.problem.problem_for`), so that one running many cells of one case builds its FE
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

from fixbench.bench.records.rows import SCHEMA_VERSION, planner_mode
from fixbench.bench.records.store import TRACE_COLUMNS
from fixbench.bench.references.score import metrics, policy_columns
from fixbench.bench.running.matrix import Cell
from fixbench.bench.running.provenance import provenance
from fixbench.cases.problem import problem_for


def fixbench_version() -> str:
    try:
        return importlib.metadata.version("fixbench")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - running from a checkout
        return "unknown"


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


