"""Exact optima of the ``*_small`` cases, and greedy's gap to them at 2 % of the enumeration cost.

Not a test: a closing-note benchmark. ``python -m bench.small_benchmark [CASE ...]`` prints one
row per case: exact's wall time, its mean max deformation (per-task mode), greedy's samples and
its relative gap in mean max deformation.
"""

from __future__ import annotations

import sys
import time

from cases import load_problem
from solvers import get

CASES = ("fan_small", "wing_panel_small", "wing_spar_small", "bus_panel_small")
GREEDY_SHARE = 0.02


def run(case: str, seed: int = 0) -> dict:
    problem = load_problem(case)
    _ = problem.oracle  # the factorisation is set-up, not search: keep it out of exact's time
    full = problem.joint_size * problem.n_tasks
    start = time.perf_counter()
    exact = get("exact")().solve(problem, budget=full)
    exact_s = time.perf_counter() - start
    greedy = get("greedy")().solve(problem, budget=int(GREEDY_SHARE * full), seed=seed)
    return {"case": case, "joint_size": problem.joint_size, "tasks": problem.n_tasks,
            "exact_s": exact_s, "exact_mean_um": 1e6 * exact.objective,
            "greedy_samples": greedy.samples, "greedy_mean_um": 1e6 * greedy.objective,
            "greedy_gap_pct": 100 * (greedy.objective / exact.objective - 1)}


def main(cases: list[str]) -> None:
    print("| case | joint x tasks | exact s | optimum mean um | greedy samples | greedy mean um | gap % |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for case in cases:
        r = run(case)
        print(f"| {r['case']} | {r['joint_size'] * r['tasks']:.3g} | {r['exact_s']:.1f} | "
              f"{r['exact_mean_um']:.3f} | {r['greedy_samples']} | {r['greedy_mean_um']:.3f} | "
              f"{r['greedy_gap_pct']:.1f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or list(CASES))
