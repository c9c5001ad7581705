"""surrogate-ts: exact budget, same seed -> same bits, better than random search, held-out track."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers.bandits.surrogate import Ensemble, Responder, SurrogateTS
from fixbench.solvers.base import PlannerError


@pytest.fixture(scope="module")
def problem():
    return Problem(load_case_spec("wing_panel_small"))


def test_spends_exactly_its_budget_and_repeats_bit_for_bit(problem):
    small = Problem(problem.spec.with_tasks([0, 2]))
    budget = 2 * 37 + 1  # uneven shares: 38 and 37 samples
    threads = torch.get_num_threads()
    first = SurrogateTS(train_steps=20).solve(small, budget, seed=5)
    again = SurrogateTS(train_steps=20).solve(small, budget, seed=5)
    assert torch.get_num_threads() == threads
    assert first.samples == budget and first.info["samples_per_task"] == [38, 37]
    assert first.info["rounds"] > 1 and first.info["train_steps"] == 20 * first.info["rounds"]
    np.testing.assert_array_equal(first.layouts, again.layouts)
    np.testing.assert_array_equal(first.trace, again.trace)  # every sample's best, in order
    np.testing.assert_array_equal(first.max_deformation, again.max_deformation)
    assert first.info["final_loss"] == again.info["final_loss"]
    loss = first.training.curves["fit_loss"]  # one value a fit (one a round here), the last the info's final_loss
    assert loss.unit == "fit" and len(loss.values) == first.info["rounds"]
    assert loss.values[-1] == first.info["final_loss"]
    assert loss.values.tobytes() == again.training.values("fit_loss").tobytes()
    assert len(first.training.values("round_samples")) == first.info["rounds"] + 1  # round 0 and the rounds
    other = SurrogateTS(train_steps=20).solve(small, budget, seed=6)
    assert not np.array_equal(first.trace, other.trace)


def test_refuses_a_budget_below_one_sample_a_task(problem):
    with pytest.raises(PlannerError, match="budget too small"):
        SurrogateTS().solve(problem, problem.n_tasks - 1, seed=0)
    with pytest.raises(PlannerError, match="does not support mode 'shared'"):
        SurrogateTS().solve(problem, 100, seed=0, mode="shared")


def test_best_response_tables_equal_the_network():
    """The tabulated first layer gives the network's own prediction of every action of an agent."""
    g = torch.Generator().manual_seed(0)
    n_tasks, f, s, sizes = 3, 2, 2, (4, 5, 3)
    feats = torch.rand(n_tasks, f, generator=g)
    pts = torch.rand(sum(sizes), s, generator=g)
    sets = np.split(np.arange(sum(sizes)), np.cumsum(sizes)[:-1])
    model = Ensemble(2, f + len(sizes) * s, 8, g)
    r = Responder(model, feats, pts, sets)
    local = np.array([[1, 2, 0], [3, 0, 2]])
    tasks = np.array([2, 0])
    for k in range(2):
        for i in range(len(sizes)):
            got = r.scores(k, torch.from_numpy(tasks), torch.from_numpy(local), i)
            for q in range(len(tasks)):
                lay = np.tile(local[q], (sizes[i], 1))
                lay[:, i] = np.arange(sizes[i])
                glob = np.column_stack([sets[j][lay[:, j]] for j in range(len(sizes))])
                x = torch.cat([feats[tasks[q]].expand(sizes[i], f),
                               pts[torch.from_numpy(glob)].reshape(sizes[i], -1)], 1)
                want = model(x.expand(2, -1, -1))[k]
                torch.testing.assert_close(got[q], want.detach(), rtol=1e-5, atol=1e-5)


def test_held_out_tasks_without_a_round_get_the_ensemble_means_layout_and_no_sample(problem):
    """A budget inside round 0: the ensemble is trained once for the held-out tasks and acts there."""
    train, budget = [0, 2], 2 * 4
    first = SurrogateTS(train_steps=20).solve(problem, budget, seed=3, train_tasks=train)
    again = SurrogateTS(train_steps=20).solve(problem, budget, seed=3, train_tasks=train)
    assert first.samples == budget and set(first.trace[:, 0].astype(int)) == set(train)
    np.testing.assert_array_equal(first.held_out, [1, 3])
    assert first.info["rounds"] == 0 and first.info["train_steps"] == 20  # the held-out fit alone
    assert "held_out_from" not in first.info and first.info["held_out_sweeps"] >= 2
    np.testing.assert_array_equal(first.layouts, again.layouts)
