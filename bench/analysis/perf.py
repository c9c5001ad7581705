"""`fixbench perf`: the oracle against re-assembly + direct sparse solve, side by side.

All timings come from one process on the same machine, so the ratios are what counts:
- ``single_speedup``: median time of one direct solve (assemble K, impose supports and fixture
  constraints, sparse solve) divided by the median time of one oracle evaluation;
- ``batched_layouts_per_s``: one call evaluating many random layouts;
- ``precompute_s``: model build + factorisations + compliance columns of every candidate, computed
  afresh (the disk cache of :mod:`fixbench.cases.cache` is neither read nor written here);
- ``peak_rss_mb``: the process's peak resident memory after all of the above.
"""

from __future__ import annotations

import resource
import time

import numpy as np
from tqdm import tqdm

from fixbench.cases.oracle import Oracle
from fixbench.cases.problem import load_problem


def median_time(fn, repeat: int) -> float:
    """Median wall seconds of ``repeat`` calls of ``fn`` (one at a time, no warm-up call)."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def run_perf(case: str = "wing_panel", batch: int = 200_000, single: int = 2000,
             direct: int = 5, seed: int = 0, progress: bool = True) -> dict:
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    problem = load_problem(case)
    model = problem.model
    oracle = Oracle(model, problem.candidates)  # no cache key: the set-up is what is measured
    cols = sum(fo.n_rows for fo in oracle.fields.values())
    with tqdm(total=cols, desc="compliance columns", disable=not progress, unit="col") as bar:
        oracle.ensure(np.arange(len(problem.candidates)), progress=bar.update)
    precompute = time.perf_counter() - t0

    def random_layouts(n):
        return np.column_stack([rng.choice(a, size=n) for a in problem.action_sets])

    task = problem.n_tasks // 2
    oracle.evaluate(task, random_layouts(2))  # compile the kernel before timing
    singles = random_layouts(single)
    it = iter(singles)
    t_single = median_time(lambda: oracle.evaluate(task, next(it)[None, :]), single)
    lay = random_layouts(direct)[0]
    t_direct = median_time(lambda: model.solve_direct(task, problem.candidates[lay], reassemble=True),
                            direct)
    many = random_layouts(batch)
    t = time.perf_counter()
    oracle.evaluate(task, many)
    t_batch = time.perf_counter() - t
    return {
        "case": case,
        "dofs": {f: int(fs.basis.N) for f, fs in model.fields.items()},
        "candidates": int(len(problem.candidates)),
        "measurement_points": int(len(model.measure_points)),
        "compliance_columns": int(cols),
        "precompute_s": precompute,
        "single_oracle_s": t_single,
        "direct_solve_s": t_direct,
        "single_speedup": t_direct / t_single,
        "batched_layouts_per_s": batch / t_batch,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }
