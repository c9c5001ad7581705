"""The budget driver (``Planner.drive``) keeps its contract, checked on this host against this host.

Every planner that runs through the driver (``random``, ``greedy``, ``local``, ``ga``, ``pso``,
``optuna``; with and without ``transfer = 2`` where its config has it) is run twice on the small
catalog cases, both modes (shared mode with transfer on fan_small only), with a budget and without,
seed 0: once as it is, once with its own search step under ``tests/budget_reference.py``, a second
reading of the contract written apart from the driver's code. What each search is handed (task,
allowance, warm layouts in order), the layouts, the scored max deformation, the samples, the anytime
trace and the planner's info must agree to the bit: a change that moves one evaluation, one draw of
``rng`` or one warm layout fails. Both runs are computed here, so they hold on any host (another
BLAS rounds both alike): nothing here is skipped for the host.

Beside it, checks that need no reference: the budget is spent exactly (each task its share, the
remainder to the first tasks), the same seed gives the same bits, a held-out task gets no sample,
and a budget too small for one layout a task (or one shared layout) is refused.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from budget_reference import watch

from fixbench.cases import load_problem
from fixbench.solvers import PlannerError, get

#: the small cases: 5 agents on 4 and 3 tasks, 3 agents on 6 tasks, and robots that place two pads
#: (the PSO encoding of pairs); bus_panel_small is left out (its oracle takes a minute to build)
CASES = ("wing_panel_small", "wing_spar_small", "fan_small", "wing_panel_pairs_small")
PLANNERS = ("random", "greedy", "local", "ga", "pso", "optuna")
MODES = ("per-task", "shared")
#: samples a task: past one round of greedy's checks (5 agents x 19 alternatives); optuna's studies are
#: kept shorter (past its 10 random startup trials), as each TPE ask costs more the longer the study
PER_TASK = {"random": 120, "greedy": 120, "local": 120, "ga": 120, "pso": 120, "optuna": 40}
EXTRA = 2  # samples past PER_TASK x n_tasks: the split's remainder (two tasks get one more)
SEED = 0
#: what each planner spends on a task (on the shared layout) when the budget is unlimited, made small
UNLIMITED = {"random": {"samples_per_task": 30}, "greedy": {"restarts": 2}, "local": {"samples_per_task": 30},
             "ga": {"evals_per_task": 30}, "pso": {"evals_per_task": 30}, "optuna": {"samples_per_task": 30}}
HELD_OUT_TRAIN = (1, 4)  # fan_small's training tasks in the held-out runs
SHARED_TRANSFER = "fan_small"  # the case shared mode also runs with transfer on


@functools.cache
def problem(case: str):
    return load_problem(case)


def transfers(name: str) -> tuple[int, ...]:
    return (0, 2) if "transfer" in get(name).Config.__dataclass_fields__ else (0,)


def runs() -> list[tuple[str, str, int, str]]:
    """(case, planner, transfer, mode) of every budgeted comparison: both modes with and without
    transfer; shared mode with transfer (which must change nothing: no warm start there) on
    SHARED_TRANSFER only, to keep the time down."""
    return [(case, name, transfer, mode) for case in CASES for name in PLANNERS
            for transfer in transfers(name) for mode in MODES
            if not (transfer and mode == "shared" and case != SHARED_TRANSFER)]


def key(case: str, name: str, transfer: int, mode: str) -> str:
    return f"{case}/{name}{f'+transfer={transfer}' if transfer else ''}/{mode}"


def budget(case: str, name: str, train=None) -> int:
    """The planner's PER_TASK a task searched (the training tasks, where some are held out), and EXTRA."""
    return PER_TASK[name] * (problem(case).n_tasks if train is None else len(train)) + EXTRA


def solve(case: str, name: str, transfer: int, mode: str, *, reference: bool = False, unlimited: bool = False,
          train=None):
    """One run of the real planner, or of its search step under the reference loop (``reference``):
    (result, what each search was handed)."""
    cls = get(name)
    planner = cls(**UNLIMITED[name]) if unlimited else cls(transfer=transfer) if transfer else cls()
    handed = watch(planner, reference)
    result = planner.solve(problem(case), None if unlimited else budget(case, name, train), seed=SEED, mode=mode,
                           train_tasks=train)
    assert handed, f"{name} did not hand its search to the budget loop"
    return result, handed


@functools.cache
def driven(case: str, name: str, transfer: int, mode: str, unlimited: bool = False, train=None):
    """The real planner's run (kept: the comparison and the budget checks read the same one)."""
    return solve(case, name, transfer, mode, unlimited=unlimited, train=train)


def assert_same_bits(got, want) -> None:
    """Two runs, (result, handed) each, agree to the bit: what each search was handed (task, allowance,
    warm layouts in order), and the layouts, scored max deformation, samples, trace and info."""
    (got, got_handed), (want, want_handed) = got, want
    assert got_handed == want_handed
    np.testing.assert_array_equal(got.layouts, want.layouts)
    assert got.max_deformation.tobytes() == want.max_deformation.tobytes()
    assert got.samples == want.samples
    assert got.trace.shape == want.trace.shape and got.trace.tobytes() == want.trace.tobytes()
    assert got.info == want.info
    assert got.policy_layouts is None and want.policy_layouts is None  # the returned layouts are the incumbents


def spent_on(result, task: int) -> int:
    """Samples the run spent on ``task`` (from the trace's task_samples column)."""
    rows = result.trace[result.trace[:, 0] == task]
    return int(rows[:, 1].max()) if len(rows) else 0


@pytest.mark.parametrize("run", runs(), ids=lambda r: key(*r))
def test_driver_matches_reference(run):
    assert_same_bits(driven(*run), solve(*run, reference=True))
    _, _, transfer, mode = run
    if transfer and mode == "per-task":  # the warm start is exercised, not only allowed
        assert any(warm for _, _, warm in driven(*run)[1])


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", PLANNERS)
def test_unlimited_budget_matches_reference(name, mode):
    """With no budget each search gets the planner's own number (made small here)."""
    assert_same_bits(driven("fan_small", name, 0, mode, unlimited=True),
                     solve("fan_small", name, 0, mode, reference=True, unlimited=True))


@pytest.mark.parametrize("name", PLANNERS)
def test_held_out_tasks_match_reference_and_get_no_sample(name):
    """Per-task mode searches only the tasks the evaluator allows; the held-out ones cost nothing."""
    transfer = max(transfers(name))
    train = HELD_OUT_TRAIN
    assert_same_bits(driven("fan_small", name, transfer, "per-task", train=train),
                     solve("fan_small", name, transfer, "per-task", reference=True, train=train))
    got, handed = driven("fan_small", name, transfer, "per-task", train=train)
    assert [task for task, _, _ in handed] == list(train)
    assert set(got.trace[:, 0].astype(int).tolist()) == set(train)
    assert [spent_on(got, t) for t in train] == [PER_TASK[name] + (i < EXTRA) for i in range(len(train))]


@pytest.mark.parametrize("run", runs(), ids=lambda r: key(*r))
def test_budget_spent_exactly(run):
    """Per-task: each task is handed its share, PER_TASK and one more on the first EXTRA tasks, and
    spends it; shared: every shared layout the budget pays for (the remainder, less than n_tasks, is
    left)."""
    case, name, _, mode = run
    (result, handed), n = driven(*run), problem(case).n_tasks
    if mode == "per-task":
        shares = [PER_TASK[name] + (t < EXTRA) for t in range(n)]
        assert [(task, allowance) for task, allowance, _ in handed] == list(enumerate(shares))
        assert [spent_on(result, t) for t in range(n)] == shares
        assert result.samples == budget(case, name)
    else:
        assert [(task, allowance) for task, allowance, _ in handed] == [(None, PER_TASK[name])]
        assert result.samples == PER_TASK[name] * n
        assert (result.layouts == result.layouts[0]).all()


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", PLANNERS)
def test_same_seed_same_bits(name, mode):
    """A second run of the same planner, seed and budget gives the same bits (fan_small: six tasks)."""
    run = ("fan_small", name, max(transfers(name)), mode)
    assert_same_bits(solve(*run), driven(*run))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", PLANNERS)
def test_budget_below_one_layout_a_task_is_refused(name, mode):
    p = problem("wing_spar_small")
    with pytest.raises(PlannerError, match="budget too small"):
        get(name)().solve(p, p.n_tasks - 1, seed=SEED, mode=mode)
