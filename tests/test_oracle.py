"""The fast oracle equals a direct constrained solve, and every sample is counted exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fixbench.cases import BudgetExhausted, CaseError, load_problem

#: random layouts checked against a direct solve (each direct solve re-assembles and factorises the part):
#: the plate with every kind of support and load the bus panel has (conftest.WINDOWED: window and
#: rail held in w only, a background pressure) and the fan (rotational loads on blades round a hub),
#: where a direct solve takes milliseconds. The wing panel, spar and bus panel themselves (seconds a
#: solve; the bus panel 307k DOFs) are checked by `fixbench validate` (cases/part_checks.py).
EXAMPLES = {"windowed plate": 60, "fan": 20}
FIELDS = ("max_ux", "max_uy", "max_w", "max_u", "max_uxy")


def _layouts(problem):
    """Hypothesis strategy: (task, layout) with one candidate from each agent's set."""
    sets = problem.action_sets
    return st.tuples(st.integers(0, problem.n_tasks - 1),
                     st.tuples(*[st.sampled_from(a.tolist()) for a in sets]))


@pytest.mark.parametrize("case", EXAMPLES)
def test_oracle_equals_direct_solve(case, tmp_path):
    from conftest import windowed

    if case == "windowed plate":  # 10 candidates, 3 robots: 36 layouts x 3 tasks to draw from
        text = windowed().replace("count = 2", "count = 3").replace(
            "points_mm = [[100, 50], [100, 150], [200, 50], [200, 150], [300, 50], [300, 150]]",
            "points_mm = [[100, 50], [100, 150], [150, 100], [200, 50], [200, 150], [250, 100], "
            "[300, 50], [300, 150], [350, 150], [350, 50]]")
        (tmp_path / "windowed.toml").write_text(text)
        problem = load_problem(tmp_path / "windowed.toml")
    else:
        problem = load_problem(case)
    worst = []

    @settings(max_examples=EXAMPLES[case], deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(_layouts(problem))
    def check(drawn):
        task, layout = drawn
        fast = problem.evaluator().evaluate(task, [list(layout)])
        slow = problem.direct_deformation(task, [list(layout)])
        for f in FIELDS:
            a, b = getattr(fast, f)[0], getattr(slow, f)[0]
            rel = abs(a - b) / max(abs(b), 1e-300) if b != 0 else abs(a)
            worst.append(rel)
            assert rel <= 1e-9, (f, a, b, rel)

    check()
    assert len(worst) >= len(FIELDS) * EXAMPLES[case]
    print(f"{case}: worst relative difference {max(worst):.2e} over {len(worst) // len(FIELDS)} layouts")


def test_batched_equals_one_by_one():
    problem = load_problem("wing_panel_small")
    rng = np.random.default_rng(3)
    layouts = np.column_stack([rng.choice(a, 64) for a in problem.action_sets])
    batch = problem.evaluator().evaluate(1, layouts).max_u
    single = [problem.evaluator().evaluate(1, lay[None, :]).max_u[0] for lay in layouts]
    np.testing.assert_array_equal(batch, single)


def test_large_batch_in_locality_order_is_the_same_bits(monkeypatch):
    """A batch of LOCALITY_MIN layouts or more is evaluated sorted by candidate blocks: every column
    (soft max too) is the same bits as in the given order, and "no pad" (-1) entries keep their place."""
    from fixbench.cases import oracle as om

    problem = load_problem("wing_panel_small")
    rng = np.random.default_rng(5)
    layouts = np.column_stack([rng.choice(a, 600) for a in problem.action_sets])
    layouts[::7, 1] = -1  # an idle robot in some layouts
    monkeypatch.setattr(om, "LOCALITY_BYTES", 4096)  # blocks of a few candidates: a real reordering
    monkeypatch.setattr(om, "LOCALITY_MIN", 10**9)
    given_order = problem.oracle.evaluate(2, layouts, soft_power=8.0)
    assert not np.array_equal(problem.oracle._locality_order(layouts), np.arange(len(layouts)))
    monkeypatch.setattr(om, "LOCALITY_MIN", 100)
    np.testing.assert_array_equal(problem.oracle.evaluate(2, layouts, soft_power=8.0), given_order)


@pytest.mark.parametrize("power", [1.0, 4.0, 16.0])
def test_soft_max_equals_direct_solve_and_lies_below_the_max(power):
    problem = load_problem("fan_small")
    rng = np.random.default_rng(int(power))
    layouts = np.column_stack([rng.choice(a, 3) for a in problem.action_sets])
    fast = problem.evaluator().evaluate(2, layouts, soft_power=power)
    for i, lay in enumerate(layouts):
        slow = problem.direct_deformation(2, lay[None, :], soft_power=power)
        assert fast.soft_u[i] == pytest.approx(slow.soft_u[0], rel=1e-9)
    assert (fast.soft_u < fast.max_u).all()
    assert np.isnan(problem.evaluator().evaluate(2, layouts).soft_u).all()  # only when asked for


def test_samples_counted_exactly():
    problem = load_problem("wing_panel_small")
    ev = problem.evaluator(budget=10)
    lay = [[a[0] for a in problem.action_sets]]
    ev.evaluate(0, lay * 3)
    ev.evaluate(1, lay)
    assert ev.samples == 4 and ev.remaining == 6
    with pytest.raises(BudgetExhausted, match="budget of 10"):
        ev.evaluate(0, lay * 7)
    assert ev.samples == 4  # a refused batch spends nothing
    ev.evaluate(0, lay * 6)
    assert ev.samples == 10 and ev.remaining == 0
    with pytest.raises(BudgetExhausted):
        ev.evaluate(0, lay)


def test_compliance_columns_are_charged():
    problem = load_problem("wing_panel_small")
    ev = problem.evaluator()
    per = {f: fo.per for f, fo in problem.oracle.fields.items()}
    C, H = ev.compliance("bending", [0, 1, 2])
    assert ev.samples == 3 * per["bending"]
    assert C.shape == (3 * per["bending"], problem.oracle.fields["bending"].n_rows)
    ev.compliance("membrane", [0, 0, 5])  # duplicates are one candidate
    assert ev.samples == 3 * per["bending"] + 2 * per["membrane"]
    with pytest.raises(BudgetExhausted):
        problem.evaluator(budget=1).compliance("membrane", [0])


def test_budget_must_be_positive_or_zero():
    problem = load_problem("wing_panel_small")
    with pytest.raises(CaseError, match="must be positive"):
        problem.evaluator(budget=-1)
    with pytest.raises(BudgetExhausted):  # 0: no sample at all (k = 0)
        problem.evaluator(budget=0).evaluate(0, [[a[0] for a in problem.action_sets]])


def test_fixtures_reduce_deformation():
    """Physics sanity: adding fixtures never increases the energy-norm response; here max |u|."""
    problem = load_problem("wing_panel_small")
    free = problem.model.measure(problem.model.solve_direct(0, np.zeros((0, 2))))
    held = problem.evaluator().evaluate(0, [[a[len(a) // 2] for a in problem.action_sets]])
    assert held.max_u[0] < 0.5 * np.abs(free["w"]).max()


def test_deterministic():
    problem = load_problem("wing_panel_small")
    rng = np.random.default_rng(0)
    layouts = np.column_stack([rng.choice(a, 200) for a in problem.action_sets])
    a = problem.evaluator().evaluate(2, layouts).max_u
    b = problem.evaluator().evaluate(2, layouts).max_u
    np.testing.assert_array_equal(a, b)


def test_cache_size_bounds_the_models_kept():
    """A benchmark worker keeps one model: building the next one evicts the last one first."""
    import fixbench.cases.problem as cp

    saved = cp.CACHE_SIZE
    try:
        cp.set_cache_size(1)
        a, b = load_problem("fan_small"), load_problem("fan_small", material="steel")
        model_a = a.model
        assert list(cp._MODELS.values()) == [model_a]
        model_b = b.model
        assert list(cp._MODELS.values()) == [model_b]
    finally:
        cp.set_cache_size(saved)
