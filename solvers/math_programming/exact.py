"""The proven optimum: exhaustive enumeration, or a mixed-integer program solved by HiGHS.

**Enumeration** (joint action space up to ``max_enumeration`` layouts). Every joint layout is
evaluated on the counted evaluator, in chunks decoded from a layout index by mixed-radix digits
(agent 0 most significant). It costs ``joint_size * n_tasks`` samples in both modes, honestly
counted, and refuses a smaller budget (a partial enumeration proves nothing). Per-task: the layout
of least max deformation for each task; shared: the layout whose worst task is least.

**MILP** (larger spaces), solved by HiGHS through :func:`scipy.optimize.milp`. For the tasks of one
solve (one per task in per-task mode, all tasks together in shared mode) it reads, and is charged
for, the compliance data of every candidate in every active field (``Evaluator.compliance``: one
sample per column) and each task's free response (``Evaluator.unconstrained``: one sample per field
and task). Variables: a binary z_j per candidate (exactly one per agent), a scaled pad force
l_r = lambda_r / M in [-1, 1] per candidate constraint row, with

- ``|l_r| <= z_j`` (only a chosen pad j carries force),
- ``|d0_r - M sum_s C_rs l_s| <= G_r (1 - z_j)`` (a chosen pad holds its components at zero;
  G_r = |d0_r| + M * sum over agents and components of the agent's largest |C_rs|, which bounds
  the left side whatever is chosen),
- the field at the measurement points ``u = m0 - M H^T l``,
- ``e . u_p <= t`` for every measurement point p and every direction e of {-1, 0, 1}^k (normalised;
  k the active components among ux, uy, w), and the objective ``min t``.

``max_e e . u`` is a polyhedral norm below the Euclidean one (exact when only w is active; within
a factor 1.13 for three components), so the MILP's dual bound is a proven lower bound on the true
optimum of max |u|. The returned layout's true max |u| is evaluated (one sample per task) and
``gap = (true - lower bound) / true`` is reported: it is proven relative to the force bound M.

M is ``big_m_factor`` times the largest pad force over every single pad and every pair of pads
from different agents (computed from the compliance data already read); a layout whose pad forces
exceed M would be cut off, so the proof rests on that bound; ``info["big_m_ok"]`` checks it on the
returned layouts. The MILP is dense in the compliance columns: above ``max_milp_columns`` the
planner refuses with a :class:`PlannerError` rather than run out of memory or time.

Robots that place m pads (``Effector``): the binaries are the robots' actions (one per agent), a
candidate's pad is placed when an action holding it is chosen (a linear map of the binaries),
G_r counts m pads per agent, M also covers pairs of pads of one robot, and a pad limit is one more
row (a layout over the limit is never better than one within it: the pads handed out are a layout
within it).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse as sp
from tqdm import tqdm

from fixbench.cases.problem import Problem, decode_layouts
from fixbench.solvers.base import (
    Planner,
    PlannerConfig,
    PlannerError,
    TracedEvaluator,
    at_least,
    require,
    require_budget,
)

#: measured components of each field, in the order of the field's measurement rows
_COMPONENTS = {"bending": ("w",), "membrane": ("ux", "uy")}


@dataclass(frozen=True)
class ExactConfig(PlannerConfig):
    max_enumeration: int = 10**8
    """Largest joint action space enumerated exhaustively; larger ones are solved as a MILP."""

    chunk: int = 2**18
    """Layouts per oracle call while enumerating (memory against call overhead; same result)."""

    time_limit_s: float = 60.0
    """HiGHS wall-clock limit of each MILP solve (one per task, or one in shared mode)."""

    big_m_factor: float = 10.0
    """MILP pad-force bound M as a multiple of the largest force over single pads and pad pairs."""

    max_milp_columns: int = 2000
    """Most compliance columns (candidates x held components, all fields) the dense MILP accepts."""

    proven_gap: float = 1e-6
    """Largest relative gap a MILP result is called proven with. HiGHS stops at a relative MIP gap of
    1e-9, but its feasibility tolerances (1e-7 absolute) leave round-off of a few 1e-9 between its
    bound and the oracle's value of an optimal layout (measured 2.3e-9); the gap itself is always
    reported. A negative gap proves nothing."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 0, "max_enumeration", "max_milp_columns")
        at_least(self, 1, "chunk")
        require(self, "time_limit_s", self.time_limit_s > 0, "positive")
        require(self, "big_m_factor", self.big_m_factor > 0, "positive")


class Exact(Planner):
    name = "exact"
    family = "exact"
    description = "proven optimum: exhaustive enumeration, or a HiGHS MILP with its proven gap"
    Config = ExactConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        if problem.joint_size <= self.config.max_enumeration:
            return self._enumerate(problem, ev, mode)
        return self._milp(problem, ev, mode)

    # -- enumeration --------------------------------------------------------------------------------

    def _enumerate(self, problem: Problem, ev: TracedEvaluator, mode: str):
        n, T = problem.joint_size, (problem.n_tasks if mode == "shared" else len(ev.tasks))
        require_budget(self.name, ev.remaining, n * T, f"enumerating {n:,} layouts x {T} tasks")
        best = np.full(problem.n_tasks, np.inf)
        best_layout = np.full((problem.n_tasks, problem.n_agents), -1, dtype=np.int64)
        with tqdm(total=n * T, unit="layout", unit_scale=True, desc=f"exact {problem.name}",
                  disable=None, delay=2.0, leave=False) as bar:
            for start in range(0, n, self.config.chunk):
                layouts = decode_layouts(problem.action_sets, start, min(n, start + self.config.chunk))
                if mode == "shared":
                    values = ev.evaluate_shared(layouts)  # all tasks or none: checked before any is run
                    i = int(np.argmin(values))
                    if values[i] < best[0]:
                        best[:], best_layout[:] = values[i], layouts[i]
                else:
                    for task in ev.tasks:
                        values = ev.evaluate(task, layouts).max_u
                        i = int(np.argmin(values))
                        if values[i] < best[task]:
                            best[task], best_layout[task] = values[i], layouts[i]
                bar.update(len(layouts) * T)
        return best_layout, {"method": "enumeration", "proven": True, "gap": 0.0}

    # -- mixed-integer program ----------------------------------------------------------------------

    def _milp(self, problem: Problem, ev: TracedEvaluator, mode: str):
        cand = np.concatenate(problem.candidate_sets)
        fields = list(problem.oracle.fields)  # which fields are active: structure, not data
        per = {f: problem.oracle.fields[f].per for f in fields}
        columns = sum(per.values()) * len(cand)
        T = problem.n_tasks
        if columns > self.config.max_milp_columns:
            raise PlannerError(f"planner '{self.name}': {problem.name} has {problem.joint_size:.3g} "
                               f"layouts (over max_enumeration) and {columns} compliance columns "
                               f"(over max_milp_columns={self.config.max_milp_columns})")
        require_budget(self.name, ev.remaining, columns + len(fields) * T + T,
                       "the MILP (compliance columns, free responses, scoring the result)")
        data = {}
        for f in fields:
            C, H = ev.compliance(f, cand)
            order = np.argsort(cand)  # compliance rows come in sorted candidate order
            rows = (cand[:, None] * per[f] + np.arange(per[f])).ravel()
            back = (np.argsort(order)[:, None] * per[f] + np.arange(per[f])).ravel()
            free = [ev.unconstrained(f, t) for t in range(T)]
            data[f] = {"C": C[back][:, rows], "H": H[back], "d0": np.array([d[rows] for d, _ in free]),
                       "m0": np.array([m for _, m in free]), "per": per[f]}
        agent = np.repeat(np.arange(problem.n_agents), [len(a) for a in problem.candidate_sets])
        choice = _choices(problem, cand)
        groups = [list(range(T))] if mode == "shared" else [[t] for t in range(T)]
        layouts = np.zeros((T, problem.n_agents), dtype=np.int64)
        lower = np.zeros(T)
        big_m_ok = True
        for tasks in groups:
            z, bound, ok = self._solve_milp(data, agent, tasks, problem.n_agents, choice)
            layout = np.array([choice.actions[choice.agent == a][np.argmax(z[choice.agent == a])]
                               for a in range(problem.n_agents)])
            layouts[tasks] = layout
            lower[tasks] = bound
            big_m_ok &= ok
        if mode == "shared":
            true = np.full(T, ev.evaluate_shared(layouts[:1])[0])
        else:
            true = np.array([ev.evaluate(t, layouts[t:t + 1]).max_u[0] for t in range(T)])
        gaps = np.maximum(0.0, (true - lower) / true)
        gap = float(gaps.max())
        return layouts, {"method": "milp", "solver": "HiGHS (scipy.optimize.milp)",
                         "proven": gap <= self.config.proven_gap, "gap": gap, "gaps": gaps.tolist(),
                         "lower_bound": lower.tolist(), "big_m_ok": bool(big_m_ok)}

    def _solve_milp(self, data: dict, agent: np.ndarray, tasks: list[int], n_agents: int, choice: _Choices):
        """One MILP over ``tasks`` sharing z; returns (z, proven lower bound in metres, big-M ok)."""
        n_c = choice.Y.shape[1]  # binaries: one per action (= per candidate with one pad a robot)
        m_pads = choice.per_agent
        s_u = max(np.abs(d["m0"][tasks]).max() for d in data.values()) or 1.0
        big_m = {f: self.config.big_m_factor * _pair_force_bound(d, agent, tasks, m_pads > 1)
                 for f, d in data.items()}
        n_comp = sum(len(_COMPONENTS[f]) for f in data)
        n_meas = sum(d["m0"].shape[1] for d in data.values()) // n_comp
        offset = {}  # (task, field) -> (first force variable, first measurement variable)
        n_var = n_c
        for t in tasks:
            for f, d in data.items():
                offset[t, f] = (n_var, n_var + d["C"].shape[0])
                n_var += d["C"].shape[0] + d["H"].shape[1]
        t_var = n_var
        n_var += 1
        blocks, lo, hi = [], [], []

        def add(pieces, low, high):
            """Constraint rows low <= sum of (column offset, matrix) pieces . x <= high."""
            n_rows = pieces[0][1].shape[0]
            coo = [sp.coo_matrix(m) for _, m in pieces]
            blocks.append(sp.csr_matrix((np.concatenate([m.data for m in coo]),
                                         (np.concatenate([m.row for m in coo]),
                                          np.concatenate([m.col + c for (c, _), m in zip(pieces, coo)]))),
                                        shape=(n_rows, n_var)))
            lo.append(np.broadcast_to(low, n_rows))
            hi.append(np.broadcast_to(high, n_rows))

        one_hot = sp.csr_matrix((np.ones(n_c), (choice.agent, np.arange(n_c))), shape=(n_agents, n_c))
        add([(0, one_hot)], 1.0, 1.0)  # one action per agent
        if choice.limit:  # at most `pads` pads in all
            add([(0, sp.csr_matrix(choice.n_pads[None, :].astype(float)))], -np.inf, float(choice.limit))
        for t in tasks:
            comps = []
            for f, d in data.items():
                (l0, u0), per, C, H, M = offset[t, f], d["per"], d["C"], d["H"], big_m[f]
                nr, nm = C.shape[0], H.shape[1]
                owner = np.repeat(np.arange(len(agent)), per)  # candidate of each row
                # a row's pad is placed when an action holding its candidate is chosen
                z_of_row = (sp.csr_matrix((np.ones(nr), (np.arange(nr), owner)), shape=(nr, len(agent)))
                            @ choice.Y).tocsr()
                eye = sp.identity(nr, format="csr")
                add([(l0, eye), (0, -z_of_row)], -np.inf, 0.0)  # l_r <= z_j
                add([(l0, -eye), (0, -z_of_row)], -np.inf, 0.0)  # -l_r <= z_j
                # |d0 - M C l| <= G (1 - z), rows scaled by s_d
                d0 = d["d0"][t]
                s_d = np.abs(d0).max() or 1.0
                comp = np.arange(nr) % per
                reach = m_pads * sum(np.abs(C[:, (agent[owner] == a) & (comp == c)]).max(axis=1)
                                     for a in range(n_agents) for c in range(per))
                G = np.abs(d0) + M * reach
                CM = -M / s_d * C
                add([(l0, CM), (0, z_of_row.multiply(G[:, None] / s_d))], -np.inf, (G - d0) / s_d)
                add([(l0, CM), (0, z_of_row.multiply(-G[:, None] / s_d))], (-G - d0) / s_d, np.inf)
                # u = (m0 - M H^T l) / s_u  <=>  u + (M / s_u) H^T l = m0 / s_u
                m = d["m0"][t] / s_u
                add([(l0, M / s_u * H.T), (u0, sp.identity(nm, format="csr"))], m, m)
                comps += [u0 + k * n_meas + np.arange(n_meas) for k in range(len(_COMPONENTS[f]))]
            for e in _directions(n_comp):  # e . u_p - t <= 0 for every direction e and point p
                minus_t = (np.full(n_meas, -1.0), (np.arange(n_meas), np.full(n_meas, t_var)))
                pieces = [(0, sp.csr_matrix(minus_t, shape=(n_meas, n_var)))]
                pieces += [(0, sp.csr_matrix((np.full(n_meas, e[k]), (np.arange(n_meas), comps[k])),
                                             shape=(n_meas, n_var))) for k in np.flatnonzero(e)]
                add(pieces, -np.inf, 0.0)
        lb = np.full(n_var, -np.inf)
        ub = np.full(n_var, np.inf)
        lb[:n_c], ub[:n_c] = 0.0, 1.0
        for l0, u0 in offset.values():
            lb[l0:u0], ub[l0:u0] = -1.0, 1.0
        lb[t_var] = 0.0
        cost = np.zeros(n_var)
        cost[t_var] = 1.0
        integrality = np.zeros(n_var)
        integrality[:n_c] = 1
        res = scipy.optimize.milp(cost, integrality=integrality, bounds=scipy.optimize.Bounds(lb, ub),
                                  constraints=scipy.optimize.LinearConstraint(
                                      sp.vstack(blocks).tocsr(), np.concatenate(lo), np.concatenate(hi)),
                                  options={"time_limit": self.config.time_limit_s, "mip_rel_gap": 1e-9})
        if res.x is None:
            raise PlannerError(f"planner '{self.name}': HiGHS found no layout within "
                               f"{self.config.time_limit_s} s ({res.message})")
        bound = res.mip_dual_bound if res.mip_dual_bound is not None else res.fun
        ok = all(np.abs(res.x[l0:u0]).max() < 1.0 - 1e-6 for l0, u0 in offset.values())
        return res.x[:n_c], max(0.0, bound) * s_u, ok


@dataclass(frozen=True)
class _Choices:
    """The MILP's binaries: one per action of every agent, and the pads each places."""

    actions: np.ndarray  # action index of each binary
    agent: np.ndarray  # its agent
    Y: sp.csr_matrix  # (candidates in MILP order, binaries): 1 where the action places the candidate
    n_pads: np.ndarray  # pads each action places
    per_agent: int
    limit: int  # most pads in all (0: none)


def _choices(problem: Problem, cand: np.ndarray) -> _Choices:
    """Binaries of the MILP; ``cand`` the candidates in the MILP's order (by agent)."""
    eff = problem.spec.effector
    actions = np.concatenate(problem.action_sets)
    agent = np.repeat(np.arange(problem.n_agents), [len(a) for a in problem.action_sets])
    where = np.full(len(problem.candidates), -1, dtype=np.int64)
    where[cand] = np.arange(len(cand))
    opts = problem.options[actions]
    b, k = np.nonzero(opts >= 0)
    Y = sp.csr_matrix((np.ones(len(b)), (where[opts[b, k]], b)), shape=(len(cand), len(actions)))
    return _Choices(actions, agent, Y, (opts >= 0).sum(axis=1), eff.per_agent, eff.pads)


def _directions(k: int) -> np.ndarray:
    """Unit vectors of {-1, 0, 1}^k without 0: the facets of the polyhedral norm."""
    e = np.array([v for v in itertools.product((-1.0, 0.0, 1.0), repeat=k) if any(v)])
    return e / np.linalg.norm(e, axis=1)[:, None]


def _pair_force_bound(d: dict, agent: np.ndarray, tasks: list[int], same_agent: bool = False) -> float:
    """Largest |pad force| over every single pad and every pair of pads of different agents (of any
    agents with ``same_agent``, when a robot places several pads).

    Pairs whose coupling block is numerically singular (overlapping pads) are skipped: the oracle
    refuses such layouts too.
    """
    per, C, d0 = d["per"], d["C"], d["d0"][tasks]
    n_c = len(agent)
    rows = np.arange(n_c)[:, None] * per + np.arange(per)
    i, j = np.triu_indices(n_c, 1)
    keep = np.ones(len(i), dtype=bool) if same_agent else agent[i] != agent[j]
    force = 0.0
    for r in (rows, np.concatenate([rows[i[keep]], rows[j[keep]]], axis=1)):
        A = C[r[:, :, None], r[:, None, :]]
        good = np.linalg.cond(A) < 1e12
        lam = np.linalg.solve(A[good], np.moveaxis(d0[:, r[good]], 0, -1))  # (blocks, rows, tasks)
        force = max(force, float(np.abs(lam).max(initial=0.0)))
    return force  # 0 for a field these tasks do not load: every pad force is then 0
