"""The catalog's full parts checked whole, by ``fixbench validate`` (beside their w/t rows,
:mod:`fixbench.cases.linearity`):

- **oracle**: the fast oracle (:mod:`fixbench.cases.oracle`) against a direct constrained solve of the
  part at :data:`ORACLE_LAYOUTS` seeded random layouts on tasks spread over the job: every maximum
  (ux, uy, w, |u|, in-plane |u|) within a relative :data:`ORACLE_TOL`;
- **mesh**: max |u| at the layout of the shipped reference's worst task (the layouts planners aim
  for), on the part's mesh and on one with every element size halved: within :data:`MESH_TOL`, the aim
  docs/cases.md states for the catalog.

Both properties are the code's as much as the parts': the tests check them on small plates that carry
every kind of support and load the parts do (tests/conftest.py's WINDOWED plate), where a solve takes
milliseconds. Here they are checked on the parts themselves, whose direct solves take seconds to
minutes (the bus panel: 307k DOFs, 1.2 M at half the element size), so they belong to the command the
main job runs first (``make bench``), not to the test suite a developer reruns often.
"""

from __future__ import annotations

import numpy as np

from fixbench.cases.errors import CaseError
from fixbench.cases.problem import Problem
from fixbench.cases.references import load_reference
from fixbench.cases.spec import case_names, load_case_spec

#: random layouts a part is checked at against a direct solve
ORACLE_LAYOUTS = 4
#: largest relative difference accepted between the oracle and a direct solve
ORACLE_TOL = 1e-9
#: largest change of max |u| accepted when every element size is halved
MESH_TOL = 0.02
FIELDS = ("max_ux", "max_uy", "max_w", "max_u", "max_uxy")


def fixture_cases(only=()) -> list[str] | None:
    """The catalog cases ``fixbench validate --part`` names, checked (None: every one); a name that is
    not a catalog case with fixtures is a CaseError naming it."""
    if not only:
        return None
    known = [n for n in case_names() if not load_case_spec(n).validations]
    for name in only:
        if name not in known:
            raise CaseError("--part", name, f"is not a catalog case with fixtures (one of {', '.join(known)})")
    return list(dict.fromkeys(only))


def full_parts() -> list[str]:
    """The catalog's fixture cases that are not ``*_small`` variants (no ``[validation]`` table)."""
    return [n for n in case_names() if not n.endswith("_small") and not load_case_spec(n).validations]


def oracle_row(name: str, layouts: int = ORACLE_LAYOUTS, seed: int = 0) -> dict:
    """The worst relative difference between the oracle and a direct solve over ``layouts`` seeded
    random layouts, one a task spread evenly over the job."""
    problem = Problem(load_case_spec(name))
    rng = np.random.default_rng(seed)
    tasks = np.linspace(0, problem.n_tasks - 1, layouts).round().astype(int)
    worst = 0.0
    for task in tasks:
        layout = [[int(rng.choice(a)) for a in problem.action_sets]]
        fast = problem.deformation(problem.measure(int(task), layout))
        slow = problem.direct_deformation(int(task), layout)
        for f in FIELDS:
            a, b = float(getattr(fast, f)[0]), float(getattr(slow, f)[0])
            worst = max(worst, abs(a - b) / abs(b) if b != 0 else abs(a))
    return {"check": "oracle", "name": name, "layouts": int(layouts), "seed": seed,
            "worst_rel_difference": worst, "limit": ORACLE_TOL, "flagged": bool(worst > ORACLE_TOL)}


def mesh_row(name: str) -> dict:
    """Max |u| of the shipped reference's worst task (by the file's own maxima) on the part's mesh, as
    the file gives it, and with every element size halved."""
    spec = load_case_spec(name)
    ref = load_reference(name, spec.material.name, spec.n_agents)
    if ref is None:
        return {"check": "mesh", "name": name, "task": None, "max_u_m": None, "max_u_fine_m": None,
                "change": None, "limit": MESH_TOL, "flagged": False,
                "note": f"no current shipped reference (fixbench references build {name})"}
    k = int(np.argmax([t["max_deformation_m"] for t in ref["tasks"]]))
    layout = np.array([ref["tasks"][k]["layout"]], dtype=np.int64)
    coarse = float(Problem(spec).direct_deformation(k, layout).max_u[0])
    fine = float(Problem(spec, mesh_scale=0.5).direct_deformation(k, layout).max_u[0])
    change = fine / coarse - 1
    file_difference = abs(coarse / ref["tasks"][k]["max_deformation_m"] - 1)
    return {"check": "mesh", "name": name, "task": k, "max_u_m": coarse, "max_u_fine_m": fine,
            "change": change, "limit": MESH_TOL, "reference_rel_difference": file_difference,
            "flagged": bool(abs(change) > MESH_TOL or file_difference > ORACLE_TOL)}


def full_part_rows(names=None) -> list[dict]:
    """An oracle row and a mesh row for each full part (default: every one in the catalog)."""
    rows = []
    for name in names if names is not None else full_parts():
        rows += [oracle_row(name), mesh_row(name)]
    return rows
