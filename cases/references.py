"""Shipped regret references: the best layout known for every task of a catalog problem.

Where ``exact`` cannot run (the full parts: millions of layouts per agent set), regret needs a
reference that no planner beats. It is found offline by a search portfolio (``fixbench references
build``, see :mod:`fixbench.bench.references.build`), which is not a planner of the benchmark and is never
counted, and it is shipped here as versioned data: one JSON file per (case, material, agents) in
``cases/catalog/references/``.

File format (``FORMAT`` 1)::

    {"format": 1, "case": "wing_panel", "material": "aluminium", "agents": 5, "n_tasks": 500,
     "case_fingerprint": "<sha256 of the case's merged TOML, the material and the agent count>",
     "tasks": [{"layout": [i1, ..., iN], "max_deformation_m": 1.23e-05,
                "status": "best-known" | "proven", "lower_bound_m": null}, ...],
     "provenance": [{"action": "build" | "update", ...methods, budgets, seeds, wall time...}],
     "content_hash": "<sha256 of the canonical JSON of tasks>"}

``status`` is ``proven`` only where a proof exists (an exhaustive enumeration, or a bound that
closes the gap); ``lower_bound_m`` holds a certified lower bound on the position's optimum where one
was computed (``fixbench references bound``: :mod:`fixbench.bench.references.compliance_bound`), null elsewhere; a bound
above the layout's own value is refused like a damaged table. The content
hash lets a reader check that the table was not edited by hand; the fingerprint says which case
definition the layouts were measured on: a reference whose case changed is *stale* and is not used.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

from fixbench.cases.errors import CaseError
from fixbench.cases.files import write_text_atomic
from fixbench.cases.spec import drawing_digests, read_toml, resolve_case

FORMAT = 1
REFERENCE_DIR = Path(__file__).parent / "catalog" / "references"
STATUSES = ("proven", "best-known")
#: relative round-off a certified bound may sit above the value it bounds (the bound's own safety margin
#: is 1e-6 below; the two are measured on the same oracle)
BOUND_SLACK = 1e-9


def reference_path(case: str, material: str, agents: int, folder: Path | None = None) -> Path:
    return Path(folder or REFERENCE_DIR) / f"{case}__{material}__a{agents}.json"


def case_fingerprint(case: str | Path, material: str, agents: int) -> str:
    """What a reference's numbers depend on: the case's merged TOML, the material and the agents."""
    data, _ = read_toml(resolve_case(case))
    body = {"case": data, "material": material, "agents": int(agents)}
    if drawings := drawing_digests(data):  # a DXF outline: its contents, not only its path
        body["drawings"] = drawings
    text = json.dumps(body, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def content_hash(tasks: list[dict]) -> str:
    return hashlib.sha256(json.dumps(tasks, sort_keys=True).encode()).hexdigest()[:16]


def check_reference(ref: dict, source: str) -> dict:
    """Validate a loaded reference (format, per-task records, content hash); one-line CaseError."""
    if not isinstance(ref, dict) or ref.get("format") != FORMAT:
        raise CaseError(source, "format", f"not a fixbench reference of format {FORMAT}")
    tasks = ref.get("tasks")
    if not isinstance(tasks, list) or len(tasks) != ref.get("n_tasks"):
        raise CaseError(source, "tasks", f"must hold n_tasks = {ref.get('n_tasks')} records")
    for i, t in enumerate(tasks):
        u = t.get("max_deformation_m") if isinstance(t, dict) else None
        if not isinstance(u, (int, float)) or not u > 0 or t.get("status") not in STATUSES \
                or not isinstance(t.get("layout"), list) or len(t["layout"]) != ref.get("agents"):
            raise CaseError(source, f"tasks[{i}]", "needs a layout of one candidate per agent, a positive "
                            f"max_deformation_m and a status in {STATUSES}")
        lb = t.get("lower_bound_m")
        if lb is not None and not (isinstance(lb, (int, float)) and 0 <= lb <= u * (1 + BOUND_SLACK)):
            raise CaseError(source, f"tasks[{i}].lower_bound_m", f"must be null or in [0, max_deformation_m = "
                            f"{u:.6g}], got {lb!r}: a bound above a value reached is no bound (the file was "
                            "changed by hand or damaged)")
    if ref.get("content_hash") != content_hash(tasks):
        raise CaseError(source, "content_hash", "does not match the tasks (the file was changed by hand "
                        "or damaged); rebuild it with fixbench references build")
    return ref


def load_reference(case: str, material: str, agents: int, folder: Path | None = None) -> dict | None:
    """The shipped reference of a catalog problem, checked; None when there is none or it is stale
    (its case fingerprint differs from the case as it is now)."""
    path = reference_path(case, material, agents, folder)
    if not path.is_file():
        return None
    ref = _read_checked(path)
    if ref.get("case_fingerprint") != case_fingerprint(case, material, agents):
        return None
    ref["path"] = str(path)
    return ref


def _read_checked(path: Path) -> dict:
    """A reference file read and checked (:func:`check_reference`); one-line CaseError."""
    try:
        ref = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaseError(str(path), "", f"not valid JSON ({exc})") from None
    return check_reference(ref, str(path))


def source_text(ref: dict) -> str:
    """How a row names the shipped reference it was scored against: its file and content hash."""
    return f"catalog reference {Path(ref['path']).name} (content {ref['content_hash']})"


#: :func:`source_text` read back
SOURCE = re.compile(r"catalog reference (?P<file>[^ /]+\.json) \(content (?P<hash>[0-9a-f]+)\)")


def check_sources(sources: Iterable, where: str, folder: Path | None = None) -> None:
    """Refuse (one-line :class:`CaseError`) results scored against a shipped reference other than the
    one shipped now: ``sources`` are their ``reference_source`` values (``exact``, empty or a
    :func:`source_text`), ``where`` names the run. A shipped file that fails its own check is refused
    with its file and problem; one whose content hash differs from the rows' says how many rows and how
    to bring them up to it."""
    named = Counter(s for s in sources if isinstance(s, str) and s.startswith("catalog reference"))
    for source, n in sorted(named.items()):
        m = SOURCE.fullmatch(source)
        if m is None:
            raise CaseError(where, "reference_source", f"{n} rows name '{source}' without a content hash: "
                            "they cannot be checked against the shipped reference; rescore the run "
                            f"(fixbench references rescore {where})")
        path = Path(folder or REFERENCE_DIR) / m["file"]
        if not path.is_file():
            raise CaseError(where, "reference_source", f"{n} rows were scored against {m['file']}, which is "
                            "no longer shipped")
        shipped = _read_checked(path)
        if shipped["content_hash"] != m["hash"]:
            raise CaseError(where, "reference_source", f"{n} rows were scored against {m['file']} of content "
                            f"{m['hash']}, the shipped one is {shipped['content_hash']}: rescore the run "
                            f"(fixbench references rescore {where})")


def write_reference(ref: dict, folder: Path | None = None) -> Path:
    """Write a reference atomically (temporary file + rename); sets its content hash."""
    ref = {k: v for k, v in ref.items() if k != "path"}
    ref["content_hash"] = content_hash(ref["tasks"])
    check_reference(ref, "reference")
    path = reference_path(ref["case"], ref["material"], ref["agents"], folder)
    write_text_atomic(path, _dumps(ref), ".json.tmp")
    return path


def _dumps(ref: dict) -> str:
    """Strict JSON, one task per line (readable diffs when a run improves a few tasks)."""
    head = {k: v for k, v in ref.items() if k != "tasks"}
    lines = ",\n".join("  " + json.dumps(t, sort_keys=True, allow_nan=False) for t in ref["tasks"])
    text = json.dumps(head, indent=1, allow_nan=False)
    return text[:-2] + ',\n "tasks": [\n' + lines + "\n ]\n}\n"
