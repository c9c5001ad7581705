"""The step *prove*: the regret reference of a run's problem, proven where it can be.

``fixbench run`` scores each problem of its matrix against ``exact``'s optimum where it can be had
(:func:`compute_reference`: the MILP, or the enumeration in one job), else against the case's shipped
reference restricted to the problem's tasks (:func:`shipped_reference`); the step writes nothing to
the catalog.

**The proof phase**: each problem's regret reference proven position by position.

Where every layout of a position can be enumerated (:func:`enumerates`: at most
``exact``'s ``max_enumeration``, 10^8 layouts a position, and the matrix's ``proof_limit``), the
driver hands out one job a position (:func:`prove_position`) and, with shared
cells in the matrix, one for the shared optimum. Each finished position is appended at once to
``DIR/reference/KEY.proof.jsonl``::

    {"proof": KEY, "case": ..., "material": ..., "agents": N, "n_tasks": T, "joint_size": J,
     "case_fingerprint": ..., "method": "enumeration"}                           (the header)
    {"position": 7, "layout": [...], "max_deformation_m": ..., "samples": J, "wall_s": ...}
    {"position": "shared", "objective_m": ..., "layout": [...], "proven": true, "samples": ..., "wall_s": ...}

so a run killed in the phase loses at most the positions being enumerated: a rerun reads the records
back and proves only the positions missing (a record cut short by the kill is dropped). The header
must match the problem as it is now (case fingerprint, layouts a position, positions), else the
records are of another case definition and the phase starts again. Once every position is in, the
reference (``DIR/reference/KEY.json``, the same fields as :func:`compute_reference`
writes) is assembled from the records in position order: the same bits whether the phase ran at once or
was resumed (JSON keeps a float's every bit); only ``wall_s``, the sum of the positions' own times,
depends on the host.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fixbench.bench.records.rows import reference_key
from fixbench.cases.errors import CaseError
from fixbench.cases.files import write_text_atomic
from fixbench.cases.problem import Problem, problem_for, task_subset
from fixbench.cases.references import case_fingerprint, load_reference


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
    position instead where it can: :func:`prove_position`, :class:`Proof`): the ``exact``
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
    Returns the proof record (:class:`Proof`), or ``{"position", "error"}``; never raises.
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


class Proof:
    """The proof of one problem's reference: its records file and the positions proven so far."""

    def __init__(self, store_root: Path, key4: tuple, shared: bool):
        case, material, agents, tasks = key4
        p = problem_for(*key4)
        self.key4, self.shared = key4, shared
        self.head = reference_head(case, material, agents, tasks, p)
        self.joint_size = p.joint_size
        self.path = Path(store_root) / "reference" / f"{self.head['key']}.proof.jsonl"
        self.header = {"proof": self.head["key"], "case": case, "material": self.head["material"],
                       "agents": self.head["agents"], "n_tasks": self.head["n_tasks"], "joint_size": self.joint_size,
                       "case_fingerprint": self.head["case_fingerprint"], "method": "enumeration"}
        self.records: dict = {}  # position (int, or "shared") -> its record
        self.errors: list[str] = []
        self._resume()

    @property
    def n_tasks(self) -> int:
        return self.head["n_tasks"]

    def wanted(self) -> list:
        """Every position the reference needs (and "shared" with shared cells)."""
        return list(range(self.n_tasks)) + (["shared"] if self.shared else [])

    def missing(self) -> list[Position]:
        """The jobs still to run, in position order."""
        return [Position(*self.key4, None if w == "shared" else w) for w in self.wanted() if w not in self.records]

    def layouts_of(self, position) -> int:
        """Layouts the proof of ``position`` enumerates (the shared optimum: every layout on every position)."""
        return self.joint_size * (self.n_tasks if position == "shared" else 1)

    def _resume(self) -> None:
        """Read the records of an earlier run; rewrite the file when a record was cut short or the
        header is another problem's (then every position is proven again)."""
        if not self.path.is_file():
            return
        lines = self.path.read_text(encoding="utf-8").splitlines()
        parsed = [_parse(line) for line in lines]
        if not parsed or parsed[0] != self.header:
            print(f"fixbench run: {self.path}: records of another case definition; proving "
                  f"{self.head['case']} again", file=sys.stderr)
            self._write_all()
            return
        for rec in parsed[1:]:
            if self._valid(rec):
                self.records[rec["position"]] = rec
        if len(self.records) != len(lines) - 1:  # a record cut short (or doubled): keep the good ones only
            self._write_all()

    def _valid(self, rec) -> bool:
        if not isinstance(rec, dict) or rec.get("position") not in self.wanted() or rec.get("error"):
            return False
        value = rec.get("objective_m" if rec["position"] == "shared" else "max_deformation_m")
        layout = rec.get("layout")
        return (isinstance(layout, list) and len(layout) == self.head["agents"]
                and isinstance(value, float) and isinstance(rec.get("samples"), int))

    def _write_all(self) -> None:
        lines = [self.header] + [self.records[w] for w in self.wanted() if w in self.records]
        write_text_atomic(self.path, "".join(json.dumps(rec) + "\n" for rec in lines))

    def add(self, record: dict) -> None:
        """Keep a finished position's record and append it to the file (synced: a kill keeps it)."""
        if record.get("error"):
            self.errors.append(f"position {record['position']}: {record['error']}")
            return
        self.records[record["position"]] = record
        if not self.path.is_file():
            self._write_all()
            return
        try:
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(json.dumps(record) + "\n")
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise CaseError(str(self.path), "", f"cannot write ({exc.strerror or exc})") from None

    def complete(self) -> bool:
        return all(w in self.records for w in self.wanted())

    def reference(self) -> dict:
        """The regret reference from the records (positions in order), or one carrying the errors."""
        ref = dict(self.head)
        if self.errors or not self.complete():
            ref["error"] = "; ".join(self.errors) or "proof incomplete"
            return ref
        recs = [self.records[t] for t in range(self.n_tasks)]
        ref.update(per_task=[r["max_deformation_m"] for r in recs], proven=True, gap=0.0,
                   lower_bounds=[r["max_deformation_m"] for r in recs],  # enumerated: each one proven
                   samples=sum(r["samples"] for r in recs), source="exact",
                   layouts=[r["layout"] for r in recs], method="enumeration",
                   wall_s=sum(r["wall_s"] for r in recs))
        if self.shared:
            shared = self.records["shared"]
            ref.update(shared=shared["objective_m"], proven=bool(shared["proven"]),
                       wall_s=ref["wall_s"] + shared["wall_s"])
        ref["proof_records"] = self.path.name
        return ref


def _parse(line: str):
    try:
        return json.loads(line)
    except json.JSONDecodeError:
        return None
