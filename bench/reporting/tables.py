"""The report's per-run tables and the number formatting every table shares.

``summary_table`` (per case and planner: counts, means and IQMs with bootstrap CIs, rank),
``reference_table`` (the regret references) and ``profile_table`` (the performance profile's
summary); the comparison tables (main, sweep, held-out, probability of improvement) are in
:mod:`fixbench.bench.reporting.comparison`. Each table comes as numbers (for CSV) and formatted by a
``show_*`` function (for Markdown and LaTeX).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from fixbench.bench.records.rows import REFERENCE, VARIED_SETTINGS
from fixbench.bench.references.score import reference_bounds
from fixbench.bench.reporting.stats import bootstrap_ci, iqm
from fixbench.cases.errors import CaseError

# formatting ------------------------------------------------------------------------------------------

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


def ci_column(df: pd.DataFrame, name: str) -> list[str]:
    """Column ``name`` with its ``name_lo`` and ``name_hi`` as ``point [lo, hi]`` texts."""
    return [ci_text(p, lo, hi) for p, lo, hi in zip(df[name], df[f"{name}_lo"], df[f"{name}_hi"])]


def setting_text(key: str, v) -> object:
    """A setting's value in a shown table: NaN budget is unlimited, NaN samples a task is a planner's
    own budget (outside the sweep), whole numbers without a decimal point."""
    if isinstance(v, float) and math.isnan(v):
        return {"budget": "unlimited", "samples_per_task": "own budget"}.get(key, "-")
    return int(v) if isinstance(v, float) and v.is_integer() else v


def show_numbers(table: pd.DataFrame, digits: int = 3) -> pd.DataFrame:
    """``table`` with every float as ``fmt`` writes it (a table of plain numbers, shown)."""
    return table.map(lambda v: fmt(v, digits) if isinstance(v, float) else v)


# the per-run tables ----------------------------------------------------------------------------------

def group_keys(rows: pd.DataFrame) -> list[str]:
    """``case`` and the :data:`~fixbench.bench.records.rows.VARIED_SETTINGS` the run varies; a sweep's
    budget follows from its samples a task."""
    varied = [k for k in VARIED_SETTINGS if rows[k].nunique(dropna=True) > 1]
    if "samples_per_task" in varied:
        varied = [k for k in varied if k != "budget"]
    return ["case"] + varied


def summary_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per case (and varied setting) x planner: counts, means and IQMs with bootstrap CIs, rank."""
    keys = group_keys(rows)
    recs = []
    for gk, g in rows.groupby(keys + ["label"], sort=True, dropna=False):
        gk = gk if isinstance(gk, tuple) else (gk,)
        ok = g[g["ok"]]
        strata = list(ok[list(REFERENCE[1:])].itertuples(index=False, name=None))  # a case's problems
        rec = dict(zip(keys + ["planner"], gk))
        rec.update(cells=len(g), failed=int((~g["ok"]).sum()))
        stats = {
            "objective_um": (ok["objective_m"] * 1e6, np.mean),
            "iqm_um": (ok["objective_m"] * 1e6, iqm),
            "regret_pct": (ok["relative_regret"] * 100, np.mean),
            "regret_upper_pct": (ok["relative_regret_upper"] * 100, np.mean),
            "samples_to_1pct": (ok["samples_to_1pct"], np.mean),
            "samples_to_5pct": (ok["samples_to_5pct"], np.mean),
            "success_5pct_pct": (ok["success_5pct"] * 100, np.mean),
            "wall_s": (ok["wall_s"], np.mean),
        }
        for name, (vals, stat) in stats.items():
            rec[name], rec[f"{name}_lo"], rec[f"{name}_hi"] = bootstrap_ci(vals.to_numpy(), strata, stat)
        rec["reached_1pct"] = int(ok["samples_to_1pct"].notna().sum())
        rec["reached_5pct"] = int(ok["samples_to_5pct"].notna().sum())
        recs.append(rec)
    df = pd.DataFrame(recs)
    if df.empty:
        return df
    within = keys
    df["rank"] = df.groupby(within, dropna=False)["objective_um"].rank(method="min")
    return df


def show_summary(df: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """The summary table formatted for Markdown and LaTeX: ``mean [lo, hi]`` per statistic."""
    out = pd.DataFrame()
    for k in keys:
        out[k] = df[k].map(lambda v, k=k: setting_text(k, v))
    out["planner"] = df["planner"]
    out["cells"] = df["cells"]
    out["failed"] = df["failed"]
    out["max def. (um)"] = ci_column(df, "objective_um")
    out["IQM (um)"] = ci_column(df, "iqm_um")
    out["regret (%)"] = ci_column(df, "regret_pct")
    out["regret to bound (%)"] = ci_column(df, "regret_upper_pct")
    out["samples to 1%"] = [f"{c} ({r}/{n - f})" for c, r, n, f in
                            zip(ci_column(df, "samples_to_1pct"), df["reached_1pct"], df["cells"], df["failed"])]
    out["samples to 5%"] = [f"{c} ({r}/{n - f})" for c, r, n, f in
                            zip(ci_column(df, "samples_to_5pct"), df["reached_5pct"], df["cells"], df["failed"])]
    out["success 5% (%)"] = ci_column(df, "success_5pct_pct")
    out["wall (s)"] = ci_column(df, "wall_s")
    out["rank"] = df["rank"].map(lambda r: "-" if not np.isfinite(r) else str(int(r)))
    return out


def reference_table(refs: dict) -> pd.DataFrame:
    """One line a regret reference: its optima (mean, min, max; shared), proven or not, method, and its
    own gap: how many positions hold a certified lower bound and (reference - bound) / reference over
    them (median, worst), the most by which a regret against the reference can understate the true one."""
    recs = []
    for (case, mat, agents, n_tasks), ref in sorted(refs.items(), key=lambda kv: str(kv[0])):
        value, bound = np.asarray(ref["per_task"], dtype=float), reference_bounds(ref)
        has = np.isfinite(bound)
        gap = 100 * (1 - bound[has] / value[has])
        opt = value * 1e6
        recs.append({"case": case, "material": mat, "agents": agents, "tasks": n_tasks,
                     "mean optimum (um)": float(opt.mean()), "min (um)": float(opt.min()),
                     "max (um)": float(opt.max()),
                     "shared optimum (um)": (ref["shared"] * 1e6 if ref.get("shared") is not None
                                             else math.nan),
                     "proven": bool(ref.get("proven")), "method": ref.get("method") or "",
                     "samples": ref.get("samples"), "bounded": int(has.sum()),
                     "gap to bound, median (%)": float(np.median(gap)) if has.any() else math.nan,
                     "worst (%)": float(gap.max()) if has.any() else math.nan})
    return pd.DataFrame(recs)


def profile_table(ratios: pd.DataFrame, rho: dict) -> pd.DataFrame:
    """The performance profile's summary (:func:`fixbench.bench.reporting.stats.performance_profile`): per planner,
    the fraction of problems on which it is the best, within 1.1 and 2 of the best, failed or missing."""
    return pd.DataFrame({"planner": list(rho),
                         "problems": len(ratios),
                         "best (tau=1)": [float(rho[k][0]) for k in rho],
                         "within 1.1": [float((ratios[k] <= 1.1).mean()) for k in rho],
                         "within 2": [float((ratios[k] <= 2).mean()) for k in rho],
                         "failed or missing": [float((~np.isfinite(ratios[k])).mean()) for k in rho]})


# the README's copies of report tables -----------------------------------------------------------------

#: a README block that mirrors a report table: ``<!-- table: PATH -->`` ... ``<!-- /table -->``
TABLE_BLOCK = re.compile(r"(<!-- table: (?P<path>[^ ]+) -->\n)(?P<body>.*?)(<!-- /table -->)", re.S)


def refresh_readme(readme: str | Path, report_dir: str | Path) -> int:
    """Copy every table of ``report_dir`` that ``readme`` mirrors (its ``<!-- table: PATH -->`` blocks,
    PATH relative to the README) into it; returns how many blocks were refreshed. A block naming a
    table of this report that does not exist is an error (the README would show a stale table)."""
    readme, report_dir = Path(readme), Path(report_dir).resolve()
    text, n = readme.read_text(encoding="utf-8"), 0

    def swap(m: re.Match) -> str:
        nonlocal n
        path = (readme.parent / m["path"]).resolve()
        if report_dir not in path.parents:
            return m[0]
        if not path.is_file():
            raise CaseError(str(readme), m["path"], "the report has no such table")
        n += 1
        return m[1] + path.read_text(encoding="utf-8").rstrip("\n") + "\n" + m[4]

    new = TABLE_BLOCK.sub(swap, text)
    if new != text:
        from fixbench.cases.files import write_text_atomic

        write_text_atomic(readme, new)
    return n
