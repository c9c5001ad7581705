"""The comparison fixbench exists for: planners (MARL and classical) at equal samples.

:func:`fixbench.bench.reporting.report.make_report` writes these as report sections:

    main_table          the README's main table: mean relative regret per case and mean rank over problems
    sweep_table         budget sweep: relative regret per case x planner x samples a task (its figure:
                        :func:`fixbench.bench.reporting.figures.sweep_figure`)
    heldout_table       held-out track: regret on the held-out tasks of learners that trained on the others,
                        beside planners that pay samples on every task, scored on the same tasks
    improvement_table   rliable's probability of improvement P(X < Y) between every ordered pair of planners
    versus_best_table   P(X < best) of every planner against the one ranked first, per column of the main
                        table (the README's second table: can anything beat the best?)
    policy_table        the learners' second figure: their greedy policy's regret beside the incumbents'
    iqm_table           per-position regrets pooled over runs: interquartile mean with rliable's stratified
                        bootstrap (runs resampled within each position), beside the main table's means
    headline_table      the README's headline: the best entry of each family of planners by that IQM, per
                        case and track, and the chance the best learner's cells beat the best classical one's

Scoring (docs/protocol.md#scoring): per-task and shared cells are scored by each planner's incumbent
(the best layout it evaluated on a task), held-out cells by the layouts returned on the held-out tasks;
a learner's policy is never in the ranking, only in ``policy_table``.

Every table takes a run's rows as :func:`fixbench.bench.records.rows.load_rows` gives them (``label``, ``ok``,
``mode`` filled in) and groups them by the keys of :mod:`fixbench.bench.records.rows`.
Relative regret is ``objective / reference objective - 1`` (:mod:`fixbench.bench.running.cells`); every statistic leaves
failed cells out (the main table's rank counts them last). Confidence intervals are 95 % percentile
bootstraps (:func:`fixbench.bench.reporting.stats.mean_ci`,
:func:`fixbench.bench.reporting.stats.probability_of_improvement`), so the same rows always give the same tables.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from fixbench.bench.records.keys import split
from fixbench.bench.records.rows import RANKED, budget_level, reference_of, with_case_defaults
from fixbench.bench.reporting.stats import bootstrap_ci, iqm, mean_ci, probability_of_improvement
from fixbench.bench.reporting.tables import ci_column, fmt, setting_text

#: the headline's families of planners (``Planner.family``), in its order, with their headings; a family
#: not listed (a plugin's own) follows under its own name
FAMILIES = {"marl": "MARL learners", "bandit": "bandit learners", "evolutionary": "swarm / evolutionary",
            "local-search": "local and greedy search", "case-based": "case-based", "qp": "QP relaxation",
            "bayesian-optimisation": "Bayesian optimisation", "rules": "rules", "random": "random"}
#: the families that learn across positions (the seed's question: do they beat the others?)
LEARNING = ("marl", "bandit")
#: families outside the comparison: the reference planner
NOT_COMPARED = ("exact",)


# rows scored against the reference --------------------------------------------------------------------

def scored_cells(rows: pd.DataFrame) -> pd.DataFrame:
    """Successful rows with a finite relative regret, with ``regret_pct`` (%)."""
    ok = rows[rows["ok"] & np.isfinite(rows["relative_regret"])]
    return ok.assign(regret_pct=ok["relative_regret"] * 100)


def _regret_stats(values) -> dict:
    """Mean relative regret (%) and its CI as a table record's columns."""
    p, lo, hi = mean_ci(values)
    return {"regret_pct": p, "regret_pct_lo": lo, "regret_pct_hi": hi}


# the budget sweep -----------------------------------------------------------------------------------

def sweep_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Budget sweep: per case x planner label x samples a task, the mean relative regret (%) of the
    per-task-mode cells with its 95 % CI, and the number of cells (failed ones left out)."""
    d = scored_cells(rows)
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
                         "regret (%)": ci_column(table, "regret_pct")})


# the held-out track ---------------------------------------------------------------------------------

def _heldout_regret(row, refs: dict, every: int) -> float:
    """Relative regret of a per-task row on the held-out tasks only: mean of its per-task max
    deformation over them against the reference's mean over them; NaN without either."""
    ref = refs.get(reference_of(row))
    per_task = row.get("per_task_m")
    if ref is None or not isinstance(per_task, list) or not per_task:
        return math.nan
    u = np.asarray(per_task, dtype=float)
    opt = np.asarray(ref["per_task"], dtype=float)
    idx = split(int(row["n_tasks"]), every)[1]
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
    held = scored_cells(ok[ok["mode"] == "held-out"])
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
                         "cells": table["cells"], "regret on held-out tasks (%)": ci_column(table, "regret_pct")})


# probability of improvement -------------------------------------------------------------------------

def improvement_table(rows: pd.DataFrame, group: Sequence[str] = ()) -> pd.DataFrame:
    """rliable's probability of improvement P(X < Y) of relative regret between every ordered pair of
    planner labels per case (and per value of the ``group`` columns, e.g. samples a task), with its 95 %
    CI and the cells of each. Each unordered pair is bootstrapped once: P(Y < X) = 1 - P(X < Y) holds in
    every resample (ties count 1/2 both ways), so the reverse line is its mirror."""
    keys = ["case", *group]
    d = scored_cells(rows)
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

def problem_ranks(rows: pd.DataFrame) -> pd.DataFrame:
    """Rank of each planner label on each problem (case x material x seed x agents x tasks x mode x
    budget level): 1 = lowest objective, failed cells last (ties share the mean rank). A cell without a
    budget level (a planner with its own budget, e.g. ``exact`` unlimited) competes at every level of its
    other keys; planners without a cell on a problem take no part in it (:data:`~fixbench.bench.records.rows.RANKED`,
    :func:`~fixbench.bench.records.rows.budget_level`)."""
    keys = list(RANKED)
    rows = with_case_defaults(rows)
    d = rows.assign(level=budget_level(rows),
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
    modes = list(dict.fromkeys(rows["mode"]))
    cases = list(dict.fromkeys(rows["case"]))
    if len(modes) == 1:
        return [(case, case, None) for case in cases]
    return [(f"{case} ({mode})", case, mode) for mode in modes for case in cases]


def _in_column(scored: pd.DataFrame, case: str, mode: str | None) -> pd.Series:
    """The rows of one main-table column (:func:`main_columns`): its case, and its mode when the run
    has several."""
    pick = scored["case"] == case
    if mode is not None:
        pick &= scored["mode"] == mode
    return pick


def common_ranks(rows: pd.DataFrame) -> tuple[pd.DataFrame, int, int]:
    """Each label's ranks (:func:`problem_ranks`) on the problems every label ran on, so that a mean
    rank compares like with like; where no problem has them all, on every problem. Returns (ranks,
    problems used, problems in all)."""
    ranks = problem_ranks(rows)
    keys = [*RANKED, "level"]
    present = ranks.groupby(keys, dropna=False)["label"].transform("nunique")
    common = ranks[present == ranks["label"].nunique()]
    n_all = len(ranks[keys].drop_duplicates())
    used = common if len(common) else ranks
    return used, len(used[keys].drop_duplicates()), n_all


def main_table(rows: pd.DataFrame) -> pd.DataFrame:
    """The README's main table: one line a planner label with the mean relative regret (%) on each
    case, and mode when the run has several (columns ``<name>``, ``<name>_lo``, ``<name>_hi``: 95 % CI
    over its successful cells, all budgets of the run) and the mean rank over the problems every label
    ran on (:func:`common_ranks`; ``attrs["ranked_on"]``: (problems used, problems in all)), sorted by it."""
    used, n_used, n_all = common_ranks(rows)
    ranks = used.groupby("label")["rank"].agg(["mean", "size"])
    scored = scored_cells(rows)
    recs = []
    for label in sorted(rows["label"].unique()):
        rec = {"planner": label}
        for name, case, mode in main_columns(rows):
            pick = (scored["label"] == label) & _in_column(scored, case, mode)
            p, lo, hi = mean_ci(scored.loc[pick, "regret_pct"])
            rec.update({name: p, f"{name}_lo": lo, f"{name}_hi": hi})
        ranked = label in ranks.index
        rec.update(mean_rank=float(ranks.loc[label, "mean"]) if ranked else math.nan,
                   problems=int(ranks.loc[label, "size"]) if ranked else 0)
        recs.append(rec)
    df = pd.DataFrame(recs)
    df = df.sort_values(["mean_rank", "planner"], kind="stable", na_position="last").reset_index(drop=True)
    df.attrs["ranked_on"] = (n_used, n_all)
    return df


def show_main(table: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """The main table formatted like README: ``mean [lo, hi]`` per column, then the mean rank."""
    out = pd.DataFrame({"planner": table["planner"]})
    for name in columns:
        out[name] = ci_column(table, name)
    out["mean rank"] = table["mean_rank"].map(lambda v: fmt(v, 3))
    out["problems"] = table["problems"]
    return out


def versus_best_table(rows: pd.DataFrame, main: pd.DataFrame,
                      exclude: Sequence[str] = ()) -> tuple[pd.DataFrame, str]:
    """rliable's probability of improvement P(X < best) of every other planner label X against the label
    ranked first in the main table (``exclude``: labels that are not contenders, e.g. the reference
    planner ``exact``), per main-table column (case, and mode when several; all budgets pooled as
    there), with its 95 % CI and the cells of each side. Returns the table (columns ``<name>``,
    ``<name>_lo``, ``<name>_hi``, ``<name>_cells``, in main-table order) and the best label."""
    contenders = [str(p) for p in main["planner"] if p not in exclude]
    best = contenders[0]
    scored = scored_cells(rows)
    recs = []
    for label in contenders[1:]:
        rec = {"planner": label}
        for name, case, mode in main_columns(rows):
            pick = _in_column(scored, case, mode)
            x = scored.loc[pick & (scored["label"] == label), "regret_pct"].to_numpy()
            y = scored.loc[pick & (scored["label"] == best), "regret_pct"].to_numpy()
            p, lo, hi = probability_of_improvement(x, y) if len(x) and len(y) else (np.nan,) * 3
            rec.update({name: p, f"{name}_lo": lo, f"{name}_hi": hi, f"{name}_cells": f"{len(x)} vs {len(y)}"})
        recs.append(rec)
    return pd.DataFrame(recs), best


def policy_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per planner label with a policy figure (a learner) and main-table column of a per-task track: the
    mean relative regret (%) of its incumbents (what the ranking uses) and of its greedy policy's layouts,
    each with a 95 % CI over the same cells (columns ``<name>``, ``<name>_lo``, ``<name>_hi`` and
    ``<name> policy``...)."""
    scored = scored_cells(rows)
    if "policy_relative_regret" not in scored:
        return pd.DataFrame()
    scored = scored.assign(policy_pct=scored["policy_relative_regret"] * 100)
    scored = scored[np.isfinite(scored["policy_pct"]) & (scored["mode"] != "held-out")]
    columns = [(n, c, m) for n, c, m in main_columns(rows) if m != "held-out"]
    recs = []
    for label in sorted(scored["label"].unique()):
        rec = {"planner": label}
        for name, case, mode in columns:
            pick = (scored["label"] == label) & _in_column(scored, case, mode)
            for col, key in ((name, "regret_pct"), (f"{name} policy", "policy_pct")):
                p, lo, hi = mean_ci(scored.loc[pick, key])
                rec.update({col: p, f"{col}_lo": lo, f"{col}_hi": hi})
        recs.append(rec)
    return pd.DataFrame(recs)


def show_policy(table: pd.DataFrame) -> pd.DataFrame:
    """The policy table formatted like the main table: ``mean [lo, hi]`` per column."""
    out = pd.DataFrame({"planner": table["planner"]})
    for name in [c for c in table.columns if c != "planner" and not c.endswith(("_lo", "_hi"))]:
        out[name.replace(" policy", ", policy") if name.endswith(" policy") else f"{name}, incumbent"] = \
            ci_column(table, name)
    return out


def position_regrets(row, refs: dict) -> np.ndarray | None:
    """A row's relative regret (%) on each task it is scored on, against the reference's value there
    (held-out rows: the held-out tasks); None without a per-task list or a reference."""
    ref = refs.get(reference_of(row))
    per_task = row.get("per_task_m")
    if ref is None or not isinstance(per_task, list) or not per_task:
        return None
    u = np.asarray(per_task, dtype=float)
    opt = np.asarray(ref["per_task"], dtype=float)
    n = int(row["n_tasks"])
    if not len(u) == len(opt) == n:
        return None
    idx = split(n, int(row["heldout_every"]))[1] if row["mode"] == "held-out" else list(range(n))
    return (u[idx] / opt[idx] - 1) * 100


def iqm_table(rows: pd.DataFrame, refs: dict) -> pd.DataFrame:
    """Per planner label and main-table column of a per-task or held-out track: the interquartile mean
    of the per-position relative regrets (%) of all its cells pooled (runs x positions), with a 95 %
    stratified-bootstrap CI (rliable, Agarwal et al. NeurIPS 2021: the runs are resampled within each
    position), beside the mean of the same pooled values. The main table's regret is the mean
    deformation's regret, so a few positions where a planner is far off weigh in it; the IQM drops the
    best and worst quarter of (run, position) pairs. Shared-mode cells (scored by their worst task) are
    left out."""
    scored = scored_cells(rows)
    scored = scored[scored["mode"].isin(["per-task", "held-out"])]
    columns = [(n, c, m) for n, c, m in main_columns(rows) if m != "shared"]
    recs = []
    for label in sorted(scored["label"].unique()):
        rec = {"planner": label}
        for name, case, mode in columns:
            pick = (scored["label"] == label) & _in_column(scored, case, mode)
            regrets = [r for r in (position_regrets(row, refs) for _, row in scored[pick].iterrows())
                       if r is not None]
            values = np.concatenate(regrets) if regrets else np.array([])
            strata = np.concatenate([np.arange(len(r)) for r in regrets]) if regrets else None
            p, lo, hi = bootstrap_ci(values, strata=strata, stat=iqm)
            rec.update({name: p, f"{name}_lo": lo, f"{name}_hi": hi,
                        f"{name} mean": float(values.mean()) if len(values) else math.nan})
        recs.append(rec)
    return pd.DataFrame(recs)


def show_iqm(table: pd.DataFrame) -> pd.DataFrame:
    """The IQM table formatted like the main table: ``IQM [lo, hi]`` and the pooled mean per column."""
    out = pd.DataFrame({"planner": table["planner"]})
    for name in [c for c in table.columns if c != "planner" and not c.endswith(("_lo", "_hi", " mean"))]:
        out[f"{name}, IQM"] = ci_column(table, name)
        out[f"{name}, mean"] = table[f"{name} mean"].map(fmt)
    return out


def show_versus_best(table: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """The versus-best table formatted like the main table: ``P [lo, hi] (cells)`` per column."""
    out = pd.DataFrame({"planner": table["planner"]})
    for name in columns:
        out[name] = [f"{t} ({c})" for t, c in zip(ci_column(table, name), table[f"{name}_cells"])]
    return out


def headline_table(rows: pd.DataFrame, iq: pd.DataFrame, family_of: dict[str, str]) -> pd.DataFrame:
    """The README's headline, from the IQM table (:func:`iqm_table`): for each main-table column of a
    per-task or held-out track and each family of planners (``family_of``: planner name -> family), the
    family's best entry (label) by the IQM of its per-position regret, with the IQM's interval; and per
    column rliable's probability that a cell of the best learning entry (families :data:`LEARNING`) ends
    with a lower regret than a cell of the best other entry (``family`` "P(learner < classical)": the
    two labels in ``entry``). Long form: one line a (family, column)."""
    planner = rows.drop_duplicates("label").set_index("label")["planner"]
    fam = {label: family_of.get(str(name), "other") for label, name in planner.items()}
    families = [f for f in FAMILIES if f in fam.values()]
    families += sorted({f for f in fam.values() if f not in FAMILIES and f not in NOT_COMPARED})
    columns = {name: (case, mode) for name, case, mode in main_columns(rows)}
    scored = scored_cells(rows)
    recs = []
    for name in [c for c in iq.columns if c in columns]:
        values = iq.set_index("planner")[[name, f"{name}_lo", f"{name}_hi"]].dropna()
        best = {}
        for f in families:
            mine = values[values.index.map(fam.get) == f]
            if len(mine):
                label = mine[name].idxmin()
                best[f] = label
                recs.append({"family": f, "column": name, "entry": label, "iqm": mine.loc[label, name],
                             "iqm_lo": mine.loc[label, f"{name}_lo"], "iqm_hi": mine.loc[label, f"{name}_hi"]})
        learners = [best[f] for f in LEARNING if f in best]
        others = [best[f] for f in families if f not in LEARNING and f in best]
        if learners and others:
            x_label = min(learners, key=lambda b: values.loc[b, name])
            y_label = min(others, key=lambda b: values.loc[b, name])
            pick = _in_column(scored, *columns[name])
            x = scored.loc[pick & (scored["label"] == x_label), "regret_pct"]
            y = scored.loc[pick & (scored["label"] == y_label), "regret_pct"]
            p, lo, hi = probability_of_improvement(x, y)
            recs.append({"family": "P(learner < classical)", "column": name, "entry": f"{x_label} vs {y_label}",
                         "iqm": p, "iqm_lo": lo, "iqm_hi": hi})
    return pd.DataFrame(recs, columns=["family", "column", "entry", "iqm", "iqm_lo", "iqm_hi"])


def show_headline(table: pd.DataFrame) -> pd.DataFrame:
    """The headline formatted: a line a family (its heading), a column a case and track, each cell the best
    entry and ``IQM [lo, hi]``; the last line the probability of improvement and the two entries."""
    text = table.assign(cell=[f"{e}: {t}" for e, t in zip(table["entry"], ci_column(table, "iqm"))])
    wide = text.pivot(index="family", columns="column", values="cell")
    present = set(table["family"])
    order = [f for f in FAMILIES if f in present] + [f for f in dict.fromkeys(table["family"]) if f not in FAMILIES]
    wide = wide.reindex(index=[f for f in order if f != "P(learner < classical)"] + ["P(learner < classical)"],
                        columns=list(dict.fromkeys(table["column"]))).fillna("-")
    wide.index = [FAMILIES.get(f, f) for f in wide.index]
    return wide.rename_axis("best of each family").reset_index()

