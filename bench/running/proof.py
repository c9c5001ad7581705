"""The proof phase of ``fixbench run``: each problem's regret reference proven position by position.

Where every layout of a position can be enumerated (:func:`fixbench.bench.running.references.enumerates`: at most
``exact``'s ``max_enumeration``, 10^8 layouts a position, and the matrix's ``proof_limit``), the
driver hands out one job a position (:func:`fixbench.bench.running.references.prove_position`) and, with shared
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
reference (``DIR/reference/KEY.json``, the same fields as :func:`fixbench.bench.running.references.compute_reference`
writes) is assembled from the records in position order: the same bits whether the phase ran at once or
was resumed (JSON keeps a float's every bit); only ``wall_s``, the sum of the positions' own times,
depends on the host.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from fixbench.bench.running.cells import problem_for
from fixbench.bench.running.references import Position, reference_head
from fixbench.cases.errors import CaseError
from fixbench.cases.files import write_text_atomic


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
