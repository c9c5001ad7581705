"""Every figure of the report (matplotlib, seaborn): anytime curves, runtime ECDFs, performance
profiles, violins, the budget sweep, the learners' Figure 4 and deformation fields.

Each function returns a figure; the caller saves it. Colours come from :func:`palette`, one per
planner label for the whole report; figures with several panels share one legend
(:func:`figure_legend`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import seaborn as sns  # noqa: E402
from matplotlib.ticker import FuncFormatter, MaxNLocator, NullLocator  # noqa: E402

from fixbench.bench.records.rows import reference_of  # noqa: E402
from fixbench.bench.reporting.plots import outline  # noqa: E402
from fixbench.bench.reporting.stats import BOOT_SEED, TARGETS, on_grid, runtime, sample_grid  # noqa: E402
from fixbench.cases.rewards import REFERENCE_OPTIMAL_REWARD  # noqa: E402
from fixbench.solvers.base import Training  # noqa: E402

#: relative regrets (%) below this are drawn at it on log axes (a regret of 0 has no logarithm)
REGRET_FLOOR_PCT = 1e-3
#: the regret reference's planner: the anytime curves' 0 line, not a planner line of its own
REFERENCE_PLANNER = "exact"


# layout ----------------------------------------------------------------------------------------------

def palette(labels) -> dict:
    """A distinct colour per label: tab10 up to 10 labels, tab20 up to 20 (the paper run has 13)."""
    cols = sns.color_palette("tab10" if len(labels) <= 10 else "tab20", max(len(labels), 1))
    return {lab: cols[i % len(cols)] for i, lab in enumerate(labels)}


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


# planners against the reference ----------------------------------------------------------------------

def anytime_records(recs: list[dict], case: str) -> list[dict]:
    """The gap traces of ``case`` that the anytime figure draws: every planner but the reference's
    (``exact`` enumerates, so its trace would stretch the x axis over samples no planner spends)."""
    return [r for r in recs if r["case"] == case and r["planner"] != REFERENCE_PLANNER]


def anytime_figure(recs: list[dict], case: str, colors: dict):
    """Best-so-far gap to the reference (%) against the samples spent on a task: median and
    interquartile band per planner label, x axis up to the most samples a task any planner spent."""
    sub = anytime_records(recs, case)
    grid = sample_grid(sub)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for lab in sorted({r["label"] for r in sub}):
        vals = np.vstack([on_grid(r["s"], r["gap"], grid) for r in sub if r["label"] == lab]) * 100
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
        grid = sample_grid(sub)
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


def profile_figure(taus, rho, colors, n_problems):
    """Dolan-More performance profiles: rho(tau) per planner label
    (:func:`fixbench.bench.reporting.stats.performance_profile`)."""
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


# learners: the seed paper's Figure 4 ----------------------------------------------------------------

#: the training curves Figure 4 draws, by the names a learner declares them under (its ``Training``:
#: ``step_*`` one value a training step, ``episode_*`` one an episode; a run directory stores them)
FIGURE4_CURVES = ("step_reward", "episode_return", "episode_regret_ref", "episode_regret_true", "step_max_u",
                  "step_task")


def figure4_run(curves: Mapping[str, np.ndarray], optimum: np.ndarray | None = None) -> dict:
    """One run of Figure 4's input: the ``FIGURE4_CURVES`` among ``curves`` (name -> values; empty where the
    learner declared none: its panels are drawn without it) and ``optimum``, the per-task optima (or None)."""
    return {**{k: np.asarray(curves.get(k, ()), dtype=float) for k in FIGURE4_CURVES}, "optimum": optimum}


def training_run(training: Training) -> dict:
    """Figure 4's input of one :class:`~fixbench.solvers.base.Training` (a run's own, no optima)."""
    return figure4_run({name: c.values for name, c in training.curves.items()})


def learner_runs(ok: pd.DataFrame, curves: pd.DataFrame, cells: list[str], refs: dict) -> dict[str, list[dict]]:
    """Figure 4's input from a run directory: {label: [one dict a cell]}, labels sorted; each dict is
    :func:`figure4_run` of the cell's stored curves, ``optimum`` the per-task optima of its regret
    reference (None without one)."""
    info = ok.set_index("cell")
    sub = curves[curves["cell"].isin(cells)].sort_values(["cell", "curve", "index"], kind="stable")
    by = {c: {k: g["value"].to_numpy(dtype=float) for k, g in gc.groupby("curve", sort=False)}
          for c, gc in sub.groupby("cell", sort=False)}
    runs = {}
    for lab in sorted(info.loc[cells, "label"].unique()):
        runs[lab] = []
        for c in (c for c in cells if info.loc[c, "label"] == lab):
            ref = refs.get(reference_of(info.loc[c]))
            runs[lab].append(figure4_run(by.get(c, {}),
                                         None if ref is None else np.asarray(ref["per_task"], dtype=float)))
    return runs


def figure4(runs: dict[str, list[dict]], colors: dict):
    """Seed Figure 4 as one figure of 2 x 3 panels (the report's); see :func:`draw_figure4`."""
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5))
    ax_a, ax_b, ax_c, ax_c2, ax_d, ax_none = axes.ravel()
    ax_none.axis("off")
    draw_figure4((ax_a, ax_b, ax_c, ax_c2, ax_d), runs, colors)
    fig.tight_layout()
    return fig


def figure4_panels(runs: dict[str, list[dict]], colors: dict) -> list:
    """Seed Figure 4 as four figures, one a panel: (a), (b), (c) with both regrets, (d) (the files of
    ``python -m studies.marl``); see :func:`draw_figure4`."""
    (fig_a, ax_a), (fig_b, ax_b) = plt.subplots(figsize=(7, 4)), plt.subplots(figsize=(7, 4))
    fig_c, (ax_c, ax_c2) = plt.subplots(1, 2, figsize=(11, 4))
    fig_d, ax_d = plt.subplots(figsize=(7, 4))
    draw_figure4((ax_a, ax_b, ax_c, ax_c2, ax_d), runs, colors)
    for fig in (fig_a, fig_b, fig_c, fig_d):
        fig.tight_layout()
    return [fig_a, fig_b, fig_c, fig_d]


def _median_band(ax, arrays: list[np.ndarray], x0: int, color, label):
    """Median over the runs with the interquartile band; runs of different lengths pad with NaN."""
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
    """Moving average over a fiftieth of the curve (the step reward is too noisy to read raw)."""
    w = max(1, len(a) // 50)
    return pd.Series(a).rolling(w, min_periods=1).mean().to_numpy() if w > 1 else a


def _true_regret(r: dict) -> tuple[np.ndarray, np.ndarray, str]:
    """One run's episodic true regret (um; panel c2), each training step's deformation above the optimum
    (%; panel d) and what the optimum is: the regret reference's per-task optima, else the best layout
    the run saw on each task (the run's declared ``episode_regret_true``, else the same sum from its
    steps)."""
    u, task, eps = r["step_max_u"], r["step_task"].astype(int), len(r["episode_return"])
    steps, empty = len(u) > 0 and len(u) == len(task), np.zeros(0)
    whole = eps > 0 and len(u) % eps == 0  # the steps split into the episodes
    if r["optimum"] is not None and steps:
        opt = r["optimum"][task]
        return (u - opt).reshape(eps, -1).sum(axis=1) * 1e6 if whole else empty, (u / opt - 1) * 100, \
            "reference optimum"
    regret = r["episode_regret_true"] * 1e6
    if not steps:
        return regret, empty, "best seen in the run"
    best = pd.Series(u).groupby(task).transform("min").to_numpy()
    if not len(regret) and whole:
        regret = (u - best).reshape(eps, -1).sum(axis=1) * 1e6
    return regret, (u / best - 1) * 100, "best seen in the run"


def draw_figure4(axes, runs: dict[str, list[dict]], colors: dict) -> None:
    """The seed paper's Figure 4 of learners' training runs on ``axes`` (a, b, c, c2, d): (a) step reward,
    (b) episodic return, (c) episodic regret (the reference code's, and c2 the true regret against each
    task's optimum, or the best layout the run saw on it without one), (d) violin of the deformation of
    every layout tried in training above that optimum. ``runs``: {label: [run, ...]}, each run a dict of
    ``FIGURE4_CURVES`` and ``optimum`` (:func:`figure4_run`); one line a label, the median over its runs
    with the interquartile band; a learner draws in the panels whose curves it declared (a panel none
    has data for says so)."""
    ax_a, ax_b, ax_c, ax_c2, ax_d = axes
    violin, true_src = [], set()
    for lab, lc in runs.items():
        col = colors[lab]
        _median_band(ax_a, [_smooth(r["step_reward"]) for r in lc], 1, col, lab)
        _median_band(ax_b, [r["episode_return"] for r in lc], 1, col, lab)
        _median_band(ax_c, [r["episode_regret_ref"] for r in lc], 1, col, lab)
        true_reg = []
        for r in lc:
            regret, above, source = _true_regret(r)
            true_reg.append(regret)
            true_src.add(source)
            if len(above):
                violin.append(pd.DataFrame({"planner": lab, "diff": above}))
        _median_band(ax_c2, true_reg, 1, col, lab)
    ax_a.set(xlabel="training step", ylabel="step reward (Gaussian)", title="(a) step reward")
    ax_b.set(xlabel="episode", ylabel="episodic return", title="(b) episodic return")
    ax_c.set(xlabel="episode", ylabel=f"N T {REFERENCE_OPTIMAL_REWARD:g} - N sum r",
             title="(c) episodic regret (reference code)")
    ax_c2.set(xlabel="episode", ylabel="sum of (max |u| - u*) (um)",
              title=f"(c) episodic true regret vs {' / '.join(sorted(true_src)) or '-'}")
    panel_needs = ("step_reward", "episode_return", "episode_regret_ref",
                   "step_max_u, step_task and episode_return, or episode_regret_true")
    for ax, needs in zip((ax_a, ax_b, ax_c, ax_c2), panel_needs):
        if ax.lines:
            ax.legend(fontsize=7)
        else:  # no learner of the figure declared the curve this panel draws
            ax.text(0.5, 0.5, f"no learner declares {needs}", transform=ax.transAxes, ha="center", fontsize=8)
        ax.title.set_fontsize(9)
    if violin:
        d = pd.concat(violin, ignore_index=True)
        order = sorted(d["planner"].unique())
        sns.violinplot(data=d, x="planner", y="diff", hue="planner", order=order, hue_order=order,
                       palette=colors, cut=0, ax=ax_d, legend=False, density_norm="width")
    ax_d.set(xlabel="learner", ylabel="deformation above the optimum (%)",
             title="(d) layouts tried in training")
    ax_d.title.set_fontsize(9)


# deformation fields ---------------------------------------------------------------------------------

def _problem_for_row(row):
    """The problem a row was run on (its case, material, agents and tasks), to draw its fields."""
    from fixbench.cases.problem import problem_for

    n_tasks = int(row["n_tasks"])
    p = problem_for(row["case"], row["material"], None, n_tasks)
    if p.n_agents != int(row["agents"]):
        p = problem_for(row["case"], row["material"], int(row["agents"]), n_tasks)
    return p


def field_figure(ok: pd.DataFrame, case: str, refs: dict, name: str | None = None):
    """The part's |u| under each planner's best layout (and the optimum), one material and task, titled
    with ``name`` (default: ``case``, as the rows hold it). Each panel has its own colour scale and bar:
    one scale set by the worst layout would flatten the good ones into one colour."""
    d = ok[(ok["case"] == case) & ok["layouts"].notna()]
    mat = sorted(d["material"].unique())[0]
    d = d[d["material"] == mat]
    first = d.iloc[0]
    problem = _problem_for_row(first)
    ref = refs.get(reference_of(first))
    task = int(np.argmax(ref["per_task"])) if ref is not None and first["mode"] != "shared" else 0
    panels = []
    if ref is not None and ref.get("layouts") and first["mode"] != "shared":
        panels.append((f"optimum ({'proven' if ref.get('proven') else 'best known'})",
                       ref["layouts"][task]))
    for lab in sorted(d["label"].unique()):
        best = d[d["label"] == lab].sort_values(["objective_m", "seed"], kind="stable").iloc[0]
        lay = best["layouts"]
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
        outline(ax, problem, lw=0.8)
        c = problem.pad_xy(lay) * 1e3
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
    fig.suptitle(f"{name or case}, {mat}, task {task}: fixtures in red", fontsize=10)
    return fig, mat, task
