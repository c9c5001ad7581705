"""Fixturing rules: the layout a fixture engineer draws by hand, with zero samples.

The floor every learner must clear: a planner that never calls the evaluator and places the pads
by the classic rules of fixture design for compliant (sheet-metal) parts, from the part's geometry,
its fixed supports and where the task loads it. Deterministic: no random draw, ties go to the
lowest index.

The rules and where they come from (docs/sources.md, "Fixture design"):

The objective the rules stand in for is Menassa and DeVries's (1991): support positions chosen to
minimise the workpiece's deflection under the machining load (they search for them with FE and an
optimiser; the rules place them by hand, without an FE solve).

1. **A support at the load** (Rong and Zhu 1999, *Computer-Aided Fixture Design*: supports are
   placed close to the machining point, on the side the cutting force pushes against, so the force
   goes into a support rather than bending the part). Of all the robots' options, the one whose
   pad lies nearest the task's load point is placed first.
2. **The others spread over the free regions** (Cai, Hu and Yuan 1996: the N-2-1 principle for
   deformable sheet metal, where the 3-2-1 rule's three locators on the primary datum become
   N > 3 supports, so that no large region of the compliant part is left unsupported; Rong and
   Zhu 1999: supports spread to cover the free edges). Greedily, as in farthest-point sampling:
   each step places, of the robots not yet placed, the option that maximises

       score = d_free - load_weight * d_load

   where d_free is a pad's distance to the nearest thing already holding the part (the base
   supports, i.e. the ``[[supports]]`` edges, holes and points, and the pads placed so far) and
   d_load its distance to the load point. With ``load_weight`` 0 the pads fill the largest holes
   in the support (free edges far from every support); the load term keeps them on the loaded
   region of the part, which is where the deformation is (a documented trade-off, not a rule of
   the sources, which leave the balance to the engineer). It must stay below 1: a pad moved by s
   changes its d_free by s at most, so from 1 on moving towards the load always wins and the pads
   bunch at the load. The default 0.25 was chosen on the small cases below (a sweep of 0 to 0.9,
   so the figures are optimistic there): it is the bus panel's best (272.8 um; 282.3 at 0.1-0.2,
   337.5 at 0.3, 343.6 at 0.5) and the sweep's best on the spar and the pads panel, 9 % and 11 %
   above it on the wing panel and the pairs (35.5 and 43.2 um at 0.9, where the spar is 3.6 times
   worse); 0 costs the wing panel 32 % and the spar 71 %. The fan has no load point, so the weight does not act there.
3. **Shared mode** (one layout for every task): the same rules with the centroid of all the
   tasks' load points as the load.

Loads: a task's load point is the mean of its concentrated loads' positions: a drilling patch's
centre (``Load.at``) and an edge traction's segment midpoint. Distributed loads (pressure, own
weight, centrifugal) have no point: a task with only those (the fan) skips rule 1 and rule 2 drops
its load term (pure spreading away from the supports, i.e. towards the tips of cantilevered parts).

Effectors with several pads (pairs, m pads a robot): an option counts as its worst pad (its score
is the least of its pads' scores), and rule 1 takes the option with the pad nearest the load
(ties, common since a candidate belongs to several pairs, go to the better score). "No pad"
options are never chosen by the rules, except when a pad limit (``agents.pads``) is reached: the
robots not yet placed then idle. Without an idle action they still choose by rule 2, and the
robot-order hand-out of pads (:class:`~fixbench.cases.spec.Effector`) decides which pads count.

Measured (mean max |u| over tasks, um; per-task mode, default config; random: 200 uniform layouts
a task, seed 0; random search: 100 samples a task, seed 0):

=======================  =====  ==============  ===========  ==================
case                     rules  without rule 1  random mean  random search, 100
=======================  =====  ==============  ===========  ==================
wing_panel_small         38.8   130.1           1008         30.7
wing_spar_small          16.2   17.2            43.7         3.7
bus_panel_small          272.8  282.5           537.4        370.8
fan_small                94.1   94.1            388.1        52.1
wing_panel_pairs_small   47.8   114.9           1473         46.7
wing_panel_pads_small    68.2   192.6           1874         84.8
=======================  =====  ==============  ===========  ==================

The rules beat 81 % (spar) to 99.9 % (bus panel) of random layouts. Weakest on the spar: spreading
by distance puts the pads on the web's edges, zigzag, where its own weight wants them nearer the
centre line. A coverage rule tried instead of rule 2 (greedily minimise the mean distance of the
part's points to their nearest support or pad) did better only on the fan (58 um) and worse on the
spar (27-36 um) and the panels, so it was left out. Shared mode (worst task, um, same order as the
table): 278.1, 13.4, 387.9, 240.8, 344.0, 375.6, against random layouts' mean worst 3,214, 71.3,
645.9, 1,112, 4,578, 5,684 and random search's 188.4, 2.8, 394.7, 127.8, 342.6, 607.2 (100 a task).

Left out: the 3-2-1 rule's in-plane locators (the base supports of a case are given, not chosen)
and any check of the layout by the FE model (that would cost samples).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import shapely

from fixbench.cases.problem import Problem
from fixbench.cases.spec import CaseSpec, Task
from fixbench.solvers.base import Planner, PlannerConfig, TracedEvaluator, require


@dataclass(frozen=True)
class RulesConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "load_weight": ("float", 0.0, 0.9),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    load_weight: float = 0.25
    """Rule 2's pull towards the load: metres of spread a pad gives up per metre nearer the load, in
    [0, 1) (0: spread away from the supports and pads alone; from 1 on spreading never pays)."""

    near_load: bool = True
    """Rule 1: place one pad as near the load point as the robots' options allow (False: all pads
    by rule 2)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self, "load_weight", 0 <= self.load_weight < 1, "in [0, 1)")


def load_point(task: Task) -> np.ndarray | None:
    """Mean position (m) of ``task``'s concentrated loads (patch centres, edge-traction segment
    midpoints), None if it has only distributed ones (pressure, weight, centrifugal)."""
    pts = [ld.at for ld in task.loads if ld.kind == "patch"]
    pts += [ld.segment.mean(axis=0) for ld in task.loads if ld.kind == "edge_traction"]
    return np.mean(pts, axis=0) if pts else None


def support_distance(spec: CaseSpec) -> np.ndarray:
    """Distance (m) of every fixture candidate to the nearest base support (its edge segment,
    hole boundary, outer boundary or point disc)."""
    poly = spec.polygon
    geoms = []
    for sup in spec.supports:
        if sup.segment is not None:
            geoms.append(shapely.LineString(sup.segment))
        elif sup.hole is not None:
            geoms.append(poly.interiors[sup.hole])
        elif sup.outer:
            geoms.append(poly.exterior)
        else:
            geoms.append(shapely.Point(sup.point).buffer(sup.radius) if sup.radius else shapely.Point(sup.point))
    pts = shapely.points(spec.candidates)
    return np.min([shapely.distance(g, pts) for g in geoms], axis=0)


class Rules(Planner):
    name = "rules"
    family = "rules"
    description = "fixturing rules by hand: a pad at the load, the others spread over free regions (zero samples)"
    Config = RulesConfig
    zero_shot = True

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        d_sup = support_distance(problem.spec)
        loads = [load_point(t) for t in problem.tasks]
        if mode == "shared":
            located = [p for p in loads if p is not None]
            loads = [np.mean(located, axis=0) if located else None] * problem.n_tasks
        layouts = np.empty((problem.n_tasks, problem.n_agents), dtype=np.int64)
        first = []
        done: dict[tuple | None, tuple[np.ndarray, int]] = {}
        for t, load in enumerate(loads):
            key = None if load is None else tuple(load)
            if key not in done:
                done[key] = self._layout(problem, d_sup, load)
            layouts[t], agent = done[key]
            first.append(agent)
        return layouts, {"near_load_agent": first}

    def _layout(self, problem: Problem, d_sup: np.ndarray, load: np.ndarray | None) -> tuple[np.ndarray, int]:
        """One layout for ``load`` and the robot placed by rule 1 (-1: none)."""
        cfg, cand, opts = self.config, problem.candidates, problem.options
        d_load = np.zeros(len(cand)) if load is None else np.linalg.norm(cand - load, axis=1)
        weight = 0.0 if load is None else cfg.load_weight
        d_free = d_sup.copy()  # distance of each candidate to the nearest support or placed pad
        limit = problem.spec.effector.pads or np.inf
        layout = np.full(problem.n_agents, -1, dtype=np.int64)
        placed_pads = 0

        def score(acts: np.ndarray) -> np.ndarray:
            """Rule 2's score of each option: its worst pad's; -inf for "no pad"."""
            pads = opts[acts]
            s = np.where(pads >= 0, d_free[pads] - weight * d_load[pads], np.inf).min(axis=1)
            return np.where(np.isinf(s), -np.inf, s)

        def place(agent: int, act: int) -> None:
            nonlocal d_free, placed_pads
            layout[agent] = act
            for c in opts[act][opts[act] >= 0]:
                d_free = np.minimum(d_free, np.linalg.norm(cand - cand[c], axis=1))
                placed_pads += 1

        near_agent = -1
        if cfg.near_load and load is not None:  # rule 1: nearest pad to the load, ties to the best score
            best = None
            for a, acts in enumerate(problem.action_sets):
                pads = opts[acts]
                near = np.where(pads >= 0, d_load[np.maximum(pads, 0)], np.inf).min(axis=1)
                i = int(np.lexsort((-score(acts), near))[0])
                key = (near[i], -score(acts)[i])
                if best is None or key < best[0]:
                    best = (key, a, int(acts[i]))
            near_agent = best[1]
            place(near_agent, best[2])
        while placed_pads < limit and (layout < 0).any():  # rule 2: greedy spread
            best = None
            for a in np.flatnonzero(layout < 0):
                acts = problem.action_sets[a]
                s = score(acts)
                i = int(np.argmax(s))
                if best is None or s[i] > best[0]:
                    best = (s[i], int(a), int(acts[i]))
            place(best[1], best[2])
        for a in np.flatnonzero(layout < 0):  # pad limit reached: idle if the robot can
            acts = problem.action_sets[a]
            idle = np.flatnonzero((opts[acts] < 0).all(axis=1))
            layout[a] = acts[idle[0]] if len(idle) else acts[int(np.argmax(score(acts)))]
        return layout, near_agent
