"""`fixbench perf`: the oracle against re-assembly + direct sparse solve, side by side; with
``--planner``, one planner's runs at several values of a setting, side by side.

All timings come from one process on the same machine, so the ratios are what counts. The oracle:
- ``single_speedup``: median time of one direct solve (assemble K, impose supports and fixture
  constraints, sparse solve) divided by the median time of one oracle evaluation;
- ``batched_layouts_per_s``: one call evaluating many random layouts;
- ``precompute_s``: model build + factorisations + compliance columns of every candidate, computed
  afresh (the disk cache of :mod:`fixbench.cases.cache` is neither read nor written here);
- ``peak_rss_mb``: the process's peak resident memory after all of the above.

``case`` may be ``CASE@MATERIAL``: the case in a grade, on the same mesh (a laminate part against the
same part in aluminium: the oracle's cost does not depend on the stiffness it carries).
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
    name, _, material = case.partition("@")  # CASE@MATERIAL: the case in another material
    problem = load_problem(name, material or None)
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


def run_planner_perf(case: str, planner: str, sets: tuple[str, ...], vary: str, budget: int | None = None,
                     samples_per_task: int | None = None, seed: int = 0,
                     heldout_every: int | None = None) -> list[dict]:
    """One planner on ``case`` once per value of ``vary`` ("key=v1,v2,..."), the rest of its config from
    ``sets``, on the same problem, seed and budget (``samples_per_task`` x the tasks it may evaluate, or
    ``budget``) in this process, one after the other: CPU seconds of each (the process's, so the
    oracle's set-up and an untimed warm-up run, made before the first, are in none), the phases a learner times in its
    ``info`` (``time_*_s``, wall seconds), the samples and the score (mean incumbent max deformation,
    and the policy's where the planner returns one), and each run's CPU time as a ratio of the first's.
    """
    from fixbench.bench.records.keys import split
    from fixbench.solvers.base import PlannerError
    from fixbench.solvers.config import apply_sets
    from fixbench.solvers.registry import get

    key, sep, values = vary.partition("=")
    if not sep or not key or not values:
        raise PlannerError(f"--vary {vary}: expected key=value1,value2,...")
    cls = get(planner)
    base = apply_sets(cls.Config, sets, cls.name)
    variants = [apply_sets(cls.Config, [f"{key}={v}"], cls.name) for v in values.split(",")]
    configs = [cls.Config(**{**base, **v}) for v in variants]  # every value checked before any run
    problem = load_problem(case)
    problem.oracle.prepare()
    train = None if heldout_every is None else split(problem.n_tasks, heldout_every)[0]
    n_open = problem.n_tasks if train is None else len(train)
    run_budget = samples_per_task * n_open if samples_per_task else budget
    try:  # untimed warm-up, one sample a task: libraries loaded, kernels compiled before the first timing
        cls(configs[0]).solve(problem, n_open, seed=seed, train_tasks=train)
    except PlannerError:
        pass
    out = []
    for v, cfg in zip(values.split(","), configs):
        t_cpu, t_wall = time.process_time(), time.perf_counter()
        res = cls(cfg).solve(problem, run_budget, seed=seed, train_tasks=train)
        cpu, wall = time.process_time() - t_cpu, time.perf_counter() - t_wall
        out.append({"case": case, "planner": planner, key: v, "samples": res.samples, "cpu_s": cpu,
                    "wall_s": wall, **{k: val for k, val in res.info.items() if k.startswith("time_") and
                                       k not in ("time_total_s", "time_setup_s")},
                    "objective_m": res.objective, "policy_objective_m": res.policy_objective})
    for r in out:
        r["cpu_ratio"] = r["cpu_s"] / out[0]["cpu_s"]
    return out
