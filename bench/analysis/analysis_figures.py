"""Figures of the analyses (matplotlib): the seed's Figure 3 (a 2-agent joint table with its
best-response curves and person-by-person optima), the equilibrium landscape of the small cases,
and the best max deformation against the number of robots.

Each function returns a figure; the caller saves it (:func:`fixbench.bench.reporting.plots.save_png`).
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm, Normalize  # noqa: E402

from fixbench.bench.analysis.equilibria import Landscape, pbp_mask  # noqa: E402
from fixbench.bench.reporting.figures import REGRET_FLOOR_PCT, panel_grid  # noqa: E402


def figure3(table: np.ndarray, title: str):
    """Heat map of a 2-agent table (max |u| in um; log colours over more than a decade) over agent
    0's (x) and agent 1's (y) candidates, each agent's best-response curve over it, every PBP optimum
    (where the curves meet) circled and the global optimum starred."""
    if table.ndim != 2:
        raise ValueError(f"Figure 3 needs a 2-agent table, got {table.ndim} agents")
    um = table.T * 1e6  # rows: agent 1's candidates (y), columns: agent 0's (x)
    fig, ax = plt.subplots(figsize=(6.8, 6.0))
    wide = um.max() > 10 * um.min()  # log colours only over more than a decade
    norm = LogNorm(vmin=um.min(), vmax=um.max()) if wide else Normalize(vmin=um.min(), vmax=um.max())
    mesh = ax.pcolormesh(um, norm=norm, cmap="viridis_r")
    fig.colorbar(mesh, ax=ax, label="max |u| (um)")
    n0, n1 = table.shape
    centre = 0.5
    ax.plot(np.argmin(table, axis=0) + centre, np.arange(n1) + centre, color="deepskyblue", lw=1.2,
            marker=".", ms=3, label="agent 0's best response to agent 1")
    ax.plot(np.arange(n0) + centre, np.argmin(table, axis=1) + centre, color="orange", lw=1.2,
            marker=".", ms=3, label="agent 1's best response to agent 0")
    i, j = np.nonzero(pbp_mask(table))
    ax.scatter(i + centre, j + centre, s=90, facecolors="none", edgecolors="red", lw=1.8,
               label=f"person-by-person optima ({len(i)})")
    g0, g1 = np.unravel_index(np.argmin(table), table.shape)
    ax.scatter([g0 + centre], [g1 + centre], marker="*", s=220, color="red", edgecolors="black", lw=0.8,
               label=f"global optimum ({table.min() * 1e6:.3g} um)")
    ax.set_xlabel(f"agent 0's candidate (position in its set of {n0})")
    ax.set_ylabel(f"agent 1's candidate (position in its set of {n1})")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=2, frameon=False)
    return fig


def landscape_figure(landscapes: dict[str, list[Landscape]]):
    """Per case (a column): top, every PBP optimum's regret against its basin (share of descents);
    bottom, the share of best-response descents ending within a regret (ECDF), one line per task.
    A regret of 0 (a global optimum) is drawn at REGRET_FLOOR_PCT on the log axes, a PBP optimum that
    no descent reached as a triangle at half a descent's share."""
    cases = list(landscapes)
    fig, axes = panel_grid(2 * len(cases), max_cols=len(cases), width=3.2 * len(cases), row_height=3.2)
    colors = plt.get_cmap("tab10")
    for c, case in enumerate(cases):
        top, bottom = axes[c], axes[len(cases) + c]
        for t, land in enumerate(landscapes[case]):
            pct = np.maximum(land.regret * 100, REGRET_FLOOR_PCT)
            share = land.basin / land.starts * 100
            seen = share > 0
            top.scatter(pct[seen], share[seen], s=14, color=colors(t % 10), label=f"task {t}")
            top.scatter(pct[~seen], np.full((~seen).sum(), 100 / land.starts / 2), s=14, marker="v",
                        color=colors(t % 10))
            end = np.sort(np.maximum(land.end_regret * 100, REGRET_FLOOR_PCT))
            bottom.step(end, np.arange(1, len(end) + 1) / len(end) * 100, where="post", color=colors(t % 10),
                        label=f"task {t}")
        top.set(xscale="log", yscale="log", title=case, xlabel="regret of the PBP optimum (%)",
                ylabel="basin (% of descents)" if c == 0 else None)
        bottom.set(xscale="log", ylim=(0, 101), xlabel="regret where a descent stops (%)",
                   ylabel="descents (%, cumulative)" if c == 0 else None)
        for ax in (top, bottom):
            ax.axvline(5, color="0.5", lw=0.8, ls="--")
            ax.grid(alpha=0.3)
        bottom.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"Person-by-person optima (top) and where best-response descents stop (bottom); a regret of 0 "
                 f"(a global optimum) is drawn at {REGRET_FLOOR_PCT:g} %, 5 % dashed", fontsize=9)
    return fig


def robots_figure(rows: list[dict], tolerance_m: float, title: str):
    """Best max deformation (um, log) against the number of robots: one line per task, or above 12
    tasks the median with a min-max bar; proven points filled, best-known ones open; lines join only
    consecutive agent counts (none is drawn across an unavailable one); the tolerance dashed.
    ``rows``: :func:`fixbench.bench.analysis.robots.robots_table` records."""
    known = [r for r in rows if r["per_task_m"] is not None]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    if known:
        n = np.array([r["agents"] for r in known])
        u = np.array([r["per_task_m"] for r in known]) * 1e6  # (N values, tasks)
        proven = np.array([r["proven"] for r in known])
        runs = np.split(np.arange(len(n)), np.flatnonzero(np.diff(n) > 1) + 1)  # consecutive counts
        many = u.shape[1] > 12
        lines = ([("tasks: median", np.median(u, axis=1))] if many
                 else [(f"task {t}", u[:, t]) for t in range(u.shape[1])])
        colors = plt.get_cmap("tab10")
        for i, (label, y) in enumerate(lines):
            c = colors(i % 10)
            for k, run in enumerate(runs):
                ax.plot(n[run], y[run], color=c, lw=1, label=label if k == 0 else None)
            ax.scatter(n[proven], y[proven], color=c, s=18)
            ax.scatter(n[~proven], y[~proven], facecolors="white", edgecolors=c, s=18, zorder=3)
        if many:
            ax.vlines(n, u.min(axis=1), u.max(axis=1), color=colors(0), alpha=0.4, lw=6, label="tasks: min-max")
    ax.axhline(tolerance_m * 1e6, color="black", ls="--", lw=1, label=f"tolerance {tolerance_m * 1e6:g} um")
    missing = [r["agents"] for r in rows if r["per_task_m"] is None]
    ax.set(yscale="log", xlabel="robots (agents)", ylabel="best max |u| (um)",
           title=title + (f"\nno optimum or reference for N = {', '.join(map(str, missing))}" if missing else ""))
    ax.set_xticks([r["agents"] for r in rows])
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncols=2)
    return fig
