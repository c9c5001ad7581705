"""The step *bound*: certified lower bounds on the optimum of every position of a shipped reference,
written into its file (``fixbench references bound CASE``), so that regret on a full part is a
bracket (against the reference's layouts, and against the bounds) and a position whose bound meets
its layout's value is ``proven``. The mathematics is in :mod:`.compliance_bound` (the compliance
branch-and-bound, position by position) and :mod:`.zone_bound` (one robot free, the others' zones
clamped: every position at once, looser); docs/references.md#lower-bounds gives the argument.
"""

from __future__ import annotations

import datetime
import time
from dataclasses import asdict

import numpy as np

from fixbench.bench.references.compliance_bound import BoundConfig, ComplianceBound, lower_bound
from fixbench.bench.references.zone_bound import ZoneBound, ZoneConfig
from fixbench.cases.errors import CaseError
from fixbench.cases.problem import load_problem
from fixbench.cases.references import load_reference, write_reference

#: the methods of :func:`bound` (``fixbench references bound --method``)
BOUND_METHODS = ("branch-and-bound", "zones")


def bound(case: str, material: str | None = None, agents: int | None = None, time_limit_s: float = 60.0,
          tasks: list[int] | None = None, folder=None, echo=print, method: str = "branch-and-bound") -> dict:
    """Certified lower bounds on the positions of a shipped reference, written into its file: for each
    position (all, or ``tasks``) either the compliance branch-and-bound of
    :func:`fixbench.bench.references.compliance_bound.lower_bound` with the reference's layout as incumbent, within
    ``time_limit_s`` of wall time a position, or (``method="zones"``) the zone bound of
    :class:`fixbench.bench.references.zone_bound.ZoneBound`, every position at once. A position keeps the larger of
    its old and new bound; a layout the search finds below the reference's (measured on the oracle)
    replaces it; a bound that meets its layout's value makes the position ``proven``. The provenance
    records the method, its settings and the time spent. Returns a summary (per position: reference,
    bound, gap)."""
    if method not in BOUND_METHODS:
        raise CaseError(case, "--method", f"{method!r} is not one of {', '.join(BOUND_METHODS)}")
    p = load_problem(case, material=material, agents=agents)
    ref = load_reference(case, p.spec.material.name, p.n_agents, folder)
    if ref is None:
        raise CaseError(case, "", f"no shipped reference for {p.spec.material.name}, {p.n_agents} robots "
                        "(fixbench references build first)")
    ids = list(range(p.n_tasks)) if tasks is None else [p.check_task(t) for t in tasks]
    wall, cpu = time.perf_counter(), time.process_time()
    out = []

    def record(t: int, value: float, **extra) -> None:
        rec = ref["tasks"][t]
        u = rec["max_deformation_m"]
        lb = min(max(rec.get("lower_bound_m") or 0.0, float(value)), u)
        rec["lower_bound_m"] = lb
        if extra.pop("proven", False) or lb >= u:
            rec.update(status="proven", lower_bound_m=u)
        out.append({"task": t, "reference_m": u, "bound_m": rec["lower_bound_m"],
                    "gap": 1 - rec["lower_bound_m"] / u, **extra})
        echo(out[-1])

    if method == "zones":
        cfg = ZoneConfig()
        zones = ZoneBound(p, cfg)
        setup_s = time.perf_counter() - wall
        for t, value in zip(ids, zones.bounds(ids)):
            record(t, value)
        name = "zone bound (fixbench.bench.references.zone_bound; docs/references.md#zone-bound)"
    else:
        cfg = BoundConfig(time_limit_s=time_limit_s)
        bounder = ComplianceBound(p, cfg)
        setup_s = time.perf_counter() - wall
        for t in ids:
            rec = ref["tasks"][t]
            r = lower_bound(p, t, cfg, bounder, incumbent=np.asarray(rec["layout"]))
            if r.best < rec["max_deformation_m"] * (1 - 1e-12):  # the search found a better layout
                rec.update(layout=[int(a) for a in r.layout], max_deformation_m=float(r.best))
            record(t, r.bound, proven=r.proven, nodes=r.nodes, layouts=r.leaves, wall_s=round(r.seconds, 2))
        name = ("compliance branch-and-bound (fixbench.bench.references.compliance_bound.lower_bound; "
                "docs/references.md#lower-bounds)")
    ref["provenance"].append({
        "action": "bound", "date": datetime.date.today().isoformat(), "method": name,
        "settings": asdict(cfg), "tasks": ids if tasks is not None else "all", "setup_s": round(setup_s, 1),
        "wall_s": round(time.perf_counter() - wall, 1), "cpu_s": round(time.process_time() - cpu, 1),
        "proven": sum(ref["tasks"][t]["status"] == "proven" for t in ids)})
    path = write_reference(ref, folder)
    return {"path": str(path), "positions": out}
