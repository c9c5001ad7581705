"""The ``fixbench`` command line.

Every user error (a bad case file, a bad argument) is one line on stderr naming the file or
option, the key and the problem, with exit code 2 and no traceback.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click
import numpy as np

from fixbench import __version__
from fixbench.bench.cli_common import echo_json, run_command
from fixbench.cases.errors import CaseError


def _problem(case: str, material: str | None, agents: int | None = None, fixtures_per_agent: int | None = None):
    from fixbench.cases.problem import load_problem

    return load_problem(case, material=material, agents=agents, fixtures_per_agent=fixtures_per_agent)


def _parse_layout(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a comma-separated list of candidate indices",
                                 param_hint="--layout") from None


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", "-V", prog_name="fixbench", message="%(prog)s %(version)s")
def cli() -> None:
    """fixbench: multi-robot fixture planning benchmarks on validated plate FEA."""


@cli.command()
@click.argument("names", nargs=-1, metavar="[CASE]...")
@click.option("--reward", is_flag=True,
              help="Also give the share of random layouts whose Gaussian reward is 0 or 1 (64 uncounted layouts on "
                   "4 tasks a case: each case's oracle is set up) and warn where it is over half.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list instead of a table.")
def cases(names: tuple[str, ...], reward: bool, as_json: bool) -> None:
    """Table of cases (the catalog's, or the CASE names and paths given): part, DOFs, candidates (and
    grid points dropped outside the part or in its holes), agents, pads a robot places, tasks,
    joint-space size; with --reward, whether the case's Gaussian reward widths suit it."""
    from tabulate import tabulate
    from tqdm import tqdm

    from fixbench.cases.fem import dof_count
    from fixbench.cases.problem import Problem
    from fixbench.cases.spec import case_names, load_case_spec

    specs = [load_case_spec(name) for name in names or case_names()]  # every file checked before any work
    rows = []
    for spec in tqdm(specs, desc="meshing cases", disable=as_json or not sys.stderr.isatty()):
        p = Problem(spec)  # candidates and agents only: nothing is assembled unless --reward
        row = {"case": spec.name, "part": spec.part, "material": spec.material.name, "dofs": dof_count(spec),
               "candidates": len(p.candidates), "dropped": spec.candidates_dropped,
               "agents": p.n_agents, "pads": _pads_text(spec.effector), "tasks": p.n_tasks,
               "joint_size": p.joint_size}
        if reward:
            row["reward_0_or_1"] = _reward_check(p)[0]
            _warn_degenerate(p, row["reward_0_or_1"])
        rows.append(row)
    if as_json:
        echo_json(rows)
    else:
        table = [{**r, "joint_size": f"{r['joint_size']:.3g}",
                  **({"reward_0_or_1": f"{r['reward_0_or_1']:.0%}"} if reward else {})} for r in rows]
        click.echo(tabulate(table, headers="keys", tablefmt="pipe", disable_numparse=True,
                            colalign=("left",) * 3 + ("right",) * (len(table[0]) - 3)))


def _pads_text(eff) -> str:
    """What each robot places, in a word: "1", "2 (pair <= 60 mm)", "1 or none, 3 in all"."""
    text = str(eff.per_agent) + (f" (pair <= {eff.span * 1e3:g} mm)" if eff.kind == "pair" else "")
    if eff.idle:
        text += " or none"
    return text + (f", {eff.pads} in all" if eff.pads else "")


@cli.command()
@click.argument("case")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), help="PNG file to write.")
def show(case: str, material: str | None, out: Path | None) -> None:
    """Picture of CASE: part, mesh, candidates coloured by robot (named by their regions where the case
    names them), supports, tasks; and whether its Gaussian reward widths give random layouts a reward
    other than 0 or 1 (a warning if not)."""
    from fixbench.bench.reporting.plots import show_case

    problem = _problem(case, material)
    path = show_case(problem, out or Path(f"{problem.name}.png"))
    n, dropped = len(problem.candidates), problem.spec.candidates_dropped
    click.echo(f"{problem.name}: {n} fixture candidates"
               + (f" ({dropped} grid points outside the part or inside its holes dropped)" if dropped else ""))
    click.echo(f"wrote {path}")
    share, sx, sz = _reward_check(problem)
    click.echo(f"Gaussian reward (sigma_x {sx * 1e6:g} um, sigma_z {sz * 1e6:g} um): {share:.0%} of random layouts "
               "at 0 or 1")
    _warn_degenerate(problem, share)


def _warn_degenerate(problem, share: float) -> None:
    """A warning on stderr when most random layouts get a Gaussian reward of 0 or 1."""
    if share > 0.5:
        click.echo(f"warning: {problem.spec.source}: [reward] widths are degenerate for this part: {share:.0%} of "
                   "random layouts get a Gaussian reward below 0.001 or above 0.999; the learners' default reward "
                   "('scaled') does not use them, a 'gaussian' run would learn nothing", err=True)


def _reward_check(problem, n: int = 64, tasks: int = 4) -> tuple[float, float, float]:
    """Share of uniform random layouts (``n`` on ``tasks`` tasks spread over the job, uncounted) whose
    Gaussian reward is degenerate (below 0.001 or above 0.999), and the widths."""
    from fixbench.cases.rewards import degenerate_share
    from fixbench.solvers.base import random_layouts

    rng = np.random.default_rng(0)
    ids = np.unique(np.linspace(0, problem.n_tasks - 1, min(tasks, problem.n_tasks)).round().astype(int))
    rewards = [problem.deformation(problem.measure(int(t), random_layouts(problem, rng, n))).reward_gaussian
               for t in ids]
    return (degenerate_share(np.concatenate(rewards)), *problem.spec.reward_sigma)


def _parse_point(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a point x,y in mm", param_hint="--at") from None
    if not (np.isfinite(x) and np.isfinite(y)):
        raise click.BadParameter(f"'{text}' is not a finite point x,y in mm", param_hint="--at")
    return x, y


@cli.command()
@click.argument("case")
@click.option("--task", type=int, required=True, help="Task index.")
@click.option("--layout", help="One action per agent: i1,...,ik (candidate indices, with one pad a robot; "
                                "else indices into the case's pad tuples, as fixbench solve --json gives them).")
@click.option("--free", is_flag=True,
              help="No fixtures: the part on its base supports alone (the free response), instead of --layout.")
@click.option("--at", "at", multiple=True, metavar="X,Y",
              help="Also the displacement at this point (mm; repeatable), from the FE field itself.")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), help="Contour PNG of |u|.")
@click.option("--vtk", type=click.Path(dir_okay=False, path_type=Path), help="VTU file for ParaView.")
def evaluate(case, task, layout, free, at, material, as_json, plot, vtk) -> None:
    """Deformation of one fixture layout of CASE for one task (one oracle sample), or with --free of the
    part with no fixtures; --at x,y adds the displacement at given points (check a model by hand)."""
    if (layout is None) == (not free):
        raise click.UsageError("give exactly one of --layout i1,...,ik and --free")
    idx = None if free else _parse_layout(layout)
    points = [_parse_point(p) for p in at]
    problem = _problem(case, material)
    if free:  # one FE solve on the base supports: counted as one sample, as Evaluator.unconstrained
        d, samples = problem.direct_deformation(task, None), 1
    else:
        ev = problem.evaluator()
        d = ev.evaluate(task, [idx])
        samples = ev.samples
    result = {"case": problem.name, "material": problem.spec.material.name, "task": task,
              "layout": "free (no fixtures)" if free else idx, **d.row(0), "samples": samples}
    if not free and not problem.spec.effector.simple:
        result["pads"] = problem.pads([idx])[0].tolist()
    if points:
        u = problem.displacement_at(task, None if free else [idx], np.array(points) * 1e-3)
        result["at"] = [{"x_mm": x, "y_mm": y, "ux_m": float(ux), "uy_m": float(uy), "w_m": float(w),
                         "u_m": float(np.sqrt(ux**2 + uy**2 + w**2))}
                        for (x, y), (ux, uy, w) in zip(points, u)]
    lay = None if free else [idx]
    if plot:
        from fixbench.bench.reporting.plots import field_plot

        field_plot(problem, task, lay, plot)
    if vtk:
        from fixbench.bench.reporting.plots import write_vtk

        write_vtk(problem, task, lay, vtk)
    if as_json:
        echo_json(result)
        return
    for k, v in result.items():
        if k == "at":
            for p in v:
                click.echo(f"{'at':>16}: ({p['x_mm']:g}, {p['y_mm']:g}) mm  ux {p['ux_m']:.6g} m  "
                           f"uy {p['uy_m']:.6g} m  w {p['w_m']:.6g} m  |u| {p['u_m']:.6g} m")
            continue
        unit = " m" if k.startswith("max_") else ""
        click.echo(f"{k:>16}: {v:.6g}{unit}" if isinstance(v, float) else f"{k:>16}: {v}")


@cli.command()
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list of checks.")
@click.option("--parts/--no-parts", "with_parts", default=True, show_default=True,
              help="The catalog parts' lines (they solve every part directly: tens of minutes).")
@click.option("--part", "only", multiple=True, metavar="CASE",
              help="Only these catalog cases' lines (repeatable; default: every fixture case).")
def validate(as_json: bool, with_parts: bool, only: tuple[str, ...]) -> None:
    """Analytic checks (plates of Timoshenko and Roark, a membrane strip); exit 1 if any > 1%. Then one
    line per catalog part: its largest w/t at the reference layouts (shipped reference, or the proven
    optimum of a *_small case at the default matrix's agent count); exit 1 if any is beyond 0.5. Then,
    for each full part, the fast oracle against a direct solve (exit 1 beyond a relative 1e-9) and the
    mesh at its shipped reference's worst task (exit 1 if halving the elements moves max |u| > 2 %)."""
    from fixbench.bench.running.matrix import find_matrix, load_matrix
    from fixbench.cases.analytic import validate as run
    from fixbench.cases.linearity import part_rows
    from fixbench.cases.part_checks import fixture_cases, full_part_rows, full_parts

    names = fixture_cases(only)
    checks = run()
    agents = min(load_matrix(find_matrix("default")).agents)
    parts = part_rows(small_agents=agents, names=names) if with_parts else []
    whole = full_part_rows([n for n in full_parts() if names is None or n in names]) if with_parts else []
    if as_json:
        echo_json(checks + parts + whole)
    else:
        import pandas as pd

        click.echo(pd.DataFrame(checks).to_markdown(index=False, floatfmt=".5g"))
    if with_parts and not as_json:
        click.echo()
        table = [{"part": r["name"], "layouts": r["layouts"], "agents": r["agents"], "tasks": r["tasks"],
                  "max w (mm)": None if r["max_w_m"] is None else 1e3 * r["max_w_m"],
                  "t (mm)": 1e3 * r["thickness_m"], "w/t": r["w_over_t"],
                  "": "BEYOND 0.5: outside linear plate theory" if r["flagged"] else ""} for r in parts]
        click.echo(pd.DataFrame(table).to_markdown(index=False, floatfmt=".3g"))
        click.echo()
        table = [{"part": r["name"], "check": r["check"],
                  "measured": r["worst_rel_difference"] if r["check"] == "oracle" else r["change"],
                  "limit": r["limit"],
                  "what": (f"worst relative difference to a direct solve, {r['layouts']} random layouts"
                           if r["check"] == "oracle" else r.get("note") or
                           f"change of max |u| at task {r['task']} with half the element size"),
                  "": "FAILED" if r["flagged"] else ""} for r in whole]
        click.echo(pd.DataFrame(table).to_markdown(index=False, floatfmt=".3g"))
    if any(c["rel_error"] > 0.01 for c in checks) or any(r["flagged"] for r in parts + whole):
        sys.exit(1)


@cli.command()
@click.option("--case", "cases", multiple=True, default=("wing_panel",), show_default=True,
              help="Case to measure (CASE@MATERIAL: in that material); repeat it to measure several side "
              "by side (ratios to the first).")
@click.option("--batch", default=200_000, show_default=True, help="Layouts in the batched call.")
@click.option("--planner", "planner_name", help="Time this planner instead of the oracle: one run per "
              "value of --vary, side by side.")
@click.option("--vary", metavar="KEY=V1,V2,...", help="With --planner: the setting whose values are compared "
              "(the first is the ratios' base).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help="With --planner: the rest of its config.")
@click.option("--samples-per-task", type=click.IntRange(min=1), default=100, show_default=True,
              help="With --planner: the budget, this many samples for each task it may evaluate.")
@click.option("--heldout-every", type=click.IntRange(min=2), help="With --planner: the held-out track.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object (with --planner: a list).")
def perf(cases: tuple[str, ...], batch: int, planner_name: str | None, vary: str | None, sets: tuple[str, ...],
         samples_per_task: int, heldout_every: int | None, seed: int, as_json: bool) -> None:
    """Oracle against re-assembly + direct sparse solve, run side by side; or, with --planner and --vary,
    one planner at several values of a setting (CPU seconds, phases, score), side by side."""
    from fixbench.bench.analysis.perf import run_perf, run_planner_perf

    if planner_name or vary:
        if not (planner_name and vary):
            raise click.UsageError("--planner and --vary go together")
        if len(cases) > 1:
            raise click.UsageError("--planner takes one --case")
        rows = run_planner_perf(cases[0], planner_name, sets, vary, samples_per_task=samples_per_task, seed=seed,
                                heldout_every=heldout_every)
        if as_json:
            echo_json(rows)
        else:
            import pandas as pd

            click.echo(pd.DataFrame(rows).drop(columns=["case", "planner"]).to_markdown(index=False, floatfmt=".4g"))
        return
    results = [run_perf(case, batch=batch, progress=not as_json) for case in cases]
    if len(results) > 1:
        base = results[0]
        for res in results:
            res["batched_vs_first"] = res["batched_layouts_per_s"] / base["batched_layouts_per_s"]
            res["single_vs_first"] = base["single_oracle_s"] / res["single_oracle_s"]
    if as_json:
        echo_json(results[0] if len(results) == 1 else results)
    elif len(results) == 1:
        for k, v in results[0].items():
            click.echo(f"{k:>24}: {v:.4g}" if isinstance(v, float) else f"{k:>24}: {v}")
    else:
        import pandas as pd

        shown = [{k: f"{v:.4g}" if isinstance(v, float) else v for k, v in res.items()} for res in results]
        click.echo(pd.DataFrame(shown).set_index("case").T.to_markdown())


@cli.command()
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list.")
def solvers(as_json: bool) -> None:
    """List the registered planners (built-ins and plugins): name, family (the kind of method) and a
    one-line description; --json adds their modes and modules."""
    from fixbench.solvers.registry import listing

    rows = listing()
    if as_json:
        echo_json(rows)
    else:
        for r in rows:
            click.echo(f"{r['planner']:>12}  {r['family']:<21}  {r['description']}")


@cli.command()
@click.argument("case")
@click.option("--planner", "planner_name", required=True,
              help="Registered name, or package.module:Class of your own planner.")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--agents", type=int, help="Number of agents (default: the case's).")
@click.option("--fixtures-per-agent", type=click.IntRange(min=1),
              help="Pads each robot places, m distinct candidates of its set (default: the case's).")
@click.option("--budget", type=int, help="Hard sample budget (default: unlimited).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--mode", type=click.Choice(["per-task", "shared"]), default="per-task", show_default=True)
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help="Override a config field.")
@click.option("--heldout-every", type=click.IntRange(min=2),
              help="Held-out track: train on every K-th task only, act on the others with no samples.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path),
              help="PNG of the anytime curves (best so far against samples).")
def solve(case, planner_name, material, agents, fixtures_per_agent, budget, seed, mode, sets, heldout_every,
          as_json, plot) -> None:
    """Plan fixture layouts for CASE with one planner and report what it reached."""
    from fixbench.solvers.config import apply_sets
    from fixbench.solvers.registry import get

    cls = get(planner_name)
    planner = cls(**apply_sets(cls.Config, sets, cls.name))
    problem = _problem(case, material, agents, fixtures_per_agent)
    from fixbench.bench.records.keys import split

    train = None if heldout_every is None else split(problem.n_tasks, heldout_every)[0]
    result = planner.solve(problem, budget, seed=seed, mode=mode, train_tasks=train)
    if plot:
        from fixbench.bench.reporting.plots import anytime_plot

        anytime_plot(result, plot)
    summary = result.summary()
    if as_json:
        echo_json(summary)
    else:
        for k in ("planner", "case", "material", "mode", "seed", "budget", "samples",
                  "mean_max_deformation_m", "worst_max_deformation_m", "mean_reward", "objective_m"):
            v = summary[k]
            click.echo(f"{k:>24}: {v:.6g}" if isinstance(v, float) else f"{k:>24}: {v}")


@cli.command()
@click.argument("matrix", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Run directory (created; rerunning resumes).")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local", show_default=True)
@click.option("--workers", type=click.IntRange(min=1), help="Parallel workers (default: one per core).")
@click.option("--ray-address", help="Ray cluster to run on (HOST:PORT of its head; auto: the one on this machine; "
              "local: a private instance). Default: RAY_ADDRESS, else the cluster `ray start` started on this "
              "machine, else a private instance of --workers CPUs.")
@click.option("--cell-timeout", type=click.FloatRange(min=0, min_open=True),
              help="Stop a cell after this many seconds; it becomes a row with an error.")
@click.option("--retry-failed", is_flag=True, help="Rerun cells whose row carries an error.")
@click.option("--only", help="Run only some cells now: planners or entry labels, and case=, material=, "
              "mode=, seed=, samples_per_task= filters (comma-separated); a later run without --only "
              "completes the matrix.")
def run(matrix, out, executor, workers, ray_address, cell_timeout, retry_failed, only) -> None:
    """Run the benchmark MATRIX (a TOML file, or the name of a shipped one: default, paper, sweep, families)
    into OUT; rerun to resume."""
    from fixbench.bench.running.runner import run_matrix

    try:
        summary = run_matrix(matrix, out, executor=executor, workers=workers, address=ray_address,
                             cell_timeout=cell_timeout, retry_failed=retry_failed, progress=sys.stderr.isatty(),
                             only=tuple(x.strip() for x in (only or "").split(",") if x), plain_every=60.0)
    except KeyboardInterrupt as exc:
        done = getattr(exc, "summary", {}).get("run", 0)
        click.echo(f"fixbench: interrupted: {done} cells finished in this run and are kept in {out}; "
                   "the same command resumes", err=True)
        raise click.exceptions.Exit(130) from None
    click.echo(f"{summary['cells']} cells: {summary['run']} run ({summary['failed']} failed), "
               f"{summary['skipped']} already done"
               + (f", {summary['deferred']} left for a run without --only" if "deferred" in summary else "")
               + (f", {summary['damaged_moved']} damaged rows moved to {out}/damaged and rerun"
                  if "damaged_moved" in summary else "")
               + f"; results in {out}")


@cli.command()
@click.argument("planner")
@click.option("--trials", type=int, default=20, show_default=True,
              help="Trials (the same number for every planner: the declared tuning budget).")
@click.option("--cases", default=",".join(("wing_panel_small", "wing_spar_small", "bus_panel_small", "fan_small")),
              show_default=True, help="Tuning cases, comma-separated (*_small only: never a reported problem).")
@click.option("--seeds", default="0", show_default=True, help="Seeds of each trial's runs, comma-separated.")
@click.option("--samples-per-task", type=int, default=100, show_default=True)
@click.option("--track", type=click.Choice(["per-task", "held-out"]), default="per-task", show_default=True,
              help="The track tuned for: per-task (every position sampled) or held-out (train on every "
                   "--heldout-every-th position, scored on the others with no sample).")
@click.option("--heldout-every", type=click.IntRange(min=2), default=2, show_default=True,
              help="The held-out track's split of the tuning cases.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the tuned [[planners]] entry (a matrix fragment) to this file.")
def tune(planner, trials, cases, seeds, samples_per_task, track, heldout_every, out) -> None:
    """Tune PLANNER's tunable config fields with Optuna on the *_small cases, for one track (bench/tune.py)."""
    from fixbench.bench.tune import matrix_entry, tune, write_entry

    try:
        seed_list = tuple(int(s) for s in seeds.split(",") if s.strip())
    except ValueError:
        raise CaseError("--seeds", "", f"'{seeds}' is not a comma-separated list of integers") from None
    result = tune(planner, trials, tuple(c.strip() for c in cases.split(",") if c.strip()), seed_list,
                  samples_per_task, echo=lambda m: click.echo(m, err=True), track=track, heldout_every=heldout_every)
    if out:
        write_entry(result, out)
    click.echo(matrix_entry(result), nl=False)


@cli.command("tune-table")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--readme", multiple=True, type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Also refresh this file's copy of the table (its <!-- table: FOLDER/table.md --> block); "
                   "repeatable.")
def tune_table(folder, readme) -> None:
    """Write FOLDER/table.md, the table of the tuned entries in FOLDER (`fixbench tune PLANNER --out
    FOLDER/PLANNER.toml`), and print it."""
    from fixbench.bench.reporting.tables import refresh_readme
    from fixbench.bench.tune import tuning_table
    from fixbench.cases.files import write_text_atomic

    table = tuning_table(folder)
    write_text_atomic(folder / "table.md", table)
    for doc in readme:
        if not refresh_readme(doc, folder):
            raise CaseError(str(doc), "", f"has no <!-- table: ... --> block naming {folder / 'table.md'}")
    click.echo(table, nl=False)


@cli.command()
@click.argument("run_dirs", metavar="RUN_DIR [RUN_DIR ...]", nargs=-1,
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--with", "with_runs", multiple=True, metavar="NAME",
              help="Merge the committed run results/NAME too (paper, sweep, reference, tiny); repeatable.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Report folder (default: the first RUN_DIR's report/).")
@click.option("--no-fields", is_flag=True,
              help="Skip the deformation-field pictures (they rebuild each case's FE model).")
@click.option("--readme", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Also refresh this README's copies of the report's tables (its <!-- table: PATH --> blocks).")
def report(run_dirs, with_runs, out, no_fields, readme) -> None:
    """Tables (Markdown, LaTeX, CSV) and figures (PNG, PDF) of the run in RUN_DIR; of several runs of
    one protocol (RUN_DIRs and --with runs) merged into one report."""
    from fixbench.bench.reporting.merge import committed_run
    from fixbench.bench.reporting.report import make_report
    from fixbench.bench.reporting.tables import refresh_readme

    runs = [*run_dirs, *(committed_run(name) for name in with_runs)]
    if not runs:
        raise click.UsageError("give a RUN_DIR or --with NAME")
    res = make_report(runs, out, fields=not no_fields)
    click.echo(f"wrote {res['report']} ({len(res['tables'])} tables, {len(res['figures'])} figures"
               + (f", {len(res['notes'])} skipped" if res["notes"] else "") + ")")
    if readme is not None:
        click.echo(f"refreshed {refresh_readme(readme, res['report'].parent)} tables in {readme}")


@cli.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--cells", "k", type=click.IntRange(min=1), default=10, show_default=True,
              help="Cells to rerun, sampled across planners.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the sample.")
@click.option("--only", help="Sample only among these cells (as fixbench run --only).")
@click.option("--workers", type=click.IntRange(min=1), help="Parallel workers (default: one per core).")
def verify(run_dir, k, seed, only, workers) -> None:
    """Rerun K cells of RUN_DIR here and print the committed and the new value of each; exit 1 when
    one disagrees (bench/verify.py)."""
    from fixbench.bench.verify import show
    from fixbench.bench.verify import verify as rerun

    records = rerun(run_dir, k, seed, tuple(x.strip() for x in (only or "").split(",") if x), workers,
                    echo=lambda m: click.echo(m, err=True))
    click.echo(show(records))
    if not all(r["agrees"] for r in records):
        raise click.exceptions.Exit(1)


@cli.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["iohprofiler", "marl-eval", "csv"]), required=True,
              help="iohprofiler (IOHanalyzer's folders), marl-eval (one JSON) or csv (rows and traces).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write (default: RUN_DIR/export/FORMAT); an earlier export there is replaced.")
def export(run_dir, fmt, out) -> None:
    """Write the run in RUN_DIR in a format other tools read (IOHanalyzer, marl-eval, CSV)."""
    from fixbench.bench.reporting.export import export_run

    res = export_run(run_dir, fmt, out or run_dir / "export" / fmt)
    counts = {k: v for k, v in res.items() if isinstance(v, int)}
    skipped = res.get("skipped") or {}
    click.echo(f"wrote {res['out']} ({fmt}: " + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in counts.items())
               + "".join(f"; {v} cells left out ({k})" for k, v in skipped.items()) + ")")


#: largest joint table ``fixbench equilibria`` builds (float64: 160 MB a task)
MAX_TABLE = 2 * 10**7


@cli.command()
@click.argument("case")
@click.option("--task", type=int, help="One task (default: every task); Figure 3 needs one.")
@click.option("--agents", type=click.IntRange(min=1), help="Number of agents (default: the case's).")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--starts", type=click.IntRange(min=1), default=10_000, show_default=True,
              help="Best-response descents from uniform random layouts (the basins).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the random starts.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
              help="PNG of the seed's Figure 3 (2 agents and one --task).")
@click.option("--json", "as_json", is_flag=True, help="Print strict JSON (with the table for 2 agents).")
def equilibria(case, task, agents, material, starts, seed, out, as_json) -> None:
    """Person-by-person optima of CASE by exhaustive enumeration (analysis, uncounted; not a planner):
    how many, their regret against the optimum, their basins under greedy best response."""
    from fixbench.bench.analysis.equilibria import analyse

    problem = _problem(case, material, agents)
    if problem.joint_size > MAX_TABLE:
        raise click.BadParameter(f"{problem.name} has {problem.joint_size:.3g} layouts at {problem.n_agents} "
                                 f"agents; the analysis enumerates at most {MAX_TABLE:.0e}", param_hint="--agents")
    if out and (task is None or problem.n_agents != 2):
        raise click.BadParameter("Figure 3 draws one task of a 2-agent problem: give --task and --agents 2",
                                 param_hint="--out")
    tasks = range(problem.n_tasks) if task is None else [problem.check_task(task)]
    res, tables, _ = analyse(problem, tasks, starts, seed)
    if problem.n_agents == 2:
        for rec in res["tasks"]:
            rec["table_m"] = tables[rec["task"]]
    if out:
        from fixbench.bench.analysis.analysis_figures import figure3
        from fixbench.bench.reporting.plots import save_png

        fig = figure3(tables[task], f"{problem.name} ({res['material']}), task {task}: max |u| of all "
                      f"{problem.joint_size:,} layouts\n(exhaustive enumeration: analysis, not a planner)")
        click.echo(f"wrote {save_png(fig, out)}", err=as_json)
    if as_json:
        echo_json(res)
        return
    click.echo(f"{problem.name} ({res['material']}), {problem.n_agents} agents, {problem.joint_size:,} layouts "
               f"a task, every one evaluated (analysis, uncounted); basins from {starts:,} random starts, seed {seed}")
    for rec in res["tasks"]:
        click.echo(f"task {rec['task']}: {rec['pbp_optima']} person-by-person optima, optimum "
                   f"{rec['optimum_m'] * 1e6:.4g} um; worst regret {rec['pbp_regret_max']:.1%}; "
                   f"{rec['global_basin_share']:.1%} of descents reach the optimum, "
                   f"{rec['descents_within_5pct']:.1%} end within 5 %")
        for o in rec["optima"][:10]:
            click.echo(f"  {','.join(map(str, o['layout'])):>24}  {o['max_deformation_m'] * 1e6:10.4g} um  "
                       f"regret {o['regret']:8.2%}  basin {o['basin_share']:6.2%}")
        if len(rec["optima"]) > 10:
            click.echo(f"  ... {len(rec['optima']) - 10} more (--json lists all)")


@cli.command()
@click.argument("case")
@click.option("--tolerance-um", type=click.FloatRange(min=0, min_open=True), required=True,
              help="Largest acceptable max deformation (um).")
@click.option("--max-agents", type=click.IntRange(min=1), help="Try N = 1..K robots (default: the case's count).")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--fraction", type=click.FloatRange(0, 1, min_open=True), default=1.0, show_default=True,
              help="Share of the tasks that must be within the tolerance.")
@click.option("--max-evaluations", type=click.IntRange(min=1), help="Enumerate an agent count only up to "
              "this many layout evaluations (layouts x tasks; default 1e8), else use a shipped reference.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), help="PNG of deformation against N.")
@click.option("--json", "as_json", is_flag=True, help="Print strict JSON.")
def robots(case, tolerance_um, max_agents, material, fraction, max_evaluations, out, as_json) -> None:
    """How many robots keep CASE within a tolerance: the best max deformation of every task for N = 1..K
    (proven optimum by enumeration, else a shipped reference, else unavailable)."""
    from fixbench.bench.analysis.robots import MAX_EVALUATIONS, robots_needed, robots_table

    k = max_agents or _problem(case, material).n_agents
    tol = tolerance_um * 1e-6
    rows = robots_table(case, material, k, tol, max_evaluations or MAX_EVALUATIONS)
    answers = [robots_needed(rows, f) for f in sorted({1.0, fraction})]
    if out:
        from fixbench.bench.analysis.analysis_figures import robots_figure
        from fixbench.bench.reporting.plots import save_png

        fig = robots_figure(rows, tol, f"{rows[0]['case']} ({rows[0]['material']}): best max |u| per task")
        click.echo(f"wrote {save_png(fig, out)}", err=as_json)
    if as_json:
        echo_json({"case": rows[0]["case"], "material": rows[0]["material"], "tolerance_m": tol,
                   "rows": rows, "answers": answers})
        return
    from fixbench.bench.analysis.robots import answer_text, show_robots

    click.echo(show_robots(rows).to_markdown(index=False))
    for a in answers:
        click.echo(answer_text(a, tolerance_um))


@cli.command()
@click.argument("case")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), help="PNG of the case (default: CASE.png).")
@click.option("--json", "as_json", is_flag=True, help="Print strict JSON of every figure.")
def check(case: str, material: str | None, out: Path | None, as_json: bool) -> None:
    """Check CASE (a catalog name or your TOML) before trusting a run: mesh convergence, deflection over
    thickness, reference cost, Gaussian reward widths, picture. Warnings on stderr; exit 0 (docs/check.md)."""
    from fixbench.bench.check import check_case, text

    res = check_case(case, material, out)
    if as_json:
        echo_json(res)
    else:
        for line in text(res):
            click.echo(line)
    for w in res["warnings"]:
        click.echo(f"warning: {w}", err=True)


@cli.command()
@click.argument("family")
@click.option("--seed", type=int, required=True, help="Seed of the draws (an integer).")
@click.option("--count", type=click.IntRange(min=1), default=1, show_default=True, help="Parts to generate.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder of the case files, their references and suite.json (rerunning resumes).")
@click.option("--set", "sets", multiple=True, metavar="NAME=RANGE",
              help="Narrow a parameter: NAME=A:B or NAME=A, or NAME=X,Y for a choice (see `fixbench families`).")
def generate(family: str, seed: int, count: int, out: Path, sets: tuple[str, ...]) -> None:
    """Generate COUNT parts of FAMILY from SEED into OUT: case files, each checked (mesh, w/t of its
    proven optima) and proven position by position, redrawn with its reason when a check fails
    (docs/families.md)."""
    from fixbench.bench.generate import generate as run_generate
    from fixbench.cases.families import FamilyError

    overrides = {}
    for item in sets:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise FamilyError(f"--set {item}", "write NAME=RANGE (NAME=A:B, NAME=A or NAME=X,Y)")
        overrides[key.strip()] = value.strip()
    suite = run_generate(family, seed, count, out, overrides)
    redraws = sum(len(p["redraws"]) for p in suite["parts"])
    click.echo(f"{count} {family} part(s) in {out} ({redraws} redraw(s), every position proven); manifest "
               f"{out / 'suite.json'}")


@cli.command()
@click.argument("suite")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Folder of the generated parts (default: beside the suite file, NAME/).")
def suite(suite: str, out: Path | None) -> None:
    """Generate every part of SUITE (a suite file, or a shipped suite: families-train, families-test),
    each as `fixbench generate` makes it, and the suite's manifest (docs/families.md#suites)."""
    from fixbench.bench.generate import generate_suite

    made = generate_suite(suite, out)
    redraws = sum(len(p["redraws"]) for p in made["parts"])
    click.echo(f"suite {made['suite']}: {len(made['parts'])} parts of {len(made['generations'])} generation(s), "
               f"{redraws} redraw(s), every position proven")


@cli.command()
@click.option("--json", "as_json", is_flag=True, help="Print strict JSON.")
def families(as_json: bool) -> None:
    """The part families `fixbench generate` draws from, and each one's parameter ranges."""
    from fixbench.cases.families import FAMILIES

    table = {name: {"summary": f.summary, "ranges": {k: r.text() for k, r in f.ranges.items()}}
             for name, f in FAMILIES.items()}
    if as_json:
        echo_json(table)
        return
    for name, f in table.items():
        click.echo(f"{name}: {f['summary']}")
        for k, r in f["ranges"].items():
            click.echo(f"  {k} = {r}")


@cli.group()
def references() -> None:
    """Regret references of the full parts: build them, merge better layouts from a run."""


@references.command("build")
@click.argument("case")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--agents", type=int, help="Number of agents (default: the case's).")
@click.option("--samples-per-task", type=click.IntRange(min=1), help="Effort of each portfolio planner a task.")
@click.option("--rounds", type=click.IntRange(min=0), help="Most neighbour-exchange rounds.")
@click.option("--planners", help="Comma-separated planners of the first phase (empty: exchange rounds only).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write to (default: the catalog's references folder).")
def references_build(case, material, agents, samples_per_task, rounds, planners, out) -> None:
    """Run the reference portfolio on CASE and write (or improve) its shipped reference."""
    from dataclasses import replace

    from fixbench.bench.references.build import Portfolio, build_and_write

    effort = Portfolio()
    if samples_per_task is not None:
        effort = replace(effort, samples_per_task=samples_per_task)
    if rounds is not None:
        effort = replace(effort, max_rounds=rounds)
    if planners is not None:
        effort = replace(effort, planners=tuple(x.strip() for x in planners.split(",") if x.strip()))
    path = build_and_write(case, material, agents, effort, echo=lambda m: click.echo(m, err=True), folder=out)
    click.echo(f"wrote {path}")


@references.command("update")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("rescore_dirs", nargs=-1, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="References folder (default: the catalog's).")
def references_update(run_dir, rescore_dirs, out) -> None:
    """The loop: merge into the shipped references every layout of RUN_DIR that beats them (re-measured
    first), then rescore RUN_DIR and each RESCORE_DIR against the references as they now are."""
    from fixbench.bench.references.update import update

    changed = update(run_dir, rescore_dirs, echo=lambda m: click.echo(m, err=True), folder=out)
    click.echo(f"{sum(changed.values())} tasks replaced in {len(changed)} reference files")


@references.command("rescore")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
def references_rescore(run_dir) -> None:
    """Recompute RUN_DIR's regret columns against the shipped references as they are now."""
    from fixbench.bench.references.score import rescore

    rescore(run_dir, echo=click.echo)


@references.command("bound")
@click.argument("case")
@click.option("--material", help="Material name (default: the case's).")
@click.option("--agents", type=int, help="Number of agents (default: the case's).")
@click.option("--time-limit", "time_limit", type=click.FloatRange(min=0, min_open=True), default=60.0,
              show_default=True, help="Seconds of branch-and-bound a position.")
@click.option("--method", type=click.Choice(["branch-and-bound", "zones"]), default="branch-and-bound",
              show_default=True, help="zones: one robot free, the others' zones clamped, every position at once "
              "(docs/references.md#zone-bound).")
@click.option("--tasks", help="Comma-separated positions (default: every one).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="References folder (default: the catalog's).")
def references_bound(case, material, agents, time_limit, method, tasks, out) -> None:
    """Certified lower bounds on CASE's shipped reference, written into it (docs/references.md#lower-bounds)."""
    from fixbench.bench.references.bound import bound

    try:
        ids = None if tasks is None else [int(x) for x in tasks.split(",") if x.strip()]
    except ValueError:
        raise click.BadParameter(f"not a comma-separated list of positions: {tasks!r}", param_hint="--tasks") from None
    res = bound(case, material, agents, time_limit, ids, folder=out, echo=lambda m: click.echo(m, err=True),
                method=method)
    gaps = sorted(r["gap"] for r in res["positions"])
    click.echo(f"wrote {res['path']}: {len(gaps)} positions, gap (reference - bound) / reference: median "
               f"{100 * gaps[len(gaps) // 2]:.1f} %, worst {100 * gaps[-1]:.1f} %")


@references.command("check")
@click.option("--json", "as_json", is_flag=True, help="Print the rows as strict JSON.")
def references_check(as_json) -> None:
    """Run the portfolio on every *_small case and compare with exact's proven optima."""
    from fixbench.bench.references.build import check_small

    rows = check_small(echo=lambda r: None if as_json else click.echo(r))
    if as_json:
        echo_json(rows)
    else:
        n, k = sum(r["tasks"] for r in rows), sum(r["reached"] for r in rows)
        click.echo(f"optimum reached on {k} of {n} tasks ({100 * k / n:.1f} %)")


@cli.group()
def cache() -> None:
    """The on-disk cache of oracle set-up data (compliance columns): the folder $FIXBENCH_CACHE_DIR
    names, or a run directory's DIR/oracle-cache."""


_DIR = click.option("--dir", "path", type=click.Path(file_okay=False, path_type=Path),
                    help="Cache folder (default: $FIXBENCH_CACHE_DIR; a run's is RUN_DIR/oracle-cache).")


@cache.command("info")
@_DIR
@click.option("--json", "as_json", is_flag=True, help="Print strict JSON.")
def cache_info(path: Path | None, as_json: bool) -> None:
    """Where the cache is, its size limit, and every entry (newest use first)."""
    import time

    from fixbench.cases import cache as oracle_cache

    base = path or oracle_cache.root()
    es = oracle_cache.entries(base)
    if as_json:
        echo_json({"root": str(base) if base else None, "max_bytes": oracle_cache.max_bytes(), "entries": es})
        return
    if base is None:
        click.echo("cache: off (no --dir, and FIXBENCH_CACHE_DIR is unset or off)")
        return
    total = sum(e["bytes"] for e in es)
    click.echo(f"cache: {base}  {len(es)} entries, {total / 2**20:.0f} MB of "
               f"{oracle_cache.max_bytes() / 2**30:.1f} GB (FIXBENCH_CACHE_MAX_GB)")
    for e in es:
        used = time.strftime("%Y-%m-%d %H:%M", time.localtime(e["last_used"]))
        click.echo(f"  {e['key']}  {e['bytes'] / 2**20:8.0f} MB  used {used}  {e['description']}")


@cache.command("clear")
@_DIR
def cache_clear(path: Path | None) -> None:
    """Remove every entry (they are rebuilt when next needed)."""
    from fixbench.cases import cache as oracle_cache

    base = path or oracle_cache.root()
    if base is None:
        click.echo("cache: off (no --dir, and FIXBENCH_CACHE_DIR is unset or off); nothing removed")
        return
    click.echo(f"removed {oracle_cache.clear(base)} entries from {base}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``fixbench``: :func:`run_command` on the command group."""
    return run_command(cli, argv, "fixbench")

if __name__ == "__main__":
    sys.exit(main())
