"""Regret references in one place: the harness's side of them (the file format and its checks are
:mod:`fixbench.cases.references`).

**A run's references** (:func:`compute_reference`, :func:`prove_position`, :func:`shipped_reference`):
each problem of a matrix is scored against ``exact``'s optimum where it can be had, position by
position in the proof phase (:mod:`fixbench.bench.running.proof`), else against the case's shipped
reference; :func:`rescore` brings a run's rows up to the shipped references as they are now, and
:func:`update` merges into them every layout of a run that beats them.

**The reference portfolio**: an uncounted, large-budget search for the best layout of every task.

``fixbench references build CASE [--material M] [--agents N]`` runs it and writes the shipped
reference (:mod:`fixbench.cases.references`); ``fixbench references update DIR`` merges into the shipped
references every layout of a run directory that beats them (each one re-measured on the oracle,
never taken from the row on trust) and rescores the run's rows against them; ``fixbench references
rescore DIR`` rescores another run directory against the shipped references as they are now.

The portfolio (:class:`Portfolio`), in this order:

1. **Planners with transfer.** Each of ``planners`` (the benchmark's own: ``pso``, ``ga``,
   ``local``, ``greedy``) solves every task in order with ``samples_per_task`` samples a task and
   warm starts from the ``transfer`` nearest solved tasks, once per seed; the best layout of each
   task over all runs is kept.
The first phase starts from the shipped references of the case in every material (its own first;
layouts measured again on this material: the best layout of a linear problem hardly depends on the
material), so a rebuild can only improve a reference and a new material starts where the others
are. ``planners`` may be empty (exchange rounds only).

2. **Neighbour exchange.** Rounds over the tasks, forward then backward: each task tries the
   current best layouts of its ``exchange`` nearest tasks (by task features) and its own, and a
   local search (:func:`fixbench.solvers.search.local.local_search`, ``polish_samples`` layouts) polishes the
   best of them. A better layout found on a task is passed on within the same round. Rounds stop
   when one brings no improvement (relative 1e-9) or after ``max_rounds``.

Every evaluation is counted for the provenance (``samples``) but none is charged to any planner:
the portfolio is not a planner of the benchmark, and nothing in it is tuned against a reference.
A task is ``proven`` only with a proof: where enumerating every layout of every task is affordable
(``prove_limit``), ``exact`` runs after the portfolio, its optimum replaces the portfolio's layout
and the provenance records on how many tasks the portfolio had stayed above it. The portfolio
alone yields ``best-known``.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import math
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from fixbench.bench.running.cells import metrics, problem_for
from fixbench.bench.running.keys import split
from fixbench.bench.running.matrix import task_subset
from fixbench.bench.running.rows import (
    SCHEMA_VERSION,
    SHIPPED,
    load_rows,
    planner_mode,
    reference_key,
    reference_of,
)
from fixbench.cases.materials import MATERIALS
from fixbench.cases.problem import Problem, load_problem
from fixbench.cases.references import case_fingerprint, load_reference, write_reference
from fixbench.cases.spec import resolve_case

# a run's references --------------------------------------------------------------------------------

def reference_head(case: str, material: str | None, agents: int | None, tasks: int | None, p: Problem) -> dict:
    """The fields every regret reference of the problem starts with (the problem ``p`` resolves the
    material and agents), before its numbers are in."""
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
            proven = bool(res.info.get("proven", False))
            ref.update(per_task=res.max_deformation.tolist(), layouts=res.layouts.tolist(), proven=proven,
                       lower_bounds=res.max_deformation.tolist() if proven else [None] * p.n_tasks,
                       gap=res.info.get("gap"),
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
    from fixbench.cases.references import source_text
    from fixbench.cases.spec import case_names

    if case not in case_names():
        return None
    full = load_reference(case, material, agents)
    if full is None:
        return None
    ids = task_subset(full["n_tasks"], tasks)
    recs = [full["tasks"][i] for i in ids]
    return {"per_task": [r["max_deformation_m"] for r in recs], "layouts": [r["layout"] for r in recs],
            "lower_bounds": [r.get("lower_bound_m") for r in recs],
            "proven": all(r["status"] == "proven" for r in recs), "gap": None, "method": "portfolio",
            "source": source_text(full)}


# the reference portfolio --------------------------------------------------------------------------

@dataclass(frozen=True)
class Portfolio:
    """Effort of the reference portfolio (the defaults are the shipped references' effort)."""

    planners: tuple[str, ...] = ("pso", "local", "greedy")
    """Planners run over all tasks in order, with transfer, in the first phase (``ga`` can be added;
    it is left out by default: on the wing panel at 100 samples a task it ended at twice pso's
    deformation, and pymoo's per-generation cost makes it the slowest of the four)."""

    samples_per_task: int = 2000
    """Samples a task of each planner run of the first phase."""

    seeds: tuple[int, ...] = (0,)
    """Seeds of the first phase (each planner runs once per seed)."""

    transfer: int = 3
    """Solved tasks, nearest by features, that warm-start each task in the first phase."""

    exchange: int = 6
    """Nearest tasks whose best layouts each task tries in every exchange round."""

    polish_samples: int = 2000
    """Local-search layouts from the best exchanged layout, per task and round."""

    max_rounds: int = 12
    """Most exchange rounds (they stop earlier when one improves nothing)."""

    soft_power: float = 0.0
    """What the exchange's local search descends on: 0 = the max itself. The first phase's
    planners get near on the soft max; the last steps are decided on the max (on wing_panel_small
    in steel and titanium a soft-max exchange (p = 4) left one task each 0.01 % and 0.08 % above the
    proven optimum; on the max, none)."""

    prove_limit: float = 2e8
    """Enumerate every layout of every task (``exact``) when joint size x tasks is at most this:
    the tasks are then ``proven`` and the portfolio's layouts are checked against the optimum."""


@dataclass
class _Progress:
    samples: int = 0
    log: list[dict] = field(default_factory=list)


def build(case: str, material: str | None = None, agents: int | None = None, effort: Portfolio | None = None,
          echo=print, problem: Problem | None = None) -> dict:
    """Run the portfolio on a catalog case; returns the reference record (not yet written)."""
    from fixbench.solvers.base import random_layouts
    from fixbench.solvers.encoding import task_features
    from fixbench.solvers.registry import get
    from fixbench.solvers.search.local import LocalConfig, local_search
    from fixbench.solvers.transfer import nearest_tasks

    effort = effort or Portfolio()
    p = problem or load_problem(case, material=material, agents=agents)
    t0 = time.perf_counter()
    T, prog = p.n_tasks, _Progress()
    best = np.full(T, np.inf)
    layout = np.zeros((T, p.n_agents), dtype=np.int64)

    def offer(task: int, layouts: np.ndarray, values: np.ndarray) -> bool:
        i = int(np.argmin(values))
        if values[i] < best[task] * (1 - 1e-9):
            best[task], layout[task] = values[i], layouts[i]
            return True
        return False

    own = p.spec.material.name
    for mat in ([own] + sorted(set(MATERIALS) - {own})) if problem is None else []:
        shipped = load_reference(case, mat, p.n_agents)  # go on from what is known, measured again here
        if shipped is None or shipped["n_tasks"] != T:
            continue
        L = np.array([rec["layout"] for rec in shipped["tasks"]])
        improved = sum(offer(k, L[k:k + 1], p.measure(k, L[k:k + 1])[:, 3]) for k in range(T))
        prog.samples += T
        prog.log.append({"phase": "start", "from": f"the shipped reference of {mat}", "tasks_improved": improved,
                         "mean_m": float(best.mean())})
        echo(f"{p.name}/{own}: start from the {mat} reference: mean {1e6 * best.mean():.4g} um")

    for seed in effort.seeds:
        for name in effort.planners:
            t = time.perf_counter()
            res = get(name)(transfer=effort.transfer).solve(p, effort.samples_per_task * T, seed=seed)
            prog.samples += res.samples + T  # + scoring
            improved = sum(offer(k, res.layouts[k:k + 1], res.max_deformation[k:k + 1]) for k in range(T))
            prog.log.append({"phase": "planner", "planner": name, "seed": seed, "transfer": effort.transfer,
                             "samples": int(res.samples), "mean_m": float(res.max_deformation.mean()),
                             "tasks_improved": int(improved), "wall_s": round(time.perf_counter() - t, 1)})
            echo(f"{p.name}/{p.spec.material.name}: {name} seed {seed}: "
                 f"mean {1e6 * res.max_deformation.mean():.4g} um, "
                 f"reference mean {1e6 * best.mean():.4g} um ({time.perf_counter() - t:.0f} s)")

    cfg = LocalConfig(soft_power=effort.soft_power)
    rng = np.random.default_rng(effort.seeds[0])
    power = effort.soft_power or None
    feats = task_features(p, "spread")
    neighbours = [nearest_tasks(p, np.delete(np.arange(T), k), k, effort.exchange, feats) for k in range(T)]
    layout[~np.isfinite(best)] = random_layouts(p, rng, int((~np.isfinite(best)).sum()))
    for rnd in range(effort.max_rounds):
        t, improved = time.perf_counter(), 0
        order = range(T) if rnd % 2 == 0 else range(T - 1, -1, -1)
        for k in order:
            tried = np.unique(np.vstack([layout[neighbours[k]], layout[k:k + 1]]), axis=0)
            d = p.measure(k, tried)
            prog.samples += len(tried)
            better = offer(k, tried, d[:, 3])
            found = []

            def fitness(L, k=k, found=found):
                m = p.measure(k, L, power)
                found.append((L, m[:, 3]))
                return m[:, 5] if power else m[:, 3]

            local_search(p, fitness, effort.polish_samples, layout[k:k + 1].copy(), rng, cfg)
            for L, u in found:
                prog.samples += len(L)
                better |= offer(k, L, u)
            improved += bool(better)
        prog.log.append({"phase": "exchange", "round": rnd + 1, "tasks_improved": improved,
                         "mean_m": float(best.mean()), "wall_s": round(time.perf_counter() - t, 1)})
        echo(f"{p.name}/{p.spec.material.name}: exchange round {rnd + 1}: {improved} tasks improved, "
             f"reference mean {1e6 * best.mean():.4g} um ({time.perf_counter() - t:.0f} s)")
        if improved == 0:
            break
    final = np.array([p.measure(k, layout[k:k + 1])[0, 3] for k in range(T)])
    status = ["best-known"] * T
    lower: list[float | None] = [None] * T
    if p.joint_size * T <= effort.prove_limit:
        t = time.perf_counter()
        exact = get("exact")().solve(p, None)
        prog.samples += exact.samples
        worse = int((final > exact.max_deformation * (1 + 1e-9)).sum())
        layout, final = exact.layouts.copy(), exact.max_deformation.copy()
        status, lower = ["proven"] * T, final.tolist()
        prog.log.append({"phase": "proof", "method": "exact enumeration", "samples": int(exact.samples),
                         "portfolio_tasks_above_optimum": worse, "wall_s": round(time.perf_counter() - t, 1)})
        echo(f"{p.name}/{p.spec.material.name}: proven by enumeration; the portfolio was above the "
             f"optimum on {worse} of {T} tasks")
    return {"format": 1, "case": p.name, "material": p.spec.material.name, "agents": p.n_agents, "n_tasks": T,
            "case_fingerprint": case_fingerprint(case, p.spec.material.name, p.n_agents),
            "tasks": [{"layout": layout[k].tolist(), "max_deformation_m": float(final[k]), "status": status[k],
                       "lower_bound_m": lower[k]} for k in range(T)],
            "provenance": [{"action": "build", "date": datetime.date.today().isoformat(),
                            "portfolio": _jsonable(asdict(effort)), "samples": int(prog.samples),
                            "wall_s": round(time.perf_counter() - t0, 1), "steps": prog.log}]}


def _jsonable(d: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def build_and_write(case: str, material: str | None, agents: int | None, effort: Portfolio | None = None,
                    echo=print, folder=None) -> str:
    """Build a reference, keep per task the better of it and the shipped one, write it; returns the path."""
    resolve_case(case)
    ref = build(case, material, agents, effort, echo)
    old = load_reference(ref["case"], ref["material"], ref["agents"], folder)
    if old is not None:
        kept = 0
        for k, (new, was) in enumerate(zip(ref["tasks"], old["tasks"])):
            if was["max_deformation_m"] < new["max_deformation_m"]:
                ref["tasks"][k] = was
                kept += 1
        ref["provenance"] = old["provenance"] + [{**ref["provenance"][0], "tasks_kept_from_before": kept}]
    return str(write_reference(ref, folder))


def update(run_dir, echo=print, folder=None) -> dict:
    """Merge into the shipped references every layout of ``run_dir`` that beats them.

    Rows of catalog cases in per-task or held-out mode are read; a task whose recorded max
    deformation is below the reference's is re-measured on the oracle (uncounted) and replaces the
    reference only if the measurement confirms it. Returns {reference file: tasks replaced}.
    """
    from pathlib import Path

    from fixbench.cases.references import reference_path
    from fixbench.cases.spec import case_names

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
    if changed:
        rescore(run_dir, echo)
    return changed


class _Scored:
    """What :func:`fixbench.bench.running.cells.metrics` reads of a result, rebuilt from a stored row and trace."""

    def __init__(self, row: dict, trace: np.ndarray):
        self.max_deformation = np.asarray(row["per_task_m"], dtype=float)
        self.mode = planner_mode(row["mode"])
        n, k = len(self.max_deformation), row.get("heldout_every")
        self.layouts = np.empty((n, int(row["agents"])))  # metrics reads only its shape (tasks, agents)
        self.held_out = None
        if row["mode"] == "held-out" and k:
            self.held_out = np.asarray(split(n, int(k))[1], dtype=np.int64)
        self.scored_tasks = np.arange(n) if self.held_out is None else self.held_out
        u = self.max_deformation[self.scored_tasks]
        self.objective = float(u.max() if self.mode == "shared" else u.mean())
        self.trace = trace
        self.reward_bell = None


#: row columns that depend on the regret reference (rewritten by :func:`rescore`)
REFERENCE_COLUMNS = ("reference_objective_m", "reference_proven", "reference_source", "true_regret_m",
                     "relative_regret", "bound_objective_m", "relative_regret_upper", "samples_to_1pct",
                     "samples_to_5pct", "success_1pct", "success_5pct")


def rescore(run_dir, echo=print) -> int:
    """Bring a run directory's shipped-reference snapshots (``DIR/reference/*.json``) up to the
    shipped references as they are now, and recompute the reference-dependent columns of its rows;
    returns the number of rows rewritten. An ``exact`` reference is kept as it is (its rows gain any
    column added since they were written). A row of an older schema is written again as the current
    one (bench/running/store.py), whether its values changed or not."""
    import json
    from pathlib import Path

    import pandas as pd

    from fixbench.bench.running.store import Store, write_json_atomic

    store = Store(run_dir)
    rows = store.finished()
    fresh = {}
    for path in sorted((Path(run_dir) / "reference").glob("*.json")):
        ref = json.loads(path.read_text())
        if ref.get("error") or ref.get("per_task") is None:
            continue
        if str(ref.get("source", "")).startswith("catalog reference"):
            new = shipped_reference(ref["case"], ref["material"], int(ref["agents"]), int(ref["n_tasks"]))
            if new is None:
                continue
            if any(new[k] != ref.get(k) for k in new):  # values, layouts, bounds or the file's content hash
                ref.update(new)
                write_json_atomic(path, ref)
        fresh[reference_of(ref)] = ref  # exact's as it is: its columns are recomputed, to the same values
    n = 0
    for cid, row in rows.items():
        m = {}
        if not row.get("error") and row.get("per_task_m") and (ref := fresh.get(reference_of(row))) is not None:
            tp = Path(run_dir) / "traces" / f"{cid}.parquet"
            trace = pd.read_parquet(tp).to_numpy(float) if tp.exists() else np.empty((0, 4))
            m = {k: v for k, v in metrics(_Scored(row, trace), ref).items() if k in REFERENCE_COLUMNS}
            policy = row.get("policy_objective_m")
            if isinstance(policy, (int, float)) and math.isfinite(policy):  # a learner's policy, scored beside it
                m["policy_relative_regret"] = policy / m["reference_objective_m"] - 1
        changed = {k: v for k, v in m.items() if v != row.get(k) and not (v != v and row.get(k) != row.get(k))}
        if not changed and row.get("schema") == SCHEMA_VERSION:
            continue
        row.update(changed)
        store.rewrite(row)
        n += 1
    echo(f"{Path(run_dir).name}: {n} rows rescored against the shipped references")
    return n


def check_small(cases: tuple[str, ...] | None = None,
                materials: tuple[str, ...] = ("aluminium", "steel", "titanium"), effort: Portfolio | None = None,
                echo=print) -> list[dict]:
    """The portfolio without its proof step against ``exact``'s proven optimum on small cases (default:
    every ``*_small`` catalog case, at its own robots): per case and material, on how many tasks it
    reached the optimum (to 1e-9) and its worst gap."""
    from dataclasses import replace

    from fixbench.cases.spec import case_names
    from fixbench.solvers.registry import get

    effort = replace(effort or Portfolio(), prove_limit=0)
    out = []
    for case in cases or [n for n in case_names() if n.endswith("_small")]:
        for material in materials:
            p = load_problem(case, material=material)
            t = time.perf_counter()
            ref = build(case, material, problem=p, effort=effort, echo=lambda m: None)
            wall = time.perf_counter() - t
            opt = get("exact")().solve(p, None).max_deformation
            u = np.array([r["max_deformation_m"] for r in ref["tasks"]])
            rec = {"case": case, "material": material, "tasks": p.n_tasks,
                   "reached": int((u <= opt * (1 + 1e-9)).sum()), "worst_gap_pct": float(100 * (u / opt - 1).max()),
                   "samples": ref["provenance"][0]["samples"], "portfolio_s": round(wall, 1)}
            echo(rec)
            out.append(rec)
    return out



#: the methods of :func:`bound` (``fixbench references bound --method``)
BOUND_METHODS = ("branch-and-bound", "zones")


def bound(case: str, material: str | None = None, agents: int | None = None, time_limit_s: float = 60.0,
          tasks: list[int] | None = None, folder=None, echo=print, method: str = "branch-and-bound") -> dict:
    """Certified lower bounds on the positions of a shipped reference, written into its file: for each
    position (all, or ``tasks``) either the compliance branch-and-bound of
    :func:`fixbench.solvers.bound.lower_bound` with the reference's layout as incumbent, within
    ``time_limit_s`` of wall time a position, or (``method="zones"``) the zone bound of
    :class:`fixbench.solvers.zone_bound.ZoneBound`, every position at once. A position keeps the larger of
    its old and new bound; a layout the search finds below the reference's (measured on the oracle)
    replaces it; a bound that meets its layout's value makes the position ``proven``. The provenance
    records the method, its settings and the time spent. Returns a summary (per position: reference,
    bound, gap)."""
    from fixbench.cases.errors import CaseError
    from fixbench.solvers.bound import BoundConfig, ComplianceBound, lower_bound
    from fixbench.solvers.zone_bound import ZoneBound, ZoneConfig

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
        name = "zone bound (fixbench.solvers.zone_bound; docs/references.md#zone-bound)"
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
        name = "compliance branch-and-bound (fixbench.solvers.bound.lower_bound; docs/references.md#lower-bounds)"
    ref["provenance"].append({
        "action": "bound", "date": datetime.date.today().isoformat(), "method": name,
        "settings": asdict(cfg), "tasks": ids if tasks is not None else "all", "setup_s": round(setup_s, 1),
        "wall_s": round(time.perf_counter() - wall, 1), "cpu_s": round(time.process_time() - cpu, 1),
        "proven": sum(ref["tasks"][t]["status"] == "proven" for t in ids)})
    path = write_reference(ref, folder)
    return {"path": str(path), "positions": out}
