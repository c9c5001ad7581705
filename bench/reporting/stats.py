"""Statistics of the report: interval estimates and the aggregations of a run's rows and traces.

Interval estimates (docs/reporting.md): percentile-bootstrap confidence intervals, stratified
(rliable) in :func:`bootstrap_ci`, plain (``scipy.stats.bootstrap``) in :func:`mean_ci` and
:func:`probability_of_improvement`; the interquartile mean. Every interval uses a fresh generator
seeded with ``BOOT_SEED``, so the same rows always give the same numbers whatever the call order.

Aggregations: each (problem, task)'s optimum (:func:`optima`), the best-so-far gap traces and their
runtimes to a target (COCO), and Dolan-More performance profiles.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.stats import bootstrap, mannwhitneyu, trim_mean
from scipy.stats import t as t_dist

from fixbench.bench.records.rows import PROFILE_PROBLEM, VARIED_SETTINGS, problem_of, reference_of

#: the bootstrap's seed, resamples and confidence level
BOOT_SEED = 20250101
N_BOOT = 2000
LEVEL = 0.95
#: runtime-to-target targets: relative gaps above the optimum (COCO)
TARGETS = (0.01, 0.02, 0.05, 0.10, 0.20)


# interval statistics ---------------------------------------------------------------------------------

def iqm(x, axis=None):
    """Interquartile mean (rliable): the mean of the middle 50 %."""
    return trim_mean(x, 0.25, axis=axis)


def bootstrap_ci(values, strata=None, stat=np.mean, n_boot: int = N_BOOT, seed: int = BOOT_SEED,
                 level: float = LEVEL) -> tuple[float, float, float]:
    """Point estimate and percentile-bootstrap CI of ``stat``; NaNs are dropped.

    With ``strata`` the resampling is stratified (rliable): each stratum is resampled within
    itself. ``stat`` takes an array and ``axis``. A fresh generator with a fixed seed per call
    keeps results independent of the call order.
    """
    x = np.asarray(values, dtype=float)
    s = np.zeros(len(x), dtype=int) if strata is None else pd.factorize(pd.Series(list(strata)))[0]
    keep = np.isfinite(x)
    x, s = x[keep], s[keep]
    if len(x) == 0:
        return math.nan, math.nan, math.nan
    point = float(stat(x))
    if len(x) == 1:
        return point, point, point
    rng = np.random.default_rng(seed)
    parts = []
    for g in np.unique(s):
        idx = np.flatnonzero(s == g)
        parts.append(idx[rng.integers(0, len(idx), (n_boot, len(idx)))])
    boot = stat(x[np.concatenate(parts, axis=1)], axis=1)
    a = (1 - level) / 2
    lo, hi = np.quantile(boot, [a, 1 - a])
    return point, float(lo), float(hi)


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


def prediction_interval(values, level: float = LEVEL) -> tuple[float, float]:
    """Where one more value of the population ``values`` were drawn from falls with probability
    ``level``: mean +- t s sqrt(1 + 1/n) (normal model, Student's t with n - 1 degrees of freedom); NaNs
    dropped, (NaN, NaN) with fewer than 2 values. The interval one rerun of a cell is judged by
    (``fixbench verify``): a confidence interval of the mean (:func:`bootstrap_ci`) says where the mean
    lies, about sqrt(n) times narrower than the spread of single values, and leaves out committed
    values of the group's own seeds."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) < 2:
        return math.nan, math.nan
    half = t_dist.ppf((1 + level) / 2, len(x) - 1) * x.std(ddof=1) * math.sqrt(1 + 1 / len(x))
    return float(x.mean() - half), float(x.mean() + half)


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


# rows, references and traces -------------------------------------------------------------------------

def optima(ok: pd.DataFrame, traces: pd.DataFrame, refs: dict) -> tuple[dict, bool]:
    """Optimum per (problem, task): the reference's, or else the best value seen in the run
    (traces and final rows). Returns the dict and whether any fallback was used."""
    out: dict[tuple, float] = {}
    fallback = False
    if traces.empty or ok.empty:
        return out, fallback
    info = ok.set_index("cell")
    pkey = {c: problem_of(r) for c, r in info.iterrows()}
    tr = traces[traces["cell"].isin(info.index)]
    seen = tr.assign(pk=tr["cell"].map(pkey)).groupby(["pk", "task"])["best"].min()
    for cell, task in tr[["cell", "task"]].drop_duplicates().sort_values(["cell", "task"]).itertuples(
            index=False):
        row = info.loc[cell]
        pk = pkey[cell]
        key = (pk, int(task))
        if key in out:
            continue
        ref = refs.get(reference_of(row))
        val = None
        if ref is not None:
            if row["mode"] == "shared":
                val = ref.get("shared")
            elif 0 <= int(task) < len(ref["per_task"]):
                val = ref["per_task"][int(task)]
        if val is None:
            fallback = True
            val = float(seen.loc[(pk, task)])
        out[key] = float(val)
    return out, fallback


def gap_traces(ok: pd.DataFrame, traces: pd.DataFrame, opt: dict) -> list[dict]:
    """One record per (cell, task): samples and relative gap best/opt - 1 (clipped at 0), with the
    cell's planner, label and case."""
    info = ok.set_index("cell")
    out = []
    tr = traces[traces["cell"].isin(info.index)]
    for (cell, task), g in tr.groupby(["cell", "task"], sort=True):
        row = info.loc[cell]
        o = opt.get((problem_of(row), int(task)))
        if o is None or not o > 0:
            continue
        g = g.sort_values("task_samples", kind="stable")
        gap = np.maximum(np.minimum.accumulate(g["best"].to_numpy()) / o - 1, 0.0)
        out.append({"cell": cell, "task": int(task), "planner": row["planner"], "label": row["label"],
                    "case": row["case"], "s": g["task_samples"].to_numpy(dtype=float), "gap": gap})
    return out


def on_grid(s: np.ndarray, v: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """A step curve (value ``v`` from sample ``s`` on) read at ``grid``; NaN before its first sample."""
    pos = np.searchsorted(s, grid, side="right") - 1
    return np.where(pos >= 0, v[np.maximum(pos, 0)], np.nan)


def sample_grid(recs: list[dict]) -> np.ndarray:
    """About 200 whole sample counts, geometric from 1 to past the most samples of the gap traces."""
    top = 1.3 * max(float(r["s"].max()) for r in recs)  # a margin, so final states show
    return np.unique(np.geomspace(1, max(top, 2), 200).round())


def runtime(rec: dict, target: float) -> float:
    """Samples a gap trace took to come within ``target`` of the optimum (inf: never)."""
    hit = np.flatnonzero(rec["gap"] <= target)
    return float(rec["s"][hit[0]]) if len(hit) else math.inf


def performance_profile(ok_and_failed: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray, dict]:
    """Ratios objective / best objective per problem (:data:`~fixbench.bench.records.rows.PROFILE_PROBLEM`
    and each of :data:`~fixbench.bench.records.rows.VARIED_SETTINGS` the run varies); failed or missing runs
    have ratio inf. Returns the ratio table (problems x planners), a tau grid and rho(tau) per planner."""
    df = ok_and_failed.copy()
    df["obj"] = np.where(df["ok"], df["objective_m"], np.inf)
    keys = [*PROFILE_PROBLEM, *(k for k in VARIED_SETTINGS if df[k].nunique() > 1)]
    piv = df.pivot_table(index=keys, columns="label", values="obj", aggfunc="min", dropna=False)
    piv = piv.fillna(np.inf)
    best = piv.min(axis=1)
    piv = piv[np.isfinite(best) & (best > 0)]
    ratios = piv.div(piv.min(axis=1), axis=0)
    finite = ratios.to_numpy()[np.isfinite(ratios.to_numpy())]
    top = max(float(finite.max()) * 1.2 if len(finite) else 2.0, 2.0)
    taus = np.unique(np.concatenate([[1.0], np.geomspace(1, top, 300), np.sort(finite)]))
    rho = {lab: (ratios[lab].to_numpy()[None, :] <= taus[:, None]).mean(axis=1) for lab in ratios.columns}
    return ratios, taus, rho
