"""The step *update*, and the loop it closes: better layouts from a run into the catalog, then every
run that uses those references rescored.

``fixbench references update RUN_DIR [DIR ...]`` is the loop: :func:`merge` takes every layout of
RUN_DIR that beats a shipped reference (measured again on the oracle, never taken from the row on
trust) into the catalog's reference files, and :func:`update` then rescores RUN_DIR and each DIR
against the references as they now are (:func:`fixbench.bench.references.score.rescore`), so that no
committed run is left scored against references that moved.
"""

from __future__ import annotations

import datetime
from pathlib import Path

from fixbench.bench.records.rows import SHIPPED, load_rows
from fixbench.bench.references.score import rescore
from fixbench.cases.problem import load_problem, task_subset
from fixbench.cases.references import load_reference, reference_path, write_reference
from fixbench.cases.spec import case_names


def update(run_dir, rescore_dirs=(), echo=print, folder=None) -> dict:
    """The loop: merge into the shipped references (:func:`merge`) every layout of ``run_dir`` that
    beats them, then rescore ``run_dir`` (when a reference changed) and every run directory of
    ``rescore_dirs`` against the references as they are now
    (:func:`~fixbench.bench.references.score.rescore`). Returns {reference file: tasks replaced}."""
    changed = merge(run_dir, echo, folder)
    for d in dict.fromkeys(Path(d) for d in ([run_dir] if changed else []) + list(rescore_dirs)):
        rescore(d, echo)
    return changed


def merge(run_dir, echo=print, folder=None) -> dict:
    """Merge into the shipped references every layout of ``run_dir`` that beats them.

    Rows of catalog cases in per-task or held-out mode are read; a task whose recorded max
    deformation is below the reference's is re-measured on the oracle (uncounted) and replaces the
    reference only if the measurement confirms it. Returns {reference file: tasks replaced}.
    """
    rows = load_rows(run_dir)
    rows = rows[rows["ok"] & rows["mode"].isin(["per-task", "held-out"])
                & rows["case"].isin(case_names()) & rows["per_task_m"].notna()]
    changed: dict[str, int] = {}
    for (case, material, agents), group in rows.groupby(list(SHIPPED), sort=True):
        ref = load_reference(case, material, int(agents), folder)
        if ref is None:
            echo(f"{case}/{material}/{int(agents)} agents: no shipped reference; skipped "
                 f"({reference_path(case, material, int(agents), folder).name})")
            continue
        claims: dict[int, list] = {}  # task -> [(claimed u, layout, row)]
        for _, row in group.iterrows():
            if not isinstance(row["layouts"], list):  # a row rescored from its trace: no layouts to offer
                continue
            u, layouts = row["per_task_m"], row["layouts"]
            ids = task_subset(ref["n_tasks"], len(u))
            for k, t in enumerate(ids):
                if u[k] < ref["tasks"][t]["max_deformation_m"] * (1 - 1e-9):
                    claims.setdefault(t, []).append((u[k], layouts[k], row))
        if not claims:
            continue
        p = load_problem(case, material=material, agents=int(agents))
        if p.n_tasks != ref["n_tasks"]:
            echo(f"{case}/{material}: the reference has {ref['n_tasks']} tasks, the case {p.n_tasks}; skipped")
            continue
        replaced = []
        for t, options in sorted(claims.items()):
            for _, lay, row in sorted(options, key=lambda o: o[0]):
                u = float(p.measure(t, p.check_layouts([lay]))[0, 3])
                if u < ref["tasks"][t]["max_deformation_m"] * (1 - 1e-9):
                    bound = ref["tasks"][t].get("lower_bound_m")  # a bound on the optimum: it stays
                    ref["tasks"][t] = {"layout": [int(x) for x in lay], "max_deformation_m": u, "status": "best-known",
                                       "lower_bound_m": None if bound is None else min(bound, u)}
                    replaced.append({"task": t, "planner": row["planner"], "cell": row["cell"]})
                    break
        if replaced:
            ref["provenance"].append({"action": "update", "date": datetime.date.today().isoformat(),
                                      "run_dir": Path(run_dir).name, "tasks_replaced": len(replaced),
                                      "by": sorted({r["planner"] for r in replaced})})
            path = write_reference(ref, folder)
            changed[str(path)] = len(replaced)
            echo(f"{path.name}: {len(replaced)} tasks replaced by better layouts of {Path(run_dir).name}")
    return changed
