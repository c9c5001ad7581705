"""Exact optima of the ``*_small`` cases, and how close the search planners get at 2 % of it.

Not a test: a closing-note benchmark. ``python -m studies.small_benchmark [CASE ...]`` (default:
the four ``*_small`` cases) prints one row per case: set-up time (FE model and oracle), exact's wall
time and its mean max deformation (per-task mode), then greedy's, GA's and PSO's mean over seeds of
their gap in mean max deformation with a budget of 2 % of the enumeration's samples.
"""

from __future__ import annotations

import sys
import time

import click
import numpy as np

from fixbench.bench.cli_common import run_command
from fixbench.cases import load_problem
from fixbench.solvers import get

CASES = ("fan_small", "wing_panel_small", "wing_spar_small", "bus_panel_small")
SEARCHERS = ("greedy", "ga", "pso", "random")
SHARE = 0.02
SEEDS = (0, 1, 2)


def run(case: str) -> dict:
    start = time.perf_counter()
    problem = load_problem(case)
    _ = problem.oracle  # the factorisation is set-up, not search
    setup_s = time.perf_counter() - start
    full = problem.joint_size * problem.n_tasks
    start = time.perf_counter()
    exact = get("exact")().solve(problem, budget=full)
    row = {"case": case, "evaluations": full, "setup_s": setup_s, "exact_s": time.perf_counter() - start,
           "optimum_um": 1e6 * exact.objective, "budget": int(SHARE * full)}
    for name in SEARCHERS:
        gaps = [get(name)().solve(problem, budget=row["budget"], seed=s).objective / exact.objective - 1
                for s in SEEDS]
        row[name] = 100 * float(np.mean(gaps))
    return row


PROG = "python -m studies.small_benchmark"


@click.command(help=__doc__, context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("cases", nargs=-1, metavar="[CASE]...")
def cli(cases: tuple[str, ...]) -> None:
    cases = cases or CASES
    head = " | ".join(f"{n} gap %" for n in SEARCHERS)
    print(f"| case | joint x tasks | set-up s | exact s | optimum um | budget | {head} |")
    print("|---|---:|---:|---:|---:|---:|" + "---:|" * len(SEARCHERS))
    for case in cases:
        r = run(case)
        gaps = " | ".join(f"{r[n]:.2f}" for n in SEARCHERS)
        print(f"| {r['case']} | {r['evaluations']:.3g} | {r['setup_s']:.1f} | {r['exact_s']:.1f} | "
              f"{r['optimum_um']:.4g} | {r['budget']} | {gaps} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit code (2: a usage error)."""
    return run_command(cli, argv, PROG)


if __name__ == "__main__":
    sys.exit(main())
