"""The answer on generated parts (docs/families.md): the comparison over families of parts, not parts.

A run on a shipped suite's parts (a matrix's ``suites = [...]``) has tens of cases, each a draw; what is
asked of it is per family of parts and pooled over them. :func:`fixbench.bench.reporting.report.make_report`
adds these when a run's cases are generated parts:

    family_iqm_table       per planner entry, per family of parts and samples a position k, and pooled over
                           every part at each k: the interquartile mean of the per-position relative regret
                           (rliable; a stratified bootstrap, the cells resampled within each (part, position))
    family_headline        per column, the best entry of each family of planners by that IQM and rliable's
                           P(best learning entry < best other entry) over their cells
    rank_correlation_table Kendall's tau between the entries' orders (by IQM) of every two columns at one k:
                           does the ranking carry from one family of parts to another?
    cpu_regret_figure      each entry's median CPU a cell beside its pooled IQM, at each k
"""

from __future__ import annotations

import itertools
import json

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from scipy.stats import kendalltau

from fixbench.bench.reporting.comparison import FAMILIES, LEARNING, NOT_COMPARED, position_regrets, scored_cells
from fixbench.bench.reporting.stats import bootstrap_ci, iqm, probability_of_improvement
from fixbench.bench.reporting.tables import ci_column, fmt
from fixbench.cases.families.suites import SUITE_DIR

#: the column pooling every family of parts
POOLED = "all parts"


def part_families() -> dict[str, str]:
    """Every generated part of the shipped suites, by case name, with its family."""
    out = {}
    for manifest in sorted(SUITE_DIR.glob("*/suite.json")):
        for p in json.loads(manifest.read_text(encoding="utf-8"))["parts"]:
            out[p["name"]] = p["family"]
    return out


def _columns(scored: pd.DataFrame) -> list[tuple[str, str | None, int]]:
    """(column name, family of parts or None for the pool, k) in the order the tables show them."""
    ks = sorted({int(k) for k in scored["samples_per_task"].dropna()})
    fams = list(dict.fromkeys(scored["part_family"]))
    return [(f"{f}, k={k}", f, k) for k in ks for f in fams] + [(f"{POOLED}, k={k}", None, k) for k in ks]


def _with_families(rows: pd.DataFrame) -> pd.DataFrame:
    """The per-task cells on generated parts, scored, with their part's family."""
    fam = part_families()
    scored = scored_cells(rows)
    scored = scored[(scored["mode"] == "per-task") & scored["case"].isin(fam)]
    return scored.assign(part_family=scored["case"].map(fam))


def family_iqm_table(rows: pd.DataFrame, refs: dict) -> pd.DataFrame:
    """Per planner entry and column (:func:`_columns`): IQM of the per-position relative regrets (%) of
    its cells pooled, a 95 % stratified-bootstrap CI (strata: part x position), and the cells."""
    scored = _with_families(rows)
    recs = []
    for label, mine in scored.groupby("label", sort=True):
        rec = {"planner": label}
        for name, fam, k in _columns(scored):
            pick = mine[(mine["samples_per_task"] == k) & ((mine["part_family"] == fam) if fam else True)]
            regrets, strata = [], []
            for _, row in pick.iterrows():
                r = position_regrets(row, refs)
                if r is not None:
                    regrets.append(r)
                    strata.append([f"{row['case']}/{i}" for i in range(len(r))])
            values = np.concatenate(regrets) if regrets else np.array([])
            keys = np.unique(np.concatenate(strata), return_inverse=True)[1] if strata else None
            p, lo, hi = bootstrap_ci(values, strata=keys, stat=iqm)
            rec.update({name: p, f"{name}_lo": lo, f"{name}_hi": hi, f"{name}_cells": len(regrets)})
        recs.append(rec)
    return pd.DataFrame(recs)


def _names(iq: pd.DataFrame) -> list[str]:
    return [c for c in iq.columns if c != "planner" and not c.endswith(("_lo", "_hi", "_cells"))]


def show_family_iqm(iq: pd.DataFrame) -> pd.DataFrame:
    """``IQM [lo, hi]`` per column; at k = 0 an entry with no cell cannot act without a sample."""
    out = pd.DataFrame({"planner": iq["planner"]})
    for name in _names(iq):
        shown = ci_column(iq, name)
        if name.endswith("k=0"):
            shown = [s if n else "cannot act" for s, n in zip(shown, iq[f"{name}_cells"])]
        out[name] = shown
    return out.sort_values("planner").reset_index(drop=True)


def family_headline(rows: pd.DataFrame, iq: pd.DataFrame, family_of: dict[str, str]) -> pd.DataFrame:
    """Per column: the best entry of each family of planners (``family_of``: planner -> family) by IQM,
    and P(a cell of the best learning entry has a lower regret than one of the best other entry)."""
    planner = rows.drop_duplicates("label").set_index("label")["planner"]
    fam = {label: family_of.get(str(name), "other") for label, name in planner.items()}
    scored = _with_families(rows)
    cols = {name: (f, k) for name, f, k in _columns(scored)}
    recs = []
    for name in _names(iq):
        values = iq.set_index("planner")[[name, f"{name}_lo", f"{name}_hi"]].dropna()
        best = {}
        for f in [f for f in FAMILIES if f not in NOT_COMPARED]:
            mine = values[values.index.map(fam.get) == f]
            if len(mine):
                best[f] = mine[name].idxmin()
                recs.append({"family": f, "column": name, "entry": best[f], "iqm": mine.loc[best[f], name],
                             "iqm_lo": mine.loc[best[f], f"{name}_lo"], "iqm_hi": mine.loc[best[f], f"{name}_hi"]})
        learners = [best[f] for f in LEARNING if f in best]
        others = [best[f] for f in best if f not in LEARNING]
        if learners and others:
            x_label = min(learners, key=lambda b: values.loc[b, name])
            y_label = min(others, key=lambda b: values.loc[b, name])
            f, k = cols[name]
            here = scored[(scored["samples_per_task"] == k) & ((scored["part_family"] == f) if f else True)]
            p, lo, hi = probability_of_improvement(here.loc[here["label"] == x_label, "regret_pct"],
                                                   here.loc[here["label"] == y_label, "regret_pct"])
            recs.append({"family": "P(learner < classical)", "column": name, "entry": f"{x_label} vs {y_label}",
                         "iqm": p, "iqm_lo": lo, "iqm_hi": hi})
    return pd.DataFrame(recs, columns=["family", "column", "entry", "iqm", "iqm_lo", "iqm_hi"])


def show_family_headline(head: pd.DataFrame) -> pd.DataFrame:
    text = head.assign(cell=[f"{e}: {t}" for e, t in zip(head["entry"], ci_column(head, "iqm"))])
    wide = text.pivot(index="family", columns="column", values="cell")
    order = [f for f in FAMILIES if f in set(head["family"])] + ["P(learner < classical)"]
    wide = wide.reindex(index=[f for f in order if f in wide.index],
                        columns=list(dict.fromkeys(head["column"]))).fillna("-")
    wide.index = [FAMILIES.get(f, f) for f in wide.index]
    return wide.rename_axis("best of each family").reset_index()


def rank_correlation_table(iq: pd.DataFrame) -> pd.DataFrame:
    """Kendall's tau (tau-b) between the entries' IQM orders in every two columns with the same k, over
    the entries with a value in both (at least three)."""
    recs = []
    by_k: dict[str, list[str]] = {}
    for name in _names(iq):
        by_k.setdefault(name.rsplit("k=", 1)[1], []).append(name)
    for k, names in by_k.items():
        for a, b in itertools.combinations(names, 2):
            both = iq[[a, b]].dropna()
            if len(both) < 3:  # two entries agree or not by a coin's toss: no order to compare
                continue
            tau = kendalltau(both[a], both[b]).statistic
            recs.append({"k": int(k), "a": a.rsplit(",", 1)[0], "b": b.rsplit(",", 1)[0], "entries": len(both),
                         "kendall_tau": float(tau)})
    return pd.DataFrame(recs, columns=["k", "a", "b", "entries", "kendall_tau"])


def show_rank_correlation(table: pd.DataFrame) -> pd.DataFrame:
    return table.assign(kendall_tau=table["kendall_tau"].map(fmt))


def cpu_regret_figure(rows: pd.DataFrame, iq: pd.DataFrame):
    """Each entry's median CPU seconds a cell (x, log) beside its pooled IQM regret (y, log), one panel
    a k: what each entry's regret costs on a machine, beside what it costs in samples."""
    scored = _with_families(rows)
    pooled = [n for n in _names(iq) if n.startswith(POOLED)]
    fig, axes = plt.subplots(1, max(len(pooled), 1), figsize=(5.5 * max(len(pooled), 1), 4.5), squeeze=False)
    for ax, name in zip(axes[0], pooled):
        k = int(name.rsplit("k=", 1)[1])
        cpu = scored[scored["samples_per_task"] == k].groupby("label")["cpu_s"].median()
        table = iq.set_index("planner")[name].dropna()
        labels = [lb for lb in table.index if lb in cpu.index]
        ax.scatter([cpu[lb] for lb in labels], [table[lb] for lb in labels], s=18)
        for lb in labels:
            ax.annotate(lb, (cpu[lb], table[lb]), fontsize=7, xytext=(3, 2), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_xlabel("median CPU a cell (s)")
        ax.set_ylabel("IQM relative regret over every part (%)")
        ax.set_title(f"k = {k} samples a position")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig
