"""The comparison fixbench exists for: planners (MARL and classical) at equal samples.

:func:`fixbench.bench.report.make_report` writes these as report sections:

    main_table          the README's main table: mean relative regret per case and mean rank over problems
    sweep_table         budget sweep: relative regret per case x planner x samples a task, with its figure
    heldout_table       held-out track: regret on the held-out tasks of learners that trained on the others,
                        beside planners that pay samples on every task, scored on the same tasks
    improvement_table   rliable's probability of improvement P(X < Y) between every ordered pair of planners

Relative regret is ``objective / reference objective - 1`` (:mod:`fixbench.bench.cells`); every statistic leaves
failed cells out (the main table's rank counts them last). Confidence intervals are 95 % percentile
bootstraps (``scipy.stats.bootstrap``, ``N_BOOT`` resamples, a fresh generator seeded with ``BOOT_SEED``
per interval), so the same rows always give the same tables.

The module also holds what :mod:`fixbench.bench.report` shares with it: number formatting, the reference key of
a row and the figure layout helpers (grid of panels, one legend per figure).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.ticker import FuncFormatter, NullLocator  # noqa: E402
from scipy.stats import bootstrap, mannwhitneyu  # noqa: E402

BOOT_SEED = 20250101
N_BOOT = 2000
LEVEL = 0.95
#: relative regrets (%) below this are drawn at it on log axes (a regret of 0 has no logarithm)
REGRET_FLOOR_PCT = 1e-3
#: columns that, with the budget level, make a problem for ranking (cells of one problem compete)
RANK_PROBLEM = ("case", "material", "seed", "agents", "n_tasks", "mode")


# shared with fixbench.bench.report ---------------------------------------------------------------------------

def fmt(v, digits: int = 3) -> str:
    """A number with ``digits`` significant digits; ``-`` for None and non-finite values."""
    if v is None or not np.isfinite(v):
        return "-"
    return f"{v:.{digits}g}"


def ci_text(p, lo, hi) -> str:
    """``point [lo, hi]``, or ``-`` without a point estimate."""
    if not np.isfinite(p):
        return "-"
    return f"{fmt(p)} [{fmt(lo)}, {fmt(hi)}]"


def setting_text(key: str, v) -> object:
    """A setting's value in a shown table: NaN budget is unlimited, NaN samples a task is a planner's
    own budget (outside the sweep), whole numbers without a decimal point."""
    if isinstance(v, float) and math.isnan(v):
        return {"budget": "unlimited", "samples_per_task": "own budget"}.get(key, "-")
    return int(v) if isinstance(v, float) and v.is_integer() else v


def ref_key(row) -> tuple | None:
    """The key of a row's regret reference in :func:`fixbench.bench.report.load_references`:
    (case, material, agents, n_tasks); None when the row lacks them (a failed cell)."""
    try:
        return (row["case"], row["material"], int(row["agents"]), int(row["n_tasks"]))
    except (TypeError, ValueError):
        return None


def panel_grid(n: int, max_cols: int = 2, width: float = 10.0, row_height: float = 3.6):
    """A constrained-layout figure of ``n`` panels, at most ``max_cols`` a row, about page width;
    panels beyond ``n`` are switched off. Returns the figure and the ``n`` axes in order."""
    ncol = max(1, min(n, max_cols))
    nrow = max(1, math.ceil(n / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(width * ncol / max_cols, row_height * nrow), squeeze=False,
                             layout="constrained")
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.axis("off")
    return fig, flat[:n]


def figure_legend(fig, axes, title: str | None = None) -> None:
    """One legend for the whole figure below the panels (each label once), instead of one a panel."""
    handles: dict[str, object] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="outside lower center",
                   ncols=min(len(handles), 5), fontsize=8, title=title, title_fontsize=8, frameon=False)


# statistics -----------------------------------------------------------------------------------------

def mean_ci(values, seed: int = BOOT_SEED) -> tuple[float, float, float]:
    """Mean and its percentile-bootstrap CI (NaNs dropped); with fewer than 2 values the CI is the
    value itself (nothing to resample)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return math.nan, math.nan, math.nan
    point = float(x.mean())
    if len(x) < 2:
        return point, point, point
    res = bootstrap((x,), np.mean, n_resamples=N_BOOT, confidence_level=LEVEL, method="percentile",
                    rng=np.random.default_rng(seed))
    return point, float(res.confidence_interval.low), float(res.confidence_interval.high)


def _p_lower(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """P(X < Y) from the Mann-Whitney U of (y, x): U counts the pairs with y > x, ties 1/2."""
    u = mannwhitneyu(y, x, axis=axis, method="asymptotic").statistic
    return u / (x.shape[axis] * y.shape[axis])


def probability_of_improvement(x, y, seed: int = BOOT_SEED) -> tuple[float, float, float]:
    """rliable's probability of improvement of X over Y for regrets (lower is better): the chance that
    a random value of ``x`` is below a random value of ``y``, ties counting 1/2, with its bootstrap CI
    (both samples resampled independently). NaNs are dropped; NaN without values, and the point itself
    as CI when a sample has fewer than 2 values."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if len(x) == 0 or len(y) == 0:
        return math.nan, math.nan, math.nan
    point = float(_p_lower(x, y))
    if len(x) < 2 or len(y) < 2:
        return point, point, point
    res = bootstrap((x, y), _p_lower, n_resamples=N_BOOT, confidence_level=LEVEL, method="percentile",
                    vectorized=True, rng=np.random.default_rng(seed))
    return point, float(res.confidence_interval.low), float(res.confidence_interval.high)


def _scored(rows: pd.DataFrame) -> pd.DataFrame:
    """Successful rows with a finite relative regret, with ``regret_pct`` (%)."""
    ok = rows[rows["ok"] & np.isfinite(rows["relative_regret"])]
    return ok.assign(regret_pct=ok["relative_regret"] * 100)


def _regret_stats(values) -> dict:
    p, lo, hi = mean_ci(values)
    return {"regret_pct": p, "regret_pct_lo": lo, "regret_pct_hi": hi}


def _ci_column(df: pd.DataFrame, name: str) -> list[str]:
    return [ci_text(p, lo, hi) for p, lo, hi in zip(df[name], df[f"{name}_lo"], df[f"{name}_hi"])]


# the budget sweep -----------------------------------------------------------------------------------

def sweep_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Budget sweep: per case x planner label x samples a task, the mean relative regret (%) of the
    per-task-mode cells with its 95 % CI, and the number of cells (failed ones left out)."""
    d = _scored(rows)
    d = d[(d["mode"] == "per-task") & np.isfinite(d["samples_per_task"])]
    recs = []
    for (case, label, spt), g in d.groupby(["case", "label", "samples_per_task"], sort=True):
        recs.append({"case": case, "planner": label, "samples_per_task": int(spt), "cells": len(g),
                     **_regret_stats(g["regret_pct"])})
    return pd.DataFrame(recs, columns=["case", "planner", "samples_per_task", "cells", "regret_pct",
                                       "regret_pct_lo", "regret_pct_hi"])


def show_sweep(table: pd.DataFrame) -> pd.DataFrame:
    """The sweep table formatted for Markdown and LaTeX."""
    return pd.DataFrame({"case": table["case"], "planner": table["planner"],
                         "samples a task": table["samples_per_task"], "cells": table["cells"],
                         "regret (%)": _ci_column(table, "regret_pct")})


def sweep_figure(table: pd.DataFrame, colors: dict):
    """Relative regret (%) against samples a task, one panel a case (log-log; each panel its own
    scales), a line with markers a planner and its 95 % CI as a band; one legend for the figure."""
    cases = list(dict.fromkeys(table["case"]))
    fig, axes = panel_grid(len(cases), row_height=3.5)
    for ax, case in zip(axes, cases):
        sub = table[table["case"] == case]
        for label, g in sub.groupby("planner", sort=True):
            g = g.sort_values("samples_per_task")
            x = g["samples_per_task"].to_numpy(dtype=float)
            y, lo, hi = (np.maximum(g[c].to_numpy(dtype=float), REGRET_FLOOR_PCT)
                         for c in ("regret_pct", "regret_pct_lo", "regret_pct_hi"))
            ax.plot(x, y, marker="o", ms=4, lw=1.3, color=colors[label], label=label)
            ax.fill_between(x, lo, hi, color=colors[label], alpha=0.2, lw=0)
        ticks = np.sort(sub["samples_per_task"].unique()).astype(float)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(ticks)
        ax.xaxis.set_minor_locator(NullLocator())
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_xlabel("samples per task")
        ax.set_ylabel(f"relative regret to reference (%)\n(log; below {REGRET_FLOOR_PCT:g} % drawn at it)",
                      fontsize=8)
        ax.set_title(str(case), fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
    figure_legend(fig, axes, title="planner (mean over cells, band: 95 % CI)")
    return fig


# the held-out track ---------------------------------------------------------------------------------

def heldout_tasks(n_tasks: int, every: int) -> list[int]:
    """The tasks a held-out cell acts on without samples: those not in range(0, n_tasks, every)."""
    return [t for t in range(n_tasks) if t % every]


def _heldout_regret(row, refs: dict, every: int) -> float:
    """Relative regret of a per-task row on the held-out tasks only: mean of its per-task max
    deformation over them against the reference's mean over them; NaN without either."""
    ref = refs.get(ref_key(row))
    per_task = row.get("per_task_m")
    if ref is None or not isinstance(per_task, str) or not per_task:
        return math.nan
    u = np.asarray(json.loads(per_task), dtype=float)
    opt = np.asarray(ref["per_task"], dtype=float)
    idx = heldout_tasks(int(row["n_tasks"]), every)
    if not idx or not len(u) == len(opt) == int(row["n_tasks"]):
        return math.nan
    return float(u[idx].mean() / opt[idx].mean() - 1)


def _trained_note(spt: float, every: int) -> str:
    """How a held-out line spends its samples: on tasks 0, k, 2k, ... only."""
    each = f"{spt:g} a task" if np.isfinite(spt) else "its budget"
    return f"{each} on tasks 0, {every}, {2 * every}, ...; 0 on the others"


def heldout_table(rows: pd.DataFrame, refs: dict) -> pd.DataFrame:
    """Held-out track per case and planner label: the held-out cells' mean relative regret (%) on the
    held-out tasks with its CI and the samples they spent (on the training tasks only), and beside them
    the per-task cells (which pay samples on every task) scored on the same held-out tasks, one line a
    (label, samples a task, budget). Rows without a per-task list or a reference are skipped."""
    ok = rows[rows["ok"]]
    held = _scored(ok[ok["mode"] == "held-out"])
    recs = []
    for (case, every), hc in held.groupby(["case", "heldout_every"], sort=True):
        every = int(every)
        for (label, spt), g in hc.groupby(["label", "samples_per_task"], sort=True, dropna=False):
            recs.append({"case": case, "heldout_every": every, "planner": label, "track": "held-out",
                         "samples_per_task": spt, "samples_note": _trained_note(spt, every),
                         "samples": float(g["samples"].mean()), "cells": len(g),
                         **_regret_stats(g["regret_pct"])})
        per = ok[(ok["case"] == case) & (ok["mode"] == "per-task")]
        per = per.assign(regret_pct=[_heldout_regret(r, refs, every) * 100 for _, r in per.iterrows()])
        per = per[np.isfinite(per["regret_pct"])]
        for (label, spt, _budget), g in per.groupby(["label", "samples_per_task", "budget"], sort=True,
                                                    dropna=False):
            pays = spt if np.isfinite(spt) else float((g["samples"] / g["n_tasks"]).mean())
            recs.append({"case": case, "heldout_every": every, "planner": label, "track": "per-task",
                         "samples_per_task": spt, "samples_note": f"pays {fmt(pays)} a task",
                         "samples": float(g["samples"].mean()), "cells": len(g),
                         **_regret_stats(g["regret_pct"])})
    return pd.DataFrame(recs, columns=["case", "heldout_every", "planner", "track", "samples_per_task",
                                       "samples_note", "samples", "cells", "regret_pct", "regret_pct_lo",
                                       "regret_pct_hi"])


def show_heldout(table: pd.DataFrame) -> pd.DataFrame:
    """The held-out table formatted for Markdown and LaTeX."""
    return pd.DataFrame({"case": table["case"], "planner": table["planner"], "track": table["track"],
                         "samples": table["samples_note"], "samples a cell": table["samples"].map(fmt),
                         "cells": table["cells"], "regret on held-out tasks (%)": _ci_column(table, "regret_pct")})


# probability of improvement -------------------------------------------------------------------------

def improvement_table(rows: pd.DataFrame, group: Sequence[str] = ()) -> pd.DataFrame:
    """rliable's probability of improvement P(X < Y) of relative regret between every ordered pair of
    planner labels per case (and per value of the ``group`` columns, e.g. samples a task), with its 95 %
    CI and the cells of each. Each unordered pair is bootstrapped once: P(Y < X) = 1 - P(X < Y) holds in
    every resample (ties count 1/2 both ways), so the reverse line is its mirror."""
    keys = ["case", *group]
    d = _scored(rows)
    recs = []
    for gk, g in d.groupby(keys, sort=True, dropna=False):
        gk = gk if isinstance(gk, tuple) else (gk,)
        by = {lab: s.to_numpy() for lab, s in g.groupby("label", sort=True)["regret_pct"]}
        labels = list(by)
        for i, x in enumerate(labels):
            for y in labels[i + 1:]:
                p, lo, hi = probability_of_improvement(by[x], by[y])
                for a, b, pp, ll, hh in ((x, y, p, lo, hi), (y, x, 1 - p, 1 - hi, 1 - lo)):
                    recs.append({**dict(zip(keys, gk)), "X": a, "Y": b, "cells_X": len(by[a]),
                                 "cells_Y": len(by[b]), "P": pp, "P_lo": ll, "P_hi": hh})
    cols = [*keys, "X", "Y", "cells_X", "cells_Y", "P", "P_lo", "P_hi"]
    return pd.DataFrame(recs, columns=cols).sort_values([*keys, "X", "Y"], kind="stable").reset_index(drop=True)


def show_improvement(table: pd.DataFrame, group: Sequence[str] = ()) -> pd.DataFrame:
    """The probability-of-improvement table formatted for Markdown and LaTeX."""
    out = table[["case", *group, "X", "Y"]].copy()
    for k in group:
        out[k] = out[k].map(lambda v, k=k: setting_text(k, v))
    out["P(X < Y)"] = table["P"].map(fmt)
    out["95 % CI"] = [f"[{fmt(lo)}, {fmt(hi)}]" for lo, hi in zip(table["P_lo"], table["P_hi"])]
    out["cells"] = [f"{a} vs {b}" for a, b in zip(table["cells_X"], table["cells_Y"])]
    return out


# the main table -------------------------------------------------------------------------------------

def _budget_level(rows: pd.DataFrame) -> pd.Series:
    """The budget part of a problem: samples a task in a sweep run, else the cell's budget."""
    return rows["samples_per_task"] if rows["samples_per_task"].notna().any() else rows["budget"]


def _with_case_defaults(rows: pd.DataFrame) -> pd.DataFrame:
    """Rows whose problem columns are missing get their case's value where the case has one: a failed
    cell's row keeps the matrix's raw settings (no tasks count; no agents or material where the case's
    default was meant), so without this it would sit alone on a problem of its own."""
    out = rows.copy()
    for col in ("material", "agents", "n_tasks"):
        values = out.dropna(subset=[col]).groupby("case")[col].unique()
        single = {case: v[0] for case, v in values.items() if len(v) == 1}
        out[col] = out[col].fillna(out["case"].map(single))
    return out


def problem_ranks(rows: pd.DataFrame) -> pd.DataFrame:
    """Rank of each planner label on each problem (case x material x seed x agents x tasks x mode x
    budget level): 1 = lowest objective, failed cells last (ties share the mean rank). A cell without a
    budget level (a planner with its own budget, e.g. ``exact`` unlimited) competes at every level of its
    other keys; planners without a cell on a problem take no part in it."""
    keys = list(RANK_PROBLEM)
    rows = _with_case_defaults(rows)
    d = rows.assign(level=_budget_level(rows),
                    obj=np.where(rows["ok"] & np.isfinite(rows["objective_m"]), rows["objective_m"], np.inf))
    d = d[keys + ["level", "label", "obj"]]
    levelled = d[d["level"].notna()]
    own = d[d["level"].isna()]
    if len(levelled) and len(own):
        levels = levelled[keys + ["level"]].drop_duplicates()
        own = own.drop(columns="level").merge(levels, on=keys, how="left")
        d = pd.concat([levelled, own], ignore_index=True)
    best = d.groupby(keys + ["level", "label"], dropna=False, sort=True)["obj"].min().reset_index()
    best["rank"] = best.groupby(keys + ["level"], dropna=False)["obj"].rank(method="average")
    return best


def main_columns(rows: pd.DataFrame) -> list[tuple[str, str, str | None]]:
    """The main table's regret columns: (name, case, mode); one per case, or per case and mode when
    the run has several modes (per-task and held-out regrets are not the same measurement)."""
    modes = list(dict.fromkeys(rows["mode"].fillna("per-task")))
    cases = list(dict.fromkeys(rows["case"]))
    if len(modes) == 1:
        return [(case, case, None) for case in cases]
    return [(f"{case} ({mode})", case, mode) for mode in modes for case in cases]


def main_table(rows: pd.DataFrame) -> pd.DataFrame:
    """The README's main table: one line a planner label with the mean relative regret (%) on each
    case, and mode when the run has several (columns ``<name>``, ``<name>_lo``, ``<name>_hi``: 95 % CI
    over its successful cells, all budgets of the run) and the mean rank over problems
    (:func:`problem_ranks`), sorted by it."""
    ranks = problem_ranks(rows).groupby("label")["rank"].agg(["mean", "size"])
    scored = _scored(rows)
    recs = []
    for label in sorted(rows["label"].unique()):
        rec = {"planner": label}
        for name, case, mode in main_columns(rows):
            pick = (scored["label"] == label) & (scored["case"] == case)
            if mode is not None:
                pick &= scored["mode"].fillna("per-task") == mode
            p, lo, hi = mean_ci(scored.loc[pick, "regret_pct"])
            rec.update({name: p, f"{name}_lo": lo, f"{name}_hi": hi})
        rec.update(mean_rank=float(ranks.loc[label, "mean"]), problems=int(ranks.loc[label, "size"]))
        recs.append(rec)
    df = pd.DataFrame(recs)
    return df.sort_values(["mean_rank", "planner"], kind="stable").reset_index(drop=True)


def show_main(table: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """The main table formatted like README: ``mean [lo, hi]`` per column, then the mean rank."""
    out = pd.DataFrame({"planner": table["planner"]})
    for name in columns:
        out[name] = _ci_column(table, name)
    out["mean rank"] = table["mean_rank"].map(lambda v: fmt(v, 3))
    out["problems"] = table["problems"]
    return out
