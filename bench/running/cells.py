"""What a worker runs: regret references and matrix cells (no file I/O; results go back to the driver).

A worker asks the process's problem cache for each cell's problem
(:func:`fixbench.cases.problem.cached_problem`), so that one running many cells of one case builds its FE
model and oracle once.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import io
import json
import math
import os
import re
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from fixbench.bench.running.matrix import Cell, task_subset
from fixbench.bench.running.provenance import provenance
from fixbench.bench.running.store import SCHEMA_VERSION, TRACE_COLUMNS
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


def reference_key(case: str, material: str | None, agents: int | None, tasks: int | None) -> str:
    """A file-name-safe key; a case given as a path becomes its stem plus a hash of the path."""
    name = case
    if case.endswith(".toml") or "/" in case or os.sep in case:
        digest = hashlib.sha1(str(Path(case).resolve()).encode()).hexdigest()[:8]
        name = f"{Path(case).stem}-{digest}"
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
    return f"{name}__{material or 'default'}__a{agents or 'default'}__t{tasks or 'all'}"


def reference_head(case: str, material: str | None, agents: int | None, tasks: int | None, p: Problem) -> dict:
    """The fields every regret reference of the problem starts with (the problem ``p`` resolves the
    material and agents), before its numbers are in."""
    from fixbench.cases.references import case_fingerprint

    return {"key": reference_key(case, material, agents, tasks), "case": case, "material": p.spec.material.name,
            "agents": p.n_agents, "n_tasks": p.n_tasks, "error": "", "per_task": None, "shared": None,
            "proven": False, "gap": None, "samples": 0, "source": "",
            "case_fingerprint": case_fingerprint(case, p.spec.material.name, p.n_agents)}


def enumerates(p: Problem, proof_limit: int | None) -> bool:
    """Whether the proof phase enumerates every layout of each position of ``p``, position by position:
    at most ``proof_limit`` (the matrix's; None: no cap of its own) and ``exact``'s ``max_enumeration``
    layouts a position."""
    from fixbench.solvers.registry import get

    cap = get("exact").Config().max_enumeration
    return p.joint_size <= (cap if proof_limit is None else min(cap, proof_limit))


def compute_reference(case: str, material: str | None, agents: int | None, tasks: int | None,
                      modes: tuple[str, ...], proof_limit: int | None = None) -> dict:
    """The regret reference of a problem in one job (the proof phase enumerates a problem position by
    position instead where it can: :func:`prove_position`, :mod:`fixbench.bench.running.proof`): the ``exact``
    planner's optimum (its MILP: proven, or best known with its gap); where ``exact`` refuses (too
    large), or the problem has more than ``proof_limit`` layouts a position (the matrix's cap), the
    shipped catalog reference of the case (:mod:`fixbench.cases.references`: the portfolio's best-known
    layouts), restricted to the problem's tasks. ``source`` says which was used; ``case_fingerprint``
    which case file, material and agent count it was computed on (merged reports compare it:
    :mod:`fixbench.bench.reporting.merge`)."""
    from fixbench.solvers.base import PlannerError
    from fixbench.solvers.registry import get

    p = problem_for(case, material, agents, tasks)
    ref = reference_head(case, material, agents, tasks, p)
    t0 = time.perf_counter()
    try:
        exact = get("exact")()
        try:
            if proof_limit is not None and p.joint_size > proof_limit:
                raise PlannerError(f"{p.joint_size:.3g} layouts a position, over the matrix's proof_limit "
                                   f"({proof_limit:.3g})")
            res = exact.solve(p, None, seed=0, mode="per-task")
        except PlannerError as refused:
            shipped = shipped_reference(case, p.spec.material.name, p.n_agents, tasks)
            if shipped is None:
                raise PlannerError(f"{refused}; and no shipped reference for {p.name}/{p.spec.material.name}/"
                                   f"{p.n_agents} agents (fixbench references build)") from None
            ref.update(shipped)
        else:
            ref.update(per_task=res.max_deformation.tolist(), layouts=res.layouts.tolist(),
                       proven=bool(res.info.get("proven", False)), gap=res.info.get("gap"),
                       method=res.info.get("method"), samples=res.samples, source="exact")
            if "shared" in modes:
                shared = exact.solve(p, None, seed=0, mode="shared")
                ref["shared"] = shared.objective
                ref["proven"] = ref["proven"] and bool(shared.info.get("proven", False))
    except Exception as exc:  # a failing reference is recorded, never a crash of the matrix
        ref["error"] = f"{type(exc).__name__}: {exc}"
    ref["wall_s"] = time.perf_counter() - t0
    return ref


@dataclass(frozen=True)
class Position:
    """One position (task) of a problem whose optimum the proof phase proves by enumeration; ``task``
    None: the shared optimum (one layout for every position, judged by the worst)."""

    case: str
    material: str | None
    agents: int | None
    tasks: int | None
    task: int | None

    @property
    def problem_key(self) -> tuple:
        return (self.case, self.material, self.agents, self.tasks)


def prove_position(pos: Position) -> dict:
    """The proven optimum of one position: ``exact``'s enumeration on a counted evaluator open on that
    position alone (the layout of least max deformation, first in enumeration order on a tie), measured
    as :meth:`~fixbench.solvers.base.Planner.solve` scores it; with ``task`` None the shared optimum.
    Returns the proof record (:mod:`fixbench.bench.running.proof`), or ``{"position", "error"}``; never raises.
    ``exact``'s own progress bar is kept off the terminal: the driver shows the phase's."""
    from fixbench.solvers.base import TracedEvaluator
    from fixbench.solvers.registry import get

    t0 = time.perf_counter()
    try:
        p = problem_for(*pos.problem_key)
        exact = get("exact")()
        with _quiet_stderr():
            if pos.task is None:
                res = exact.solve(p, None, seed=0, mode="shared")
                return {"position": "shared", "objective_m": float(res.objective),
                        "layout": res.layouts[0].tolist(), "proven": bool(res.info.get("proven", False)),
                        "samples": int(res.samples), "wall_s": time.perf_counter() - t0}
            ev = TracedEvaluator(p, None, [pos.task])
            exact.plan(p, ev, np.random.default_rng(0), "per-task")
        layout = ev.best_layout[pos.task]
        u = p.deformation(p.measure(pos.task, layout[None])).max_u[0]
    except Exception as exc:  # a failing position is recorded by the driver, never a crash of the matrix
        return {"position": "shared" if pos.task is None else pos.task, "error": f"{type(exc).__name__}: {exc}"}
    return {"position": pos.task, "layout": layout.tolist(), "max_deformation_m": float(u),
            "samples": int(ev.samples), "wall_s": time.perf_counter() - t0}


@contextlib.contextmanager
def _quiet_stderr():
    """Run with ``sys.stderr`` captured (a progress bar that asks for a terminal stays off), then pass
    on whatever was written there (a warning)."""
    buffer = io.StringIO()
    try:
        with contextlib.redirect_stderr(buffer):
            yield
    finally:
        sys.stderr.write(buffer.getvalue())


def shipped_reference(case: str, material: str, agents: int, tasks: int | None) -> dict | None:
    """The shipped reference of a catalog case for ``tasks`` of its tasks (all: None), or None."""
    from fixbench.cases.references import load_reference, source_text
    from fixbench.cases.spec import case_names

    if case not in case_names():
        return None
    full = load_reference(case, material, agents)
    if full is None:
        return None
    ids = task_subset(full["n_tasks"], tasks)
    recs = [full["tasks"][i] for i in ids]
    return {"per_task": [r["max_deformation_m"] for r in recs], "layouts": [r["layout"] for r in recs],
            "proven": all(r["status"] == "proven" for r in recs), "gap": None, "method": "portfolio",
            "source": source_text(full)}


def _samples_to(trace: np.ndarray, task: int, target: float) -> float:
    rows = trace[(trace[:, 0] == task) & (trace[:, 3] <= target)]
    return float(rows[0, 1]) if len(rows) else math.nan


def metrics(result, reference: dict | None) -> dict:
    """Regret and runtime-to-target figures of one result against its reference."""
    n_agents = result.layouts.shape[1]
    bell = result.reward_bell if result.reward_bell is not None else np.zeros(len(result.layouts))
    out = {"reference_regret": float(n_agents * len(result.layouts) * REFERENCE_OPTIMAL_REWARD
                                     - n_agents * bell.sum())}
    nan = {k: math.nan for k in ("reference_objective_m", "true_regret_m", "relative_regret",
                                 "samples_to_1pct", "samples_to_5pct", "success_1pct", "success_5pct")}
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
            "policy_per_task_m": json.dumps(result.policy_max_deformation.tolist()),
            "policy_layouts": json.dumps(result.policy_layouts.tolist())}


def base_row(cell: Cell) -> dict:
    return {"schema": SCHEMA_VERSION, "cell": cell.id, "planner": cell.planner, "config": json.dumps(dict(cell.config)),
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
        res = planner.solve(p, budget, seed=cell.seed, mode="per-task" if cell.mode == "held-out" else cell.mode,
                            train_tasks=cell.train_tasks(p.n_tasks))
        scores = metrics(res, reference)
        row.update(config_hash=res.config_hash, part=p.spec.part, material=res.material,
                   agents=p.n_agents, n_tasks=p.n_tasks, samples=res.samples,
                   budget=math.nan if budget is None else budget, n_scored_tasks=len(res.scored_tasks),
                   per_task_m=json.dumps(res.max_deformation.tolist()),
                   mean_max_deformation_m=float(res.max_deformation.mean()),
                   worst_max_deformation_m=float(res.max_deformation.max()),
                   best_max_deformation_m=float(res.max_deformation.min()),
                   objective_m=res.objective, mean_reward=float(res.reward.mean()),
                   mean_reward_bell=float(res.reward_bell.mean()),
                   layouts=json.dumps(res.layouts.tolist()),
                   **policy_columns(res, scores["reference_objective_m"]),
                   info=json.dumps({k: v for k, v in res.info.items() if not _is_curve(v)}, default=str),
                   **scores)
        trace = pd.DataFrame(res.trace, columns=list(TRACE_COLUMNS)).to_dict("list")
        curves = _curves(res.info)
    except Exception as exc:  # a failing run is a row with its error, not a crash of the matrix
        row["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0]
        row["info"] = json.dumps({"traceback": traceback.format_exc(limit=4)})
    row["wall_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0
    row["provenance"] = json.dumps(provenance())
    return {"row": row, "trace": trace, "curves": curves}


def _is_curve(v) -> bool:
    return isinstance(v, (list, tuple, np.ndarray)) and len(v) > 1 and all(
        isinstance(x, (int, float, np.floating, np.integer)) for x in np.asarray(v, dtype=object).ravel()[:50])


def _curves(info: dict) -> dict | None:
    frames = []
    for k, v in info.items():
        if _is_curve(v):
            arr = np.asarray(v, dtype=float).ravel()
            frames.append(pd.DataFrame({"curve": k, "index": np.arange(len(arr)), "value": arr}))
        elif isinstance(v, dict):  # e.g. per-agent loss curves
            for sub, vv in v.items():
                if _is_curve(vv):
                    arr = np.asarray(vv, dtype=float).ravel()
                    frames.append(pd.DataFrame({"curve": f"{k}/{sub}", "index": np.arange(len(arr)),
                                                "value": arr}))
    return pd.concat(frames, ignore_index=True).to_dict("list") if frames else None


def execute(job: tuple) -> dict:
    """Entry point of every executor: ("reference", args), ("position", (position,)) or ("cell", (cell, reference))."""
    kind, payload = job
    if kind == "reference":
        return {"reference": compute_reference(*payload)}
    if kind == "position":
        return prove_position(payload[0])
    cell, reference = payload
    return run_cell(cell, reference)
