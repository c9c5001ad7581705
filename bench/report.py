"""``fixbench report``: tables and figures of a run directory (see README "Reports").

Everything is read back from the results store (:mod:`fixbench.bench.store`): rows, anytime traces,
learners' training curves and the regret references. The report folder gets

    report.md                   the tables (Markdown) and the figures (relative links)
    tables/<name>.csv|.tex|.md  every table: CSV with plain numbers, LaTeX and Markdown formatted
    figures/<name>.png|.pdf     every figure

Statistics follow the conventions of REFERENCE.md section 7: means and rliable-style interquartile
means with 95 % stratified percentile-bootstrap confidence intervals (strata: the problems, i.e.
materials, agents and task counts; resampled over seeds), COCO-style runtime-to-target ECDFs and
Dolan-More performance profiles. Cells whose row carries an error are counted in ``failed`` and left
out of every statistic. The bootstrap generator has a fixed seed and PDFs carry no creation date, so
the same run directory always gives the same report.

The comparison fixbench exists for (planners at equal samples) comes from :mod:`fixbench.bench.comparison`:
the main table (``main``: regret per case, mean rank over problems), the budget sweep (``sweep``, table
and figure), the held-out track (``heldout``) and rliable's probability of improvement
(``improvement``); a section the run has no rows for is skipped with its reason.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import seaborn as sns  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402
from scipy.stats import trim_mean  # noqa: E402

from fixbench.bench.comparison import (  # noqa: E402
    BOOT_SEED,
    N_BOOT,
    ci_text,
    figure_legend,
    fmt,
    heldout_table,
    improvement_table,
    main_columns,
    main_table,
    panel_grid,
    ref_key,
    setting_text,
    show_heldout,
    show_improvement,
    show_main,
    show_sweep,
    sweep_figure,
    sweep_table,
)
from fixbench.bench.store import load_curves, load_results, load_traces  # noqa: E402
from fixbench.cases.errors import CaseError  # noqa: E402

TARGETS = (0.01, 0.02, 0.05, 0.10, 0.20)
#: settings that split the summary into separate groups when the run varies them
SETTINGS = ("agents", "mode", "budget", "samples_per_task")
#: columns of a problem instance (cells with the same values share a regret reference)
PROBLEM = ("case", "material", "agents", "n_tasks", "mode")
NUMERIC = ("agents", "budget", "seed", "n_tasks", "objective_m", "relative_regret", "samples_to_1pct",
           "samples_to_5pct", "success_1pct", "success_5pct", "wall_s", "cpu_s", "samples",
           "reference_objective_m", "samples_per_task", "heldout_every", "n_scored_tasks")
LEARNER_CURVES = ("episode_return", "step_reward")


# statistics -----------------------------------------------------------------------------------------

def iqm(x, axis=None):
    """Interquartile mean (rliable): the mean of the middle 50 %."""
    return trim_mean(x, 0.25, axis=axis)


def _mean(x, axis=None):
    return np.mean(x, axis=axis)


def bootstrap_ci(values, strata=None, stat=_mean, n_boot: int = N_BOOT, seed: int = BOOT_SEED,
                 level: float = 0.95) -> tuple[float, float, float]:
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


# loading --------------------------------------------------------------------------------------------

def slug(text: str) -> str:
    """A file-name-safe form of a case name (which may be a path to a TOML file)."""
    name = Path(str(text)).stem if str(text).endswith(".toml") else str(text)
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "case"


def _config_text(config) -> str:
    try:
        d = json.loads(config) if isinstance(config, str) and config else {}
    except json.JSONDecodeError:
        return str(config)
    return ",".join(f"{k}={v}" for k, v in sorted(d.items()))


def load_rows(run_dir: Path) -> pd.DataFrame:
    """Rows with numeric columns coerced, ``ok`` (no error) and ``label``: the matrix entry's label
    where the row has one, else the planner (with its config when the run has one planner under several
    configs among the unlabelled rows; rows of older runs have no label column)."""
    rows = load_results(run_dir)
    for c in NUMERIC:
        rows[c] = pd.to_numeric(rows[c], errors="coerce")
    rows["error"] = rows["error"].fillna("").astype(str)
    rows["ok"] = rows["error"] == ""
    rows["mode"] = rows["mode"].fillna("per-task")
    cfg = rows["config"].map(_config_text)
    given = rows["label"].map(lambda v: v if isinstance(v, str) else "")
    several = rows[given == ""].assign(cfg=cfg).groupby("planner")["cfg"].nunique()
    rows["label"] = [g or (f"{p} ({c or 'default'})" if several.get(p, 1) > 1 else p)
                     for g, p, c in zip(given, rows["planner"], cfg)]
    return rows


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
        key = (ref.get("case"), ref.get("material"), int(ref.get("agents")), int(ref.get("n_tasks")))
        out[key] = ref
    return out


def _problem_key(row) -> tuple:
    return tuple(row[c] for c in PROBLEM)


# the report -----------------------------------------------------------------------------------------

class _Writer:
    def __init__(self, out: Path):
        self.out = out
        self.md: list[str] = []
        self.notes: list[str] = []
        self.tables: dict[str, Path] = {}
        self.figures: dict[str, Path] = {}
        (out / "tables").mkdir(parents=True, exist_ok=True)
        (out / "figures").mkdir(parents=True, exist_ok=True)

    def table(self, name: str, numeric: pd.DataFrame, shown: pd.DataFrame, explain: str) -> None:
        """CSV of the numbers; Markdown and LaTeX of the formatted table; a section in report.md."""
        base = self.out / "tables" / name
        numeric.to_csv(base.with_suffix(".csv"), index=False)
        md = shown.to_markdown(index=False)
        base.with_suffix(".md").write_text(md + "\n")
        base.with_suffix(".tex").write_text(shown.to_latex(index=False, escape=True))
        self.tables[name] = base.with_suffix(".csv")
        self.md += [explain, "", md, "",
                    f"(tables/{name}.csv, tables/{name}.tex)", ""]

    def figure(self, name: str, fig, explain: str) -> None:
        base = self.out / "figures" / name
        fig.savefig(base.with_suffix(".png"), dpi=130, metadata={"Software": None})
        fig.savefig(base.with_suffix(".pdf"), metadata={"CreationDate": None, "ModDate": None,
                                                          "Producer": None, "Creator": None})
        plt.close(fig)
        self.figures[name] = base.with_suffix(".png")
        self.md += [explain, "", f"![{name}](figures/{name}.png)", ""]

    def skip(self, what: str, why: str) -> None:
        self.notes.append(f"{what}: {why}")
        self.md += [f"*{what} skipped: {why}.*", ""]


def _group_keys(rows: pd.DataFrame) -> list[str]:
    """``case`` and the SETTINGS the run varies; a sweep's budget follows from its samples a task."""
    varied = [k for k in SETTINGS if rows[k].nunique(dropna=True) > 1]
    if "samples_per_task" in varied:
        varied = [k for k in varied if k != "budget"]
    return ["case"] + varied


def summary_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per case (and varied setting) x planner: counts, means and IQMs with bootstrap CIs, rank."""
    keys = _group_keys(rows)
    recs = []
    for gk, g in rows.groupby(keys + ["label"], sort=True, dropna=False):
        gk = gk if isinstance(gk, tuple) else (gk,)
        ok = g[g["ok"]]
        strata = list(zip(ok["material"], ok["agents"], ok["n_tasks"]))
        rec = dict(zip(keys + ["planner"], gk))
        rec.update(cells=len(g), failed=int((~g["ok"]).sum()))
        stats = {
            "objective_um": (ok["objective_m"] * 1e6, _mean),
            "iqm_um": (ok["objective_m"] * 1e6, iqm),
            "regret_pct": (ok["relative_regret"] * 100, _mean),
            "samples_to_1pct": (ok["samples_to_1pct"], _mean),
            "samples_to_5pct": (ok["samples_to_5pct"], _mean),
            "success_5pct_pct": (ok["success_5pct"] * 100, _mean),
            "wall_s": (ok["wall_s"], _mean),
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


def _show_summary(df: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    out = pd.DataFrame()
    for k in keys:
        out[k] = df[k].map(lambda v, k=k: setting_text(k, v))
    out["planner"] = df["planner"]
    out["cells"] = df["cells"]
    out["failed"] = df["failed"]

    def col(name):
        return [ci_text(p, lo, hi) for p, lo, hi in zip(df[name], df[f"{name}_lo"], df[f"{name}_hi"])]

    out["max def. (um)"] = col("objective_um")
    out["IQM (um)"] = col("iqm_um")
    out["regret (%)"] = col("regret_pct")
    out["samples to 1%"] = [f"{c} ({r}/{n - f})" for c, r, n, f in
                            zip(col("samples_to_1pct"), df["reached_1pct"], df["cells"], df["failed"])]
    out["samples to 5%"] = [f"{c} ({r}/{n - f})" for c, r, n, f in
                            zip(col("samples_to_5pct"), df["reached_5pct"], df["cells"], df["failed"])]
    out["success 5% (%)"] = col("success_5pct_pct")
    out["wall (s)"] = col("wall_s")
    out["rank"] = df["rank"].map(lambda r: "-" if not np.isfinite(r) else str(int(r)))
    return out


def reference_table(refs: dict) -> pd.DataFrame:
    recs = []
    for (case, mat, agents, n_tasks), ref in sorted(refs.items(), key=lambda kv: str(kv[0])):
        opt = np.asarray(ref["per_task"], dtype=float) * 1e6
        recs.append({"case": case, "material": mat, "agents": agents, "tasks": n_tasks,
                     "mean optimum (um)": float(opt.mean()), "min (um)": float(opt.min()),
                     "max (um)": float(opt.max()),
                     "shared optimum (um)": (ref["shared"] * 1e6 if ref.get("shared") is not None
                                             else math.nan),
                     "proven": bool(ref.get("proven")), "method": ref.get("method") or "",
                     "samples": ref.get("samples")})
    return pd.DataFrame(recs)


# traces against optima ------------------------------------------------------------------------------

def optima(ok: pd.DataFrame, traces: pd.DataFrame, refs: dict) -> tuple[dict, bool]:
    """Optimum per (problem, task): the reference's, or else the best value seen in the run
    (traces and final rows). Returns the dict and whether any fallback was used."""
    out: dict[tuple, float] = {}
    fallback = False
    if traces.empty or ok.empty:
        return out, fallback
    info = ok.set_index("cell")
    pkey = {c: _problem_key(r) for c, r in info.iterrows()}
    tr = traces[traces["cell"].isin(info.index)]
    seen = tr.assign(pk=tr["cell"].map(pkey)).groupby(["pk", "task"])["best"].min()
    for cell, task in tr[["cell", "task"]].drop_duplicates().sort_values(["cell", "task"]).itertuples(
            index=False):
        row = info.loc[cell]
        pk = pkey[cell]
        key = (pk, int(task))
        if key in out:
            continue
        ref = refs.get(ref_key(row))
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
        o = opt.get((_problem_key(row), int(task)))
        if o is None or not o > 0:
            continue
        g = g.sort_values("task_samples", kind="stable")
        gap = np.maximum(np.minimum.accumulate(g["best"].to_numpy()) / o - 1, 0.0)
        out.append({"cell": cell, "task": int(task), "planner": row["planner"], "label": row["label"],
                    "case": row["case"], "s": g["task_samples"].to_numpy(dtype=float), "gap": gap})
    return out


def _on_grid(s: np.ndarray, v: np.ndarray, grid: np.ndarray) -> np.ndarray:
    pos = np.searchsorted(s, grid, side="right") - 1
    return np.where(pos >= 0, v[np.maximum(pos, 0)], np.nan)


def _grid(recs: list[dict]) -> np.ndarray:
    top = 1.3 * max(float(r["s"].max()) for r in recs)  # a margin, so final states show
    return np.unique(np.geomspace(1, max(top, 2), 200).round())


def runtime(rec: dict, target: float) -> float:
    hit = np.flatnonzero(rec["gap"] <= target)
    return float(rec["s"][hit[0]]) if len(hit) else math.inf


# figures --------------------------------------------------------------------------------------------

def _palette(labels) -> dict:
    """A distinct colour per label: tab10 up to 10 labels, tab20 up to 20 (the paper run has 13)."""
    cols = sns.color_palette("tab10" if len(labels) <= 10 else "tab20", max(len(labels), 1))
    return {lab: cols[i % len(cols)] for i, lab in enumerate(labels)}


#: the regret reference's planner: the anytime curves' 0 line, not a planner line of its own
REFERENCE_PLANNER = "exact"


def anytime_records(recs: list[dict], case: str) -> list[dict]:
    """The gap traces of ``case`` that the anytime figure draws: every planner but the reference's
    (``exact`` enumerates, so its trace would stretch the x axis over samples no planner spends)."""
    return [r for r in recs if r["case"] == case and r["planner"] != REFERENCE_PLANNER]


def anytime_figure(recs: list[dict], case: str, colors: dict):
    """Best-so-far gap to the reference (%) against the samples spent on a task: median and
    interquartile band per planner label, x axis up to the most samples a task any planner spent."""
    sub = anytime_records(recs, case)
    grid = _grid(sub)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for lab in sorted({r["label"] for r in sub}):
        vals = np.vstack([_on_grid(r["s"], r["gap"], grid) for r in sub if r["label"] == lab]) * 100
        n = np.isfinite(vals).sum(axis=0)
        ok = n * 2 >= len(vals)  # drawn where at least half of the curves have started
        with np.errstate(all="ignore"):
            med = np.nanmedian(vals[:, ok], axis=0)
            lo, hi = np.nanquantile(vals[:, ok], [0.25, 0.75], axis=0)
        ax.step(grid[ok], med, where="post", color=colors[lab], label=f"{lab} ({len(vals)})")
        ax.fill_between(grid[ok], lo, hi, step="post", color=colors[lab], alpha=0.2, lw=0)
    ax.set_xscale("log")
    ax.set_xlim(1, grid[-1])
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("samples spent on the task")
    ax.set_ylabel("best so far above the reference (%)\n(0 = the reference; symlog)", fontsize=8)
    ax.set_title(f"{case}: median over cells x tasks, band 25-75 %", fontsize=9)
    ax.legend(fontsize=7, title="planner (curves)", title_fontsize=7)
    fig.tight_layout()
    return fig


def ecdf_figure(recs: list[dict], cases: list[str], colors: dict, targets=TARGETS):
    """Runtime-to-target ECDFs, one panel a case (two a row), one legend for the figure."""
    fig, axes = panel_grid(len(cases), row_height=3.6)
    for ax, case in zip(axes, cases):
        sub = [r for r in recs if r["case"] == case]
        grid = _grid(sub)
        for lab in sorted({r["label"] for r in sub}):
            rt = np.array([runtime(r, t) for r in sub if r["label"] == lab for t in targets])
            frac = (rt[None, :] <= grid[:, None]).mean(axis=1)
            ax.step(grid, frac, where="post", color=colors[lab], label=lab)
        ax.set_xscale("log")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("samples spent on the task")
        ax.set_ylabel("fraction of (cell, task, target) solved", fontsize=8)
        ax.set_title(f"{case}: targets {', '.join(f'{t:.0%}' for t in targets)} above the optimum",
                     fontsize=8)
    figure_legend(fig, axes, title="planner")
    return fig


def performance_profile(ok_and_failed: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray, dict]:
    """Ratios objective / best objective per problem (case, material, seed, settings); failed or
    missing runs have ratio inf. Returns the ratio table (problems x planners), a tau grid and
    rho(tau) per planner."""
    df = ok_and_failed.copy()
    df["obj"] = np.where(df["ok"], df["objective_m"], np.inf)
    keys = ["case", "material", "seed"] + [k for k in SETTINGS if df[k].nunique() > 1]
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


def profile_figure(taus, rho, colors, n_problems):
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for lab in sorted(rho):
        ax.step(taus, rho[lab], where="post", color=colors[lab], label=lab)
    ax.set_xscale("log")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("tau (objective / best planner's objective)")
    ax.set_ylabel("fraction of problems within tau")
    ax.set_title(f"Dolan-More performance profile over {n_problems} problems", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def violin_figure(ok: pd.DataFrame, colors):
    """Horizontal violins of the difference from the reference (%), planners on the y axis, one panel
    a case (two a row); the figure stays at most 2.5:1 so that it reads at page width."""
    cases = list(dict.fromkeys(ok["case"]))
    width = 5.0 * min(len(cases), 2)  # panel_grid's: 10 inches for two panels a row
    nrow = math.ceil(len(cases) / 2)
    fig, axes = panel_grid(len(cases), row_height=max(0.35 * ok["label"].nunique() + 1.3, width / 2.5 / nrow))
    for ax, case in zip(axes, cases):
        d = ok[ok["case"] == case].assign(diff=lambda x: x["relative_regret"] * 100)
        order = sorted(d["label"].unique())
        sns.violinplot(data=d, x="diff", y="label", hue="label", order=order, hue_order=order, orient="h",
                       palette=colors, cut=0, inner=None, ax=ax, legend=False, density_norm="width")
        rng = np.random.default_rng(BOOT_SEED)  # deterministic jitter (seaborn's is not seeded)
        for i, lab in enumerate(order):
            x = d.loc[d["label"] == lab, "diff"].to_numpy()
            ax.scatter(x, i + rng.uniform(-0.1, 0.1, len(x)), color="black", s=6, zorder=3)
        if d["diff"].max() > 100:  # learners reach 1e4 %: a linear axis hides every other planner at 0
            ax.set_xscale("symlog", linthresh=1.0)
            ax.set_xlabel("difference from reference (%, symmetric log: linear below 1 %)")
        else:
            ax.set_xlabel("difference from reference (%)")
        ax.set_ylabel("planner")
        ax.set_title(f"{case}: one point per cell", fontsize=9)
    return fig


# learners: the seed paper's Figure 4 ----------------------------------------------------------------

def learner_cells(curves: pd.DataFrame, ok: pd.DataFrame) -> list[str]:
    if curves.empty:
        return []
    has = curves[curves["curve"].isin(LEARNER_CURVES)]["cell"].unique()
    return sorted(set(has) & set(ok["cell"]))


def _curve(curves: dict, cell: str, name: str) -> np.ndarray:
    return curves.get((cell, name), np.zeros(0))


def _median_band(ax, arrays: list[np.ndarray], x0: int, color, label):
    arrays = [a for a in arrays if len(a)]
    if not arrays:
        return
    n = max(len(a) for a in arrays)
    m = np.full((len(arrays), n), np.nan)
    for i, a in enumerate(arrays):
        m[i, :len(a)] = a
    x = np.arange(n) + x0
    with np.errstate(all="ignore"):
        med = np.nanmedian(m, axis=0)
        lo, hi = np.nanquantile(m, [0.25, 0.75], axis=0)
    ax.plot(x, med, color=color, label=f"{label} ({len(arrays)})", lw=1.2)
    ax.fill_between(x, lo, hi, color=color, alpha=0.2, lw=0)


def _smooth(a: np.ndarray) -> np.ndarray:
    w = max(1, len(a) // 50)
    return pd.Series(a).rolling(w, min_periods=1).mean().to_numpy() if w > 1 else a


def figure4(ok: pd.DataFrame, curves: pd.DataFrame, cells: list[str], refs: dict, colors: dict):
    """Seed Figure 4: (a) step reward, (b) episodic return, (c) episodic regret (reference code's,
    and true regret against the optimum), (d) violin of the deformation of every layout tried in
    training relative to the task's optimum."""
    info = ok.set_index("cell")
    sub = curves[curves["cell"].isin(cells)].sort_values(["cell", "curve", "index"], kind="stable")
    curves = {k: g["value"].to_numpy(dtype=float) for k, g in sub.groupby(["cell", "curve"], sort=False)}
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5))
    ax_a, ax_b, ax_c, ax_c2, ax_d, ax_none = axes.ravel()
    ax_none.axis("off")
    violin, true_src = [], set()
    for lab in sorted(info.loc[cells, "label"].unique()):
        lc = [c for c in cells if info.loc[c, "label"] == lab]
        col = colors[lab]
        _median_band(ax_a, [_smooth(_curve(curves, c, "step_reward")) for c in lc], 1, col, lab)
        _median_band(ax_b, [_curve(curves, c, "episode_return") for c in lc], 1, col, lab)
        _median_band(ax_c, [_curve(curves, c, "episode_regret_ref") for c in lc], 1, col, lab)
        true_reg = []
        for c in lc:
            row = info.loc[c]
            u, task = _curve(curves, c, "step_max_u"), _curve(curves, c, "step_task").astype(int)
            ref = refs.get(ref_key(row))
            eps = len(_curve(curves, c, "episode_return"))
            if ref is not None and len(u) and len(u) == len(task):
                opt = np.asarray(ref["per_task"], dtype=float)[task]
                true_src.add("reference optimum")
                if eps and len(u) % eps == 0:
                    true_reg.append((u - opt).reshape(eps, -1).sum(axis=1) * 1e6)
                violin.append(pd.DataFrame({"planner": lab, "diff": (u / opt - 1) * 100}))
            else:
                true_src.add("best seen in the run")
                true_reg.append(_curve(curves, c, "episode_regret_true") * 1e6)
                if len(u) and len(u) == len(task):
                    best = pd.Series(u).groupby(task).transform("min").to_numpy()
                    violin.append(pd.DataFrame({"planner": lab, "diff": (u / best - 1) * 100}))
        _median_band(ax_c2, true_reg, 1, col, lab)
    ax_a.set(xlabel="training step", ylabel="step reward (Gaussian)", title="(a) step reward")
    ax_b.set(xlabel="episode", ylabel="episodic return", title="(b) episodic return")
    ax_c.set(xlabel="episode", ylabel="N T 0.7854 - N sum r", title="(c) episodic regret (reference code)")
    ax_c2.set(xlabel="episode", ylabel="sum of (max |u| - u*) (um)",
              title=f"(c) episodic true regret vs {' / '.join(sorted(true_src)) or '-'}")
    for ax in (ax_a, ax_b, ax_c, ax_c2):
        ax.legend(fontsize=7)
        ax.title.set_fontsize(9)
    if violin:
        d = pd.concat(violin, ignore_index=True)
        order = sorted(d["planner"].unique())
        sns.violinplot(data=d, x="planner", y="diff", hue="planner", order=order, hue_order=order,
                       palette=colors, cut=0, ax=ax_d, legend=False, density_norm="width")
    ax_d.set(xlabel="learner", ylabel="deformation above the optimum (%)",
             title="(d) layouts tried in training")
    ax_d.title.set_fontsize(9)
    fig.tight_layout()
    return fig


# deformation fields ---------------------------------------------------------------------------------

def _problem_for_row(row):
    from fixbench.bench.cells import problem_for

    n_tasks = int(row["n_tasks"])
    p = problem_for(row["case"], row["material"], None, n_tasks)
    if p.n_agents != int(row["agents"]):
        p = problem_for(row["case"], row["material"], int(row["agents"]), n_tasks)
    return p


def field_figure(ok: pd.DataFrame, case: str, refs: dict):
    """The part's |u| under each planner's best layout (and the optimum), one material and task. Each
    panel has its own colour scale and bar: one scale set by the worst layout would flatten the good
    ones into one colour."""
    d = ok[(ok["case"] == case) & ok["layouts"].notna()]
    mat = sorted(d["material"].unique())[0]
    d = d[d["material"] == mat]
    first = d.iloc[0]
    problem = _problem_for_row(first)
    ref = refs.get(ref_key(first))
    task = int(np.argmax(ref["per_task"])) if ref is not None and first["mode"] != "shared" else 0
    panels = []
    if ref is not None and ref.get("layouts") and first["mode"] != "shared":
        panels.append((f"optimum ({'proven' if ref.get('proven') else 'best known'})",
                       ref["layouts"][task]))
    for lab in sorted(d["label"].unique()):
        best = d[d["label"] == lab].sort_values(["objective_m", "seed"], kind="stable").iloc[0]
        lay = json.loads(best["layouts"])
        panels.append((f"{lab} (seed {int(best['seed'])})", lay[min(task, len(lay) - 1)]))
    model = problem.model
    tri = mtri.Triangulation(model.mesh.p[0] * 1e3, model.mesh.p[1] * 1e3, model.mesh.t.T)
    mags = []
    for _, lay in panels:
        vals = model.nodal(problem.solve_direct(task, [lay]))
        mags.append(np.sqrt(vals["ux"] ** 2 + vals["uy"] ** 2 + vals["w"] ** 2) * 1e6)
    ncol = min(len(panels), 3 if len(panels) <= 6 else 4)
    nrow = math.ceil(len(panels) / ncol)
    x0, y0, x1, y1 = problem.spec.polygon.bounds
    panel_height = 3.2 * min((y1 - y0) / (x1 - x0), 1.5) + 1.2  # the part's aspect, and room for labels
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, panel_height * nrow + 0.4), squeeze=False,
                             layout="constrained")
    for ax, (title, lay), mag in zip(axes.ravel(), panels, mags):
        tc = ax.tricontourf(tri, mag, levels=np.linspace(0, float(mag.max()) or 1.0, 31), cmap="viridis")
        poly = problem.spec.polygon
        for ring in (poly.exterior, *poly.interiors):
            x, y = np.asarray(ring.coords).T * 1e3
            ax.plot(x, y, color="black", lw=0.8)
        c = problem.candidates[np.asarray(lay)] * 1e3
        ax.scatter(c[:, 0], c[:, 1], color="red", s=18, zorder=3)
        ax.set_aspect("equal")
        ax.set_title(f"{title}\nmax |u| {mag.max():.3g} um", fontsize=8)
        ax.set_xlabel("x (mm)", fontsize=8)
        ax.set_ylabel("y (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
        cbar = fig.colorbar(tc, cax=ax.inset_axes([1.03, 0.0, 0.04, 1.0]), ticks=MaxNLocator(5))
        cbar.set_label("|u| (um)", fontsize=8)
        cbar.ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    fig.suptitle(f"{case}, {mat}, task {task}: fixtures in red", fontsize=10)
    return fig, mat, task


# driver ---------------------------------------------------------------------------------------------

def _main_section(w: _Writer, rows: pd.DataFrame) -> None:
    """The README's main table (``main``): regret per case and mean rank over problems."""
    if not rows["ok"].any():
        w.skip("Main table", "no successful cells")
        return
    table = main_table(rows)
    w.table("main", table, show_main(table, [name for name, _, _ in main_columns(rows)]),
            "Main table: relative regret against the reference (%, mean over every successful cell of the "
            "planner on the case (and mode, when the run has several; held-out cells are scored on the "
            f"held-out tasks) with a 95 % percentile-bootstrap CI, {N_BOOT} resamples, fixed seed) and "
            "the mean rank over problems (case x material x seed x agents x tasks x mode x budget or samples "
            "a task; rank 1 = lowest max deformation, failed cells last, ties share; a planner with its own "
            "budget competes at every budget); sorted by mean rank.")


def _comparison_sections(w: _Writer, rows: pd.DataFrame, refs: dict) -> pd.DataFrame:
    """The budget sweep, held-out and probability-of-improvement tables (:mod:`fixbench.bench.comparison`),
    each skipped with its reason when the run lacks its rows. Returns the sweep table, whose figure
    comes with the figures."""
    sweep = sweep_table(rows)
    if rows["samples_per_task"].isna().all():
        w.skip("Budget sweep table", "the run has no budget sweep (samples_per_task)")
    elif sweep.empty:
        w.skip("Budget sweep table", "no successful per-task sweep cell has a regret reference")
    else:
        w.table("sweep", sweep, show_sweep(sweep),
                "Budget sweep: relative regret against the reference (%) per case, planner and samples a "
                "task (per-task mode; mean over cells with a 95 % percentile-bootstrap CI, the value itself "
                "for one cell).")
    held = heldout_table(rows, refs)
    if not (rows["mode"] == "held-out").any():
        w.skip("Held-out table", "the run has no held-out cells")
    elif not (held["track"] == "held-out").any():
        w.skip("Held-out table", "no successful held-out cell has a regret reference")
    else:
        w.table("heldout", held, show_heldout(held),
                "Held-out track: relative regret (%) on the held-out tasks (those outside range(0, tasks, k)) "
                "of planners that trained on tasks 0, k, 2k, ... and acted on the others with zero samples, "
                "beside the per-task cells (which pay samples on every task) scored on the same held-out "
                "tasks against the same reference; `samples a cell` is the mean spent in all.")
    group = _group_keys(rows)[1:]
    imp = improvement_table(rows, group)
    if imp.empty:
        w.skip("Probability of improvement", "no case has two planners with a relative regret")
    else:
        w.table("improvement", imp, show_improvement(imp, group),
                "Probability of improvement (rliable): P(X < Y), the chance that a random cell of X has a "
                "lower relative regret than a random cell of Y (ties count 1/2; Mann-Whitney U / (n m)), per "
                f"{', '.join(['case', *group])}, with a 95 % percentile-bootstrap CI over "
                "both planners' cells.")
    return sweep


def make_report(run_dir: str | Path, out: str | Path | None = None, fields: bool = True) -> dict:
    """Write the report of ``run_dir`` into ``out`` (default ``run_dir/report``).

    Returns ``{"report": path, "tables": {name: csv}, "figures": {name: png}, "notes": [...]}``;
    ``notes`` lists what was skipped and why (also written into report.md).
    """
    run_dir = Path(run_dir)
    if not (run_dir / "rows").is_dir():
        raise CaseError(str(run_dir), "", "is not a run directory (it has no rows/ folder)")
    out = Path(out) if out is not None else run_dir / "report"
    w = _Writer(out)
    rows = load_rows(run_dir)
    if rows.attrs.get("damaged"):
        w.notes.append(f"{rows.attrs['damaged']} damaged row files: not read (each named on stderr); "
                       "`fixbench run` moves them aside and recomputes their cells")
    refs = load_references(run_dir)
    ok = rows[rows["ok"]].copy()
    name = run_dir.name
    try:
        import tomllib

        name = tomllib.loads((run_dir / "matrix.toml").read_text()).get("name", name)
    except (OSError, ValueError):
        pass
    labels = sorted(rows["label"].unique())
    colors = _palette(labels)
    cases = list(dict.fromkeys(rows["case"]))
    ok_cases = list(dict.fromkeys(ok["case"]))
    w.md += [f"# fixbench report: {name}", "",
             f"Run directory `{run_dir}`: {len(rows)} cells ({int((~rows['ok']).sum())} failed), "
             f"cases {', '.join(map(str, cases)) or '-'}, planners {', '.join(labels) or '-'}, "
             f"{len(refs)} regret reference(s).", ""]

    # tables ------------------------------------------------------------------------------------
    w.md += ["## Tables", ""]
    if rows.empty:
        w.skip("Main table", "the run directory has no rows")
        w.skip("Summary table", "the run directory has no rows")
    else:
        _main_section(w, rows)
        summ = summary_table(rows)
        keys = _group_keys(rows)
        w.table("summary", summ, _show_summary(summ, keys),
                "Per case and planner: mean over seeds x materials with 95 % stratified bootstrap CI "
                f"({N_BOOT} resamples, fixed seed) of the max deformation, its interquartile mean (IQM), "
                "the relative regret against the optimum, samples to come within 1 % / 5 % of the "
                "optimum (mean over cells that did; reached/ran in brackets), success rate within 5 %, "
                "wall time; `failed` cells are counted and left out; `rank` by mean max deformation "
                "within the case.")
    if refs:
        w.table("references", reference_table(refs), reference_table(refs).map(
            lambda v: fmt(v, 4) if isinstance(v, float) else v),
            "Regret references: the `exact` planner's per-task optima (and shared optimum), proven or "
            "best known.")
    else:
        w.skip("Reference table", "the run has no usable regret reference (reference/*.json)")
    sweep = _comparison_sections(w, rows, refs)
    ratios = None
    if ok.empty:
        w.skip("Performance profile table", "no successful cells")
    else:
        ratios, taus, rho = performance_profile(rows)
        if len(ratios):
            prof = pd.DataFrame({"planner": list(rho),
                                 "problems": len(ratios),
                                 "best (tau=1)": [float(rho[k][0]) for k in rho],
                                 "within 1.1": [float((ratios[k] <= 1.1).mean()) for k in rho],
                                 "within 2": [float((ratios[k] <= 2).mean()) for k in rho],
                                 "failed or missing": [float((~np.isfinite(ratios[k])).mean()) for k in rho]})
            w.table("profile", prof, prof.map(lambda v: fmt(v) if isinstance(v, float) else v),
                    "Performance profile summary: fraction of problems (case x material x seed) on which "
                    "each planner is the best, or within a factor 1.1 / 2 of the best planner's max "
                    "deformation.")
    failed = rows[~rows["ok"]]
    if len(failed):
        f = failed[["case", "material", "planner", "seed", "cell", "error"]].copy()
        f["error"] = f["error"].str.slice(0, 120)
        w.table("failed", f, f, "Failed cells (left out of every statistic), with their error.")

    # figures -----------------------------------------------------------------------------------
    w.md += ["## Figures", ""]
    if len(sweep):
        w.figure("sweep", sweep_figure(sweep, colors),
                 "Budget sweep: relative regret against the reference (%, log) against samples per task "
                 "(log), one panel a case; mean over cells with its 95 % CI as a band.")
    traces = load_traces(run_dir)
    recs = []
    if ok.empty:
        w.skip("Anytime curves and runtime ECDFs", "no successful cells")
    elif traces.empty:
        w.skip("Anytime curves and runtime ECDFs", "the run has no traces")
    else:
        opt, fallback = optima(ok, traces, refs)
        recs = gap_traces(ok, traces, opt)
        src = ("the regret reference's optimum" + (", or the best value seen in the run where a "
               "reference is missing" if fallback else "")) if refs else "the best value seen in the run"
        if not recs:
            w.skip("Anytime curves and runtime ECDFs", "no trace could be matched to an optimum")
        for case in [c for c in ok_cases if anytime_records(recs, c)]:
            w.figure(f"anytime_{slug(case)}", anytime_figure(recs, case, colors),
                     f"Anytime curves on {case}: best max deformation so far above the optimum ({src}) "
                     "against the samples spent on the task; median over cells x tasks with the "
                     f"interquartile band. The reference is the 0 line; `{REFERENCE_PLANNER}` (which "
                     "enumerates) is not drawn, so the x axis ends at the most samples a planner spent.")
        if recs:
            rc = [c for c in ok_cases if any(r["case"] == c for r in recs)]
            w.figure("ecdf", ecdf_figure(recs, rc, colors),
                     "Runtime-to-target ECDFs (COCO): fraction of (cell, task, target) triples solved "
                     f"against samples, targets {', '.join(f'{t:.0%}' for t in TARGETS)} above the "
                     f"optimum ({src}).")
    if ratios is not None and len(ratios):
        w.figure("profile", profile_figure(taus, rho, colors, len(ratios)),
                 "Dolan-More performance profiles: fraction of problems (case x material x seed) on "
                 "which a planner's max deformation is within a factor tau of the best planner's; failed "
                 "cells never are.")
    elif not ok.empty:
        w.skip("Performance profile", "no problem has a successful cell")
    if ok["relative_regret"].notna().any():
        w.figure("violin", violin_figure(ok[ok["relative_regret"].notna()], colors),
                 "Percentage difference of the max deformation from the reference, per planner (one point "
                 "per cell).")
    else:
        w.skip("Violin plot", "no successful cell has a regret reference")
    curves = load_curves(run_dir)
    cells = learner_cells(curves, ok)
    if cells:
        fig = _figure4(ok, curves, cells, refs, colors)
        w.figure("figure4", fig,
                 "Learners, seed Figure 4: (a) step reward (moving average) against training step, (b) "
                 "episodic return, (c) episodic regret of the reference code and true regret against "
                 "the optimum, (d) violin of the deformation of every layout tried in training above the "
                 "task's optimum; median over seeds x materials with interquartile band.")
    else:
        w.skip("Learner panels (seed Figure 4)", "no learner in the run (no training curves)")
    if not fields:
        w.skip("Deformation fields", "turned off (--no-fields)")
    elif ok.empty or "layouts" not in ok or ok["layouts"].isna().all():
        w.skip("Deformation fields", "no successful cell stores its layouts")
    else:
        for case in ok_cases:
            try:
                fig, mat, task = field_figure(ok, case, refs)
            except Exception as exc:  # a case that cannot be rebuilt here must not stop the report
                w.skip(f"Deformation field of {case}", f"{type(exc).__name__}: {exc}")
                continue
            w.figure(f"field_{slug(case)}", fig,
                     f"Deformation |u| of {case} ({mat}, task {task}, the task with the largest optimum) "
                     "under each planner's best layout over seeds, and the optimum's; each panel has its "
                     "own colour scale.")
    if w.notes:
        w.md += ["## Skipped", ""] + [f"- {n}" for n in w.notes] + [""]
    path = out / "report.md"
    path.write_text("\n".join(w.md))
    return {"report": path, "tables": w.tables, "figures": w.figures, "notes": w.notes}


def _figure4(ok, curves, cells, refs, colors):
    """The learners' Figure 4: fixbench.bench.marl.figure4 when present, else :func:`figure4` here."""
    return figure4(ok, curves, cells, refs, colors)
