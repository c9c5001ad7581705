"""``fixbench report``: tables and figures of a run directory (docs/reporting.md).

Everything is read back from the run directory: rows (:func:`fixbench.bench.records.rows.load_rows`, through
:mod:`fixbench.bench.reporting.merge`), anytime traces and learners' training curves
(:mod:`fixbench.bench.records.store`) and the regret references. The report folder gets

    report.md                   the tables (Markdown) and the figures (relative links)
    index.html                  the same as one self-contained page, with the run's provenance
    tables/<name>.csv|.tex|.md  every table: CSV with plain numbers, LaTeX and Markdown formatted
    figures/<name>.png|.pdf     every figure

Statistics follow the conventions of docs/reporting.md: means and rliable-style interquartile
means with 95 % stratified percentile-bootstrap confidence intervals (strata: the problems, i.e.
materials, agents and task counts; resampled over seeds), COCO-style runtime-to-target ECDFs and
Dolan-More performance profiles. Cells whose row carries an error are counted in ``failed`` and left
out of every statistic. The bootstrap generator has a fixed seed and PDFs carry no creation date, so
the same run directory always gives the same report.

The comparison fixbench exists for (planners at equal samples) comes from :mod:`fixbench.bench.reporting.comparison`:
the main table (``main``: regret per case, mean rank over problems), the budget sweep (``sweep``, table
and figure), the held-out track (``heldout``) and rliable's probability of improvement
(``improvement``); a section the run has no rows for is skipped with its reason.

This module reads the run and writes the folder; the numbers come from :mod:`fixbench.bench.reporting.stats`,
the tables from :mod:`fixbench.bench.reporting.tables` and :mod:`fixbench.bench.reporting.comparison`, the figures from
:mod:`fixbench.bench.reporting.figures`.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from fixbench.bench.records.rows import ORDER  # noqa: E402
from fixbench.bench.records.store import load_curves, load_traces  # noqa: E402
from fixbench.bench.reporting.comparison import (  # noqa: E402
    headline_table,
    heldout_table,
    improvement_table,
    iqm_table,
    main_columns,
    main_table,
    policy_table,
    show_headline,
    show_heldout,
    show_improvement,
    show_iqm,
    show_main,
    show_policy,
    show_sweep,
    show_versus_best,
    sweep_table,
    versus_best_table,
)
from fixbench.bench.reporting.figures import (  # noqa: E402
    REFERENCE_PLANNER,
    anytime_figure,
    anytime_records,
    ecdf_figure,
    field_figure,
    figure4,
    learner_runs,
    palette,
    profile_figure,
    sweep_figure,
    violin_figure,
)
from fixbench.bench.reporting.html_report import write_html  # noqa: E402
from fixbench.bench.reporting.merge import Runs, load_runs, run_names  # noqa: E402
from fixbench.bench.reporting.stats import N_BOOT, TARGETS, gap_traces, optima, performance_profile  # noqa: E402
from fixbench.bench.reporting.tables import (  # noqa: E402
    group_keys,
    profile_table,
    reference_table,
    show_numbers,
    show_summary,
    summary_table,
)
from fixbench.bench.reporting.verdict import show_verdict, verdict_table  # noqa: E402
from fixbench.bench.running.provenance import host_key  # noqa: E402
from fixbench.cases.references import check_sources  # noqa: E402
from fixbench.solvers.registry import listing  # noqa: E402

LEARNER_CURVES = ("episode_return", "step_reward")


# loading --------------------------------------------------------------------------------------------

def slug(text: str) -> str:
    """A file-name-safe form of a case name (which may be a path to a TOML file)."""
    name = Path(str(text)).stem if str(text).endswith(".toml") else str(text)
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "case"


def case_names(cases) -> dict[str, str]:
    """How the report names each case of the rows (as they hold it: a catalog name or a case file's
    path): a catalog case by its name, a case file by the name it gives itself (``[case] name``; the
    file's stem when the file cannot be read here); case files that give one name keep their file names
    beside it."""
    from fixbench.cases.errors import CaseError
    from fixbench.cases.spec import case_names as catalog
    from fixbench.cases.spec import load_case_spec

    known = set(catalog())
    named = {}
    for case in dict.fromkeys(map(str, cases)):
        try:
            named[case] = case if case in known else load_case_spec(case).name
        except CaseError:
            named[case] = Path(case).stem
    twice = {n for n in named.values() if list(named.values()).count(n) > 1}
    return {c: f"{n} ({Path(c).name})" if n in twice and c not in known else n for c, n in named.items()}


def check_scored_references(run_dir: Path, rows: pd.DataFrame, refs: dict) -> None:
    """Refuse (one line) a run whose rows or reference snapshots were scored against a shipped
    reference other than the one shipped now (:func:`fixbench.cases.references.check_sources`)."""
    check_sources([*rows["reference_source"], *(r.get("source") for r in refs.values())], str(run_dir))


# the report -----------------------------------------------------------------------------------------

class _Writer:
    """The report folder being written: tables and figures into their folders, report.md's lines."""

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
        """PNG and PDF of ``fig`` without dates or software names (the same run gives the same bytes)."""
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


def learner_cells(curves: pd.DataFrame, ok: pd.DataFrame) -> list[str]:
    """The successful cells with learners' training curves (Figure 4's cells)."""
    if curves.empty:
        return []
    has = curves[curves["curve"].isin(LEARNER_CURVES)]["cell"].unique()
    return sorted(set(has) & set(ok["cell"]))

# driver ---------------------------------------------------------------------------------------------

def _main_section(w: _Writer, rows: pd.DataFrame) -> None:
    """The README's main table (``main``): regret per case and mean rank over problems."""
    if not rows["ok"].any():
        w.skip("Main table", "no successful cells")
        return
    table = main_table(rows)
    n_used, n_all = table.attrs["ranked_on"]
    on = (f"all {n_all} problems (no problem has every planner)" if not table["problems"].eq(n_used).all()
          else f"the {n_used} of {n_all} problems every planner ran on")
    w.table("main", table, show_main(table, [name for name, _, _ in main_columns(rows)]),
            "Main table: relative regret against the reference (%, mean over every successful cell of the "
            "planner on the case (and mode, when the run has several; held-out cells are scored on the "
            f"held-out tasks) with a 95 % percentile-bootstrap CI, {N_BOOT} resamples, fixed seed; one "
            "scoring rule a track, every planner alike: per-task and shared cells by the planner's "
            "incumbent, the best layout it evaluated on each task, held-out cells by the layouts it returns "
            "on the held-out tasks, with zero samples there; a learner's policy is in the next table) and "
            f"the mean rank over {on} (a problem: case x material x seed x agents x tasks x mode x budget or "
            "samples a task; rank 1 = lowest max deformation, failed cells last, ties share; a planner with its "
            "own budget competes at every budget); sorted by mean rank.")
    policy = policy_table(rows)
    if not policy.empty:
        w.table("policy", policy, show_policy(policy),
                "Learners' second figure: relative regret (%) of their greedy policy's layouts (what the "
                "trained networks play with no more samples) beside that of their incumbents (the best "
                "layout they evaluated on each task, what the main table ranks), over the same per-task "
                "cells, with a 95 % percentile-bootstrap CI. Never in the ranking.")
    if (~table["planner"].isin([REFERENCE_PLANNER])).sum() < 2:
        return
    versus, best = versus_best_table(rows, table, exclude=(REFERENCE_PLANNER,))
    columns = [name for name, _, _ in main_columns(rows)]
    w.table("versus_best", versus, show_versus_best(versus, columns),
            f"Against the best: P(X < {best}), the chance that a random cell of each planner ends with a lower "
            f"relative regret than a random cell of `{best}` (ranked first in the main table after the "
            f"reference planner `{REFERENCE_PLANNER}`), per column of "
            "the main table, with a 95 % percentile-bootstrap CI and the cells of each side (rliable's "
            "probability of improvement; ties count 1/2). 0.5: as good; 0: never better.")


def _comparison_sections(w: _Writer, rows: pd.DataFrame, refs: dict) -> pd.DataFrame:
    """The budget sweep, held-out and probability-of-improvement tables (:mod:`fixbench.bench.reporting.comparison`),
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
    iq = iqm_table(rows, refs)
    if not iq.empty and len(iq.columns) > 1:
        w.table("iqm", iq, show_iqm(iq),
                "Interquartile mean (rliable) of the per-position relative regret (%), every cell's scored "
                "positions pooled (per-task: all; held-out: the held-out ones), with a 95 % stratified-"
                f"bootstrap CI ({N_BOOT} resamples, fixed seed; the runs are resampled within each position), "
                "and the mean of the same per-position regrets. The main table's regret is that of the mean "
                "deformation; the IQM leaves out the best and worst quarter of (run, position) pairs.")
        head = headline_table(rows, iq, {r["planner"]: r["family"] for r in listing()})
        if len(head):
            w.table("headline", head, show_headline(head),
                    "Headline: for each family of planners, its best entry on each case and track by the "
                    "interquartile mean of the per-position relative regret (%, the IQM table's, with its 95 % "
                    "stratified-bootstrap CI); last line: rliable's probability that a cell of the best learning "
                    "entry (MARL or bandit learners) ends with a lower relative regret than a cell of the best "
                    "other entry, with its 95 % CI (the two entries named).")
            verdict = verdict_table(head, main_columns(rows))
            if len(verdict):
                w.table("verdict", verdict, show_verdict(verdict),
                        "The answer, a line a case and track: do learning robots beat classical planners at equal "
                        "samples? The best learning entry and the best other entry (the headline's), and P; yes "
                        "where P's 95 % CI lies above 1/2, no where it lies below, level where it holds 1/2.")
    group = group_keys(rows)[1:]
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


def make_report(run_dir: str | Path | Sequence[str | Path], out: str | Path | None = None,
                fields: bool = True) -> dict:
    """Write the report of ``run_dir`` into ``out`` (default ``run_dir/report``); several run
    directories of one protocol make one merged report (:mod:`fixbench.bench.reporting.merge`; default ``out``:
    the first one's ``report``).

    Returns ``{"report": path, "html": index.html, "tables": {name: csv}, "figures": {name: png},
    "notes": [...]}``;
    ``notes`` lists what was skipped and why (also written into report.md).
    """
    runs = load_runs([run_dir] if isinstance(run_dir, (str, Path)) else list(run_dir))
    for path, (each_rows, each_refs) in zip(runs.paths, runs.each):
        check_scored_references(path, each_rows, each_refs)
    named = case_names(runs.rows["case"])  # tables and figures name a case file's case by its name
    rows = runs.rows.assign(case=runs.rows["case"].map(named))
    refs = {(named.get(k[0], k[0]), *k[1:]): v for k, v in runs.refs.items()}
    out = Path(out) if out is not None else runs.paths[0] / "report"
    w = _Writer(out)
    if rows.attrs.get("damaged"):
        w.notes.append(f"{rows.attrs['damaged']} damaged row files: not read (each named on stderr); "
                       "`fixbench run` moves them aside and recomputes their cells")
    names = run_names(runs.paths)
    labels = sorted(rows["label"].unique())
    colors = palette(labels)
    cases = list(dict.fromkeys(rows["case"]))
    where = (f"Run directory `{runs.paths[0]}`" if len(runs.paths) == 1 else
             "Run directories " + ", ".join(f"`{p}`" for p in runs.paths) + " merged (one protocol)")
    w.md += [f"# fixbench report: {' + '.join(names)}", "",
             f"{where}: {len(rows)} cells ({int((~rows['ok']).sum())} failed), "
             f"cases {', '.join(map(str, cases)) or '-'}, planners {', '.join(labels) or '-'}, "
             f"{len(refs)} regret reference(s).", ""] + _hosts(rows)
    sweep, profile = _table_sections(w, rows, refs)
    _figure_sections(w, runs, rows, refs, colors, sweep, profile, fields)
    if w.notes:
        w.md += ["## Skipped", ""] + [f"- {n}" for n in w.notes] + [""]
    path = out / "report.md"
    path.write_text("\n".join(w.md))
    page = write_html(out, rows, [p / "matrix.toml" for p in runs.paths])
    return {"report": path, "html": page, "tables": w.tables, "figures": w.figures, "notes": w.notes}


def _hosts(rows: pd.DataFrame) -> list[str]:
    """Report lines: the hosts the run's rows were made on (their provenance), with the cells of each."""
    rec = [v for v in rows.get("provenance", pd.Series(dtype=object)) if isinstance(v, dict)]
    if not rec:
        return [f"Hosts: not recorded ({len(rows)} cells made before rows carried their provenance).", ""]
    hosts = pd.Series([host_key(r) for r in rec]).value_counts()
    versions = pd.Series([f"fixbench {r.get('fixbench')}" + (f" ({r['commit'][:12]})" if r.get("commit") else "")
                          for r in rec]).value_counts()
    lines = ["Hosts (cells): " + "; ".join(f"{h}: {n}" for h, n in hosts.items())
             + (f"; not recorded: {len(rows) - len(rec)}" if len(rows) > len(rec) else "") + ".",
             "Code (cells): " + "; ".join(f"{v}: {n}" for v, n in versions.items()) + ".", ""]
    return lines


def _table_sections(w: _Writer, rows: pd.DataFrame, refs: dict) -> tuple[pd.DataFrame, tuple | None]:
    """The tables, each skipped with its reason where the run lacks its rows. Returns what the figures
    draw too: the sweep table and the performance profile (ratios, taus, rho; None without successful
    cells)."""
    w.md += ["## Tables", ""]
    if rows.empty:
        w.skip("Main table", "the run directory has no rows")
        w.skip("Summary table", "the run directory has no rows")
    else:
        _main_section(w, rows)
        summ = summary_table(rows)
        w.table("summary", summ, show_summary(summ, group_keys(rows)),
                "Per case and planner: mean over seeds x materials with 95 % stratified bootstrap CI "
                f"({N_BOOT} resamples, fixed seed) of the max deformation, its interquartile mean (IQM), "
                "the relative regret against the optimum, samples to come within 1 % / 5 % of the "
                "optimum (mean over cells that did; reached/ran in brackets), success rate within 5 %, "
                "wall time; `failed` cells are counted and left out; `rank` by mean max deformation "
                "within the case.")
    if refs:
        table = reference_table(refs)
        w.table("references", table, show_numbers(table, 4),
                "Regret references: the `exact` planner's per-task optima (and shared optimum), proven or "
                "best known (a shipped reference: the portfolio's best-known layouts). `bounded`: the "
                "positions with a certified lower bound on their optimum (proven, or `fixbench references "
                "bound`), and over them the reference's own gap (reference - bound) / reference, median "
                "and worst: how much a regret against the reference may understate the true regret "
                "(docs/references.md#lower-bounds).")
    else:
        w.skip("Reference table", "the run has no usable regret reference (reference/*.json)")
    sweep = _comparison_sections(w, rows, refs)
    _families_section(w, rows, refs)
    profile = None
    if not rows["ok"].any():
        w.skip("Performance profile table", "no successful cells")
    else:
        profile = performance_profile(rows)
        ratios, _, rho = profile
        if len(ratios):
            prof = profile_table(ratios, rho)
            w.table("profile", prof, show_numbers(prof),
                    "Performance profile summary: fraction of problems (case x material x seed) on which "
                    "each planner is the best, or within a factor 1.1 / 2 of the best planner's max "
                    "deformation.")
    failed = rows[~rows["ok"]]
    if len(failed):
        f = failed[[*ORDER, "cell", "error"]].copy()
        f["error"] = f["error"].str.slice(0, 120)
        w.table("failed", f, f, "Failed cells (left out of every statistic), with their error.")
    return sweep, profile


def _families_section(w: _Writer, rows: pd.DataFrame, refs: dict) -> None:
    """The answer over families of generated parts (:mod:`fixbench.bench.reporting.families`), where the run
    has per-task cells on a shipped suite's parts."""
    from fixbench.bench.reporting import families as fam

    iq = fam.family_iqm_table(rows, refs)
    if iq.empty:
        return
    w.md += ["## Generated parts: families", ""]
    w.table("family_iqm", iq, fam.show_family_iqm(iq),
            "Per family of generated parts and samples a position k, and over every part at each k: the "
            "interquartile mean (rliable) of each entry's per-position relative regret (%) against the proven "
            "optima, its cells pooled, with a 95 % stratified-bootstrap CI (resampled within each part and "
            f"position; {N_BOOT} resamples, fixed seed).")
    head = fam.family_headline(rows, iq, {r["planner"]: r["family"] for r in listing()})
    if len(head):
        w.table("family_headline", head, fam.show_family_headline(head),
                "Best of each family of planners per family of parts and k, by the IQM above, with its CI; "
                "last line: rliable's probability that a cell of the best learning entry (MARL or bandit) ends "
                "with a lower relative regret than a cell of the best other entry, with its 95 % CI.")
    tau = fam.rank_correlation_table(iq)
    if len(tau):
        w.table("family_rank_correlation", tau, fam.show_rank_correlation(tau),
                "Kendall's tau-b between the entries' orders by IQM in two families of parts (and the pool) at "
                "the same k, over the entries ranked in both: 1, the same order; 0, unrelated; -1, reversed.")
    w.figure("cpu_regret", fam.cpu_regret_figure(rows, iq),
             "Regret against CPU: each entry's median CPU seconds a cell beside its IQM relative regret over "
             "every part, one panel a k (the cells' `cpu_s`, on the machine that ran them).")


def _figure_sections(w: _Writer, runs: Runs, rows: pd.DataFrame, refs: dict, colors: dict,
                     sweep: pd.DataFrame, profile: tuple | None, fields: bool) -> None:
    """The figures, each skipped with its reason where the run lacks what it draws (traces and curves
    read from ``runs``, those of the cells its ``rows`` hold)."""
    ok = rows[rows["ok"]].copy()
    ok_cases = list(dict.fromkeys(ok["case"]))
    w.md += ["## Figures", ""]
    if len(sweep):
        w.figure("sweep", sweep_figure(sweep, colors),
                 "Budget sweep: relative regret against the reference (%, log) against samples per task "
                 "(log), one panel a case; mean over cells with its 95 % CI as a band.")
    traces = runs.frames(load_traces)
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
    if profile is not None and len(profile[0]):
        ratios, taus, rho = profile
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
    curves = runs.frames(load_curves)
    cells = learner_cells(curves, ok)
    if cells:
        w.figure("figure4", figure4(learner_runs(ok, curves, cells, refs), colors),
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
        as_run = dict(zip(rows["case"], runs.rows["case"]))  # the case as the rows hold it, to rebuild it
        for case in ok_cases:
            try:
                fig, mat, task = field_figure(runs.rows[runs.rows["ok"]], as_run[case], runs.refs, name=case)
            except Exception as exc:  # a case that cannot be rebuilt here must not stop the report
                w.skip(f"Deformation field of {case}", f"{type(exc).__name__}: {exc}")
                continue
            w.figure(f"field_{slug(case)}", fig,
                     f"Deformation |u| of {case} ({mat}, task {task}, the task with the largest optimum) "
                     "under each planner's best layout over seeds, and the optimum's; each panel has its "
                     "own colour scale.")
