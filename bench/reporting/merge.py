"""Merged reports: several run directories of one protocol read as one set of rows, so that
``fixbench report mine --with paper`` ranks a new planner beside the published ones without
rerunning them (COCO's post-processing does the same with its archived algorithms' data).

Runs merge when their cells are comparable; the first difference is refused in one line (exit 2):

- every problem two runs share (case, material, agents, tasks) has the same regret reference in
  both (its per-task optima within the 1e-9 relative tolerance regret uses, its shared optimum, and,
  where both runs' reference snapshots record it, the case fingerprint: the case file, material and
  agent count the reference was computed on);
- the settings of every run's cells (case, material, agents, tasks, mode, held-out spacing, budget or
  samples a task, seed) lie among those of the run with the most of them, the protocol: a cell with
  no counterpart there would be ranked against nothing (a planner with its own budget, e.g. ``exact``
  unlimited, competes at every budget, as in one run);
- a planner label names the same planner and config in every run (labels that collide are refused:
  give one of the matrix entries a ``label`` of its own);
- a cell held by two runs (an extended copy beside its original) has the same result in both, and is
  read once.

Each run is read by the one loader, :func:`fixbench.bench.records.rows.load_rows` (its labels made per
run); the settings compared are :data:`fixbench.bench.records.rows.SETTINGS`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from fixbench.bench.records.rows import (
    ORDER,
    REFERENCE,
    SETTINGS,
    config_text,
    load_rows,
    reference_of,
    with_case_defaults,
)
from fixbench.cases.errors import CaseError

#: the committed runs ``--with NAME`` names (``results/NAME`` of the fixbench checkout)
RESULTS = Path(__file__).resolve().parents[2] / "results"
#: how a message names a setting (its column otherwise)
NAMES = {"n_tasks": "tasks", "heldout_every": "held-out every"}
#: a cell's settings (:data:`~fixbench.bench.records.rows.SETTINGS`; its budget and samples a task as one
#: ``level``), in the order a difference is looked for: (column, as a message names it)
COMPARED = tuple(("level", "budget") if c == "budget" else (c, NAMES.get(c, c))
                 for c in SETTINGS if c != "samples_per_task")
#: what makes two rows of one cell the same result
RESULT = ("error", "objective_m", "per_task_m", "samples")
#: relative tolerance of two references' optima (the one regret uses)
RTOL = 1e-9


def committed_run(name: str) -> Path:
    """``results/NAME`` of the fixbench checkout (a committed run, e.g. ``paper``)."""
    path = RESULTS / name
    if not (path / "rows").is_dir():
        have = sorted(p.name for p in RESULTS.glob("*") if (p / "rows").is_dir()) if RESULTS.is_dir() else []
        raise CaseError("--with", name, "no committed run of that name in "
                        f"{RESULTS} ({'known: ' + ', '.join(have) if have else 'this installation has none'})")
    return path


@dataclass
class Runs:
    """Run directories read as one: merged ``rows``, regret references ``refs`` by problem, the
    cells each run contributes (``cells[i]``: None for all of them, a single run) and each run's own
    rows and references (``each``)."""

    paths: list[Path]
    rows: pd.DataFrame
    refs: dict
    cells: list[set | None]
    each: list[tuple[pd.DataFrame, dict]]

    def frames(self, load) -> pd.DataFrame:
        """``load(run)`` (traces or curves, with a ``cell`` column) of every run, only the cells it
        contributes."""
        if len(self.paths) == 1:
            return load(self.paths[0])
        parts = [df[df["cell"].isin(keep)] for df, keep in zip(map(load, self.paths), self.cells)
                 if not df.empty]
        parts = [p for p in parts if not p.empty]
        return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def load_references(run_dir: Path) -> dict[tuple, dict]:
    """Usable references by (case, material, agents, n_tasks)."""
    out = {}
    for p in sorted((Path(run_dir) / "reference").rglob("*.json")):  # a case path may nest folders
        try:
            ref = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if ref.get("error") or ref.get("per_task") is None:
            continue
        if (key := reference_of(ref)) is not None:
            out[key] = ref
    return out


def load_runs(paths: list[Path]) -> Runs:
    """The runs in ``paths`` as one (see the module docstring); one path: that run as it is."""
    paths = [Path(p) for p in paths]
    for p in paths:
        if not (p / "rows").is_dir():
            raise CaseError(str(p), "", "is not a run directory (it has no rows/ folder)")
    if len(paths) == 1:
        rows, refs = load_rows(paths[0]), load_references(paths[0])
        return Runs(paths, rows, refs, [None], [(rows, refs)])
    rows = [load_rows(p) for p in paths]
    refs = [load_references(p) for p in paths]
    _check_references(paths, rows, refs)
    _check_settings(paths, rows)
    _check_labels(paths, rows)
    kept, cells, seen = [], [], {}
    for path, r in zip(paths, rows):
        mine = []
        for i, row in r.iterrows():
            first = seen.get(row["cell"])
            if first is None:
                seen[row["cell"]] = (path, row)
                mine.append(i)
            elif any(_plain(first[1][k]) != _plain(row[k]) for k in RESULT):
                raise CaseError(str(path), "", f"holds cell {row['cell']} ({_cell_text(row)}) with another "
                                f"result than {first[0]} (objective {_um(row['objective_m'])} here, "
                                f"{_um(first[1]['objective_m'])} there); merge only one of them")
        kept.append(r.loc[mine])
        cells.append(set(r.loc[mine, "cell"]))
    merged = pd.concat(kept, ignore_index=True)
    first = {c: i for i, c in enumerate(dict.fromkeys(merged["case"]))}  # the first run's matrix order
    merged = merged.assign(_case=merged["case"].map(first)).sort_values(
        ["_case", *ORDER[1:], "cell"], kind="stable").drop(columns="_case")
    merged = merged.reset_index(drop=True)
    merged.attrs["damaged"] = sum(r.attrs.get("damaged", 0) for r in rows)
    union = {}
    for r in refs:
        for k, v in r.items():
            union.setdefault(k, v)
    return Runs(paths, merged, union, cells, list(zip(rows, refs)))


def _um(v) -> str:
    return f"{float(v) * 1e6:.6g} um" if isinstance(v, (int, float)) and np.isfinite(v) else "none"


def _cell_text(row) -> str:
    return f"{row['label']} on {row['case']}/{row['material']}, {row['mode']}, seed {_plain(row['seed'])}"


def _plain(v):
    """A setting's value as a message shows it and a set compares it: NaN is None, whole floats ints."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return None
    if isinstance(v, (float, np.floating)) and float(v).is_integer():
        return int(v)
    return v.item() if isinstance(v, np.generic) else v


def _problem_text(key: tuple) -> str:
    case, material, agents, tasks = key
    return f"{case}/{material} ({agents} agents, {tasks} tasks)"


def _check_references(paths: list[Path], rows: list[pd.DataFrame], refs: list[dict]) -> None:
    """Every problem two runs have cells on has the same regret reference (or none) in both."""
    seen: dict[tuple, tuple[Path, dict | None]] = {}
    for path, r, ref in zip(paths, rows, refs):
        d = with_case_defaults(r).dropna(subset=list(REFERENCE))
        for key in dict.fromkeys(map(reference_of, d[list(REFERENCE)].to_dict("records"))):
            mine = ref.get(key)
            if key not in seen:
                seen[key] = (path, mine)
                continue
            other, theirs = seen[key]
            why = _reference_difference(mine, theirs)
            if why:
                raise CaseError(str(path), "", f"not comparable with {other}: the regret reference of "
                                f"{_problem_text(key)} differs: {why}")


def _reference_difference(mine: dict | None, theirs: dict | None) -> str:
    """Why two runs' references of one problem differ ('' when they agree); 'here' is ``mine``."""
    if mine is None or theirs is None:
        if mine is theirs:
            return ""
        return f"{'none' if mine is None else 'one'} here, {'none' if theirs is None else 'one'} there"
    a, b = mine.get("case_fingerprint"), theirs.get("case_fingerprint")
    if a and b and a != b:
        return f"case fingerprint {a} here, {b} there (the case file changed between the runs)"
    u, v = np.asarray(mine["per_task"], dtype=float), np.asarray(theirs["per_task"], dtype=float)
    if u.shape != v.shape:
        return f"{len(u)} tasks here, {len(v)} there"
    off = np.flatnonzero(~np.isclose(u, v, rtol=RTOL, atol=0))
    if len(off):
        t = int(off[0])
        return f"task {t}: {_um(u[t])} here, {_um(v[t])} there"
    s, z = mine.get("shared"), theirs.get("shared")
    if (s is None) != (z is None) or (s is not None and not np.isclose(s, z, rtol=RTOL, atol=0)):
        return f"shared optimum {_um(s)} here, {_um(z)} there"
    return ""


def _settings(rows: pd.DataFrame) -> list[tuple]:
    """The distinct settings of a run's cells (:data:`COMPARED`), in row order; ``level`` is the
    samples a task of a sweep cell, else its budget, None for a planner's own (unlimited) budget."""
    d = with_case_defaults(rows)
    spt, budget = d["samples_per_task"], d["budget"]
    level = [("samples a task", _plain(s)) if _plain(s) is not None else
             ("budget", _plain(b)) if _plain(b) is not None else None for s, b in zip(spt, budget)]
    d = d.assign(level=level)
    out = [tuple(_plain(v) if k != "level" else v for k, v in zip([c for c, _ in COMPARED], vals))
           for vals in d[[c for c, _ in COMPARED]].itertuples(index=False)]
    return list(dict.fromkeys(out))


def _show(field: str, v) -> str:
    if field == "level":
        return "unlimited" if v is None else f"{v[1]} samples a task" if v[0] == "samples a task" else str(v[1])
    return str(v)


def _check_settings(paths: list[Path], rows: list[pd.DataFrame]) -> None:
    """Every run's settings lie among those of the run with the most (the protocol)."""
    settings = [_settings(r) for r in rows]
    b = max(range(len(paths)), key=lambda i: (len(settings[i]), -i))
    base = set(settings[b])
    for i, (path, mine) in enumerate(zip(paths, settings)):
        if i == b:
            continue
        for s in mine:
            pool = base
            for j, (col, name) in enumerate(COMPARED):
                if col == "level" and s[j] is None:  # its own budget: at every budget of the problem
                    continue
                match = {p for p in pool if p[j] == s[j]}
                if not match:
                    where = ", ".join(f"{n} {_show(c, s[k])}" for k, (c, n) in enumerate(COMPARED[:j])
                                      if s[k] is not None or c == "level")
                    have = ", ".join(sorted({_show(col, p[j]) for p in pool}, key=str))
                    raise CaseError(str(path), "", f"not comparable with {paths[b]}: cells at {name} "
                                    f"{_show(col, s[j])}" + (f" ({where})" if where else "")
                                    + f", where {paths[b]} has {name} {have}")
                pool = match


def _check_labels(paths: list[Path], rows: list[pd.DataFrame]) -> None:
    """A label names one planner and config in every run (and one full config, where both runs record
    its hash: a planner whose defaults changed between the runs is another planner)."""
    seen: dict[str, tuple[Path, str, set]] = {}
    for path, r in zip(paths, rows):
        for label, g in r.groupby("label", sort=True):
            what = f"{g['planner'].iloc[0]} ({config_text(g['config'].iloc[0]) or 'default'})"
            hashes = {h for h in g["config_hash"] if isinstance(h, str) and h}
            if label not in seen:
                seen[label] = (path, what, hashes)
                continue
            other, was, had = seen[label]
            if was != what or (hashes and had and hashes != had):
                here, there = (what, was) if was != what else (f"config hash {', '.join(sorted(hashes))}",
                                                              f"{', '.join(sorted(had))}")
                raise CaseError(str(path), "", f"label '{label}' is {here} here and {there} in {other}: "
                                "labels collide; give one of the matrix entries a label of its own")


def run_names(paths: list[Path]) -> list[str]:
    """Each run's matrix name (its directory's name where the matrix has none)."""
    import tomllib

    out = []
    for p in paths:
        try:
            out.append(tomllib.loads((p / "matrix.toml").read_text()).get("name", p.name))
        except (OSError, ValueError):
            out.append(p.name)
    return out

