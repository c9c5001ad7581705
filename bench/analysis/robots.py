"""How many robots does a job need? The best max deformation per task for N = 1..K agents.

For each agent count the best max deformation of every task comes from, in this order:

1. exhaustive enumeration of every layout (the proven optimum; analysis on the oracle directly,
   uncounted), when the joint space times the tasks is at most ``max_evaluations``;
2. else the shipped catalog reference of the case, material and agent count
   (:mod:`fixbench.cases.references`; proven or best-known task by task, as the file says);
3. else nothing: the count is reported as unavailable, never estimated.

The smallest N that keeps every task (or a stated fraction of the tasks) within the tolerance is
then read off. A count whose value is only best-known can show that N robots suffice (a layout
that meets the tolerance exists) but not that they do not; an unavailable count shows neither. The
answer says so: ``proven`` is true only when every smaller count is known not to suffice.

The agents of N robots split the case's candidates as the catalog does (contiguous runs of its
candidate list, :func:`fixbench.cases.problem.load_problem` with ``agents=N``); a case whose agents
are named regions cannot change its agent count.
"""

from __future__ import annotations

import numpy as np

from fixbench.bench.analysis.equilibria import enumeration_chunks
from fixbench.cases.problem import load_problem
from fixbench.cases.references import load_reference

#: most layout evaluations (joint space x tasks) enumerated for one agent count: about 5 minutes
#: at the oracle's 3.3 x 10^5 layouts/s on one core (wing_panel_small, measured)
MAX_EVALUATIONS = 10**8


def best_per_task(case: str, material: str | None, agents: int, max_evaluations: int = MAX_EVALUATIONS) -> dict:
    """The best max deformation of every task with ``agents`` robots, and where it comes from."""
    problem = load_problem(case, material=material, agents=agents)
    rec = {"case": problem.name, "material": problem.spec.material.name, "agents": agents,
           "tasks": problem.n_tasks, "joint_size": problem.joint_size}
    if problem.joint_size * problem.n_tasks <= max_evaluations:
        best = np.full(problem.n_tasks, np.inf)
        for _, values in enumeration_chunks(problem, range(problem.n_tasks)):
            for t, v in values.items():
                best[t] = min(best[t], float(v.min()))
        return {**rec, "source": "enumeration", "proven": True, "per_task_m": best.tolist()}
    ref = load_reference(problem.name, problem.spec.material.name, agents)
    if ref is not None:
        return {**rec, "source": f"shipped reference {ref['path'].rsplit('/', 1)[-1]}",
                "proven": all(t["status"] == "proven" for t in ref["tasks"]),
                "per_task_m": [t["max_deformation_m"] for t in ref["tasks"]]}
    return {**rec, "source": f"unavailable: {problem.joint_size * problem.n_tasks:.3g} evaluations to enumerate "
            f"(over {max_evaluations:.3g}) and no shipped reference", "proven": False, "per_task_m": None}


def robots_table(case: str, material: str | None, max_agents: int, tolerance_m: float,
                 max_evaluations: int = MAX_EVALUATIONS) -> list[dict]:
    """One record per N = 1..max_agents: :func:`best_per_task` plus its worst and mean task and the
    fraction of tasks within ``tolerance_m`` (None where unavailable)."""
    rows = []
    for n in range(1, max_agents + 1):
        rec = best_per_task(case, material, n, max_evaluations)
        u = None if rec["per_task_m"] is None else np.asarray(rec["per_task_m"])
        rec.update(worst_m=None if u is None else float(u.max()), mean_m=None if u is None else float(u.mean()),
                   within=None if u is None else float((u <= tolerance_m).mean()))
        rows.append(rec)
    return rows


def robots_needed(rows: list[dict], fraction: float = 1.0) -> dict:
    """The smallest N of ``rows`` whose best layouts keep at least ``fraction`` of the tasks within the
    tolerance, and whether that is proven (every smaller N proven not to suffice). ``agents`` is None
    when no N of the table is known to suffice."""
    for i, r in enumerate(rows):
        if r["within"] is not None and r["within"] >= fraction - 1e-12:
            below = rows[:i]
            unknown = [b["agents"] for b in below if b["within"] is None or not b["proven"]]
            return {"fraction": fraction, "agents": r["agents"], "proven": not unknown,
                    "unknown_below": unknown}
    return {"fraction": fraction, "agents": None, "proven": False,
            "unknown_below": [r["agents"] for r in rows if r["within"] is None or not r["proven"]]}


def show_robots(rows: list[dict]):
    """The table of :func:`robots_table` for Markdown: one line an agent count, deformations in um."""
    import pandas as pd

    def um(v):
        return "-" if v is None else f"{v * 1e6:.3g}"

    return pd.DataFrame({
        "N": [r["agents"] for r in rows],
        "source": [r["source"] + (" (proven)" if r["proven"] and r["source"] != "enumeration" else "")
                   for r in rows],
        "worst task (um)": [um(r["worst_m"]) for r in rows],
        "mean (um)": [um(r["mean_m"]) for r in rows],
        "tasks within": ["-" if r["within"] is None else f"{r['within']:.0%}" for r in rows],
        "per task (um)": ["-" if r["per_task_m"] is None or len(r["per_task_m"]) > 12
                          else ", ".join(um(v) for v in r["per_task_m"]) for r in rows],
    })


def answer_text(answer: dict, tolerance_um: float) -> str:
    """One sentence: the smallest N of :func:`robots_needed`, and how sure it is."""
    which = "every task" if answer["fraction"] >= 1 else f"{answer['fraction']:.0%} of the tasks"
    unknown = ", ".join(map(str, answer["unknown_below"]))
    if answer["agents"] is None:
        return (f"no N tried keeps {which} within {tolerance_um:g} um"
                + (f" (not proven for N = {unknown})" if unknown else ""))
    if answer["proven"]:
        return f"smallest N keeping {which} within {tolerance_um:g} um: {answer['agents']} (proven)"
    return (f"N = {answer['agents']} keeps {which} within {tolerance_um:g} um; fewer may too "
            f"(no proven optimum for N = {unknown})")
