"""MARL benchmark: the seed's Figure 4, the speed of the reference protocol, and small-case optima.

    python -m studies.marl figure4 [--case wing_panel] [--planner nashq|iql] [--agents 1,3,5] [--episodes 100]
                                   [--out DIR]
    python -m studies.marl speed   [--case wing_panel] [--planner nashq|iql] [--episodes 100] [--threads T]
                                   [--seed S] [--device cpu|cuda] [--json] [--figures DIR]
    python -m studies.marl table   [--episodes 100] [--seed 0] [--json]
    python -m studies.marl heldout [--case wing_panel] [--planner nashq|iql] [--every 5]
                                   [--episodes 100] [--json]
    python -m studies.marl floor   [--case wing_panel] [--threads T] [--json]
    python -m studies.marl batching [--case wing_panel_small] [--planners vdn,nashq,iql] [--per-step 1,2,4]
                                    [--seeds 20] [--episodes 100] [--json]

``figure4`` draws the report's Figure 4 (:func:`fixbench.bench.reporting.figures.draw_figure4`) one panel a
file: (a) step reward against step, (b) episodic return and (c) episodic regret (the reference's
N T r* - N sum r, and the true regret against the best layout seen) against episode, and (d) a
violin plot of the percentage difference in max deformation of every layout tried in training from
the best one seen on its task, one line and one violin per run (e.g. per agent count). ``speed``
runs the full protocol once and reports the wall time split into oracle, action selection and
network updates (timed inside the planner). ``table`` compares nashq and iql with the proven optimum
on every ``*_small`` case. ``heldout`` trains a learner on the held-out track's training tasks (tasks
0, k, 2k, ..., as ``fixbench run`` with mode "held-out" and ``heldout_every = k``) and compares its
zero-sample layouts on the other tasks with planners that spend 1, 5, 20 and 100 samples on each of
them (the harness's held-out table scores against the shipped reference at the matrix's one budget).
``floor`` measures what one network update of the protocol costs on this machine and what it cannot
cost less than: the floating-point work of its 11 batched products against this machine's rate on a
large matrix product, and the bytes of its optimiser pass (:func:`update_floor`). ``batching`` runs
learners at several positions a step (``positions_per_step``) on a small case, many seeds each, and
compares their regret against the proven optimum with the one-position-a-step runs (:func:`batching`).

``--planner`` takes the learners with the seed's reward and a ``device``, nashq and iql: vdn, mappo and
ippo optimise the scaled reward only (time them with ``fixbench solve``).

Oracle set-up (meshing, factorisation, and the compliance columns of every candidate, which the
oracle otherwise computes lazily the first time a layout uses a candidate) is done and timed
before a run: it is a property of the problem, costs no samples and is shared by all planners.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import click
import numpy as np

from fixbench.bench.cli_common import run_command
from fixbench.bench.reporting.figures import figure4_panels, palette, training_run
from fixbench.bench.reporting.plots import save_png
from fixbench.cases.problem import Problem, load_problem
from fixbench.cases.spec import case_names
from fixbench.solvers.base import PlanResult, Training

#: the seed's protocol: its Gaussian reward with the case's widths (the learners' default is 'scaled')
SEED_REWARD = "gaussian"
#: the learners with a ``reward`` and a ``device`` field: the only ones that can run the seed's protocol
SEED_LEARNERS = ("nashq", "iql")


def _learner_runs(results) -> dict[str, list[dict]]:
    """Figure 4's input (:func:`fixbench.bench.reporting.figures.learner_runs`) from one run or a dict {label: run},
    a run being a learner's PlanResult or its Training; the true regret and the violin are against the best
    layout each run saw on a task (a run keeps no optima)."""
    def one(x) -> dict:
        return training_run(getattr(x, "training", x))

    if isinstance(results, (PlanResult, Training)):
        return {getattr(results, "planner", "run"): [one(results)]}
    return {str(k): [one(v)] for k, v in dict(results).items()}


#: Figure 4's files, one a panel (README shows them)
FIGURE4_FILES = ("fig4a_step_reward.png", "fig4b_episodic_return.png", "fig4c_episodic_regret.png",
                 "fig4d_violin.png")


def figure4(results, out_dir: str | Path) -> list[Path]:
    """Write the four panels of the seed's Figure 4 (:func:`fixbench.bench.reporting.figures.figure4_panels`, the
    report's Figure 4 one panel a file) as PNGs into ``out_dir``; returns the paths.

    ``results``: a learner's PlanResult or Training, or a dict {label: PlanResult or Training}
    (one line and one violin per label).
    """
    runs = _learner_runs(results)
    figs = figure4_panels(runs, palette(list(runs)))
    return [save_png(fig, Path(out_dir) / name) for fig, name in zip(figs, FIGURE4_FILES)]


def prepare(problem: Problem) -> float:
    """Build the problem's oracle with every candidate's compliance columns; returns seconds."""
    t = time.perf_counter()
    problem.oracle.prepare()
    return time.perf_counter() - t


def speed(case: str = "wing_panel", planner: str = "nashq", agents: int | None = None,
          episodes: int = 100, seed: int = 0, threads: int = 0, figures: str | None = None,
          device: str = "cpu") -> dict:
    """Run the reference protocol once with ``planner`` (one of :data:`SEED_LEARNERS`); wall time and its
    split (oracle / selection / updates).

    With ``figures`` (a directory), the same run's Figure 4 panels and its training record
    (``training.json``) are written there too.
    """
    from fixbench.solvers.registry import get

    problem = load_problem(case, agents=agents)
    setup = prepare(problem)
    t = time.perf_counter()
    res = get(planner)(episodes=episodes, threads=threads, device=device,
                       reward=SEED_REWARD).solve(problem, None, seed=seed)
    wall = time.perf_counter() - t
    i = res.info
    if figures:
        figure4({f"{planner} N={problem.n_agents}": res}, figures)
        curves = {name: c.values.tolist() for name, c in res.training.curves.items()}
        (Path(figures) / "training.json").write_text(json.dumps({**i, **curves}))
    return {"case": case, "planner": planner, "agents": problem.n_agents, "tasks": problem.n_tasks,
            "episodes": i["episodes_run"], "samples": res.samples, "oracle_setup_s": setup,
            "wall_s": wall, "plan_s": i["time_total_s"], "oracle_s": i["time_oracle_s"],
            "select_s": i["time_select_s"], "update_s": i["time_update_s"],
            "greedy_s": i["time_greedy_s"], "device": device, "br_sweeps_mean": i["br_sweeps_mean"],
            "br_converged_frac": i["br_converged_frac"], "torch_threads": i["torch_threads"],
            "mean_max_deformation_m": float(res.max_deformation.mean()),
            "per_task_m": res.max_deformation.tolist(),
            "episode_return": res.training.values("episode_return").tolist(),
            "loadavg": os.getloadavg(), "cpus": os.cpu_count()}


def update_floor(case: str = "wing_panel", agents: int | None = None, threads: int = 1, repeat: int = 300,
                 seed: int = 0) -> dict:
    """One network update of the protocol (nashq, the default config) timed whole and in its parts, beside
    the bounds this machine puts on it.

    - ``bmm_*``: the update's 11 batched products (forward of the policy and target networks on the
      chosen actions, backward into the weights) on their own; ``bmm_gflop`` is counted by torch's
      ``FlopCounterMode`` on a real update (``products_gflop`` on the timed copies of its products: the
      same), against ``peak_gflops``, this machine's rate on a 2,048-square float32 product at the same
      thread count;
    - ``adamw_*``: the fused clip + AdamW + soft target pass over all weights, the bytes it moves (6
      arrays read, 5 written) and the rate reached;
    - ``update_ms``: ``td_grad`` + the optimiser step on random replay batches, the median of ``repeat``;
    - ``floor_updates_s``: the protocol's updates (one a step, 50,000 on the wing panel) reduced to their
      products at the best rate measured here (theirs or the large product's) plus the optimiser pass as
      measured: a lower bound for the same arithmetic on this machine, but for what a faster optimiser
      pass (a memory-bound stream of 11 arrays) could save.

    torch and numba run at ``threads`` threads during the measurement; their settings are restored after.
    """
    import numba
    import torch

    saved = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(threads)
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        return _update_floor(case, agents, threads, repeat, seed)
    finally:  # the caller's thread counts, however the measurement ends
        torch.set_num_threads(saved[0])
        numba.set_num_threads(saved[1])


def _update_floor(case: str, agents: int | None, threads: int, repeat: int, seed: int) -> dict:
    """:func:`update_floor`'s measurement, at the thread counts it set."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from fixbench.bench.analysis.perf import median_time
    from fixbench.solvers.learners.marl_engine import Learner, Update
    from fixbench.solvers.learners.nashq import NashQConfig

    problem = load_problem(case, agents=agents)
    cfg = NashQConfig()
    learner = Learner(problem, cfg.hidden, cfg.max_sweeps, True, torch.device("cpu"),
                      torch.Generator().manual_seed(seed))
    opt = Update(learner.q, learner.target, cfg.lr, cfg.grad_clip, cfg.tau, torch.device("cpu"))
    rng = np.random.default_rng(seed)
    n, nb, sizes = problem.n_agents, cfg.batch, np.array(learner.sizes)

    def batch():
        return (torch.from_numpy(rng.integers(0, problem.n_tasks, (n, nb))),
                torch.from_numpy((rng.random((n, nb, n)) * sizes).astype(np.int64)),
                torch.from_numpy(rng.random((n, nb)).astype(np.float32)))

    def median_ms(fn, k=repeat):
        fn()  # warm-up: compilation and first-touch of memory are no part of the figure
        return 1e3 * median_time(fn, k)

    batches = [batch() for _ in range(64)]
    it = iter(range(10**9))

    def update():
        learner.td_grad(*batches[next(it) % 64], cfg.alpha)
        opt.step()

    for _ in range(50):
        update()
    update_ms = median_ms(update)
    adamw_ms = median_ms(opt.step)
    # the 11 products: policy and target forward (layers 0-2), weight gradients of layers 0-2, and the
    # back-propagated errors of layers 2 and 1 (the output layer's chosen columns are elementwise)
    n_in, hid = learner.q.shapes[0][1], learner.q.shapes[0][2]
    x, h = torch.rand(n, nb, n_in), torch.rand(n, nb, hid)
    w0, w1 = torch.rand(n, n_in, hid), torch.rand(n, hid, hid)
    gw0, gw1 = torch.empty(n, n_in, hid), torch.empty(n, hid, hid)

    def products():
        for _ in range(2):
            torch.bmm(x, w0), torch.bmm(h, w1), torch.bmm(h, w1)
        torch.bmm(h.transpose(1, 2), h, out=gw1), torch.bmm(h.transpose(1, 2), h, out=gw1)
        torch.bmm(x.transpose(1, 2), h, out=gw0)
        torch.bmm(h, w1.transpose(1, 2)), torch.bmm(h, w1.transpose(1, 2))

    with FlopCounterMode(display=False) as counted:
        learner.td_grad(*batches[0], cfg.alpha)
    with FlopCounterMode(display=False) as timed:
        products()
    flops = counted.get_total_flops()
    bmm_ms = median_ms(products)
    a, b = torch.rand(2048, 2048), torch.rand(2048, 2048)
    peak = 2 * 2048**3 / (median_ms(lambda: torch.mm(a, b), 10) * 1e6)
    best = max(peak, flops / (bmm_ms * 1e6))  # the best rate this machine showed on either
    params = learner.q.flat.numel()
    adamw_bytes = 11 * 4 * params
    steps = problem.n_tasks * cfg.episodes
    return {"case": case, "agents": n, "threads": threads, "params": params, "update_ms": update_ms,
            "bmm_ms": bmm_ms, "bmm_gflop": flops / 1e9, "products_gflop": timed.get_total_flops() / 1e9,
            "bmm_gflops": flops / (bmm_ms * 1e6), "peak_gflops": peak, "adamw_ms": adamw_ms,
            "adamw_mb": adamw_bytes / 1e6, "adamw_gbps": adamw_bytes / (adamw_ms * 1e6),
            "protocol_updates": steps, "updates_s_at_this_rate": steps * update_ms / 1e3,
            "floor_updates_s": steps * (flops / (best * 1e9) + adamw_ms / 1e3)}


def table(episodes: int = 100, seed: int = 0, planners=("nashq", "iql")) -> list[dict]:
    """Greedy-policy mean max deformation of each planner against the proven optimum, *_small cases."""
    from fixbench.solvers.registry import get

    rows = []
    for case in [c for c in case_names() if c.endswith("_small")]:
        problem = load_problem(case)
        prepare(problem)
        opt = get("exact")().solve(problem, None).max_deformation
        for name in planners:
            t = time.perf_counter()
            res = get(name)(episodes=episodes, optima=tuple(float(x) for x in opt),
                            reward=SEED_REWARD).solve(problem, None, seed=seed)
            rows.append({"case": case, "planner": name, "agents": problem.n_agents, "tasks": problem.n_tasks,
                         "samples": res.samples, "optimum_mean_m": float(opt.mean()),
                         "planner_mean_m": float(res.max_deformation.mean()),
                         "gap_pct": 100 * float(res.max_deformation.mean() / opt.mean() - 1),
                         "tasks_within_10pct": int((res.max_deformation <= 1.1 * opt).sum()),
                         "best_seen_gap_pct": 100 * float(np.mean(res.info["best_seen_max_u"]) / opt.mean() - 1),
                         "seconds": time.perf_counter() - t})
    return rows


def heldout(case: str = "wing_panel", planner: str = "nashq", every: int = 5, episodes: int = 100,
            seed: int = 0, per_task: tuple[int, ...] = (1, 5, 20, 100),
            baselines: tuple[str, ...] = ("random", "greedy"), **planner_config) -> list[dict]:
    """A learner trained on some tasks, acting on the others with no samples, beside planners that spend
    ``per_task`` samples on every held-out task.

    The split is the harness's held-out track (:func:`fixbench.bench.records.keys.split`): the
    learner trains on tasks 0, ``every``, 2 ``every``, ... for ``episodes`` episodes, through
    ``Planner.solve(train_tasks=...)`` as a held-out cell does; its greedy policy's layouts on the other
    tasks cost nothing (``train_policy_um``: the same policy on its training tasks, ``train_best_seen_um``:
    the best layout it saw there). Each baseline solves the held-out tasks alone at each per-task budget.
    Gap: mean max deformation over the held-out tasks against the best layout any of these runs found on
    each task (no proven optimum at this size).
    """
    from fixbench.bench.records.keys import split
    from fixbench.solvers.base import PlannerError
    from fixbench.solvers.registry import get

    problem = load_problem(case)
    prepare(problem)
    train, held = (np.asarray(x, dtype=int) for x in split(problem.n_tasks, every))
    t = time.perf_counter()
    res = get(planner)(episodes=episodes, **{"reward": SEED_REWARD, **planner_config}).solve(
        problem, None, seed=seed, train_tasks=train.tolist())
    policy_u = res.max_deformation if res.policy_max_deformation is None else res.policy_max_deformation
    runs = [{"planner": planner, "samples_per_held_out_task": 0, "samples": res.samples,
             "u": res.max_deformation[held], "train_best_seen_um": 1e6 * float(res.max_deformation[train].mean()),
             "train_policy_um": 1e6 * float(policy_u[train].mean()), "seconds": time.perf_counter() - t}]
    sub = Problem(problem.spec.with_tasks(held.tolist()))
    prepare(sub)
    for name in baselines:
        for b in per_task:
            t = time.perf_counter()
            try:
                r = get(name)().solve(sub, budget=b * len(held), seed=seed)
                runs.append({"planner": name, "samples_per_held_out_task": b, "samples": r.samples,
                             "u": r.max_deformation, "seconds": time.perf_counter() - t})
            except PlannerError as e:
                runs.append({"planner": name, "samples_per_held_out_task": b, "error": str(e)})
    best = np.min([r["u"] for r in runs if "u" in r], axis=0)
    rows = []
    for r in runs:
        row = {"case": case, "train_tasks": len(train), "held_out_tasks": len(held),
               **{k: v for k, v in r.items() if k != "u"}}
        if "u" in r:
            row["held_out_mean_um"] = 1e6 * float(r["u"].mean())
            row["gap_to_best_found_pct"] = 100 * float(r["u"].mean() / best.mean() - 1)
        rows.append(row)
    return rows


def batching(case: str = "wing_panel_small", planners=("vdn", "nashq", "iql"), per_step=(1, 2, 4),
             seeds: int = 20, episodes: int = 100) -> list[dict]:
    """Each learner at each ``positions_per_step`` (its default config otherwise, the scaled reward), seeds
    0 to ``seeds`` - 1, ``episodes`` samples a position, per-task: the mean over positions of the regret
    against the proven optimum (the ``exact`` planner, uncounted) of each run, and per setting its mean with
    a percentile-bootstrap 95 % CI, the IQM with its CI, the median CPU seconds of a run (this process's, one
    thread, after an untimed one-episode run of the learner), and rliable's probability that a run of this
    setting ends below a run at one position a step (the first value of ``per_step`` is the base)."""
    from fixbench.bench.reporting.stats import bootstrap_ci, iqm, mean_ci, probability_of_improvement
    from fixbench.solvers.registry import get

    # every learner and setting configured (and so checked) before the oracle and the optimum are computed
    runs = {name: [get(name)(episodes=episodes, positions_per_step=p, threads=1) for p in per_step]
            for name in planners}
    problem = load_problem(case)
    prepare(problem)
    opt = get("exact")().solve(problem, None).max_deformation
    rows = []
    for name, settings in runs.items():
        base = None
        get(name)(episodes=1, threads=1).solve(problem, None, seed=0)  # start-up (imports, compilation): untimed
        for p, planner in zip(per_step, settings):
            regret, cpu = [], []
            for seed in range(seeds):
                t = time.process_time()
                res = planner.solve(problem, None, seed=seed)
                cpu.append(time.process_time() - t)
                regret.append(100 * float(np.mean(res.max_deformation / opt - 1)))
            base = regret if base is None else base
            mean, lo, hi = mean_ci(regret)
            q, qlo, qhi = bootstrap_ci(regret, stat=iqm)
            rows.append({"case": case, "planner": name, "positions_per_step": p, "runs": seeds,
                         "samples": res.samples, "regret_mean_pct": mean,
                         "regret_mean_ci": [lo, hi], "regret_iqm_pct": q, "regret_iqm_ci": [qlo, qhi],
                         "p_below_base": list(probability_of_improvement(regret, base)),
                         "cpu_s_median": float(np.median(cpu)), "regret_pct": regret})
    return rows


PROG = "python -m studies.marl"


def _ints(ctx, param, value: str) -> list[int]:
    """A comma-separated list of integers, or a usage error naming the option."""
    try:
        return [int(x) for x in value.split(",")]
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a comma-separated list of integers") from None
PLANNER_HELP = "the learners with the seed's reward (vdn, mappo and ippo have only the scaled reward)"


@click.group(help=__doc__.split("\n")[0], context_settings={"help_option_names": ["-h", "--help"]})
def cli() -> None:
    pass


@cli.command("figure4", short_help="Draw the report's Figure 4, one panel a file.")
@click.option("--case", default="wing_panel", show_default=True)
@click.option("--planner", type=click.Choice(SEED_LEARNERS), default="nashq", show_default=True, help=PLANNER_HELP)
@click.option("--agents", default="5", show_default=True, callback=_ints,
              help="comma-separated agent counts, one run each")
@click.option("--episodes", type=int, default=100, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--out", default="results/figures/marl", show_default=True)
def figure4_cmd(case: str, planner: str, agents: list[int], episodes: int, seed: int, out: str) -> None:
    """Draw the report's Figure 4 one panel a file, one line and one violin per agent count."""
    from fixbench.solvers.registry import get

    results = {}
    for n in agents:
        problem = load_problem(case, agents=n)
        prepare(problem)
        results[f"{planner} N={n}"] = get(planner)(episodes=episodes,
                                                   reward=SEED_REWARD).solve(problem, None, seed=seed)
    for p in figure4(results, out):
        print(f"wrote {p}")


@cli.command("speed", short_help="Run the reference protocol once; wall time and its split.")
@click.option("--case", default="wing_panel", show_default=True)
@click.option("--planner", type=click.Choice(SEED_LEARNERS), default="nashq", show_default=True, help=PLANNER_HELP)
@click.option("--agents", type=int)
@click.option("--episodes", type=int, default=100, show_default=True)
@click.option("--threads", type=int, default=0, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--device", default="cpu", show_default=True, help="cpu or cuda")
@click.option("--json", "as_json", is_flag=True)
@click.option("--figures", help="also write this run's Figure 4 panels into this directory")
def speed_cmd(case: str, planner: str, agents: int | None, episodes: int, threads: int, seed: int, device: str,
              as_json: bool, figures: str | None) -> None:
    """Run the full protocol once and report the wall time split into oracle, action selection and network
    updates."""
    res = speed(case, planner, agents, episodes, seed=seed, threads=threads, figures=figures, device=device)
    print(json.dumps(res, indent=1) if as_json else
          "\n".join(f"{k:>24}: {v:.4g}" if isinstance(v, float) else f"{k:>24}: {v}" for k, v in res.items()
                    if not isinstance(v, list)))


@cli.command("heldout", short_help="Learner's zero-sample layouts on held-out tasks vs planners.")
@click.option("--case", default="wing_panel", show_default=True)
@click.option("--planner", type=click.Choice(SEED_LEARNERS), default="nashq", show_default=True, help=PLANNER_HELP)
@click.option("--every", type=click.IntRange(min=2), default=5, show_default=True,
              help="train on tasks 0, k, 2k, ... (the held-out track's heldout_every), act on the others")
@click.option("--episodes", type=int, default=100, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "as_json", is_flag=True)
def heldout_cmd(case: str, planner: str, every: int, episodes: int, seed: int, as_json: bool) -> None:
    """Train a learner on every k-th task (the held-out track's split) and compare its zero-sample layouts
    on the other tasks with planners that spend samples on each of them."""
    _print_rows(heldout(case, planner, every, episodes, seed), as_json)


@cli.command("floor", short_help="One update's cost on this machine and its lower bound.")
@click.option("--case", default="wing_panel", show_default=True)
@click.option("--agents", type=int)
@click.option("--threads", type=int, default=1, show_default=True)
@click.option("--json", "as_json", is_flag=True)
def floor_cmd(case: str, agents: int | None, threads: int, as_json: bool) -> None:
    """Time one network update of the protocol whole and in its parts, beside this machine's peak rate
    for its products and the bytes of its optimiser pass (no oracle, no samples)."""
    res = update_floor(case, agents, threads)
    print(json.dumps(res, indent=1) if as_json else
          "\n".join(f"{k:>24}: {v:.4g}" if isinstance(v, float) else f"{k:>24}: {v}" for k, v in res.items()))


@cli.command("table", short_help="nashq and iql against the proven optimum, *_small cases.")
@click.option("--episodes", type=int, default=100, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "as_json", is_flag=True)
def table_cmd(episodes: int, seed: int, as_json: bool) -> None:
    """Compare nashq and iql with the proven optimum on every *_small case."""
    _print_rows(table(episodes, seed), as_json)


@cli.command("batching", short_help="Learners at several positions a step against the proven optimum.")
@click.option("--case", default="wing_panel_small", show_default=True, help="a case the exact planner enumerates")
@click.option("--planners", default="vdn,nashq,iql", show_default=True, help="comma-separated learners")
@click.option("--per-step", default="1,2,4", show_default=True, callback=_ints,
              help="comma-separated positions_per_step values; the first is the base of the comparison")
@click.option("--seeds", type=click.IntRange(min=2), default=20, show_default=True, help="runs 0 .. N-1 a setting")
@click.option("--episodes", type=click.IntRange(min=1), default=100, show_default=True)
@click.option("--json", "as_json", is_flag=True)
def batching_cmd(case: str, planners: str, per_step: list[int], seeds: int, episodes: int, as_json: bool) -> None:
    """Run each learner at each positions_per_step for many seeds on a small case; regret against the
    proven optimum, its intervals and CPU time, beside the first positions_per_step value's."""
    rows = batching(case, planners.split(","), per_step, seeds, episodes)
    if not as_json:  # intervals as "low-high", one run's regrets left out
        rows = [{k: f"{v[0]:.3g}-{v[1]:.3g}" if k.endswith("_ci") else f"{v[0]:.2f} [{v[1]:.2f}, {v[2]:.2f}]"
                 if k == "p_below_base" else v for k, v in r.items() if k != "regret_pct"} for r in rows]
    _print_rows(rows, as_json)


def _print_rows(rows: list[dict], as_json: bool) -> None:
    if as_json:
        print(json.dumps(rows, indent=1))
    else:
        import pandas as pd

        print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=".4g"))


def main(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit code (2: a usage error)."""
    return run_command(cli, argv, PROG)


if __name__ == "__main__":
    sys.exit(main())
