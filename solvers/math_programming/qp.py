"""Convex relaxation (a QP in cvxpy, solved by OSQP), rounded to a layout and polished.

What the planner reads, and what it pays (through the counted evaluator only):

- the compliance data of every screened candidate of every active field,
  ``ev.compliance(field, cands)``: one sample per column, i.e. ``per`` samples per candidate
  (bending: 1 row per pad, w; membrane: 2 rows, ux and uy). On the four ``*_small`` cases this is
  3 x 84 = 252 (fan_small), 3 x 96 = 288 (wing_panel_small), 2 x 100 = 200 (wing_spar_small) and
  3 x 92 = 276 (bus_panel_small) samples, paid once: the columns do not depend on the task;
- the unconstrained response of each task, ``ev.unconstrained(field, task)`` = (d0, m0): one sample
  per field and task.

Formulation. For one field, with constraint forces lambda at every candidate row (C = B K^-1 B^T,
H = P K^-1 B^T, d0 = B u0, m0 = P u0 as in :mod:`fixbench.cases.oracle`), a layout S's true reactions are
the minimiser of the complementary energy ``1/2 lambda^T C lambda - d0^T lambda`` over lambda
supported on S's rows (its value, ``-1/2 d0_S^T C_SS^-1 d0_S``, is minus half the drop in load
work: the classic fixture-stiffness objective), and its measured field is ``m0 - H^T lambda``.
The choice "one pad per agent" is relaxed to weights ``w_j >= 0`` with
``sum_{j in agent a} w_j = 1`` and ``|lambda_r| <= g_f w_j`` for each row r of candidate j (a
big-M coupling; per agent it is an L1/Linf group-lasso budget ``sum_j max_r |lambda_r| <= g_f``
that favours few pads). With ``lambda = g_f mu``::

    minimise   sum_t sum_f [ (1/2 g^2 mu^T C mu - g d0^T mu) / E0_t
                             + field_weight ||g R mu - Q^T m0||^2 / ||m0_t||^2 ]  +  ridge ||mu||^2
    subject to -w_{j(r)} <= mu_{f,t,r} <= w_{j(r)},  w >= 0,  sum_{j in a} w_j = 1 for every agent a

``H^T = Q R`` is a thin QR (the QP holds rows x rows data, not measurement points x rows); the
second term is the L2 norm of the measured field (a smooth surrogate of its maximum). ``E0_t`` is
the best single-pad energy drop of task t and ``g_f = scale * big_m *`` the largest single-pad
reaction ``|C_jj^-1 d0_j|`` of the field. t runs over one task (per-task mode: one QP per task, the
compliance read once) or every task (shared mode: one QP, one mu per task, shared w). The
quadratic is PSD and the constraints linear: a convex QP, solved with OSQP, once for each
``scale`` in ``m_scales`` (small scales force sparse supports, large ones let forces spread).

Rounding and polish. A candidate's mass is its largest ``|mu|`` (summed over fields and tasks,
each solve normalised to total 1, summed over the scales). Weights are a poor guide (with a slack
budget they are not unique), and relaxed forces spread over neighbouring pads, so each agent
takes the candidate of its set nearest to the mass-weighted centroid of its pads (no sample), and
its ``pool`` nearest candidates to that centroid are what polishing may swap in. Polish (counted)
is coordinate descent: evaluate the rounded layout, then, agent by agent, every swap to an
unseen pool candidate, keep the best, until a sweep brings no gain or the task's polish budget
is spent. What the descent leaves of that budget goes to a local search in the plane from its
layout (:func:`fixbench.solvers.search.local.local_search` with the ``local`` planner's defaults, over
every candidate, screened out or not; its start costs a sample again): a relaxation is solved to
find a start, and a planner that stopped at the pools' optimum would leave most of its samples
unspent (on the full wing panel at 100 samples a task it spent 21,102 of 50,000). The polish
budget is ``polish_samples`` a task (-1: the task's whole fair share of what the reads leave; with
an unlimited budget, ``samples_per_task``); in shared mode each layout is judged on every task, n_tasks samples.
``polish_samples=0`` returns the rounded layout unevaluated. A task's layout is the best one
evaluated on it.

Sizes and limits. The QP has ``n_rows * n_tasks_in_qp + n_candidates`` variables; on the small
cases (at most 300 rows) each solve takes well under a second. On the full cases the compliance
of every candidate would cost ``per * n`` samples (wing_panel: 3 x 3,333 = 9,999) and the QP's
dense rows x rows data would need more than 8 GB (measured: stopped after 13 minutes at 8.8 GB).
So each agent's set is screened to evenly spaced candidates in its set's order before anything is
read, as many as ``max_rows`` allows (wing_panel, 5 agents, 3 components: 40 a agent), or
``max_candidates_per_agent`` if smaller, and so that the reads take at most ``max_read_share`` of
the budget (the four ``*_small`` cases at 100 samples a task keep 13 candidates an agent on
wing_panel_small and bus_panel_small, 10 of 20 on wing_spar_small, all 28 on fan_small). No
sample is spent on the screening; the screened-out candidates are never chosen;
``info["candidates_per_agent"]`` says what was kept.

Robots that place m pads (``Effector``): the weights of a robot's candidates sum to m (at most m
when it may idle, in all at most the pad limit), each at most 1; rounding takes each robot's action
whose pads hold the most force mass and polishes over the actions nearest to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import cvxpy as cp
import numpy as np
import scipy.sparse as sp

from fixbench.cases.errors import BudgetExhausted, CaseError
from fixbench.cases.problem import Problem
from fixbench.solvers.base import (
    Planner,
    PlannerConfig,
    PlannerError,
    TracedEvaluator,
    at_least,
    require,
    require_budget,
)
from fixbench.solvers.search.local import revise, revise_budget

FIELDS = ("bending", "membrane")


@dataclass(frozen=True)
class QPConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "pool": ("int", 2, 10),
        "field_weight": ("log", 0.1, 10.0),
        "big_m": ("log", 0.3, 3.0),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    big_m: float = 1.0
    """Force scale g_f as a multiple of the field's largest single-pad reaction."""

    m_scales: tuple[float, ...] = (0.3, 1.0)
    """Continuation: the QP is solved with g_f times each of these; masses are summed over them."""

    field_weight: float = 1.0
    """Weight of the measured-field L2 term against the energy term."""

    ridge: float = 1e-6
    """Ridge weight on the scaled forces mu (keeps the QP strictly convex in mu)."""

    pool: int = 5
    """Candidates per agent (nearest to its force centroid first) that polishing may swap in."""

    polish_samples: int = -1
    """Counted layouts per task for polishing (shared mode: layouts judged on every task); -1: the
    task's whole share of the budget left after the reads."""

    samples_per_task: int = 40
    """Polish layouts per task when the budget is unlimited and ``polish_samples`` is -1."""

    max_candidates_per_agent: int = 0
    """Screen each agent's set to this many evenly spaced candidates before reading (0 = all)."""

    max_rows: int = 600
    """Most QP rows (candidates x held components, all fields): a larger problem is screened to
    ``max_rows // (components x agents)`` candidates per agent (0 = no limit). The QP's data are
    dense rows x rows and OSQP refactors them every solve: on the full wing panel (10 tasks of the
    protocol, measured) 600 rows take 0.7 s a task and 0.9 GB, 1,200 rows about 5 s a task."""

    max_read_share: float = 0.5
    """Most of the budget the compliance reads may take: where reading the screened candidates
    would cost more, each agent's set is screened further, to ``max_read_share x budget //
    (components x agents)`` candidates (1: the reads may take the whole budget; an unlimited budget
    sets no limit). Without it a case of few tasks could not be planned at all: wing_spar_small,
    5 agents, 100 samples a task (300 in all) costs 300 samples to read its 100 candidates' 3
    components, none left."""

    eps: float = 1e-5
    """OSQP absolute and relative tolerance."""

    max_iter: int = 20000
    """OSQP iteration limit per solve."""

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self, "big_m", self.big_m > 0, "positive")
        require(self, "m_scales", len(self.m_scales) > 0 and min(self.m_scales) > 0, "positive numbers (at least one)")
        require(self, "eps", self.eps > 0, "positive")
        require(self, "max_read_share", 0 < self.max_read_share <= 1, "in (0, 1]")
        at_least(self, 0, "field_weight", "ridge", "samples_per_task", "max_candidates_per_agent", "max_rows")
        at_least(self, 1, "pool", "max_iter")
        at_least(self, -1, "polish_samples")


class QPPlanner(Planner):
    name = "qp"
    family = "qp"
    description = "group-sparse QP relaxation of the pad forces (cvxpy + OSQP), rounded and polished"
    Config = QPConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        sets = screened_sets(problem, self.screen_limit(problem, ev.remaining))
        cand = np.concatenate(sets)
        order = np.argsort(cand)
        cand_sorted = cand[order]
        data = read_compliance(self.name, problem, ev, cand_sorted)
        per_call = len(data)
        tasks = list(range(problem.n_tasks)) if mode == "shared" else ev.tasks.tolist()
        require_budget(self.name, ev.remaining, per_call * len(tasks), "the unconstrained responses")
        resp = {t: {f: ev.unconstrained(f, t) for f in data} for t in tasks}
        pos = np.empty_like(order)
        pos[order] = np.arange(len(cand))  # candidate k of `cand` is column pos[k] of the data
        groups = np.repeat(np.arange(len(sets)), [len(s) for s in sets])
        eff = problem.spec.effector
        qp = RelaxedQP(data, pos, groups, len(cand), cfg, 1 if mode == "per-task" else problem.n_tasks,
                       eff.per_agent, eff.idle or bool(eff.pads), eff.pads)
        info = {"compliance_samples": int(sum(d.per * len(cand) for d in data.values())),
                "candidates_per_agent": [len(a) for a in sets],
                "unconstrained_samples": per_call * len(tasks), "candidates_read": len(cand),
                "qp_status": []}
        if mode == "shared":
            mass = qp.masses([resp[t] for t in tasks], info)
            budget = revise_budget(cfg.polish_samples, ev.remaining // problem.n_tasks, cfg.samples_per_task)
            layout = polish(problem, ev, sets, cand, mass, cfg, None, budget, rng)
            best = ev.shared_layout if ev.shared_layout is not None else layout
            return np.tile(best, (problem.n_tasks, 1)), info
        layouts = np.full((problem.n_tasks, problem.n_agents), -1, dtype=np.int64)
        for i, t in enumerate(tasks):
            mass = qp.masses([resp[t]], info)
            budget = revise_budget(cfg.polish_samples, ev.remaining // (len(tasks) - i), cfg.samples_per_task)
            layout = polish(problem, ev, sets, cand, mass, cfg, t, budget, rng)
            layouts[t] = ev.best_layout[t] if np.isfinite(ev.best[t]) else layout
        return layouts, info


    def screen_limit(self, problem: Problem, budget: float = math.inf) -> int:
        """Candidates per agent to read: the config's limit, tightened to fit ``max_rows`` QP rows
        and reads of at most ``max_read_share`` of ``budget`` samples."""
        cfg = self.config
        limit = cfg.max_candidates_per_agent
        per = sum(fo.per for fo in problem.oracle.fields.values())  # held components: structure, not data
        caps = [cfg.max_rows if cfg.max_rows > 0 else math.inf, cfg.max_read_share * budget]
        for cap in caps:
            sizes = [len(a) if limit <= 0 else min(limit, len(a)) for a in problem.candidate_sets]
            if per * sum(sizes) > cap:
                fit = max(1, int(cap) // (per * problem.n_agents))
                limit = fit if limit <= 0 else min(limit, fit)
        return limit


@dataclass
class FieldData:
    """Compliance of the screened candidates of one field (columns sorted by candidate index)."""

    per: int
    cols: np.ndarray  # the field's row indices of the screened candidates (sorted)
    C: np.ndarray  # (rows, rows): couplings among the screened candidates' rows
    H: np.ndarray  # (rows, n_meas * components)


def screened_sets(problem: Problem, limit: int) -> list[np.ndarray]:
    """Each agent's candidates, or ``limit`` evenly spaced members of them (deterministic, no sample)."""
    if limit <= 0:
        return [np.asarray(a, dtype=np.int64) for a in problem.candidate_sets]
    return [np.asarray(a, dtype=np.int64)[np.unique(np.linspace(0, len(a) - 1, min(limit, len(a))).round()
                                                    .astype(np.int64))] for a in problem.candidate_sets]


def read_compliance(name: str, problem: Problem, ev: TracedEvaluator,
                    cand: np.ndarray) -> dict[str, FieldData]:
    """Counted reads of C and H for sorted candidates, for each field the evaluator serves."""
    data = {}
    for f in FIELDS:
        try:
            C, H = ev.compliance(f, cand)
        except CaseError:  # the field is not active in this case (refused before any charge)
            continue
        except BudgetExhausted as exc:
            raise PlannerError(f"planner '{name}': budget too small to read the compliance data "
                               f"of {len(cand)} candidates ({exc})") from None
        per = H.shape[0] // len(cand)
        cols = (cand[:, None] * per + np.arange(per)).ravel()
        data[f] = FieldData(per, cols, C[:, cols], H)
    if not data:
        raise PlannerError(f"planner '{name}': the evaluator serves no compliance data")
    return data


class RelaxedQP:
    """The relaxation of the module docstring, compiled once (targets and gains are parameters)."""

    def __init__(self, data: dict[str, FieldData], pos: np.ndarray, groups: np.ndarray, n_cand: int,
                 cfg: QPConfig, n_copies: int, per_agent: int = 1, may_idle: bool = False, pads: int = 0):
        self.data, self.cfg, self.pos = data, cfg, pos
        self.w = cp.Variable(n_cand, nonneg=True)
        group_sum = sp.csr_matrix((np.ones(n_cand), (groups, np.arange(n_cand)))) @ self.w
        # m pads per robot: weights sum to m (at most m when a robot may place none), in all at most
        # the pad limit
        cons = [group_sum <= per_agent if may_idle else group_sum == per_agent]
        if per_agent > 1:
            cons.append(self.w <= 1)
        if pads:
            cons.append(cp.sum(self.w) <= pads)
        obj = 0
        self.Q, self.mu, self.par = {}, {}, {}
        for f, d in data.items():
            Q, R = np.linalg.qr(d.H.T)
            e, V = np.linalg.eigh(d.C)
            L = V * np.sqrt(np.clip(e, 0.0, None))  # C = L L^T (C is PSD; round-off clipped)
            self.Q[f] = Q
            # data row r belongs to the candidate in sorted column r // per, i.e. to cand[k] with
            # pos[k] == r // per: E maps the weights (in `cand` order) to rows
            rows = (pos[:, None] * d.per + np.arange(d.per)).ravel()
            E = sp.csr_matrix((np.ones(len(rows)), (rows, np.repeat(np.arange(n_cand), d.per))),
                              shape=(len(rows), n_cand))
            self.mu[f], self.par[f] = [], []
            for _ in range(n_copies):
                mu = cp.Variable(len(rows))
                # a = g^2 / E0, b = g d0 / E0, c = g / ||m0||, q = Q^T m0 / ||m0|| (g = force scale)
                a, c = cp.Parameter(nonneg=True), cp.Parameter(nonneg=True)
                b, q = cp.Parameter(len(rows)), cp.Parameter(R.shape[0])
                self.mu[f].append(mu)
                self.par[f].append((a, b, c, q))
                obj = (obj + 0.5 * a * cp.sum_squares(L.T @ mu) - b @ mu
                       + cfg.field_weight * cp.sum_squares(c * (R @ mu) - q) + cfg.ridge * cp.sum_squares(mu))
                cons += [mu <= E @ self.w, -mu <= E @ self.w]
        self.problem = cp.Problem(cp.Minimize(obj), cons)

    def masses(self, responses: list[dict[str, tuple[np.ndarray, np.ndarray]]], info: dict) -> np.ndarray:
        """Each candidate's force mass (its largest |mu| row, summed over fields, tasks and scales).

        ``responses`` holds each task's (d0, m0) per field. Each task's energy term is divided by
        its best single-pad energy reduction E0_t (summed over fields), its field term by
        ||m0_t||^2, so every task weighs alike.
        """
        red, lam = [], {f: 0.0 for f in self.data}
        for r in responses:
            e0 = 0.0
            for f, d in self.data.items():
                rj, lj = single_pad(d, r[f][0][d.cols])
                e0 += rj
                lam[f] = max(lam[f], lj)
            red.append(e0 or 1.0)
        norm = [np.sqrt(sum(np.sum(m0**2) for _, m0 in r.values())) or 1.0 for r in responses]
        total = np.zeros(self.w.size)
        for s in self.cfg.m_scales:
            for f, d in self.data.items():
                g = s * self.cfg.big_m * (lam[f] or 1.0)
                for (a, b, c, q), r, e0, n in zip(self.par[f], responses, red, norm):
                    a.value, b.value = g * g / e0, g * r[f][0][d.cols] / e0
                    c.value, q.value = g / n, self.Q[f].T @ r[f][1] / n
            self.problem.solve(solver=cp.OSQP, eps_abs=self.cfg.eps, eps_rel=self.cfg.eps,
                               max_iter=self.cfg.max_iter, warm_start=True)
            info["qp_status"].append(self.problem.status)
            if self.w.value is None:
                continue
            mass = np.zeros(self.w.size)
            for f, d in self.data.items():
                for mu in self.mu[f]:
                    # rows are in sorted-candidate order; self.w is in `cand` order
                    mass += np.abs(mu.value).reshape(-1, d.per).max(axis=1)[self.pos]
            total += mass / (mass.sum() or 1.0)
        return total


def single_pad(d: FieldData, d0: np.ndarray) -> tuple[float, float]:
    """Largest energy reduction d0_j C_jj^-1 d0_j and largest reaction |C_jj^-1 d0_j| of one pad."""
    best_red, best_lam = 0.0, 0.0
    for j in range(d.C.shape[0] // d.per):
        s = slice(j * d.per, (j + 1) * d.per)
        lam = np.linalg.solve(d.C[s, s], d0[s])
        best_red, best_lam = max(best_red, float(d0[s] @ lam)), max(best_lam, float(np.abs(lam).max()))
    return best_red, best_lam


def polish(problem: Problem, ev: TracedEvaluator, sets: list[np.ndarray], cand: np.ndarray,
           mass: np.ndarray, cfg: QPConfig, task: int | None, budget: int,
           rng: np.random.Generator) -> np.ndarray:
    """Round to the force centroids, descend over the pools, then search on in the plane with what
    the descent left of ``budget`` (module docstring); returns the descent's layout."""
    pools = _round_options(problem, cand, mass, cfg) if not problem.spec.effector.simple \
        else _round(problem, sets, mass, cfg)
    layout = np.array([p[0] for p in pools], dtype=np.int64)
    layout, left = coordinate_descent(problem, ev, layout, pools, budget, task, {})
    revise(problem, ev, task, left, layout[None, :], rng)  # the start costs one sample more
    return layout


def _round(problem: Problem, sets: list[np.ndarray], mass: np.ndarray, cfg: QPConfig) -> list[np.ndarray]:
    """Each agent's pool: its ``pool`` candidates nearest to its pads' force centroid, nearest first."""
    xy = problem.candidates
    offsets = np.cumsum([0] + [len(s) for s in sets])
    pools = []
    for a, s in enumerate(sets):
        m = mass[offsets[a]:offsets[a + 1]]
        centre = m @ xy[s] / m.sum() if m.sum() > 0 else xy[s].mean(axis=0)
        dist = np.sum((xy[s] - centre) ** 2, axis=1)
        pools.append(s[np.argsort(dist, kind="stable")[:max(cfg.pool, 1)]])
    return pools


def _round_options(problem: Problem, cand: np.ndarray, mass: np.ndarray, cfg: QPConfig) -> list[np.ndarray]:
    """Pools when a robot places m pads (or none): each robot's action whose pads hold the most force
    mass first, then the ``pool`` - 1 actions nearest to it in the plane (``Problem.points``)."""
    of = np.zeros(len(problem.candidates))
    of[cand] = mass
    pools = []
    for acts in problem.action_sets:
        opts = problem.options[acts]
        score = np.where(opts >= 0, of[np.maximum(opts, 0)], 0.0).sum(axis=1)
        best = acts[int(np.argmax(score))]
        dist = np.sum((problem.points[acts] - problem.points[best]) ** 2, axis=1)
        pools.append(acts[np.argsort(dist, kind="stable")[:max(cfg.pool, 1)]])
    return pools


def coordinate_descent(problem: Problem, ev: TracedEvaluator, layout: np.ndarray, pools: list[np.ndarray],
                       budget: int, task: int | None, known: dict[tuple, float]) -> tuple[np.ndarray, int]:
    """Counted polish: agent by agent, try every unseen swap to a pool candidate; keep the best.
    Returns the layout and what is left of ``budget``.

    ``budget`` counts layouts (each costs one sample, n_tasks in shared mode: ``task`` None);
    ``known`` maps layouts already evaluated to their values (the start is evaluated if it is not).
    Stops when a sweep over the agents brings no gain or the budget is spent.
    """

    def judge(layouts: np.ndarray) -> np.ndarray:
        vals = ev.evaluate_shared(layouts) if task is None else ev.evaluate(task, layouts).max_u
        known.update(zip(map(tuple, layouts.tolist()), vals.tolist()))
        return vals

    layout = np.asarray(layout, dtype=np.int64)
    if tuple(layout.tolist()) not in known:
        if budget < 1:
            return layout, budget
        judge(layout[None, :])
        budget -= 1
    best = known[tuple(layout.tolist())]
    improved = True
    while improved and budget > 0:
        improved = False
        for a, p in enumerate(pools):
            trial = np.tile(layout, (len(p), 1))
            trial[:, a] = p
            trial = np.array([x for x in trial.tolist() if tuple(x) not in known][:budget], dtype=np.int64)
            if len(trial) == 0:
                continue
            vals = judge(trial)
            budget -= len(trial)
            i = int(np.argmin(vals))
            if vals[i] < best:
                best, layout, improved = vals[i], trial[i], True
            if budget <= 0:
                break
    return layout, budget
