"""Contextual Gaussian-process bandit on local exact GPs: lower confidence bound (``gp-ucb``).

Read top to bottom (cleanrl style): hyper-parameters, the local GP, its best response, the run (fit,
propose, act on held-out tasks). The rounds loop itself (data, round 0, batch size, warm starts,
repeats, budget, held-out tasks) is :mod:`fixbench.solvers.bandits.bandit`'s, shared with ``surrogate-ts``.

References: Srinivas, Krause, Kakade and Seeger, ICML 2010, "Gaussian Process Optimization in the
Bandit Setting" (GP-UCB); Krause and Ong, NeurIPS 2011, "Contextual Gaussian Process Bandit
Optimization" (CGP-UCB: one GP over context x action, a product kernel, the bound played per
context); Desautels, Krause and Burdick, JMLR 2014, "Parallelizing Exploration-Exploitation
Tradeoffs in Gaussian Process Bandit Optimization" (GP-BUCB: a batch chosen by hallucinating the
pending observations); Hvarfner, Hellsten and Nardi, ICML 2024, "Vanilla Bayesian Optimization
Performs Great in High Dimensions" (the dimension-scaled priors of BoTorch's default GP, used here).

The model. One GP of y = log(max |u|) on x = [the task's features
(:func:`fixbench.solvers.encoding.task_features`, scaled by their spread), the layout's pad
coordinates (``Problem.points`` of each agent's action, in agent order, scaled to [-1, 1] in the
candidates' bounding box: :func:`fixbench.solvers.encoding.pad_coordinates`)]. The
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

Rounds, as in ``surrogate-ts`` (:mod:`fixbench.solvers.bandits.bandit`), the tasks of a round proposed and
evaluated task after task, each task's window including what the earlier tasks of the round just
evaluated; the hyper-parameters are refitted every ``fit_every`` rounds. Many small rounds of one
sweep each beat a few large rounds of more sweeps at the same cost (50 wing-panel positions, 100
samples each, seeds 0-1: 6 rounds of 15 with two sweeps 4.8 um, 12 rounds 3.6 um, 30 rounds of 3
with one sweep 3.1 um).

On a task outside the evaluator's tasks (held-out track, zero samples) the layout is the coordinate
descent (at most ``held_out_sweeps``) of its window's posterior MEAN, started from the nearest
training task's best layout.

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
import warnings
from collections.abc import Iterator
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
from fixbench.solvers import descent
from fixbench.solvers.bandits.bandit import BanditConfig, BanditRun, RoundsBandit
from fixbench.solvers.base import TracedEvaluator, at_least, random_layouts, require
from fixbench.solvers.encoding import pad_coordinates
from fixbench.solvers.transfer import nearest_tasks

F64 = torch.float64


# ---------------------------------------------------------------------------------------------
# hyper-parameters (and the loop's: initial_random, tries, samples_per_task, threads in BanditConfig)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GPUCBConfig(BanditConfig):
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

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "window", "fit_every", "fit_tasks", "fit_iters", "screen", "subset", "pool",
                 "held_out_sweeps")
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
        """Descent of mu - cb sigma (``cb`` 0: the mean alone) from every row of ``loc``: per-agent best
        response (:func:`fixbench.solvers.descent.descend`, agents in order, each to its lowest bound, a
        start stopping after a sweep that moved none).

        Returns (final positions, pool): the pool holds every layout scored exactly on the way
        (``loc``, ``mu``, ``var``), the sweeps summed over the starts, and the counts of actions
        scored and scored exactly.
        """
        found, counts = {"loc": [], "mu": [], "var": []}, {"scored": 0, "exact": 0}
        out = descent.descend(lambda i, rows, cur: self.step(i, torch.from_numpy(cur), cb, screen, subset, found,
                                                             counts),
                              loc, range(len(self.E)), max_sweeps=max_sweeps, ties="first", stop="sweep")
        pool = {key: torch.cat(v) for key, v in found.items()} if found["loc"] else found
        return out.layout, {**pool, "sweeps": int(out.sweeps.sum()), **counts}

    def step(self, i: int, cur: torch.Tensor, cb: float, screen: int, subset: int, found: dict,
             counts: dict) -> torch.Tensor:
        """Agent i's bound (``cb`` 0: mean) of every action (Q, actions) for every query, the others at
        ``cur`` (Q, n_agents): the ``screen`` lowest lower bounds scored exactly, then every action whose
        lower bound is below the best exact score; the rest, pruned, ``inf`` (the lowest is exact). The
        layouts scored exactly join ``found``; ``counts`` adds the actions scored and scored exactly."""
        base = sum(self.E[j][cur[:, j]] for j in range(len(self.E)) if j != i)
        base = base if torch.is_tensor(base) else torch.zeros(len(cur), self.n, dtype=F64)
        k = matern52_(base[:, None, :] + self.E[i][None]).mul_(self.kf)  # (Q, actions, n)
        mu = k @ self.alpha
        counts["scored"] += mu.numel()
        if cb == 0:
            return mu
        lb = mu - cb * torch.sqrt(self.variance_bound(k, cur[:, i], subset))
        order = torch.sort(lb, dim=1, stable=True).indices
        score = torch.full_like(mu, math.inf)
        first = torch.zeros_like(mu, dtype=torch.bool)
        first.scatter_(1, order[:, :min(screen, mu.shape[1])], True)
        for rows in (first, None):
            if rows is None:  # second pass: every action that could still beat the best
                rows = (lb < score.amin(1, keepdim=True)) & torch.isinf(score)
            qi, ai = torch.nonzero(rows, as_tuple=True)
            if not len(qi):
                continue
            m, var, _ = self.stats(k[qi, ai])
            score[qi, ai] = m - cb * torch.sqrt(var)
            counts["exact"] += len(qi)
            rows_loc = cur[qi].clone()
            rows_loc[:, i] = ai
            found["loc"].append(rows_loc)
            found["mu"].append(m)
            found["var"].append(var)
        return score

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
# the run: windows, fits, descents of the bound, GP-BUCB batches, the mean on held-out tasks
# ---------------------------------------------------------------------------------------------
class UCBRun(BanditRun):
    """One run of ``gp-ucb`` on the rounds loop (:class:`fixbench.solvers.bandits.bandit.BanditRun`)."""

    clocks = ("fit", "gp", "act", "oracle")  # gp: building the local GPs of the windows

    def __init__(self, cfg: GPUCBConfig, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator):
        super().__init__(cfg, problem, ev, rng)
        self.cb = math.sqrt(cfg.beta)
        # inputs: scaled features; pad coordinates in [-1, 1] of the candidates' bounding box
        self.feats = torch.tensor(self.features, dtype=F64)
        self.pts = torch.tensor(pad_coordinates(problem, interval=(-1.0, 1.0)), dtype=F64)
        # the GP model: product of Matern-5/2 kernels (features x pads), BoTorch's default priors
        self.covar, self.likelihood = gp_modules(self.feats.shape[1], self.pts.shape[1] * self.n)
        self.hyp: Hyper | None = None
        self.fits = self.fit_failures = 0
        self.descents = self.sweeps = self.scored = self.exact = self.pool_picks = 0

    def window(self, task: int) -> np.ndarray:
        """Rows of the ``window`` samples nearest to ``task`` by features (newest first in a task)."""
        out, room = [], self.cfg.window
        for s in nearest_tasks(self.problem, self.ids, task, len(self.ids), self.features):
            take = self.rows_of[int(s)][::-1][:room]
            out += take
            room -= len(take)
            if not room:
                break
        return np.array(out, dtype=np.int64)

    def standardised(self, rows: np.ndarray) -> np.ndarray:
        y = self.y[rows]
        sd = y.std() if len(y) > 1 else 0.0
        return (y - y.mean()) / (sd if sd > 0 else 1.0)

    def fit(self, rnd: int) -> None:
        """The hyper-parameters, refitted every ``fit_every`` rounds."""
        if rnd % self.cfg.fit_every == 0:
            self.hyp = self.fit_hyper()

    def fit_hyper(self) -> Hyper:
        """MAP hyper-parameters on the windows of ``fit_tasks`` random training tasks (warm start)."""
        cfg, rng = self.cfg, self.rng
        with self.timed("fit"):
            anchors = rng.choice(self.ids, size=min(cfg.fit_tasks, len(self.ids)), replace=False)
            rows = np.unique(np.concatenate([self.window(int(a)) for a in anchors]))
            if len(rows) > 1:
                X = self.inputs(rows, self.feats, self.pts)
                Y = torch.from_numpy(self.standardised(rows))[:, None]
                seed = int(rng.integers(2**31 - 1))
                with torch.random.fork_rng(devices=[]), warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    torch.manual_seed(seed)  # BoTorch's retries draw from torch's global generator
                    model = SingleTaskGP(X, Y, likelihood=self.likelihood, covar_module=self.covar,
                                         mean_module=ZeroMean(), outcome_transform=None)
                    try:
                        fit_gpytorch_mll(ExactMarginalLogLikelihood(self.likelihood, model),
                                         optimizer_kwargs={"options": {"maxiter": cfg.fit_iters}})
                    except ModelFittingError:  # parameters rolled back to the previous fit's
                        self.fit_failures += 1
                self.fits += 1
            return to_hyper(self.covar, self.likelihood, self.feats, self.pts, self.sets)

    def local_gp(self, task: int) -> LocalGP:
        with self.timed("gp"):
            rows = self.window(task)
            return LocalGP(self.hyp, task, self.task[rows], self.pos[self.act[rows]], self.standardised(rows))

    def propose(self, tasks: np.ndarray, counts: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """Task after task (each window holds what the tasks before it in the round just evaluated)."""
        for t, c in zip(tasks.tolist(), counts.tolist()):
            gp = self.local_gp(t)
            with self.timed("act"):
                layouts = self.ucb_batch(gp, t, c)
            yield t, layouts

    def ucb_batch(self, gp: LocalGP, task: int, c: int) -> np.ndarray:
        """``c`` layouts: the descents of the bound from the task's starts, GP-BUCB picks from their pool,
        then random neighbours of the task's best when the pool is used up."""
        cfg = self.cfg
        starts = self.starts(task)
        _, pool = gp.descend(self.pos[starts], self.cb, cfg.max_sweeps, cfg.screen, cfg.subset)
        self.descents += len(starts)
        self.sweeps += pool["sweeps"]
        self.scored += pool["scored"]
        self.exact += pool["exact"]
        taken = set()
        picks = gp.batch(pool, self.cb, c, cfg.pool, self.sets, self.seen[task], taken) if pool["exact"] else \
            np.empty((0, self.n), dtype=np.int64)
        self.pool_picks += len(picks)
        layouts = self.layouts_of(picks)
        if len(layouts) < c:  # pool used up: random neighbours of the task's best
            ev = self.ev
            base = ev.best_layout[task] if np.isfinite(ev.best[task]) else random_layouts(self.problem, self.rng, 1)[0]
            layouts = np.vstack([layouts, self.unrepeated(task, np.tile(base, (c - len(layouts), 1)), taken)])
        return layouts

    def act_held_out(self, held: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, int]:
        """The descent of each held-out task's window's posterior mean (at most ``held_out_sweeps``)."""
        if self.hyp is None:
            self.hyp = self.fit_hyper()
        layouts, sweeps = np.zeros((len(held), self.n), dtype=np.int64), 0
        for j, t in enumerate(held.tolist()):
            gp = self.local_gp(t)
            with self.timed("act"):
                local, pool = gp.descend(self.pos[starts[j]][None], 0.0, self.cfg.held_out_sweeps, self.cfg.screen, 0)
                layouts[j] = self.layouts_of(local)[0]
                sweeps += pool["sweeps"]
        return layouts, sweeps

    def model_info(self) -> dict:
        return {
            "fits": self.fits,
            "fit_failures": self.fit_failures,
            "lengthscales_features": self.covar.kernels[0].lengthscale.detach()[0].tolist(),
            "lengthscales_pads": self.covar.kernels[1].lengthscale.detach()[0].tolist(),
            "noise": float(self.likelihood.noise.detach()[0]),
            "descents": self.descents,
            "sweeps_mean": self.sweeps / self.descents if self.descents else 0.0,
            "exact_fraction": self.exact / self.scored if self.scored else 0.0,
            "pool_picks": self.pool_picks,
        }


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class GPUCB(RoundsBandit):
    name = "gp-ucb"
    family = "bandit"
    description = "Contextual GP bandit (CGP-UCB, batched by GP-BUCB) on local exact GPs of log-deformation"
    Config = GPUCBConfig
    modes = ("per-task",)
    Run = UCBRun
