"""``fixbench export``: a run directory in the formats other benchmarking tools read.

Why: fixbench's own report (:mod:`fixbench.bench.reporting.report`) is one view of a run; IOHanalyzer (fixed-target
and fixed-budget runtime statistics, ERT, ECDFs), marl-eval (BenchMARL's rliable-based aggregation)
and any spreadsheet or R session are others. Everything is read back through the results store
(rows: :func:`fixbench.bench.records.rows.load_rows`; anytime traces, learners' curves:
:mod:`fixbench.bench.records.store`); nothing is recomputed.

Formats (``export_run(run_dir, fmt, out)``; ``out`` is a folder, see "Writing" below):

``iohprofiler``
    IOHprofiler's layout (what IOHexperimenter's Analyzer logger writes and IOHanalyzer reads),
    one folder per *algorithm* (the planner's label, as in the report) because IOHanalyzer groups
    runs by the ``algId`` of an index file::

        OUT/<algorithm>/IOHprofiler_f<id>_<name>.info
        OUT/<algorithm>/data_f<id>_<name>/IOHprofiler_f<id>_DIM<agents>.dat

    A *problem* (function) is what a cell ran on: case x material x agents x mode x task set
    (``n_tasks``; held-out cells also ``heldout_every``: :func:`fixbench.bench.records.rows.track_of`);
    its name reads
    ``<case>-<material>-a<agents>-t<n_tasks>-<mode>`` and its id is a number made from the name
    (:func:`function_id`), so that one problem keeps its id in every export, whichever other
    problems a run holds. DIM is the number of agents,
    one run per cell (seed), instance 1 for every run (seeds change the planner, not the problem),
    minimisation (``maximization = "F"``). The ``.info`` file is IOHexperimenter's three lines per
    dimension: the header (``suite = "fixbench", funcId, funcName, DIM, maximization, algId,
    algInfo``, the experiment attributes ``case, material, mode, n_tasks``, and
    ``dynamicAttribute = "seed"``: IOHexperimenter's way of naming a per-run value), a ``%``
    comment line saying what the objective is, and the data file with one
    ``1:<evaluations>|<final best>;<seed>`` entry per run. The format has no dedicated field for a
    known optimum: the regret reference (rows' ``reference_objective_m``: the proven optimum or the
    best known) is the header attribute ``reference_objective_m`` (with ``reference_proven``), and
    the comment line repeats it. The ``.dat`` file has one block per run, in the order of the
    ``.info`` entries: the header line ``evaluations raw_y`` (unquoted, as IOHexperimenter's
    Analyzer writes it; :func:`read_iohprofiler` also reads the quoted headers of older files),
    then one line per improvement of the best-so-far, ending with the run's last evaluation
    (IOHanalyzer needs that line for its expected running times).

    Evaluations are samples; raw_y is the cell's objective in metres as its anytime trace records
    it. *What best-so-far means for a whole cell* (the trace is per task, and most planners solve
    the tasks one after another, so at any moment in real order most tasks have no layout yet):

    - per-task cells: the cell is read **at equal effort per task**: after ``k`` samples on every
      task (fewer where a task got fewer in all), the best-so-far is the mean over the cell's tasks
      of each task's best max deformation after its first ``k`` samples, and the evaluation count
      is the samples that takes, ``sum_t min(k, n_t)``. This is the report's per-task anytime
      curve averaged over tasks; it ends at all samples spent and the mean of the per-task bests.
      For planners that return their best layouts that end is the row's ``objective_m``; the
      learners return their policy's layouts, so their curve ends at the mean of the best layouts
      seen in training, at or below ``objective_m``. A planner that transfers layouts between tasks
      had, at "k samples on every task", already finished the earlier tasks: its curve is the
      same reading as the report's, not a replay of what it knew then.
    - shared cells: the trace's whole-cell rows (task -1: the worst task of the best shared layout
      so far, against all samples spent) as they are.
    - held-out cells: the objective is taken on tasks that cost no sample, so there is no anytime
      curve: one line, all samples spent (training) and the row's ``objective_m``.

    Samples a planner spent outside ``evaluate`` (``qp`` reads compliance columns, one sample each)
    are not in the trace: the block's last line is at the row's ``samples`` all the same.
    :func:`read_iohprofiler` reads such a folder back (runs as a DataFrame).

``marl-eval``
    One JSON file, ``OUT/marl_eval.json``, in marl-eval's raw-data layout: environment (the case)
    -> task (``<material>-a<agents>-t<n_tasks>-<mode>``) -> algorithm (label) -> run
    (``seed_<seed>``) -> ``step_<k>`` entries and ``absolute_metrics``, every metric a list of
    values. Steps are the learners' training curves (:func:`fixbench.bench.records.store.load_curves`)
    that have one value an episode (curves named ``episode_*``): ``step_<k>`` holds the value of
    episode k and ``step_count``, the samples (environment steps) spent by the end of that episode.
    Curves with other lengths (per step, per task, per agent) are left out. ``absolute_metrics``
    holds, for every planner, ``mean_max_deformation_m``, ``objective_m`` and
    ``relative_regret`` of the row (lists of one value; lower is better for all three, which
    marl-eval does not know: negate them if a plot needs "higher is better"). Strict JSON: a number
    that is not there is ``null``.

``csv``
    ``OUT/rows.csv`` (one row per finished cell as the run stores it,
    :func:`fixbench.bench.records.rows.load_results`: the columns of ``ROW_SCHEMA``, NaN as an empty
    field, a label only where the matrix entry gives one, the JSON columns (config, per-task values,
    layouts, info, provenance) as JSON text),
    ``OUT/traces.csv`` (``cell, task, task_samples, samples, best``) and, when the run has learners,
    ``OUT/curves.csv`` (``cell, curve, index, value``).

Cells whose row carries an error are left out of every format but ``csv`` (which keeps all rows);
IOHprofiler also leaves out cells that spent no sample (IOHanalyzer drops runs of zero
evaluations). The summary :func:`export_run` returns counts them.

Writing: the whole folder is built in a temporary folder beside ``out`` and renamed into place, so
a reader never sees half an export. An existing ``out`` is replaced only when it is empty or an
earlier export (it holds the marker file ``.fixbench-export``); anything else is refused.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd

from fixbench.bench.records.rows import JSON_COLUMNS, ROW_SCHEMA, load_results, load_rows, track_of
from fixbench.bench.records.store import TRACE_COLUMNS, json_text, load_curves, load_traces
from fixbench.cases.errors import CaseError, FixbenchError

FORMATS = ("iohprofiler", "marl-eval", "csv")
MARKER = ".fixbench-export"
DAT_HEADER = "evaluations raw_y"
SUITE = "fixbench"
MARL_EVAL_FILE = "marl_eval.json"
#: row columns exported as marl-eval absolute metrics (all in metres or a ratio; lower is better)
ABSOLUTE_METRICS = ("mean_max_deformation_m", "objective_m", "relative_regret")
#: learners' curves with one value an episode (nashq / iql name them so)
EPISODE_CURVE = re.compile(r"^episode_")


# reading the run ------------------------------------------------------------------------------------

def _run_dir(run_dir: str | Path) -> Path:
    """``run_dir``, or a one-line error if it is not a run directory."""
    run_dir = Path(run_dir)
    if not (run_dir / "rows").is_dir():
        raise CaseError(str(run_dir), "", "not a run directory (no rows/ folder; `fixbench run` writes one)")
    return run_dir


def _some(rows: pd.DataFrame, run_dir: Path) -> pd.DataFrame:
    if rows.empty:
        raise CaseError(str(run_dir), "rows", "no finished cell to export")
    return rows


def load_run(run_dir: str | Path) -> pd.DataFrame:
    """The finished rows of ``run_dir`` (:func:`fixbench.bench.records.rows.load_rows`) with ``algorithm``
    (how formats name a planner entry) and ``problem`` (the key of what the cell ran on); one-line error if
    it is not a run directory."""
    run_dir = _run_dir(run_dir)
    rows = _some(load_rows(run_dir), run_dir)
    rows["problem"] = [_problem_key(r) for r in rows.itertuples(index=False)]
    rows["algorithm"] = _algorithm_names(rows)
    return rows


def _problem_key(r) -> tuple:
    """One exported problem: the row's :func:`~fixbench.bench.records.rows.track_of` (its problem and
    held-out level, 0: none), since other tools cannot tell the tracks apart by mode alone."""
    case, material, agents, n_tasks, mode, k = track_of(r._asdict())
    return (str(case), str(material), _int(agents), _int(n_tasks), str(mode), k)


def _problem_name(key: tuple, with_case: bool = True) -> str:
    case, material, agents, n_tasks, mode, k = key
    parts = ([_slug(case)] if with_case else []) + [_slug(material), f"a{agents}", f"t{n_tasks}", mode]
    return "-".join(parts + ([f"k{k}"] if k else []))


def _algorithm_names(rows: pd.DataFrame) -> list[str]:
    """The report's label (``label``: :func:`fixbench.bench.records.rows.entry_labels`); where one label
    ran on a problem under several budgets (a sweep), the budget is added: ``random @10/task``,
    ``random @600``."""
    base = list(rows["label"])
    effort = [f"@{_num(s)}/task" if not _nan(s) else (f"@{_num(b)}" if not _nan(b) else "@unlimited")
              for s, b in zip(rows["samples_per_task"], rows["budget"])]
    counts = pd.DataFrame({"p": rows["problem"], "b": base, "e": effort}).groupby(["p", "b"])["e"].nunique()
    return [f"{b} {e}" if counts[(p, b)] > 1 else b for p, b, e in zip(rows["problem"], base, effort)]


def _nan(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _int(v) -> int:
    return 0 if _nan(v) else int(v)


def _num(v) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def _slug(text: str) -> str:
    """A file-name-safe name (letters, digits, ``_ . + -``); a case given as a path keeps its stem."""
    if text.endswith(".toml") or "/" in text:
        text = Path(text).stem
    return re.sub(r"[^A-Za-z0-9_.+-]+", "-", text).strip("-") or "x"


# the anytime curve of one cell ---------------------------------------------------------------------

def cell_curve(row, trace: pd.DataFrame) -> list[tuple[int, float]]:
    """(evaluations, best-so-far in metres) at each improvement, ending with the row's last sample
    (see the module docstring for what best-so-far means per mode). ``trace``: the cell's trace."""
    samples = _int(row.samples)
    if row.mode == "held-out" or trace.empty:
        return [(samples, float(row.objective_m))]
    if row.mode == "shared":
        tr = trace[trace["task"] < 0].sort_values("samples", kind="stable")
        x, y = tr["samples"].to_numpy(dtype=np.int64), np.minimum.accumulate(tr["best"].to_numpy(dtype=float))
    else:
        x, y = _equal_effort(trace[trace["task"] >= 0], _int(row.n_tasks))
        if not len(x):  # a task the planner never evaluated: no mean over all tasks exists
            return [(samples, float(row.objective_m))]
    keep = np.isfinite(y)
    x, y = x[keep], y[keep]
    curve: list[tuple[int, float]] = []
    for xi, yi in zip(x.tolist(), y.tolist()):
        if not curve or yi < curve[-1][1]:
            if curve and curve[-1][0] == xi:
                curve[-1] = (xi, yi)
            else:
                curve.append((xi, yi))
    if not curve:
        return [(samples, float(row.objective_m))]
    if curve[-1][0] < samples:
        curve.append((samples, curve[-1][1]))
    return curve


def _equal_effort(trace: pd.DataFrame, n_tasks: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-task traces read at equal effort per task: for each k in the union of the task-sample
    counts, (sum_t min(k, n_t), mean_t best_t after k samples); empty unless every task appears."""
    groups = [(g["task_samples"].to_numpy(dtype=np.int64), g["best"].to_numpy(dtype=float))
              for _, g in trace.sort_values(["task", "task_samples"], kind="stable").groupby("task", sort=True)]
    if not groups or len(groups) < n_tasks:
        return np.empty(0, dtype=np.int64), np.empty(0)
    ks = np.unique(np.concatenate([s for s, _ in groups]))
    total = np.zeros(len(ks))
    evals = np.zeros(len(ks), dtype=np.int64)
    for s, b in groups:
        pos = np.searchsorted(s, ks, side="right") - 1
        total += np.where(pos >= 0, np.minimum.accumulate(b)[np.maximum(pos, 0)], np.inf)
        evals += np.minimum(ks, s[-1])
    return evals, total / len(groups)


# IOHprofiler ----------------------------------------------------------------------------------------

def _quoted(value) -> str:
    text = str(value).replace('"', "'").replace("\n", " ")
    return f'"{text}"'


def _float(v: float) -> str:
    return repr(float(v))


def write_iohprofiler(rows: pd.DataFrame, traces: pd.DataFrame, out: Path) -> dict:
    """Write the IOHprofiler folders of ``rows`` into ``out`` (see the module docstring)."""
    skipped: Counter = Counter()
    ok = rows[rows["error"] == ""]
    skipped["failed"] = len(rows) - len(ok)
    zero = ok["samples"].fillna(0) <= 0
    skipped["no samples"] = int(zero.sum())
    ok = ok[~zero]
    by_cell = {c: g for c, g in traces.groupby("cell", sort=False)} if not traces.empty else {}
    empty = pd.DataFrame(columns=list(TRACE_COLUMNS))
    fids = {key: function_id(_problem_name(key)) for key in set(ok["problem"])}
    if len(set(fids.values())) < len(fids):  # 1 in ~10^7 for two problems: say so rather than merge them
        raise FixbenchError("two problems of this run share an IOHprofiler function id: "
                            + ", ".join(sorted(_problem_name(k) for k in fids)))
    folders: dict[str, str] = {}
    runs = 0
    for alg in sorted(set(ok["algorithm"])):
        folder = _slug(alg)
        while folder in folders.values():
            folder += "_"
        folders[alg] = folder
        mine = ok[ok["algorithm"] == alg]
        for key in sorted(set(mine["problem"]), key=str):
            cells = mine[mine["problem"] == key].sort_values(["seed", "cell"], kind="stable")
            fid, name = fids[key], _problem_name(key)
            case, material, agents, n_tasks, mode, k = key
            data_rel = f"data_f{fid}_{name}/IOHprofiler_f{fid}_DIM{agents}.dat"
            entries, blocks = [], []
            for r in cells.itertuples(index=False):
                curve = cell_curve(r, by_cell.get(r.cell, empty))
                blocks.append("\n".join([DAT_HEADER] + [f"{e} {_float(v)}" for e, v in curve]))
                entries.append(f"1:{curve[-1][0]}|{_float(curve[-1][1])};{_int(r.seed)}")
            refs = sorted({float(v) for v in cells["reference_objective_m"] if not _nan(v)})
            proven = sorted({bool(v) for v in cells["reference_proven"] if isinstance(v, (bool, np.bool_))})
            planners = sorted(set(cells["planner"]))
            header = ", ".join([
                f"suite = {_quoted(SUITE)}", f"funcId = {fid}", f"funcName = {_quoted(name)}",
                f"DIM = {agents}", 'maximization = "F"', f"algId = {_quoted(alg)}",
                f"algInfo = {_quoted('planner ' + ' '.join(planners))}", f"case = {_quoted(case)}",
                f"material = {_quoted(material)}", f"mode = {_quoted(mode)}", f"n_tasks = {n_tasks}"]
                + ([f"reference_objective_m = {_float(refs[0])}",
                    f"reference_proven = {_quoted('T' if proven == [True] else 'F')}"] if len(refs) == 1 else [])
                + ['dynamicAttribute = "seed"'])
            what = ("worst task's max |u|" if mode == "shared" else
                    f"mean over the held-out tasks (training on every {k}-th task) of max |u|" if mode == "held-out"
                    else "mean over tasks of max |u|")
            ref = (f"reference_objective_m={_float(refs[0])}" if len(refs) == 1 else
                   "reference_objective_m=" + ("none" if not refs else "varies:" + ";".join(map(_float, refs))))
            comment = (f"% objective: {what} (m), minimised; evaluations: samples; {ref} "
                       f"({'proven optimum' if proven == [True] else 'best known'}); runs: one per seed")
            info = out / folder / f"IOHprofiler_f{fid}_{name}.info"
            info.parent.mkdir(parents=True, exist_ok=True)
            info.write_text(f"{header}\n{comment}\n{data_rel}, {', '.join(entries)}\n", encoding="utf-8")
            dat = out / folder / data_rel
            dat.parent.mkdir(parents=True, exist_ok=True)
            dat.write_text("\n".join(blocks) + "\n", encoding="utf-8")
            runs += len(entries)
    return {"problems": len(fids), "algorithms": len(folders), "runs": runs,
            "skipped": {k: v for k, v in skipped.items() if v}}


def function_id(name: str) -> int:
    """The IOHprofiler function id of a problem: the first 7 hex digits of the SHA-1 of its name,
    plus one (1 .. 2^28): stable across runs and exports."""
    return int(hashlib.sha1(name.encode()).hexdigest()[:7], 16) + 1


def _split_pairs(line: str) -> dict:
    """``key = value, key = "quoted, value"`` -> dict (numbers as numbers, quotes removed)."""
    out, buf, quote = {}, "", None
    for ch in line + ",":
        if quote:
            quote = None if ch == quote else quote
            buf += ch
        elif ch in "\"'":
            quote = ch
            buf += ch
        elif ch == ",":
            key, sep, value = buf.partition("=")
            if sep:
                value = value.strip()
                if value[:1] in "\"'" and value[-1:] == value[:1]:
                    out[key.strip()] = value[1:-1]
                else:
                    try:
                        out[key.strip()] = int(value)
                    except ValueError:
                        try:
                            out[key.strip()] = float(value)
                        except ValueError:
                            out[key.strip()] = value
            buf = ""
        else:
            buf += ch
    return out


def read_iohprofiler(folder: str | Path) -> pd.DataFrame:
    """Every run of an IOHprofiler folder (``.info`` files found recursively, the layout written
    here and by IOHexperimenter): one row per run with the header's fields (``algId``, ``funcId``,
    ``funcName``, ``DIM``, ...), ``comment``, ``reference_objective_m`` (the header's, else the
    comment's, NaN if none), ``instance``, ``evaluations`` and ``best`` (the ``.info`` entry),
    ``seed`` (the dynamic attribute, when there is one) and ``curve``: the run's ``.dat`` block as
    (evaluations, raw_y) pairs."""
    folder = Path(folder)
    recs = []
    for info in sorted(folder.rglob("*.info")):
        lines = info.read_text(encoding="utf-8").splitlines()
        for i in range(0, len(lines) - 2, 3):
            header, comment, data = _split_pairs(lines[i]), lines[i + 1], lines[i + 2]
            parts = [p.strip() for p in data.split(",") if p.strip()]
            dat = info.parent / parts[0]
            blocks = _read_dat(dat)
            if len(blocks) != len(parts) - 1:
                raise FixbenchError(f"{dat}: {len(blocks)} run blocks, {info} lists {len(parts) - 1} runs")
            m = re.search(r"reference_objective_m=([0-9.eE+-]+)", comment)
            ref = float(header["reference_objective_m"]) if "reference_objective_m" in header else (
                float(m.group(1)) if m else math.nan)
            for entry, curve in zip(parts[1:], blocks):
                inst, _, rest = entry.partition(":")
                evals, _, fv = rest.partition("|")
                fv, _, attr = fv.partition(";")
                recs.append({**header, "comment": comment, "info_file": str(info.relative_to(folder)),
                             "reference_objective_m": ref,
                             "instance": int(inst), "evaluations": int(evals), "best": float(fv),
                             "seed": int(attr) if attr else None, "curve": curve})
    return pd.DataFrame(recs)


def _read_dat(path: Path) -> list[list[tuple[int, float]]]:
    blocks: list[list[tuple[int, float]]] = []
    for line in path.read_text(encoding="utf-8").splitlines():
        fields = line.split()
        if not fields:
            continue
        if not re.match(r"^[0-9.eE+-]+$", fields[0]):  # a block's header line (quoted in old files)
            blocks.append([])
        else:
            blocks[-1].append((int(float(fields[0])), float(fields[1])))
    return blocks


# marl-eval ------------------------------------------------------------------------------------------

def marl_eval_data(rows: pd.DataFrame, curves: pd.DataFrame) -> tuple[dict, dict]:
    """marl-eval's nested dict of ``rows`` (and the learners' curves) and a summary."""
    ok = rows[rows["error"] == ""].sort_values(["case", "problem", "algorithm", "seed", "cell"], kind="stable")
    by_cell = {c: g for c, g in curves.groupby("cell", sort=False)} if not curves.empty else {}
    data: dict = {}
    n_runs = n_steps = 0
    for r in ok.itertuples(index=False):
        task = _problem_name(r.problem, with_case=False)
        runs = data.setdefault(_slug(r.case), {}).setdefault(task, {}).setdefault(r.algorithm, {})
        run: dict = {}
        steps = _episode_steps(by_cell.get(r.cell), _int(r.samples))
        for k, entry in enumerate(steps):
            run[f"step_{k}"] = entry
        run["absolute_metrics"] = {m: [_finite(getattr(r, m))] for m in ABSOLUTE_METRICS}
        runs[f"seed_{_int(r.seed)}"] = run
        n_runs += 1
        n_steps += len(steps)
    summary = {"environments": len(data), "runs": n_runs, "steps": n_steps,
               "skipped": {"failed": int((rows["error"] != "").sum())} if (rows["error"] != "").any() else {}}
    return data, summary


def _episode_steps(curves: pd.DataFrame | None, samples: int) -> list[dict]:
    """One entry an episode: ``step_count`` (samples spent by its end) and each ``episode_*`` curve."""
    if curves is None or curves.empty:
        return []
    per_ep = {name: g.sort_values("index")["value"].to_numpy(dtype=float)
              for name, g in curves.groupby("curve", sort=True) if EPISODE_CURVE.match(str(name))}
    if not per_ep:
        return []
    n = max(len(v) for v in per_ep.values())
    per_ep = {k: v for k, v in per_ep.items() if len(v) == n}
    per_episode = samples / n
    return [{"step_count": int(round(per_episode * (k + 1))),
             **{name: [_finite(v[k])] for name, v in per_ep.items()}} for k in range(n)]


def _finite(v):
    v = None if v is None else float(v)
    return v if v is not None and math.isfinite(v) else None


def strict_json(data) -> str:
    """JSON that RFC 8259 parsers accept (``allow_nan=False``: a NaN that slipped through raises)."""
    return json.dumps(data, indent=1, allow_nan=False) + "\n"


# CSV ------------------------------------------------------------------------------------------------

def write_csv(rows: pd.DataFrame, traces: pd.DataFrame, curves: pd.DataFrame, out: Path) -> dict:
    table = rows[list(ROW_SCHEMA)].copy()
    for c in JSON_COLUMNS:  # a list or object in a CSV field: its JSON text
        table[c] = [json_text(v) if isinstance(v, (list, dict)) else v for v in table[c]]
    table.to_csv(out / "rows.csv", index=False)
    cols = ["cell", *TRACE_COLUMNS]
    tr = traces[cols].copy() if not traces.empty else pd.DataFrame(columns=cols)
    for c in ("task", "task_samples", "samples"):
        tr[c] = tr[c].astype(np.int64)
    tr.to_csv(out / "traces.csv", index=False)
    files = ["rows.csv", "traces.csv"]
    if not curves.empty:
        cu = curves[["cell", "curve", "index", "value"]].copy()
        cu["index"] = cu["index"].astype(np.int64)
        cu.to_csv(out / "curves.csv", index=False)
        files.append("curves.csv")
    return {"rows": len(rows), "trace_rows": len(tr), "files": files}


# the command ----------------------------------------------------------------------------------------

def export_run(run_dir: str | Path, fmt: str, out: str | Path) -> dict:
    """Export ``run_dir`` as ``fmt`` into the folder ``out`` (built aside, renamed into place);
    returns a summary (counts, and cells skipped by reason)."""
    if fmt not in FORMATS:
        raise CaseError("--format", fmt, f"unknown format (known: {', '.join(FORMATS)})")
    run_dir, out = _run_dir(run_dir), Path(out)
    rows = _some(load_results(run_dir), run_dir) if fmt == "csv" else load_run(run_dir)
    _check_out(out)
    with _building(out) as tmp:
        if fmt == "iohprofiler":
            summary = write_iohprofiler(rows, load_traces(run_dir), tmp)
        elif fmt == "marl-eval":
            data, summary = marl_eval_data(rows, load_curves(run_dir))
            (tmp / MARL_EVAL_FILE).write_text(strict_json(data), encoding="utf-8")
        else:
            summary = write_csv(rows, load_traces(run_dir), load_curves(run_dir), tmp)
        (tmp / MARKER).write_text(f"fixbench export, format {fmt}, of {run_dir.resolve()}\n", encoding="utf-8")
    return {"format": fmt, "out": str(out), **summary}


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise CaseError(str(out), "", "exists and is not a folder; choose another --out")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).is_file():
        raise CaseError(str(out), "", "exists and is not an earlier fixbench export (no "
                        f"{MARKER} in it); choose another --out")


@contextlib.contextmanager
def _building(out: Path):
    """A temporary folder beside ``out``, renamed onto it when the block succeeds (an earlier export
    there is moved aside first and then removed); removed on any failure."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp"))
    aside = None
    try:
        yield tmp
        if out.exists():
            aside = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".old"))
            os.replace(out, aside / "export")
        os.replace(tmp, out)
    except BaseException:
        if aside is not None and not out.exists():  # put the earlier export back
            os.replace(aside / "export", out)
        shutil.rmtree(tmp, ignore_errors=True)
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
        raise
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)
