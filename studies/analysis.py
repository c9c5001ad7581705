"""The committed analyses of ``results/analysis/``: the seed's Figure 3, the equilibrium landscape
of the small cases and the number of robots a job needs, with their tables.

    python -m studies.analysis [--out results/analysis] [--readme docs/equilibria.md]
        [--only equilibria|robots] [--starts 10000] [--seed 0] [--tolerance-um 50] [--fraction 0.75]

Writes to OUT:

- ``figure3_CASE_taskT.png``: :data:`FIGURE3`'s 2-agent problems (``fixbench equilibria``);
- ``equilibria.md``/``.csv``/``.json``: every task of every ``*_small`` case at the catalog's agents
  (:data:`SMALL_CASES`), and ``equilibria_2agents.md``: the Figure 3 cases at 2 agents;
  ``equilibria_landscape.png``: regret against basin of every PBP optimum, and where descents stop;
- ``robots.md``/``.json``: the smallest number of robots for :data:`ROBOTS` in each of
  :data:`MATERIALS`, and per case ``robots_CASE.md`` and ``robots_CASE_MATERIAL.png`` (``fixbench robots``).

With ``--readme`` the README's copies of these tables (``<!-- table: PATH -->`` blocks) are refreshed.
Everything here is analysis on the oracle directly (uncounted), not a benchmark run.
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import pandas as pd

from fixbench.bench.cli_common import run_command

#: the small cases whose landscape is tabulated (every task, the catalog's agents and material)
SMALL_CASES = ("wing_panel_small", "wing_spar_small", "bus_panel_small", "fan_small")
#: (case, task) of the Figure 3 pictures at 2 agents: the wing-panel hole with the most PBP optima
#: (5; the other holes have 1-2, see equilibria_2agents.md) and the fan's first operating condition
FIGURE3 = (("wing_panel_small", 1), ("fan_small", 0))
#: (case, largest agent count) of the robots tables
ROBOTS = (("wing_panel_small", 6), ("fan_small", 6), ("wing_panel", 9))
MATERIALS = ("aluminium", "steel", "titanium")


def _write(path: Path, text: str) -> Path:
    from fixbench.cases.files import write_text_atomic

    write_text_atomic(path, text)
    return path


def _markdown(df: pd.DataFrame) -> str:
    return df.to_markdown(index=False, disable_numparse=True) + "\n"


def landscape_rows(records: list[dict]) -> pd.DataFrame:
    """The landscape table: one row a (case, task), shares and regrets in per cent."""
    out = []
    for rec in records:
        for t in rec["tasks"]:
            out.append({"case": rec["case"], "agents": rec["agents"], "task": t["task"],
                        "layouts": rec["joint_size"], "PBP optima": t["pbp_optima"],
                        "optimum (um)": t["optimum_m"] * 1e6,
                        "PBP regret median (%)": t["pbp_regret_median"] * 100,
                        "PBP regret max (%)": t["pbp_regret_max"] * 100,
                        "PBP within 5 %": t["pbp_within_5pct"], "optima reached": t["optima_reached"],
                        "descents to the optimum (%)": t["global_basin_share"] * 100,
                        "descents within 5 % (%)": t["descents_within_5pct"] * 100,
                        "descent regret mean (%)": t["descent_regret_mean"] * 100,
                        "samples a descent": t["samples_mean"],
                        "samples to 5 % (expected)": t["samples_to_5pct"]})
    return pd.DataFrame(out)


def write_equilibria(out: Path, starts: int, seed: int, echo) -> list[Path]:
    """Figure 3, the landscape tables and figure (see the module docstring)."""
    from fixbench.bench.analysis.analysis_figures import figure3, landscape_figure
    from fixbench.bench.analysis.equilibria import analyse
    from fixbench.bench.reporting.plots import save_png
    from fixbench.bench.reporting.tables import show_numbers
    from fixbench.cases.problem import load_problem
    from fixbench.cases.references import case_fingerprint

    written = []
    two = []
    for case, task in FIGURE3:
        problem = load_problem(case, agents=2)
        rec, tables, _ = analyse(problem, range(problem.n_tasks), starts, seed)
        rec["case_fingerprint"] = case_fingerprint(case, rec["material"], 2)
        two.append(rec)
        title = (f"{case} ({rec['material']}), 2 agents, task {task}: max |u| of all {problem.joint_size:,} "
                 "layouts\n(exhaustive enumeration: analysis, not a planner)")
        written.append(save_png(figure3(tables[task], title), out / f"figure3_{case}_task{task}.png"))
        echo(f"{case} at 2 agents: PBP optima by task {[t['pbp_optima'] for t in rec['tasks']]}")
    written.append(_write(out / "equilibria_2agents.md", _markdown(show_numbers(landscape_rows(two)))))
    records, lands = [], {}
    for case in SMALL_CASES:
        problem = load_problem(case)
        rec, _, land = analyse(problem, range(problem.n_tasks), starts, seed)
        rec["case_fingerprint"] = case_fingerprint(case, rec["material"], rec["agents"])  # which case it was
        records.append(rec)
        lands[case] = list(land.values())
        echo(f"{case}: PBP optima by task {[t['pbp_optima'] for t in rec['tasks']]}")
    table = landscape_rows(records)
    written.append(_write(out / "equilibria.md", _markdown(show_numbers(table))))
    written.append(_write(out / "equilibria.csv", table.to_csv(index=False)))
    data = {"catalog_agents": records, "two_agents": two}
    written.append(_write(out / "equilibria.json", json.dumps(data, separators=(",", ":"), allow_nan=False) + "\n"))
    written.append(save_png(landscape_figure(lands), out / "equilibria_landscape.png"))
    return written


def write_robots(out: Path, tolerance_um: float, fraction: float, echo) -> list[Path]:
    """The robots tables and figures of :data:`ROBOTS` in every material of :data:`MATERIALS`."""
    from fixbench.bench.analysis.analysis_figures import robots_figure
    from fixbench.bench.analysis.robots import answer_text, robots_needed, robots_table, show_robots
    from fixbench.bench.reporting.plots import save_png

    tol = tolerance_um * 1e-6
    written, records = [], []
    for case, k in ROBOTS:
        sections = [f"# {case}: best max deformation per task against the number of robots\n",
                    f"Tolerance {tolerance_um:g} um (`fixbench robots {case} --tolerance-um {tolerance_um:g} "
                    f"--max-agents {k} --fraction {fraction:g} --material M`).\n"]
        for material in MATERIALS:
            rows = robots_table(case, material, k, tol)
            answers = [robots_needed(rows, f) for f in (1.0, fraction)]
            records.append({"case": case, "material": material, "tolerance_m": tol, "rows": rows,
                            "answers": answers})
            sections += [f"## {material}\n", _markdown(show_robots(rows)),
                         *(f"- {answer_text(a, tolerance_um)}" for a in answers), "",
                         f"![](robots_{case}_{material}.png)\n"]
            written.append(save_png(robots_figure(rows, tol, f"{case} ({material}): best max |u| per task"),
                                    out / f"robots_{case}_{material}.png"))
            echo(f"{case} ({material}): {answer_text(answers[0], tolerance_um)}")
        written.append(_write(out / f"robots_{case}.md", "\n".join(sections)))
    written.append(_write(out / "robots.md", _markdown(robots_summary(records, fraction))))
    written.append(_write(out / "robots.json", json.dumps(records, indent=1, allow_nan=False) + "\n"))
    return written


def robots_summary(records: list[dict], fraction: float) -> pd.DataFrame:
    """The README's robots table: per case and material, the worst task's best max deformation (um)
    for every N (``*``: best-known, not proven; ``-``: unavailable; blank: not tried) and the smallest
    N for every task and for ``fraction`` of them (``records``: as robots.json holds them)."""
    k = max(len(rec["rows"]) for rec in records)
    out = []
    for rec in records:
        worst = {r["agents"]: "-" if r["worst_m"] is None
                 else f"{r['worst_m'] * 1e6:.3g}" + ("" if r["proven"] else "*") for r in rec["rows"]}
        out.append({"case": rec["case"], "material": rec["material"],
                    **{f"N={n}": worst.get(n, "") for n in range(1, k + 1)},
                    "every task": _short(rec["answers"][0]), f"{fraction:.0%} of tasks": _short(rec["answers"][1])})
    return pd.DataFrame(out)


def _short(answer: dict) -> str:
    """The smallest N of an answer in a table cell: ``3``, ``<= 5`` (fewer not ruled out) or ``none``."""
    if answer["agents"] is None:
        return "none"
    return str(answer["agents"]) if answer["proven"] else f"<= {answer['agents']}"


PROG = "python -m studies.analysis"


@click.command(help=__doc__.split("\n")[0], context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("results/analysis"),
              show_default=True)
@click.option("--readme", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Refresh this README's copies of the tables.")
@click.option("--only", type=click.Choice(["equilibria", "robots"]), help="Write only one of the two parts.")
@click.option("--starts", type=click.IntRange(min=1), default=10_000, show_default=True,
              help="Best-response descents from uniform random layouts per task.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--tolerance-um", type=click.FloatRange(min=0, min_open=True), default=50.0, show_default=True)
@click.option("--fraction", type=click.FloatRange(0, 1, min_open=True), default=0.75, show_default=True)
def cli(out, readme, only, starts, seed, tolerance_um, fraction) -> None:
    def echo(msg: str) -> None:
        click.echo(msg, err=True)

    written = []
    if only != "robots":
        written += write_equilibria(out, starts, seed, echo)
    if only != "equilibria":
        written += write_robots(out, tolerance_um, fraction, echo)
    click.echo(f"wrote {len(written)} files to {out}")
    if readme is not None:
        from fixbench.bench.reporting.tables import refresh_readme

        click.echo(f"refreshed {refresh_readme(readme, out)} tables in {readme}")


def main(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    return run_command(cli, argv, PROG)


if __name__ == "__main__":
    raise SystemExit(main())
