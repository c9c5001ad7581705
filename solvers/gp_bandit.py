"""Contextual Gaussian-process bandit on local exact GPs: lower confidence bound (``gp-ucb``).

Read top to bottom (cleanrl style): hyper-parameters, the local GP, its best response, the loop.

References: Srinivas, Krause, Kakade and Seeger, ICML 2010, "Gaussian Process Optimization in the
Bandit Setting" (GP-UCB); Krause and Ong, NeurIPS 2011, "Contextual Gaussian Process Bandit
Optimization" (CGP-UCB: one GP over context x action, a product kernel, the bound played per
context); Desautels, Krause and Burdick, JMLR 2014, "Parallelizing Exploration-Exploitation
Tradeoffs in Gaussian Process Bandit Optimization" (GP-BUCB: a batch chosen by hallucinating the
pending observations); Hvarfner, Hellsten and Nardi, ICML 2024, "Vanilla Bayesian Optimization
Performs Great in High Dimensions" (the dimension-scaled priors of BoTorch's default GP, used here).

The model. One GP of y = log(max |u|) on x = [the task's features
(:func:`fixbench.solvers.transfer.scaled_features`), the layout's pad coordinates (``Problem.points``
of each agent's action, in agent order, scaled to [-1, 1] in the candidates' bounding box)]. The
task is the bandit's context, the layout its action. The kernel is a product (CGP-UCB's choice):
Matern-5/2 with ARD over the features times Matern-5/2 with ARD over the pad coordinates (one
length scale per coordinate of every agent), each on its own inputs (``active_dims``), no output
scale (the targets are standardised), a Gaussian likelihood. Hyper-parameters: BoTorch's
``fit_gpytorch_mll`` (L-BFGS on the exact marginal likelihood, with BoTorch's default LogNormal
priors, i.e. a MAP estimate) once per ``fit_every`` rounds, on the union of the windows (below) of
``fit_tasks`` training tasks drawn at random, warm-started from the previous fit; reused by every
task until the next fit. All GP arithmetic is float64.

Local windows. Exact inference is cubic in the data, and 100 samples on each of 500 positions are
50,000 points: every task is planned on its own exact GP, fitted on a WINDOW of the ``window``
samples nearest to it by feature distance (its own samples and its nearest tasks'; the newest first
within a task). The window's targets are standardised by their own mean and deviation, so the prior
mean of an unexplored layout is the window's mean log-deformation. A window of 192 is what the cost
target allows (below); 128 to 256 changed little on a 50-position wing panel.

Acquisition: the lower confidence bound mu(x) - sqrt(beta) sigma(x) of the log-deformation (UCB for
a minimisation), minimised over the joint layout space (hundreds of candidates per agent to the
power of the agents) by per-agent coordinate descent (Gauss-Seidel: each agent in turn takes the
action of its own set ``problem.action_sets[i]`` with the lowest bound, the others fixed; sweeps
until one changes nothing, at most ``max_sweeps``), from the task's incumbent, the best layouts of
the ``transfer`` nearest solved tasks (:func:`fixbench.solvers.transfer.warm_layouts`) and one
uniform random layout, all descended at once. One agent's step scores its whole action set with
the others fixed: the squared pad distance of a layout to a window sample is a sum over agents, so
each agent's distances to the window are tabulated once per window and a step is a table lookup,
an addition, the kernel and a product. The variance is the cost (actions x window^2 per step); it
is computed exactly only where it can matter. Conditioning on part of the data never lowers the
variance, so the variance given the one most correlated window sample, and the variance given the
``subset`` window samples most correlated with the current layout, are upper bounds of it; with
the exact mean they give a lower bound of the confidence bound. The ``screen`` actions with the
lowest lower bound are scored exactly, then every action whose lower bound is still below the best
exact score: the argmin is exact (certified), the rest (about 80 % on the wing panel) is pruned.

Batches (GP-BUCB). A round gives a task ``c`` samples at once. The bound is deterministic, so the
``c`` proposals are chosen among the ``pool`` distinct layouts of lowest bound that the descents
scored exactly (the descents' ends and the best single-agent moves around them): the one with the
lowest bound, then the posterior is conditioned on it as if observed (its mean unchanged, the other
layouts' variances reduced by a rank-one update), the next lowest bound, and so on: the batch
spreads instead of piling onto one layout. A layout already evaluated on the task is skipped for
the next best of the pool (rather than moved to a random neighbour: the pool holds scored
alternatives); only when the pool is used up are the rest random neighbours of the task's best (one
agent's action changed at random, repeatedly, until new; after ``tries`` changes a repeat is
accepted: a tiny joint space can be used up).

Rounds, as in ``surrogate-ts``: round 0 gives every training task ``initial_random`` uniform random
layouts; every later round gives every training task a batch of ``batch`` samples (larger when the
budget is large, so that there are at most ``max_rounds`` rounds), task after task, each task's
window including what the earlier tasks of the round just evaluated; the hyper-parameters are
refitted every ``fit_every`` rounds. Many small rounds of one sweep each beat a few large rounds of
more sweeps at the same cost (50 wing-panel positions, 100 samples each, seeds 0-1: 6 rounds of 15
with two sweeps 4.8 um, 12 rounds 3.6 um, 30 rounds of 3 with one sweep 3.1 um).

Budget: split equally over the training tasks (``split_budget``; ``samples_per_task`` each when
unlimited), spent exactly; at least one sample per training task, else :class:`PlannerError`.
Per-task mode only. Returned layouts: on a training task the best layout evaluated there; on a task
outside the evaluator's tasks (held-out track, zero samples) the coordinate descent (at most
``held_out_sweeps``) of its window's posterior MEAN, started from the nearest training task's best
layout.

Measured (one thread, a shared 2-core machine, the oracle prepared beforehand): wing_panel (5
agents, 500 tasks) at 100 samples a task, seed 0: mean max |u| 2.88 um (random search 21.8 um,
surrogate-ts 2.61 um) in 498 s, of which acquisition 430 s, windows 42 s, fits 17 s, oracle 5 s
(30 rounds: 2.93 um in 569 s; 30 rounds without the warm start, ``transfer`` 0: 2.92 um in 427 s).
wing_panel_small at 100 a task, seeds 0-2: 18.1 um (random search 41.8 um, surrogate-ts 18.7 um).

Randomness: ``rng`` only (and torch's global generator seeded from it around each fit, for BoTorch's
retries); torch's threads are set to ``threads`` and deterministic algorithms are asked for during
the run (both restored after), so the same seed gives the same bits.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from botorch.exceptions import ModelFittingError
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.utils.gpytorch_modules import (
    get_covar_module_with_dim_scaled_prior,
    get_gaussian_likelihood_with_lognormal_prior,
)
from gpytorch.means import ZeroMean
from gpytorch.mlls import ExactMarginalLogLikelihood

from fixbench.cases.problem import Problem
from fixbench.solvers.base import (
    Planner,
    PlannerConfig,
    TracedEvaluator,
    at_least,
    random_layouts,
    require,
    require_budget,
    split_budget,
)
from fixbench.solvers.registry import register
from fixbench.solvers.surrogate import move_repeats, pad_coordinates, set_positions
from fixbench.solvers.torch_run import torch_run
from fixbench.solvers.transfer import nearest_tasks, scaled_features, warm_layouts

F64 = torch.float64


# ---------------------------------------------------------------------------------------------
# hyper-parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GPUCBConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "beta": ("log", 0.25, 16.0),
        "window": ("choice", [128, 192, 256]),
        "batch": ("int", 2, 10),
        "initial_random": ("int", 3, 20),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    window: int = 192
    """Samples in each task's exact GP: the nearest by task features (own task first), newest first."""

    beta: float = 4.0
    """Exploration weight: the bound is mu - sqrt(beta) sigma of the standardised log-deformation."""

    initial_random: int = 10
    """Uniform random layouts per training task before the GP is first used (round 0)."""

    batch: int = 3
    """Samples per training task per round (raised so that there are at most ``max_rounds`` rounds)."""

    max_rounds: int = 24
    """Most rounds after round 0: bounds the number of descents and fits at large budgets."""

    fit_every: int = 3
    """Rounds between two fits (MAP, BoTorch's priors) of the hyper-parameters (reused in between)."""

    fit_tasks: int = 2
    """A fit is on the union of the windows of this many training tasks drawn at random."""

    fit_iters: int = 50
    """Most L-BFGS iterations per fit."""

    transfer: int = 1
    """Descents also start from the best layouts of this many solved tasks nearest by features."""

    max_sweeps: int = 1
    """Most Gauss-Seidel sweeps over the agents per descent."""

    screen: int = 32
    """Actions per agent step (lowest lower bounds) whose variance is computed before any is pruned."""

    subset: int = 32
    """Window samples (the most correlated with the current layout) of the cheap variance bound that prunes."""

    pool: int = 256
    """A batch is chosen among this many distinct scored layouts of lowest bound (at least its size)."""

    held_out_sweeps: int = 10
    """Most sweeps of the posterior-mean descent on a held-out task (no variance: cheap)."""

    tries: int = 50
    """Random one-agent changes tried to turn a repeated layout into a new one before accepting it."""

    samples_per_task: int = 100
    """Samples per training task when the budget is unlimited."""

    threads: int = 1
    """torch intra-op threads during the run (0: torch's setting); restored afterwards."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "window", "initial_random", "batch", "fit_every", "fit_tasks", "fit_iters", "max_sweeps",
                 "screen", "subset", "pool", "held_out_sweeps", "samples_per_task")
        at_least(self, 0, "max_rounds", "transfer", "tries", "threads")
        require(self, "beta", self.beta > 0, "positive")


# ---------------------------------------------------------------------------------------------
# the local GP: exact posterior of one window, queried for layouts of one task
# ---------------------------------------------------------------------------------------------
def matern52(r2: torch.Tensor) -> torch.Tensor:
    """Matern-5/2 correlation of a squared scaled distance (as gpytorch's MaternKernel, nu = 2.5)."""
    r2 = r2.clamp_min(0.0)
    s = torch.sqrt(5.0 * r2)
    return (1.0 + s + (5.0 / 3.0) * r2) * torch.exp(-s)


def matern52_(r2: torch.Tensor) -> torch.Tensor:
    """:func:`matern52` in place on a fresh tensor (the hot loop's kernel: fewer passes and copies)."""
    s = r2.clamp_min_(0.0).mul(5.0).sqrt_()
    r2.mul_(5.0 / 3.0).add_(s).add_(1.0)
    return r2.mul_(s.neg_().exp_())


def sqdist(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(len(a), len(b)) squared distances of two sets of (already scaled) points."""
    return torch.addmm((b * b).sum(1)[None, :], a, b.T, alpha=-2.0).add_((a * a).sum(1)[:, None]).clamp_min_(0.0)


@dataclass
class Hyper:
    """Fitted hyper-parameters in the form the local GPs use: inputs divided by their length scales."""

    feats: torch.Tensor  # (n_tasks, F) scaled task features / feature length scales
    coords: list[torch.Tensor]  # per agent: (actions, d) its actions' pad coordinates / their length scales
    noise: float  # likelihood noise variance (standardised units)


def gp_modules(n_feats: int, n_pads: int):
    """(kernel, likelihood) of the GP on x = [features (n_feats), pad coordinates (n_pads)]: Matern-5/2
    with ARD over each part (``active_dims``), multiplied; BoTorch's dimension-scaled LogNormal length
    scale priors and LogNormal noise prior (its defaults, Hvarfner et al. 2024); float64."""
    kf = get_covar_module_with_dim_scaled_prior(n_feats, use_rbf_kernel=False, active_dims=list(range(n_feats)))
    kp = get_covar_module_with_dim_scaled_prior(n_pads, use_rbf_kernel=False,
                                                active_dims=list(range(n_feats, n_feats + n_pads)))
    return (kf * kp).to(F64), get_gaussian_likelihood_with_lognormal_prior().to(F64)


def to_hyper(covar, likelihood, feats: torch.Tensor, pts: torch.Tensor, sets: list[np.ndarray]) -> Hyper:
    """The fitted modules' hyper-parameters as the local GPs use them: ``feats`` (n_tasks, F) and each
    agent's actions' pad coordinates ``pts`` (n_options, d) divided by their length scales."""
    with torch.no_grad():
        lf = covar.kernels[0].lengthscale.detach()[0]
        lp = covar.kernels[1].lengthscale.detach()[0].reshape(len(sets), -1)
        coords = [pts[torch.from_numpy(a)] / lp[i] for i, a in enumerate(sets)]
        return Hyper(feats / lf, coords, float(likelihood.noise.detach()[0]))


class LocalGP:
    """The exact GP posterior of one window of samples, for layouts of one task (prior variance 1).

    Layouts are given as ``loc`` (M, n_agents): each agent's position in its own action set.
    ``E[i]`` (actions of agent i, n) holds the squared scaled pad distance of each of agent i's
    actions to each window sample's agent-i pads: a layout's squared pad distance to the window is
    the sum of its agents' rows.
    """

    def __init__(self, hyp: Hyper, task: int, w_task: np.ndarray, w_loc: np.ndarray, y: np.ndarray):
        n = len(w_task)
        self.noise = hyp.noise
        self.coords = hyp.coords
        w_loc = torch.from_numpy(w_loc)
        self.E = [sqdist(c, c[w_loc[:, i]]) for i, c in enumerate(hyp.coords)]
        fw = hyp.feats[torch.from_numpy(w_task)]
        self.kf = matern52(((fw - hyp.feats[task]) ** 2).sum(1))  # (n,) task part of k(x, window)
        rp = sum(e[w_loc[:, i]] for i, e in enumerate(self.E))
        K = matern52(sqdist(fw, fw)) * matern52(rp)
        K.diagonal().add_(hyp.noise)
        self.K = K
        jitter, eye = 0.0, torch.eye(n, dtype=F64)
        L, info = torch.linalg.cholesky_ex(K)
        while info.item():  # numerically not positive definite: jitter, as gpytorch does
            jitter = max(1e-8, 10 * jitter)
            L, info = torch.linalg.cholesky_ex(K + jitter * eye)
        self.alpha = torch.cholesky_solve(torch.from_numpy(y)[:, None], L)[:, 0]
        self.linv_t = torch.linalg.solve_triangular(L, eye, upper=False).T.contiguous()
        self.n = n

    def kernel(self, loc: torch.Tensor) -> torch.Tensor:
        """k(x, window) (M, n) of layouts ``loc`` on this task."""
        return self.kf * matern52(sum(e[loc[:, i]] for i, e in enumerate(self.E)))

    def stats(self, k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(mean, variance, V = L^-1 k) of the latent log-deformation from k(x, window) (M, n)."""
        V = k @ self.linv_t
        return k @ self.alpha, (1.0 - (V * V).sum(-1)).clamp_min(1e-12), V

    def descend(self, loc: np.ndarray, cb: float, max_sweeps: int, screen: int,
                subset: int) -> tuple[np.ndarray, dict]:
        """Gauss-Seidel descent of mu - cb sigma (``cb`` 0: the mean alone) from every row of ``loc``.

        Returns (final positions, pool): the pool holds every layout scored exactly on the way
        (``loc``, ``mu``, ``var``), the sweeps summed over the starts, and the counts of actions
        scored and scored exactly.
        """
        loc = torch.from_numpy(loc.copy())
        active = torch.arange(len(loc))
        pool = {"loc": [], "mu": [], "var": []}
        sweep = sweeps = scored = exact = 0
        while len(active) and sweep < max_sweeps:
            sweep, sweeps = sweep + 1, sweeps + len(active)
            changed = torch.zeros(len(active), dtype=torch.bool)
            for i, e in enumerate(self.E):
                cur = loc[active]
                base = sum(self.E[j][cur[:, j]] for j in range(len(self.E)) if j != i)
                base = base if torch.is_tensor(base) else torch.zeros(len(cur), self.n, dtype=F64)
                k = matern52_(base[:, None, :] + e[None]).mul_(self.kf)  # (Q, actions, n)
                mu = k @ self.alpha
                q_n, a_n = mu.shape
                scored += mu.numel()
                if cb == 0:
                    best = torch.argmin(mu, dim=1)
                else:
                    lb = mu - cb * torch.sqrt(self.variance_bound(k, cur[:, i], subset))
                    order = torch.sort(lb, dim=1, stable=True).indices
                    score = torch.full_like(mu, math.inf)
                    first = torch.zeros_like(mu, dtype=torch.bool)
                    first.scatter_(1, order[:, :min(screen, a_n)], True)
                    for rows in (first, None):
                        if rows is None:  # second pass: every action that could still beat the best
                            rows = (lb < score.amin(1, keepdim=True)) & torch.isinf(score)
                        qi, ai = torch.nonzero(rows, as_tuple=True)
                        if not len(qi):
                            continue
                        m, var, _ = self.stats(k[qi, ai])
                        score[qi, ai] = m - cb * torch.sqrt(var)
                        exact += len(qi)
                        rows_loc = cur[qi].clone()
                        rows_loc[:, i] = ai
                        pool["loc"].append(rows_loc)
                        pool["mu"].append(m)
                        pool["var"].append(var)
                    best = torch.argmin(score, dim=1)
                changed |= best != cur[:, i]
                loc[active, i] = best
            active = active[changed]
        if pool["loc"]:
            pool = {key: torch.cat(v) for key, v in pool.items()}
        pool.update(sweeps=sweeps, scored=scored, exact=exact)
        return loc.numpy(), pool

    def variance_bound(self, k: torch.Tensor, cur: torch.Tensor, subset: int) -> torch.Tensor:
        """Upper bounds (Q, actions) of the posterior variance from k(x, window) (Q, actions, n).

        Conditioning on part of the data never lowers the variance: the bound is the smaller of the
        variance given the one most correlated window sample and the variance given the ``subset``
        window samples most correlated with the query's current action ``cur`` (Q,).
        """
        kmax = k.amax(-1)
        ub = 1.0 - kmax * kmax / (1.0 + self.noise)
        s = min(subset, self.n)
        if s > 1:
            S = torch.topk(k[torch.arange(len(k)), cur], s, dim=1).indices  # (Q, s)
            L, info = torch.linalg.cholesky_ex(self.K[S[:, :, None], S[:, None, :]])
            if not info.any():
                kS = torch.gather(k, 2, S[:, None, :].expand(-1, k.shape[1], -1))
                W = torch.linalg.solve_triangular(L, kS.transpose(1, 2), upper=False)
                ub = torch.minimum(ub, 1.0 - (W * W).sum(1))
        return ub.clamp_min(1e-12)

    def batch(self, pool: dict, cb: float, c: int, size: int, sets: list[np.ndarray], done: set,
              taken: set) -> np.ndarray:
        """GP-BUCB over the pool: up to ``c`` layouts (positions, (m, n_agents)) of the ``size`` distinct
        pool rows of lowest bound, each the lowest bound after hallucinating the earlier picks as
        observed. A layout (global actions) in ``done`` or ``taken`` is skipped; a pick joins ``taken``."""
        loc = pool["loc"].numpy()
        _, first = np.unique(loc, axis=0, return_index=True)
        first = np.sort(first)
        score = (pool["mu"] - cb * torch.sqrt(pool["var"]))[torch.from_numpy(first)].numpy()
        loc = torch.from_numpy(loc[first[np.argsort(score, kind="stable")[:max(size, c)]]])
        mu, var, V = self.stats(self.kernel(loc))
        x = torch.cat([c_[loc[:, i]] for i, c_ in enumerate(self.coords)], 1)  # scaled pads of the rows
        used = torch.zeros(len(mu), dtype=torch.bool)
        picks, U = [], []
        while len(picks) < c:
            score = torch.where(used, math.inf, mu - cb * torch.sqrt(var))
            p = int(torch.argmin(score))
            if math.isinf(float(score[p])):
                break
            used[p] = True
            key = tuple(int(sets[i][a]) for i, a in enumerate(loc[p].tolist()))
            if key in done or key in taken:
                continue
            taken.add(key)
            picks.append(p)
            cov = matern52(((x - x[p]) ** 2).sum(1)) - V @ V[p]  # same task: the feature part is 1
            for u in U:
                cov -= u * u[p]
            u = cov / math.sqrt(float(var[p]) + self.noise)
            U.append(u)
            var = (var - u * u).clamp_min(1e-12)
        return loc[picks].numpy().reshape(-1, loc.shape[1])


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
@register
class GPUCB(Planner):
    name = "gp-ucb"
    family = "bandit"
    description = "Contextual GP bandit (CGP-UCB, batched by GP-BUCB) on local exact GPs of log-deformation"
    Config = GPUCBConfig
    modes = ("per-task",)
    same_on_every_host = False

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        require_budget(self.name, ev.remaining, len(ev.tasks), "one layout per task")
        with torch_run(cfg.threads):
                return self._run(problem, ev, rng)

    def _run(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator):
        cfg, n, sets = self.config, problem.n_agents, problem.action_sets
        cb = math.sqrt(cfg.beta)
        t_start = time.perf_counter()
        t_fit = t_gp = t_act = t_oracle = 0.0

        # inputs: scaled features; pad coordinates in [-1, 1] of the candidates' bounding box
        f_np = scaled_features(problem)
        feats = torch.tensor(f_np, dtype=F64)
        pts = torch.tensor(pad_coordinates(problem), dtype=F64)
        d_pad = pts.shape[1]  # pad coordinates of one agent's action
        pos = set_positions(problem)

        # the data: every evaluated (task, layout) and its log max deformation
        ids = ev.tasks
        shares = np.array(split_budget(ev.budget, len(ids), cfg.samples_per_task))
        cap = int(shares.sum())
        D_task = np.zeros(cap, dtype=np.int64)
        D_act = np.zeros((cap, n), dtype=np.int64)
        D_y = np.zeros(cap)
        size = 0
        rows_of = {int(t): [] for t in ids}
        seen = {int(t): set() for t in ids}

        def evaluate(task: int, layouts: np.ndarray) -> None:
            nonlocal size, t_oracle
            t0 = time.perf_counter()
            u = ev.evaluate(task, layouts).max_u
            t_oracle += time.perf_counter() - t0
            m = len(layouts)
            D_task[size:size + m] = task
            D_act[size:size + m] = layouts
            D_y[size:size + m] = np.log(np.maximum(u, 1e-30))
            rows_of[task].extend(range(size, size + m))
            size += m
            seen[task].update(map(tuple, layouts.tolist()))

        def window(task: int) -> np.ndarray:
            """Rows of the ``window`` samples nearest to ``task`` by features (newest first in a task)."""
            out, room = [], cfg.window
            for s in nearest_tasks(problem, ids, task, len(ids), f_np):
                rows = rows_of[int(s)]
                take = rows[::-1][:room]
                out += take
                room -= len(take)
                if not room:
                    break
            return np.array(out, dtype=np.int64)

        def standardised(rows: np.ndarray) -> np.ndarray:
            y = D_y[rows]
            sd = y.std() if len(y) > 1 else 0.0
            return (y - y.mean()) / (sd if sd > 0 else 1.0)

        # the GP model: product of Matern-5/2 kernels (features x pads), BoTorch's default priors
        covar, likelihood = gp_modules(feats.shape[1], n * d_pad)
        fits = fit_failures = 0

        def fit() -> Hyper:
            """MAP hyper-parameters on the windows of ``fit_tasks`` random training tasks (warm start)."""
            nonlocal t_fit, fits, fit_failures
            t0 = time.perf_counter()
            anchors = rng.choice(ids, size=min(cfg.fit_tasks, len(ids)), replace=False)
            rows = np.unique(np.concatenate([window(int(a)) for a in anchors]))
            if len(rows) > 1:
                X = torch.cat([feats[torch.from_numpy(D_task[rows])],
                               pts[torch.from_numpy(D_act[rows])].reshape(len(rows), -1)], 1)
                Y = torch.from_numpy(standardised(rows))[:, None]
                seed = int(rng.integers(2**31 - 1))
                with torch.random.fork_rng(devices=[]), warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    torch.manual_seed(seed)  # BoTorch's retries draw from torch's global generator
                    model = SingleTaskGP(X, Y, likelihood=likelihood, covar_module=covar, mean_module=ZeroMean(),
                                         outcome_transform=None)
                    try:
                        fit_gpytorch_mll(ExactMarginalLogLikelihood(likelihood, model),
                                         optimizer_kwargs={"options": {"maxiter": cfg.fit_iters}})
                    except ModelFittingError:  # parameters rolled back to the previous fit's
                        fit_failures += 1
                fits += 1
            t_fit += time.perf_counter() - t0
            return to_hyper(covar, likelihood, feats, pts, sets)

        def local_gp(hyp: Hyper, task: int) -> LocalGP:
            nonlocal t_gp
            t0 = time.perf_counter()
            rows = window(task)
            gp = LocalGP(hyp, task, D_task[rows], pos[D_act[rows]], standardised(rows))
            t_gp += time.perf_counter() - t0
            return gp

        # round 0: uniform random layouts seed the model
        left = shares.copy()
        moved = 0
        for t, s in zip(ids, shares):
            m = min(cfg.initial_random, int(s))
            if m:
                layouts, k = move_repeats(random_layouts(problem, rng, m), seen[int(t)], set(), sets, rng, cfg.tries)
                moved += k
                evaluate(int(t), layouts)
        left -= np.minimum(cfg.initial_random, shares)

        # rounds: refit, then every training task gets a batch: descents of the bound, GP-BUCB picks
        batch = max(cfg.batch, math.ceil(int(left.max(initial=0)) / max(cfg.max_rounds, 1)))
        rounds = descents = sweeps_sum = scored = exact = pool_picks = 0
        hyp = None
        while left.any():
            if hyp is None or rounds % cfg.fit_every == 0:
                hyp = fit()
            rounds += 1
            counts = np.minimum(left, batch)
            for t, c in zip(ids, counts):
                if not c:
                    continue
                t, c = int(t), int(c)
                gp = local_gp(hyp, t)
                t0 = time.perf_counter()
                starts = [ev.best_layout[t][None]] if np.isfinite(ev.best[t]) else []
                starts.append(warm_layouts(problem, ev.best, ev.best_layout, t, cfg.transfer))
                starts.append(random_layouts(problem, rng, 1))
                starts = np.vstack(starts)
                _, first = np.unique(starts, axis=0, return_index=True)
                starts = starts[np.sort(first)]
                _, pool = gp.descend(pos[starts], cb, cfg.max_sweeps, cfg.screen, cfg.subset)
                descents += len(starts)
                sweeps_sum += pool["sweeps"]
                scored += pool["scored"]
                exact += pool["exact"]
                proposals, taken = [], set()
                if pool["exact"]:
                    picks = gp.batch(pool, cb, c, cfg.pool, sets, seen[t], taken)
                    proposals = [[sets[i][a] for i, a in enumerate(row)] for row in picks.tolist()]
                    pool_picks += len(picks)
                if len(proposals) < c:  # pool used up: random neighbours of the task's best
                    base = ev.best_layout[t] if np.isfinite(ev.best[t]) else random_layouts(problem, rng, 1)[0]
                    extra, k = move_repeats(np.tile(base, (c - len(proposals), 1)), seen[t], taken, sets, rng,
                                            cfg.tries)
                    moved += k
                    proposals += list(extra)
                t_act += time.perf_counter() - t0
                evaluate(t, np.array(proposals, dtype=np.int64).reshape(c, n))
            left -= counts

        # layouts: the best evaluated on each training task; the posterior mean's descent elsewhere
        layouts = ev.best_layout.copy()
        held = np.setdiff1d(np.arange(problem.n_tasks), ids)
        held_sweeps = 0
        if len(held):
            if hyp is None:
                hyp = fit()
            for t in held:
                src = nearest_tasks(problem, ids, int(t), 1, f_np)[0]
                gp = local_gp(hyp, int(t))
                t0 = time.perf_counter()
                local, pool = gp.descend(pos[ev.best_layout[src]][None], 0.0, cfg.held_out_sweeps, cfg.screen, 0)
                layouts[t] = [sets[i][local[0, i]] for i in range(n)]
                held_sweeps += pool["sweeps"]
                t_act += time.perf_counter() - t0
        per_task = ev.task_samples[ids]
        info = {
            "samples_per_task": int(per_task.min()) if per_task.min() == per_task.max() else per_task.tolist(),
            "rounds": rounds,
            "batch": int(batch),
            "fits": fits,
            "fit_failures": fit_failures,
            "lengthscales_features": covar.kernels[0].lengthscale.detach()[0].tolist(),
            "lengthscales_pads": covar.kernels[1].lengthscale.detach()[0].tolist(),
            "noise": float(likelihood.noise.detach()[0]),
            "descents": descents,
            "sweeps_mean": sweeps_sum / descents if descents else 0.0,
            "exact_fraction": exact / scored if scored else 0.0,
            "pool_picks": pool_picks,
            "held_out_sweeps": held_sweeps,
            "repeats_moved": int(moved),
            "time_fit_s": t_fit,
            "time_gp_s": t_gp,
            "time_act_s": t_act,
            "time_oracle_s": t_oracle,
            "time_total_s": time.perf_counter() - t_start,
            "torch_threads": torch.get_num_threads(),
        }
        return layouts, info
