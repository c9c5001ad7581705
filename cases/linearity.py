"""Is each catalog part inside linear plate theory? Its largest deflection over thickness (w/t).

Linear (small-deflection) Kirchhoff theory ignores the membrane stiffening a plate gains once it
deflects by a sizeable part of its thickness; for deflections beyond about half the thickness it
overstates them and the model stops describing the part (docs/plate.md). The fixtures are there to
keep the part still, so what must stay small is the deflection at the layouts a planner aims for:

- a full part: the layouts of its shipped regret reference (cases/catalog/references/, best-known);
- a ``*_small`` variant: the proven optimum of every task (exhaustive enumeration, here, of the
  layouts with ``agents`` agents: fewer pads sag more, so the benchmark's smallest agent count is
  the severe check).

:func:`part_rows` gives one row per catalog fixture case; a part beyond :data:`LIMIT` is flagged.
"""

from __future__ import annotations

import math

import numpy as np

from fixbench.cases.problem import Problem, decode_layouts, load_problem
from fixbench.cases.references import load_reference
from fixbench.cases.spec import case_names, load_case_spec

#: largest w/t accepted at the reference layouts (half the thickness)
LIMIT = 0.5


def optimum_layouts(problem: Problem, chunk: int = 2**18) -> np.ndarray:
    """The layout of least max |u| of every task, by enumerating the whole joint space (uncounted)."""
    sets, size = problem.action_sets, problem.joint_size
    best = np.empty((problem.n_tasks, problem.n_agents), dtype=np.int64)
    for t in range(problem.n_tasks):
        value = math.inf
        for start in range(0, size, chunk):
            layouts = decode_layouts(sets, start, min(size, start + chunk))
            u = problem.measure(t, layouts)[:, 3]  # max |u| column
            i = int(np.argmin(u))
            if u[i] < value:
                value, best[t] = float(u[i]), layouts[i]
    return best


def _row(problem: Problem, layouts: np.ndarray, source: str) -> dict:
    from fixbench.cases.fem import active_fields

    t = problem.spec.thinnest
    if "bending" not in active_fields(problem.spec):  # nothing loads w: it is zero (no model built)
        max_w = np.zeros(len(layouts))
    else:
        max_w = np.array([problem.measure(k, layouts[k:k + 1])[0, 2] for k in range(len(layouts))])
    k = int(np.argmax(max_w))
    ratio = float(max_w[k] / t)
    return {"check": "w/t", "name": problem.name, "layouts": source, "agents": problem.n_agents,
            "tasks": len(layouts), "thickness_m": t, "max_w_m": float(max_w[k]), "task": k,
            "w_over_t": ratio, "limit": LIMIT, "flagged": ratio > LIMIT}


def part_rows(small_agents: int | None = None, names=None) -> list[dict]:
    """One row per catalog fixture case (no ``[validation]`` table): the largest w/t over its tasks
    at its reference layouts (see the module docstring); ``small_agents`` sets the agent count of
    the ``*_small`` enumerations (default: each case's own)."""
    rows = []
    for name in names if names is not None else case_names():
        spec = load_case_spec(name)
        if spec.validations:
            continue
        if name.endswith("_small"):  # a case with a pad limit keeps its robots (the limit makes it)
            problem = load_problem(name, agents=None if spec.effector.pads else small_agents)
            rows.append(_row(problem, optimum_layouts(problem), "proven optimum"))
            continue
        ref = load_reference(name, spec.material.name, spec.n_agents)
        if ref is None:
            rows.append({"check": "w/t", "name": name, "layouts": "no current shipped reference "
                         f"(fixbench references build {name})", "agents": spec.n_agents,
                         "tasks": len(spec.tasks), "thickness_m": spec.thinnest, "max_w_m": None,
                         "task": None, "w_over_t": None, "limit": LIMIT, "flagged": False})
            continue
        layouts = np.array([t["layout"] for t in ref["tasks"]], dtype=np.int64)
        rows.append(_row(Problem(spec), layouts, "shipped reference"))
    return rows
