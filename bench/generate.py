"""`fixbench generate FAMILY --seed S --count N --out DIR`: generated parts, each checked as `fixbench
check` checks a new part and proven position by position, written as plain case files with their
references and a suite manifest (docs/families.md).

Part ``i`` of seed ``S`` is drawn by ``numpy.random.default_rng([S, i, attempt])``, attempt 0 first.
A draw is kept when

1. it fits (:meth:`~fixbench.cases.families.base.Family.misfit`: a cut-out inside its panel);
2. its case file loads: every key checked, every candidate owned by one robot, the part meshed;
3. its mesh converges (:func:`fixbench.bench.check.mesh_study`: max |u| moves at most 2 % between the
   two finer meshes);
4. its optimum layouts, proven by enumeration, deflect at most w/t = 0.5
   (:data:`fixbench.cases.linearity.LIMIT`) at every position;

else it is redrawn with the next attempt and the reason is recorded in the manifest, never dropped
silently. The Gaussian reward widths of a kept part are the check's suggestion from its own random
layouts (:func:`fixbench.bench.check.reward_widths`), written into its file before its proof.

Everything is written under DIR: ``NAME.toml`` (the case file), ``references/`` (the proven
optimum of every position, :mod:`fixbench.cases.references` format), ``parts.jsonl`` (one record a
finished part, appended as it finishes: a killed generation resumes from it) and ``suite.json``
(the manifest, written at the end: family, seed, ranges, every part's parameters, attempts, reasons
and checks; no timings, so one family and seed give the same bytes on a machine).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fixbench.bench.check import CheckSettings, mesh_study, random_maxima, reward_widths
from fixbench.cases.errors import CaseError, FixbenchError
from fixbench.cases.families import family as get_family
from fixbench.cases.families.base import Family, case_text
from fixbench.cases.files import write_text_atomic
from fixbench.cases.linearity import LIMIT
from fixbench.cases.problem import load_problem
from fixbench.cases.references import FORMAT, case_fingerprint, write_reference

#: the manifest's format
SUITE_FORMAT = 1
#: widths a draft is written with, before its own random layouts suggest the part's
DRAFT_SIGMA_UM = (1.0, 100.0)


@dataclass(frozen=True)
class GenerateSettings:
    """How hard a draw is checked, and how often a part is redrawn before the generation gives up."""

    max_attempts: int = 50
    """Draws of one part before generation stops with an error naming the reasons."""

    w_over_t: float = LIMIT
    """Largest deflection over thickness of a position's proven optimum."""

    check: CheckSettings = CheckSettings(tasks=8)
    """The mesh study and the random layouts of the reward widths (fewer tasks than `fixbench check`:
    a generated part has at most a dozen positions)."""


def part_name(family: str, seed: int, index: int) -> str:
    return f"{family}_s{seed}_{index:03d}"


def generate(family: str, seed: int, count: int, out: Path, overrides: dict[str, str] | None = None,
             settings: GenerateSettings | None = None, log=sys.stderr) -> dict:
    """Generate ``count`` parts of ``family`` from ``seed`` into ``out`` (resuming a generation cut
    short there) and return the manifest it writes (``out/suite.json``)."""
    s = settings or GenerateSettings()
    fam = get_family(family, overrides)  # unknown family, parameter or impossible range: before any work
    out = Path(out)
    head = {"format": SUITE_FORMAT, "family": family, "seed": seed, "count": count,
            "overrides": dict(sorted((overrides or {}).items())),
            "ranges": {k: r.text() for k, r in fam.params.items()}}
    done = _resume(out, head)
    out.mkdir(parents=True, exist_ok=True)
    records = out / "parts.jsonl"
    if not done:
        write_text_atomic(records, json.dumps({"head": head}) + "\n", ".tmp")
    for index in range(count):
        name = part_name(family, seed, index)
        if name in done:
            continue
        t0 = time.perf_counter()
        rec = _part(fam, seed, index, name, out, s)
        with records.open("a", encoding="utf-8") as f:
            f.write(json.dumps({**rec, "wall_s": round(time.perf_counter() - t0, 2)}, allow_nan=False) + "\n")
        done[name] = rec
        print(f"fixbench generate: {name}: {rec['attempts']} draw(s), {rec['tasks']} positions, "
              f"{rec['joint_size']:,} layouts a position proven", file=log)
    suite = {**head, "parts": [done[part_name(family, seed, i)] for i in range(count)]}
    write_text_atomic(out / "suite.json", json.dumps(suite, indent=1, allow_nan=False) + "\n", ".tmp")
    return suite


def _resume(out: Path, head: dict) -> dict[str, dict]:
    """The parts already generated in ``out`` by the same generation (its ``parts.jsonl``); another
    generation's folder is refused rather than mixed."""
    records = out / "parts.jsonl"
    if not records.exists():
        if out.exists() and any(out.iterdir()):
            raise FixbenchError(f"generate --out {out}: not empty and holds no generation of its own "
                                "(parts.jsonl): give an empty or new folder")
        return {}
    lines = records.read_text(encoding="utf-8").splitlines()
    try:
        first = json.loads(lines[0])["head"]
    except (IndexError, KeyError, ValueError):
        raise FixbenchError(f"generate {records}: line 1: not the head of a generation") from None
    if {k: v for k, v in first.items() if k != "count"} != {k: v for k, v in head.items() if k != "count"}:
        raise FixbenchError(f"generate --out {out}: holds another generation (family "
                            f"{first.get('family')}, seed {first.get('seed')}, its own ranges): give another folder")
    done = {}
    for line in lines[1:]:
        try:
            rec = json.loads(line)
        except ValueError:  # a record cut short by a kill: that part is generated again
            continue
        rec.pop("wall_s", None)
        done[rec["name"]] = rec
    return done


def _part(fam: Family, seed: int, index: int, name: str, out: Path, s: GenerateSettings) -> dict:
    """Draw part ``index`` until a draw passes every check; write it and its reference."""
    redraws = []
    for attempt in range(s.max_attempts):
        params = fam.draw(np.random.default_rng([seed, index, attempt]))
        why = fam.misfit(params)
        if why is None:
            header = [f"Generated by `fixbench generate {fam.name} --seed {seed}`: part {index}, draw {attempt}",
                      f"(family {fam.name}: {fam.summary}; docs/families.md).",
                      "Drawn parameters: " + ", ".join(f"{k} = {v}" for k, v in params.items())]
            result = _checked(fam.tables(params, name), header, out / f"{name}.toml", s)
            if isinstance(result, dict):
                return {"name": name, "file": f"{name}.toml", "params": params, "attempts": attempt + 1,
                        "redraws": redraws, **result}
            why = result
        redraws.append({"draw": attempt, "reason": why})
    (out / f"{name}.toml").unlink(missing_ok=True)
    reasons = "; ".join(f"{r['reason']}" for r in redraws[-3:])
    raise FixbenchError(f"generate {name}: no draw of {s.max_attempts} passed the checks (last: {reasons})")


def _checked(tables: dict, header: list[str], path: Path, s: GenerateSettings) -> dict | str:
    """Write, check and prove one draw: its checks and reference summary, or why it is redrawn."""
    tables["reward"] = {"sigma_x_um": DRAFT_SIGMA_UM[0], "sigma_z_um": DRAFT_SIGMA_UM[1]}
    try:
        return _check_and_prove(tables, header, path, s)
    except CaseError as exc:  # the draw's file is refused: a robot with no candidate, a position off the part
        return f"{exc.key}: {exc.problem}"
    except FixbenchError as exc:  # its stiffness singular: a support that holds too few nodes
        return str(exc)


def _check_and_prove(tables: dict, header: list[str], path: Path, s: GenerateSettings) -> dict | str:
    write_text_atomic(path, case_text(tables, header), ".tmp")
    problem = load_problem(path)
    mesh = mesh_study(path, None, problem, s.check)
    if mesh["flagged"]:
        return f"mesh: max |u| changes {mesh['change']:+.2%} between the two finer meshes"
    maxima, _ = random_maxima(problem, s.check)
    widths = reward_widths(problem, maxima, s.check)
    tables["reward"] = {"sigma_x_um": _um(widths["suggested_sigma_x_m"]),
                        "sigma_z_um": _um(widths["suggested_sigma_z_m"])}
    write_text_atomic(path, case_text(tables, header), ".tmp")  # the widths change no FE number: same problem
    optima = _prove(problem)
    ratio = max(t["w_m"] for t in optima) / problem.spec.thinnest
    if ratio > s.w_over_t:
        return f"deflection: a proven optimum deflects w/t = {ratio:.3g}, over {s.w_over_t:g}"
    material, agents = problem.spec.material.name, problem.n_agents
    write_reference({"format": FORMAT, "case": problem.name, "material": material, "agents": agents,
                     "n_tasks": problem.n_tasks, "case_fingerprint": case_fingerprint(path, material, agents),
                     "tasks": [{"layout": t["layout"], "max_deformation_m": t["max_deformation_m"],
                                "status": "proven", "lower_bound_m": None} for t in optima],
                     "provenance": [{"action": "generate", "method": "enumeration",
                                     "samples": problem.joint_size * problem.n_tasks}]},
                    path.parent / "references")
    return {"material": material, "agents": agents, "tasks": problem.n_tasks, "joint_size": problem.joint_size,
            "candidates": len(problem.candidates), "mesh_change": mesh["change"],
            "optimum_w_over_t": ratio, "sigma_x_um": tables["reward"]["sigma_x_um"],
            "sigma_z_um": tables["reward"]["sigma_z_um"],
            "optimum_m": [t["max_deformation_m"] for t in optima]}


def _um(metres: float) -> float:
    return float(f"{metres * 1e6:.3g}")


def _prove(problem) -> list[dict]:
    """Every position's optimum by enumeration (``exact``, uncounted here: no planner's samples):
    its layout, max |u| and w."""
    from fixbench.solvers.base import TracedEvaluator
    from fixbench.solvers.registry import get

    ev = TracedEvaluator(problem, None, list(range(problem.n_tasks)))
    get("exact")().plan(problem, ev, np.random.default_rng(0), "per-task")
    out = []
    for k in range(problem.n_tasks):
        layout = ev.best_layout[k]
        m = problem.measure(k, layout[None])
        out.append({"layout": layout.tolist(), "max_deformation_m": float(problem.deformation(m).max_u[0]),
                    "w_m": float(m[0, 2])})
    return out


def generate_suite(suite: str | Path, out: Path | None = None, settings: GenerateSettings | None = None,
                   log=sys.stderr) -> dict:
    """Generate every part of a suite (:mod:`fixbench.cases.families.suites`; a shipped suite by name)
    into ``out`` (default: beside the suite file, ``NAME/``), one folder a generation
    (``FAMILY_sSEED/``, as :func:`generate` writes it, resumable), and write ``out/suite.json``: the
    suite's name, its generations and every part (its family, case file relative to ``out``, and what
    :func:`generate` records of it)."""
    from fixbench.cases.families.suites import load_suite

    s = load_suite(suite)  # every key, family and range checked before any part is drawn
    out = Path(out) if out is not None else Path(s.source).with_suffix("")
    parts, generations = [], []
    for g in s.generations:
        made = generate(g.family, g.seed, g.count, out / g.folder, g.overrides, settings, log)
        generations.append({"family": g.family, "seed": g.seed, "count": g.count, "overrides": g.overrides,
                            "folder": g.folder})
        parts += [{"family": g.family, **p, "file": f"{g.folder}/{p['file']}"} for p in made["parts"]]
    manifest = {"format": SUITE_FORMAT, "suite": s.name, "description": s.description,
                "generations": generations, "parts": parts}
    write_text_atomic(out / "suite.json", json.dumps(manifest, indent=1, allow_nan=False) + "\n", ".tmp")
    return manifest
