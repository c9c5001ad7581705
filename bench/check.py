"""`fixbench check CASE`: what a careful engineer checks of a case before trusting a run on it.

Five checks, each a section of the result (:func:`check_case`):

- **mesh**: the case's mesh and two refinements (``mesh_scales``: every element size times 0.7 and
  0.5, :meth:`~fixbench.cases.spec.CaseSpec.with_mesh_scale`). One fixed layout, *each agent's first
  action*, is solved directly on every mesh at its worst task (the task where that layout's max |u|
  on the case's mesh is largest); a change of max |u| between the last two meshes above
  ``mesh_tolerance`` (2 %, the aim docs/cases.md states for the catalog's parts) is a warning. The
  measurement points do not move with the mesh (their spacing is read from the case file once).
- **deflection**: largest deflection over thickness, w/t, of ``layouts`` seeded uniform random
  layouts on up to ``tasks`` tasks spread over the job. Linear (small-deflection) Kirchhoff plate
  theory ignores the membrane stiffening a plate gains once it deflects by a sizeable part of its
  thickness; it holds for deflections well below the thickness (S. P. Timoshenko and S.
  Woinowsky-Krieger, *Theory of Plates and Shells*, 2nd ed., 1959, ch. 13: the large-deflection
  solutions depart from the linear ones as w approaches the thickness). fixbench uses the limit of
  ``fixbench validate``, :data:`fixbench.cases.linearity.LIMIT` (w/t = 0.5). The fixtures exist to
  hold the part still, so the check warns when the *median* random layout of the worst task is
  beyond it: the layouts a planner meets then lie outside the model (the best random layout and
  the worst are reported too).
- **reference**: layouts a position (the joint size), what a matrix's reference phase costs
  (:func:`fixbench.bench.references.prove.compute_reference`: ``exact``'s enumeration up to its
  ``max_enumeration``, else its MILP up to ``max_milp_columns``, else nothing) and what the
  reference portfolio of ``fixbench references build`` costs (:class:`~fixbench.bench.references.build.Portfolio`,
  an upper bound of its samples; with the ``exact`` proof where joint size x tasks is at most
  ``prove_limit``), in samples and in seconds on this machine from the oracle's time per layout,
  measured here: in batches of ``batch`` layouts (enumeration) and one at a time (planners: their
  calls are between the two, so the portfolio's time is a range).
- **reward**: the share of the random layouts whose Gaussian reward (:func:`fixbench.cases.rewards.gaussian`)
  is 0 or 1 with the case's widths, and suggested widths: sigma = c x the median of the random
  layouts' in-plane and out-of-plane maxima, with the factor c of ``width_factors`` that leaves the
  fewest rewards at 0 or 1 (the reward exp(-(dx/sx)^2/2 - (dz/sz)^2/2) has signal only over a
  factor of about 80 in deformation, so c centres the sample in it rather than putting the median at
  sigma). A share above ``degenerate_limit`` is a warning.
- **picture**: the drawing of ``fixbench show``.

Every figure is a number in SI units (keys end in ``_m`` or ``_s``); the warnings are one line each.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fixbench.bench.analysis.perf import median_time
from fixbench.bench.references.build import Portfolio
from fixbench.cases.linearity import LIMIT
from fixbench.cases.materials import MATERIALS
from fixbench.cases.problem import Problem, load_problem
from fixbench.cases.rewards import degenerate_share, gaussian
from fixbench.solvers.base import at_least, random_layouts, require
from fixbench.solvers.math_programming.exact import ExactConfig


@dataclass(frozen=True)
class CheckSettings:
    """How much ``fixbench check`` measures, and where it warns."""

    mesh_scales: tuple[float, ...] = (1.0, 0.7, 0.5)
    """Element-size factors of the mesh study: the case's mesh first, then finer ones."""

    mesh_tolerance: float = 0.02
    """Largest relative change of max |u| between the two finest meshes without a warning."""

    layouts: int = 64
    """Uniform random layouts (uncounted) a checked task, for w/t and the reward widths."""

    tasks: int = 16
    """Most tasks checked with random layouts, spread evenly over the job."""

    seed: int = 0
    """Seed of the random layouts."""

    batch: int = 4096
    """Layouts in the batched timing call."""

    single: int = 200
    """One-layout calls timed (their median is the time one at a time)."""

    degenerate_limit: float = 0.5
    """Largest share of random layouts with a Gaussian reward of 0 or 1 without a warning."""

    width_factors: tuple[float, ...] = tuple(np.geomspace(0.05, 5.0, 41))
    """Factors c tried for the suggested widths (sigma = c x the random layouts' median)."""

    def __post_init__(self) -> None:
        at_least(self, 1, "layouts", "tasks", "batch", "single")
        require(self, "mesh_scales", len(self.mesh_scales) >= 2 and self.mesh_scales[0] == 1.0
                and all(0 < b < a for a, b in zip(self.mesh_scales, self.mesh_scales[1:])),
                "1.0 followed by decreasing positive factors")
        require(self, "mesh_tolerance", self.mesh_tolerance > 0, "positive")
        require(self, "degenerate_limit", 0 < self.degenerate_limit < 1, "in (0, 1)")
        require(self, "width_factors", len(self.width_factors) > 0 and min(self.width_factors) > 0,
                "positive factors")


def check_case(case: str | Path, material: str | None = None, out: Path | None = None,
               settings: CheckSettings | None = None) -> dict:
    """Every figure of ``fixbench check`` for ``case`` (see the module docstring); the picture is
    written to ``out`` (default: CASE.png here). ``warnings`` lists one line per warning."""
    from fixbench.bench.reporting.plots import show_case

    s = settings or CheckSettings()
    problem = load_problem(case, material)  # the file is checked before any work
    res = {"case": problem.name, "source": problem.spec.source, "material": problem.spec.material.name,
           "thickness_m": problem.spec.thinnest, "agents": problem.n_agents, "tasks": problem.n_tasks,
           "candidates": len(problem.candidates)}
    res["reference"] = reference_cost(problem, s)  # first: it times the oracle's set-up
    res["mesh"] = mesh_study(case, material, problem, s)
    maxima, tasks = random_maxima(problem, s)
    res["deflection"] = deflection(problem, maxima, tasks, s)
    res["reward"] = reward_widths(problem, maxima, s)
    res["picture"] = str(show_case(problem, out or Path(f"{problem.name}.png")))
    res["warnings"] = warnings(res, s)
    return res


def fixed_layout(problem: Problem) -> np.ndarray:
    """The mesh study's layout: each agent's first action, as a (1, agents) array."""
    return np.array([[a[0] for a in problem.action_sets]], dtype=np.int64)


def mesh_study(case, material: str | None, problem: Problem, s: CheckSettings) -> dict:
    """Max |u| of :func:`fixed_layout` at its worst task on the case's mesh and the finer ones."""
    layout = fixed_layout(problem)
    task = int(np.argmax([problem.measure(k, layout)[0, 3] for k in range(problem.n_tasks)]))
    rows = []
    for scale in s.mesh_scales:
        p = problem if scale == 1.0 else load_problem(case, material, mesh_scale=scale)
        rows.append({"mesh_scale": scale, "elements": int(p.model.mesh.t.shape[1]),
                     "dofs": int(sum(fs.basis.N for fs in p.model.fields.values())),
                     "max_u_m": float(p.direct_deformation(task, layout).max_u[0])})
    for a, b in zip(rows, rows[1:]):
        b["change"] = b["max_u_m"] / a["max_u_m"] - 1
    change = rows[-1]["change"]
    return {"layout": layout[0].tolist(), "layout_rule": "each agent's first action", "task": task,
            "rows": rows, "change": change, "limit": s.mesh_tolerance,
            "flagged": bool(abs(change) > s.mesh_tolerance)}


def checked_tasks(problem: Problem, n: int) -> np.ndarray:
    """Up to ``n`` tasks spread evenly over the job (first and last included)."""
    return np.unique(np.linspace(0, problem.n_tasks - 1, min(n, problem.n_tasks)).round().astype(int))


def random_maxima(problem: Problem, s: CheckSettings) -> tuple[np.ndarray, np.ndarray]:
    """Oracle maxima (tasks, layouts, 6) of ``s.layouts`` seeded random layouts (the same on every
    checked task; uncounted), and the checked tasks."""
    layouts = random_layouts(problem, np.random.default_rng(s.seed), s.layouts)
    tasks = checked_tasks(problem, s.tasks)
    return np.stack([problem.measure(int(t), layouts) for t in tasks]), tasks


def deflection(problem: Problem, maxima: np.ndarray, tasks: np.ndarray, s: CheckSettings) -> dict:
    """w/t of the random layouts at the task whose median w/t is largest."""
    ratio = maxima[:, :, 2] / problem.spec.thinnest
    median = np.median(ratio, axis=1)
    k = int(np.argmax(median))
    return {"layouts": s.layouts, "seed": s.seed, "tasks_checked": len(tasks), "task": int(tasks[k]),
            "median_w_over_t": float(median[k]), "best_w_over_t": float(ratio[k].min()),
            "worst_w_over_t": float(ratio[k].max()), "limit": LIMIT, "flagged": bool(median[k] > LIMIT)}


def reward_widths(problem: Problem, maxima: np.ndarray, s: CheckSettings) -> dict:
    """The case's Gaussian widths and suggested ones, with the share of random rewards at 0 or 1."""
    dx, dz = maxima[:, :, 4].ravel(), maxima[:, :, 2].ravel()  # in-plane magnitude and w (Problem.deformation)
    sx, sz = problem.spec.reward_sigma
    med = (float(np.median(dx)), float(np.median(dz)))

    def widths(c: float) -> tuple[float, float]:  # a component no task moves keeps the case's width
        return tuple(c * m if m > 0 else w for m, w in zip(med, (sx, sz)))

    shares = [degenerate_share(gaussian(dx, dz, *widths(c))) for c in s.width_factors]
    c = s.width_factors[int(np.argmin(shares))]  # the first of the best: the smallest factor
    nx, nz = (float(f"{v:.3g}") for v in widths(c))  # 3 significant digits, as a case file would hold them
    share = degenerate_share(gaussian(dx, dz, sx, sz))
    return {"sigma_x_m": sx, "sigma_z_m": sz, "degenerate_share": share,
            "suggested_sigma_x_m": nx, "suggested_sigma_z_m": nz,
            "suggested_degenerate_share": degenerate_share(gaussian(dx, dz, nx, nz)),
            "rewards": int(dx.size), "limit": s.degenerate_limit, "flagged": bool(share > s.degenerate_limit)}


def oracle_times(problem: Problem, s: CheckSettings) -> dict:
    """The oracle's set-up (every candidate's compliance columns, or the disk cache) and its time a
    layout, batched and one at a time, on the middle task, measured here."""
    rng = np.random.default_rng(s.seed)
    t0 = time.perf_counter()
    oracle = problem.oracle
    prepared = oracle.prepare()
    setup = time.perf_counter() - t0
    task = problem.n_tasks // 2
    many = random_layouts(problem, rng, s.batch)
    problem.measure(task, many)  # columns a lazy oracle lacks, and the kernel's compilation, before timing
    batched = median_time(lambda: problem.measure(task, many), 1) / s.batch
    singles = iter(random_layouts(problem, rng, s.single))
    single = median_time(lambda: problem.measure(task, next(singles)[None, :]), s.single)
    return {"setup_s": setup, "from_cache": bool(oracle.from_cache), "prepared": bool(prepared),
            "layout_batched_s": batched, "layout_single_s": single}


def matrix_reference(problem: Problem, evaluations: int, batched: float) -> dict:
    """What ``exact`` does as a matrix's reference (bench/running/cells.py): samples and time, or why not."""
    cfg = ExactConfig()
    if problem.joint_size <= cfg.max_enumeration:
        return {"method": "enumeration", "samples": evaluations, "time_s": evaluations * batched}
    columns = problem.oracle.n_columns(np.arange(len(problem.candidates)))
    if columns <= cfg.max_milp_columns:
        return {"method": "milp", "samples": columns + (len(problem.oracle.fields) + 1) * problem.n_tasks,
                "time_s": cfg.time_limit_s * problem.n_tasks, "time_is": "HiGHS's time limit a task"}
    return {"method": "none", "samples": 0, "time_s": 0.0,
            "why": f"{problem.joint_size:.3g} layouts (over max_enumeration {cfg.max_enumeration:.0e}) and "
                   f"{columns} compliance columns (over max_milp_columns {cfg.max_milp_columns}): a matrix "
                   "leaves the regret columns empty unless a catalog case has a shipped reference"}


def portfolio_cost(problem: Problem, evaluations: int, times: dict) -> dict:
    """Most samples of ``fixbench references build`` with the default :class:`Portfolio`, and their time."""
    eff, T = Portfolio(), problem.n_tasks
    search = (len(MATERIALS) * T  # the shipped references it starts from, re-measured
              + len(eff.seeds) * len(eff.planners) * (eff.samples_per_task + 1) * T
              + eff.max_rounds * T * (eff.exchange + 1 + eff.polish_samples) + T)
    proof = evaluations if evaluations <= eff.prove_limit else 0
    return {"search_samples_at_most": search, "proof_samples": proof, "proven": bool(proof),
            "time_s_low": search * times["layout_batched_s"] + proof * times["layout_batched_s"],
            "time_s_high": search * times["layout_single_s"] + proof * times["layout_batched_s"]}


def reference_cost(problem: Problem, s: CheckSettings) -> dict:
    """Joint size and the cost of the references (see the module docstring)."""
    times = oracle_times(problem, s)
    evaluations = problem.joint_size * problem.n_tasks
    return {"joint_size": problem.joint_size, "tasks": problem.n_tasks, "evaluations": evaluations, **times,
            "matrix": matrix_reference(problem, evaluations, times["layout_batched_s"]),
            "portfolio": portfolio_cost(problem, evaluations, times)}


def warnings(res: dict, s: CheckSettings) -> list[str]:
    """One line per check that failed, each naming the case file."""
    src, out = res["source"], []
    m, d, r = res["mesh"], res["deflection"], res["reward"]
    if m["flagged"]:
        out.append(f"{src}: [mesh]: max |u| changes {m['change']:+.2%} between mesh scales "
                   f"{m['rows'][-2]['mesh_scale']:g} and {m['rows'][-1]['mesh_scale']:g} (task {m['task']}, layout "
                   f"{','.join(map(str, m['layout']))}), over {s.mesh_tolerance:.0%}: refine size_mm")
    if d["flagged"]:
        out.append(f"{src}: geometry.thickness_mm: the median of {d['layouts']} random layouts deflects "
                   f"w/t = {d['median_w_over_t']:.3g} at task {d['task']} (best {d['best_w_over_t']:.3g}), over "
                   f"{LIMIT:g}: outside linear plate theory, the FE deflections are not to be trusted")
    if r["flagged"]:
        out.append(f"{src}: [reward]: {r['degenerate_share']:.0%} of random layouts get a Gaussian reward of 0 or "
                   f"1 with sigma_x {r['sigma_x_m'] * 1e6:g} um, sigma_z {r['sigma_z_m'] * 1e6:g} um; suggested "
                   f"sigma_x_um = {r['suggested_sigma_x_m'] * 1e6:g}, sigma_z_um = "
                   f"{r['suggested_sigma_z_m'] * 1e6:g} ({r['suggested_degenerate_share']:.0%})")
    return out


def text(res: dict) -> list[str]:
    """The figures as lines for a terminal."""
    m, d, r, ref = res["mesh"], res["deflection"], res["reward"], res["reference"]
    lines = [f"{res['case']} ({res['material']}, t = {res['thickness_m'] * 1e3:g} mm; {res['source']}): "
             f"{res['candidates']} candidates, {res['agents']} agents, {res['tasks']} tasks",
             f"mesh convergence: layout {','.join(map(str, m['layout']))} ({m['layout_rule']}), task {m['task']} "
             "(its largest max |u|), direct solves"]
    for row in m["rows"]:
        change = f"  {row['change']:+.2%}" if "change" in row else ""
        lines.append(f"  mesh scale {row['mesh_scale']:<4g} {row['elements']:>7} elements {row['dofs']:>8} DOFs  "
                     f"max |u| {row['max_u_m'] * 1e6:.6g} um{change}")
    lines.append(f"  change between the two finest: {m['change']:+.2%} (warning beyond {m['limit']:.0%})")
    lines.append(f"deflection over thickness: {d['layouts']} random layouts (seed {d['seed']}) on {d['tasks_checked']} "
                 f"tasks; task {d['task']}: median w/t {d['median_w_over_t']:.3g}, best {d['best_w_over_t']:.3g}, "
                 f"worst {d['worst_w_over_t']:.3g} (warning when the median is beyond {d['limit']:g})")
    lines += reference_text(ref)
    lines.append(f"reward widths: case's sigma_x {r['sigma_x_m'] * 1e6:g} um, sigma_z {r['sigma_z_m'] * 1e6:g} um: "
                 f"{r['degenerate_share']:.0%} of {r['rewards']} random rewards at 0 or 1; suggested "
                 f"[reward] sigma_x_um = {r['suggested_sigma_x_m'] * 1e6:g}, sigma_z_um = "
                 f"{r['suggested_sigma_z_m'] * 1e6:g}: {r['suggested_degenerate_share']:.0%}")
    lines.append(f"picture: wrote {res['picture']}")
    return lines


def _count(n: int) -> str:
    """A count in full up to a billion (2,606,420), beyond in three digits (1.3e+14)."""
    return f"{n:,}" if n < 10**9 else f"{n:.3g}"


def reference_text(ref: dict) -> list[str]:
    """The reference section's lines."""
    mx, pf = ref["matrix"], ref["portfolio"]
    setup = "read from the disk cache" if ref["from_cache"] else f"{ref['setup_s']:.3g} s"
    lines = [f"reference phase: {_count(ref['joint_size'])} joint layouts a position x {ref['tasks']} positions = "
             f"{_count(ref['evaluations'])} evaluations",
             f"  oracle here: set-up {setup}; {ref['layout_batched_s'] * 1e6:.3g} us a layout batched, "
             f"{ref['layout_single_s'] * 1e6:.3g} us one at a time"]
    if mx["method"] == "enumeration":
        lines.append(f"  matrix reference (exact): enumeration, {_count(mx['samples'])} samples, "
                     f"about {mx['time_s']:.3g} s")
    elif mx["method"] == "milp":
        lines.append(f"  matrix reference (exact): MILP, {_count(mx['samples'])} samples, at most {mx['time_s']:.3g} s "
                     "(HiGHS's time limit a task)")
    else:
        lines.append(f"  matrix reference (exact): none: {mx['why']}")
    proof = (f" + proof by enumeration {_count(pf['proof_samples'])}" if pf["proven"]
             else " (no proof: over prove_limit; best-known)")
    lines.append("  portfolio (fixbench references build): at most "
                 f"{_count(pf['search_samples_at_most'])} samples{proof}, "
                 f"about {pf['time_s_low']:.3g} to {pf['time_s_high']:.3g} s")
    return lines
