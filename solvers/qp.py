"""Convex relaxation (a QP in cvxpy, solved by OSQP), rounded to a layout and polished.

What the planner reads, and what it pays (through the counted evaluator only):

- the compliance data of every screened candidate of every active field,
  ``ev.compliance(field, cands)``: one sample per column, i.e. ``per`` samples per candidate
  (bending: 1 row per pad, w; membrane: 2 rows, ux and uy). On the four ``*_small`` cases this is
  3 x 84 = 252 (fan_small), 3 x 96 = 288 (wing_panel_small), 2 x 100 = 200 (wing_spar_small) and
  3 x 92 = 276 (bus_panel_small) samples, paid once: the columns do not depend on the task;
- the unconstrained response of each task, ``ev.unconstrained(field, task)`` = (d0, m0): one sample
  per field and task.

Formulation. For one field with candidate rows r, the measured field under constraint forces
lambda (one per row) is ``u = m0 - H^T lambda``. A layout's true reactions are one particular
lambda supported on its pads' rows, so the least-squares problem below, with lambda restricted to
a layout's rows, is a lower bound on that layout's ||u||^2 (the objective surrogate: the L2 norm of
the measured field rather than its maximum). The combinatorial choice "one pad per agent" is
relaxed to weights ``w_j >= 0`` with ``sum_{j in agent a} w_j = 1`` and ``|lambda_r| <= M_f w_j``
for each row r of candidate j (a big-M coupling; per agent it amounts to an L1/Linf group-lasso
budget ``sum_j max_r |lambda_r| <= M_f``, which favours few pads). With ``lambda = M_f mu``::

    minimise   sum_t  sum_f ||R_f M_f mu_{f,t} - Q_f^T m0_{f,t}||^2 / ||m0_t||^2  +  ridge ||mu||^2
    subject to -w_{j(r)} <= mu_{f,t,r} <= w_{j(r)},  w >= 0,  sum_{j in a} w_j = 1 for every agent a

where ``H_f^T = Q_f R_f`` is a thin QR (so the QP has rows x rows data, not measurement points x
rows), ``M_f`` is ``big_m`` times the largest single-pad reaction ``|C_jj^-1 d0_j|`` of the field,
and t runs over one task (per-task mode: one QP per task, the compliance data read once) or over
all tasks (shared mode: one QP, one mu per task, shared weights w). It is a convex QP (PSD
quadratic, linear constraints), solved with OSQP. The problem is solved for each scale in
``m_scales`` (a small continuation in M: small M forces sparse weights, large M lets the forces
cancel the load); a candidate's score is its weight summed over the scales.

Rounding and polish. Each agent takes its highest-scoring candidate (no sample). Polish (counted)
is coordinate descent over each agent's ``pool`` best-scoring candidates: evaluate the rounded
layout, then, agent by agent, every swap to another pool candidate, keep the best, until a sweep
brings no gain or ``polish_samples`` (per task; shared mode: per layout-on-every-task evaluation,
n_tasks samples each) are spent. ``polish_samples=0`` returns the rounded layout unevaluated.

Sizes and limits. The QP has ``n_rows * n_tasks_in_qp + n_candidates`` variables; on the small
cases (at most 300 rows) each solve takes well under a second. On the full cases the compliance
of every candidate costs ``per * n`` samples (wing_panel: 3 x 3,333 = 9,999) and R is n_rows^2
dense (0.8 GB for 10,000 rows): set ``max_candidates_per_agent`` (e.g. 60) to screen each agent's
set to evenly spaced candidates in its set's order before anything is read (no sample spent on
the screening, and the screened-out candidates are never chosen).
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np
import scipy.sparse as sp

from cases.errors import CaseError
from cases.problem import Problem
from solvers.base import Planner, PlannerConfig, PlannerError, TracedEvaluator, require_budget
from solvers.registry import register

FIELDS = ("bending", "membrane")


@dataclass(frozen=True)
class QPConfig(PlannerConfig):
    big_m: float = 2.0
    """Force bound M_f as a multiple of the field's largest single-pad reaction."""

    m_scales: tuple[float, ...] = (0.25, 0.5, 1.0)
    """Continuation: the QP is solved with M_f times each of these; weights are summed over them."""

    ridge: float = 1e-6
    """Ridge weight on the scaled forces mu (keeps the QP strictly convex in mu)."""

    pool: int = 5
    """Candidates per agent (best scores first) that polishing may swap in."""

    polish_samples: int = 40
    """Counted evaluations per task for polishing (shared mode: layouts judged on every task)."""

    max_candidates_per_agent: int = 0
    """Screen each agent's set to this many evenly spaced candidates before reading (0 = all)."""

    eps: float = 1e-7
    """OSQP absolute and relative tolerance."""

    max_iter: int = 20000
    """OSQP iteration limit per solve."""


@register
class QPPlanner(Planner):
    name = "qp"
    description = "group-sparse QP relaxation of the pad forces (cvxpy + OSQP), rounded and polished"
    Config = QPConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        if not cfg.m_scales or min(cfg.m_scales) <= 0 or cfg.big_m <= 0:
            raise PlannerError(f"planner '{self.name}': big_m and m_scales must be positive")
        sets = screened_sets(problem, cfg.max_candidates_per_agent)
        cand = np.concatenate(sets)
        order = np.argsort(cand)
        cand_sorted = cand[order]
        data = read_compliance(self.name, problem, ev, cand_sorted)
        per_call = len(data)
        tasks = list(range(problem.n_tasks))
        require_budget(self.name, ev.remaining, per_call * problem.n_tasks, "the unconstrained responses")
        resp = {t: {f: ev.unconstrained(f, t) for f in data} for t in tasks}
        pos = np.empty_like(order)
        pos[order] = np.arange(len(cand))  # candidate k of `cand` is column pos[k] of the data
        groups = np.repeat(np.arange(len(sets)), [len(s) for s in sets])
        qp = RelaxedQP(data, pos, groups, len(cand), cfg, 1 if mode == "per-task" else problem.n_tasks)
        info = {"compliance_samples": int(sum(d.per * len(cand) for d in data.values())),
                "unconstrained_samples": per_call * problem.n_tasks, "candidates_read": len(cand),
                "qp_status": []}
        if mode == "shared":
            scores = qp.scores([resp[t] for t in tasks], info)
            layout = polish(problem, ev, sets, cand, scores, cfg, None)
            return np.tile(layout, (problem.n_tasks, 1)), info
        layouts = np.empty((problem.n_tasks, problem.n_agents), dtype=np.int64)
        for t in tasks:
            scores = qp.scores([resp[t]], info)
            layouts[t] = polish(problem, ev, sets, cand, scores, cfg, t)
        return layouts, info


@dataclass
class FieldData:
    """Compliance of the screened candidates of one field (columns sorted by candidate index)."""

    per: int
    cols: np.ndarray  # the field's row indices of the screened candidates (sorted)
    C: np.ndarray  # (rows, rows): couplings among the screened candidates' rows
    H: np.ndarray  # (rows, n_meas * components)


def screened_sets(problem: Problem, limit: int) -> list[np.ndarray]:
    """Each agent's set, or ``limit`` evenly spaced members of it (deterministic, no sample)."""
    if limit <= 0:
        return [np.asarray(a, dtype=np.int64) for a in problem.action_sets]
    return [np.asarray(a, dtype=np.int64)[np.unique(np.linspace(0, len(a) - 1, min(limit, len(a))).round()
                                                    .astype(np.int64))] for a in problem.action_sets]


def read_compliance(name: str, problem: Problem, ev: TracedEvaluator, cand: np.ndarray) -> dict[str, FieldData]:
    """Counted reads of C and H for sorted candidates, for each field the evaluator serves."""
    data = {}
    for f in FIELDS:
        try:
            C, H = ev.compliance(f, cand)
        except CaseError:  # the field is not active in this case (refused before any charge)
            continue
        per = H.shape[0] // len(cand)
        cols = (cand[:, None] * per + np.arange(per)).ravel()
        data[f] = FieldData(per, cols, C[:, cols], H)
    if not data:
        raise PlannerError(f"planner '{name}': the evaluator serves no compliance data")
    return data


class RelaxedQP:
    """The relaxation of the module docstring, compiled once (targets and gains are parameters)."""

    def __init__(self, data: dict[str, FieldData], pos: np.ndarray, groups: np.ndarray, n_cand: int,
                 cfg: QPConfig, n_copies: int):
        self.data, self.cfg = data, cfg
        self.w = cp.Variable(n_cand, nonneg=True)
        cons = [sp.csr_matrix((np.ones(n_cand), (groups, np.arange(n_cand)))) @ self.w == 1]
        obj = 0
        self.Q, self.target, self.gain = {}, {}, {}
        for f, d in data.items():
            Q, R = np.linalg.qr(d.H.T)
            self.Q[f] = Q
            # data row r belongs to the candidate in sorted column r // per, i.e. to cand[k] with
            # pos[k] == r // per: E maps the weights (in `cand` order) to rows
            rows = (pos[:, None] * d.per + np.arange(d.per)).ravel()
            E = sp.csr_matrix((np.ones(len(rows)), (rows, np.repeat(np.arange(n_cand), d.per))),
                              shape=(len(rows), n_cand))
            self.target[f], self.gain[f] = [], []
            for _ in range(n_copies):
                mu = cp.Variable(len(rows))
                q, g = cp.Parameter(R.shape[0]), cp.Parameter(nonneg=True)
                self.target[f].append(q)
                self.gain[f].append(g)
                obj = obj + cp.sum_squares(g * (R @ mu) - q) + cfg.ridge * cp.sum_squares(mu)
                cons += [mu <= E @ self.w, -mu <= E @ self.w]
        self.problem = cp.Problem(cp.Minimize(obj), cons)

    def scores(self, responses: list[dict[str, tuple[np.ndarray, np.ndarray]]], info: dict) -> np.ndarray:
        """Weights summed over the continuation scales, for each task's (d0, m0) per field.

        Each task's objective is divided by ||m0_t||^2: targets and forces are scaled by 1/||m0_t||.
        """
        norm = [np.sqrt(sum(np.sum(m0**2) for _, m0 in r.values())) or 1.0 for r in responses]
        reaction = {f: [single_pad_reaction(d, r[f][0][d.cols]) for r in responses] for f, d in self.data.items()}
        for f in self.data:
            for q, r, n in zip(self.target[f], responses, norm):
                q.value = self.Q[f].T @ r[f][1] / n
        total = np.zeros(self.w.size)
        for s in self.cfg.m_scales:
            for f in self.data:
                for g, lam, n in zip(self.gain[f], reaction[f], norm):
                    g.value = s * self.cfg.big_m * lam / n
            self.problem.solve(solver=cp.OSQP, eps_abs=self.cfg.eps, eps_rel=self.cfg.eps,
                               max_iter=self.cfg.max_iter, warm_start=True)
            info["qp_status"].append(self.problem.status)
            if self.w.value is not None:
                total += np.clip(self.w.value, 0.0, None)
        return total


def single_pad_reaction(d: FieldData, d0: np.ndarray) -> float:
    """Largest reaction |C_jj^-1 d0_j| of any one pad held alone (sets the force scale M_f)."""
    n = d.C.shape[0] // d.per
    return max(float(np.abs(np.linalg.solve(d.C[j * d.per:(j + 1) * d.per, j * d.per:(j + 1) * d.per],
                                            d0[j * d.per:(j + 1) * d.per])).max()) for j in range(n))


def polish(problem: Problem, ev: TracedEvaluator, sets: list[np.ndarray], cand: np.ndarray,
           scores: np.ndarray, cfg: QPConfig, task: int | None) -> np.ndarray:
    """Round (best score per agent), then coordinate descent over the pools (see module docstring)."""
    offsets = np.cumsum([0] + [len(s) for s in sets])
    pools = []
    for a, s in enumerate(sets):
        sc = scores[offsets[a]:offsets[a + 1]]
        pools.append(cand[offsets[a]:offsets[a + 1]][np.argsort(-sc, kind="stable")[:max(cfg.pool, 1)]])
    layout = np.array([p[0] for p in pools], dtype=np.int64)
    cost = problem.n_tasks if task is None else 1
    budget = min(cfg.polish_samples, int(min(ev.remaining, 1e18) // cost))
    if budget < 1:
        return layout

    seen: dict[tuple, float] = {}

    def judge(layouts: np.ndarray) -> np.ndarray:
        vals = ev.evaluate_shared(layouts) if task is None else ev.evaluate(task, layouts).max_u
        seen.update(zip(map(tuple, layouts.tolist()), vals.tolist()))
        return vals

    best = judge(layout[None, :])[0]
    budget -= 1
    improved = True
    while improved and budget > 0:
        improved = False
        for a, p in enumerate(pools):
            trial = np.tile(layout, (len(p), 1))
            trial[:, a] = p
            trial = np.array([x for x in trial.tolist() if tuple(x) not in seen][:budget], dtype=np.int64)
            if len(trial) == 0:
                continue
            vals = judge(trial)
            budget -= len(trial)
            i = int(np.argmin(vals))
            if vals[i] < best:
                best, layout, improved = vals[i], trial[i], True
            if budget <= 0:
                break
    return layout
