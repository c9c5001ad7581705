"""gp-ucb: exact budget, same seed -> same bits, the local GP equals BoTorch's, certified pruning,
better than random search, held-out track."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from botorch.models import SingleTaskGP
from gpytorch.means import ZeroMean

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers.bandits.gp_bandit import GPUCB, LocalGP, gp_modules, to_hyper
from fixbench.solvers.base import PlannerError


@pytest.fixture(scope="module")
def problem():
    return Problem(load_case_spec("wing_panel_small"))


def test_spends_exactly_its_budget_and_repeats_bit_for_bit(problem):
    small = Problem(problem.spec.with_tasks([0, 2]))
    budget = 2 * 37 + 1  # uneven shares: 38 and 37 samples
    threads = torch.get_num_threads()
    first = GPUCB(fit_iters=10).solve(small, budget, seed=5)
    again = GPUCB(fit_iters=10).solve(small, budget, seed=5)
    assert torch.get_num_threads() == threads
    assert first.samples == budget and first.info["samples_per_task"] == [38, 37]
    assert first.info["rounds"] > 1 and first.info["fits"] == -(-first.info["rounds"] // 3)  # fit_every 3
    assert first.info["pool_picks"] > 0
    np.testing.assert_array_equal(first.layouts, again.layouts)
    np.testing.assert_array_equal(first.trace, again.trace)  # every sample's best, in order
    np.testing.assert_array_equal(first.max_deformation, again.max_deformation)
    assert first.info["lengthscales_pads"] == again.info["lengthscales_pads"]
    assert first.training.values("round_samples")[-1] == budget  # round 0 and the rounds, the last spends it all
    assert len(first.training.values("round_best_mean_u")) == first.info["rounds"] + 1
    other = GPUCB(fit_iters=10).solve(small, budget, seed=6)
    assert not np.array_equal(first.trace, other.trace)


def test_refuses_a_budget_below_one_sample_a_task(problem):
    with pytest.raises(PlannerError, match="budget too small"):
        GPUCB().solve(problem, problem.n_tasks - 1, seed=0)
    with pytest.raises(PlannerError, match="does not support mode 'shared'"):
        GPUCB().solve(problem, 100, seed=0, mode="shared")
    with pytest.raises(PlannerError, match="window"):
        GPUCB(window=0).solve(problem, 100, seed=0)


def test_held_out_tasks_without_a_round_get_the_posterior_means_layout_and_no_sample(problem):
    """A budget inside round 0: the hyper-parameters are fitted once for the held-out tasks."""
    train, budget = [0, 2], 2 * 4
    first = GPUCB(fit_iters=10).solve(problem, budget, seed=3, train_tasks=train)
    again = GPUCB(fit_iters=10).solve(problem, budget, seed=3, train_tasks=train)
    assert first.samples == budget and set(first.trace[:, 0].astype(int)) == set(train)
    np.testing.assert_array_equal(first.held_out, [1, 3])
    assert first.info["rounds"] == 0 and first.info["fits"] == 1 and first.info["descents"] == 0
    assert "held_out_from" not in first.info and first.info["held_out_sweeps"] >= 2
    np.testing.assert_array_equal(first.layouts, again.layouts)


def _random_gp(seed: int, sizes=(6, 7, 5), n_tasks=4, n_window=30):
    """A LocalGP on a random window, the BoTorch model on the same data, and their inputs."""
    g = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    feats = torch.rand(n_tasks, 2, generator=g, dtype=torch.float64)
    pts = torch.rand(sum(sizes), 2, generator=g, dtype=torch.float64) * 2 - 1
    sets = np.split(np.arange(sum(sizes)), np.cumsum(sizes)[:-1])
    covar, lik = gp_modules(2, 2 * len(sizes))
    covar.kernels[0].lengthscale = torch.rand(1, 2, generator=g, dtype=torch.float64) + 0.3
    covar.kernels[1].lengthscale = torch.rand(1, 2 * len(sizes), generator=g, dtype=torch.float64) + 0.5
    lik.noise = torch.tensor([0.05], dtype=torch.float64)
    w_task = rng.integers(n_tasks, size=n_window)
    w_loc = np.column_stack([rng.integers(s, size=n_window) for s in sizes])
    y = rng.normal(size=n_window)

    def inputs(tasks, loc):
        glob = np.column_stack([sets[i][loc[:, i]] for i in range(len(sizes))])
        return torch.cat([feats[torch.from_numpy(tasks)], pts[torch.from_numpy(glob)].reshape(len(loc), -1)], 1)

    model = SingleTaskGP(inputs(w_task, w_loc), torch.from_numpy(y)[:, None], likelihood=lik, covar_module=covar,
                         mean_module=ZeroMean(), outcome_transform=None).eval()
    hyp = to_hyper(covar, lik, feats, pts, sets)
    return hyp, model, inputs, w_task, w_loc, y, sizes


def test_local_gp_equals_the_botorch_posterior():
    hyp, model, inputs, w_task, w_loc, y, sizes = _random_gp(0)
    task = 1
    gp = LocalGP(hyp, task, w_task, w_loc, y)
    rng = np.random.default_rng(1)
    loc = np.column_stack([rng.integers(s, size=40) for s in sizes])
    mu, var, _ = gp.stats(gp.kernel(torch.from_numpy(loc)))
    post = model.posterior(inputs(np.full(40, task), loc))
    torch.testing.assert_close(mu, post.mean[:, 0], rtol=1e-7, atol=1e-9)
    torch.testing.assert_close(var, post.variance[:, 0], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pruned_descent_equals_the_exhaustive_one(seed):
    """The one-sample variance bound prunes, the argmin of every step stays exact."""
    hyp, _, _, w_task, w_loc, y, sizes = _random_gp(seed, sizes=(40, 35, 30), n_window=60)
    gp = LocalGP(hyp, 2, w_task, w_loc, y)
    starts = np.column_stack([np.random.default_rng(seed).integers(s, size=3) for s in sizes])
    pruned, pool = gp.descend(starts, 2.0, 20, screen=1, subset=8)
    single, pool_single = gp.descend(starts, 2.0, 20, screen=1, subset=0)  # the one-sample bound alone
    full, pool_full = gp.descend(starts, 2.0, 20, screen=1000, subset=0)
    np.testing.assert_array_equal(single, full)
    np.testing.assert_array_equal(pruned, full)
    assert pool_full["exact"] == pool_full["scored"] and pool["exact"] < pool_single["exact"] < pool["scored"]
    # each end is a fixed point: no single-agent move lowers the exact bound
    for q in range(len(starts)):
        mu, var, _ = gp.stats(gp.kernel(torch.from_numpy(full[q][None])))
        for i, s in enumerate(sizes):
            moves = np.tile(full[q], (s, 1))
            moves[:, i] = np.arange(s)
            m, v, _ = gp.stats(gp.kernel(torch.from_numpy(moves)))
            assert float((m - 2.0 * v.sqrt()).min()) >= float((mu - 2.0 * var.sqrt())[0]) - 1e-12
