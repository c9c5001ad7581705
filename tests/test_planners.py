"""Every registered planner, through the same checks (issue: planner plugin API).

Valid layouts (one candidate per agent from its own set), the budget never exceeded and the
samples counted exactly, same seed -> same result, and a budget too small for the method gives a
clear error or a documented best effort: never a crash.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from fixbench.cases import FixbenchError, load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers import PlannerError, available, get, register
from fixbench.solvers.search.random_search import RandomSearch

#: exact's budget covers the enumeration of the problem below (42 x 42 layouts x 2 tasks); the others get
#: less than the joint space, as on every real part (a search that has seen most of a tiny space spends
#: the rest of a larger budget hunting the few layouts it has not)
BUDGETS = {"exact": 4_000}
BUDGET = 1_000


def budget(name: str) -> int:
    return BUDGETS.get(name, BUDGET)


@pytest.fixture(scope="module")
def problem():
    return Problem(load_case_spec("fan_small", n_agents=2).with_tasks([0, 5]))


def _quick(name):
    """The planner with settings that keep the test quick (documented config fields only)."""
    cls = get(name)
    quick = {"nashq": {"episodes": 3}, "iql": {"episodes": 3},
             "cbr": {"bootstrap": ("wing_panel_small",), "bootstrap_budget": 5}}.get(name, {})
    return cls(**quick)


@pytest.mark.parametrize("name", sorted(available()))
def test_planner_contract(problem, name):
    first = _quick(name).solve(problem, budget(name), seed=11)
    assert first.layouts.shape == (problem.n_tasks, problem.n_agents)
    for a, allowed in enumerate(problem.action_sets):
        assert np.isin(first.layouts[:, a], allowed).all()
    assert 0 <= first.samples <= budget(name)
    assert first.trace.shape[1] == 4 and (first.trace[:, 2] <= first.samples).all()
    assert np.all(first.max_deformation > 0)
    again = _quick(name).solve(problem, budget(name), seed=11)
    np.testing.assert_array_equal(first.layouts, again.layouts)
    assert first.samples == again.samples


@pytest.mark.parametrize("name", sorted(available()))
def test_budget_too_small(problem, name):
    try:
        result = _quick(name).solve(problem, 1, seed=0)
    except FixbenchError as exc:  # a clear, one-line error
        assert "\n" not in str(exc) and str(exc)
    else:  # a documented best effort within the budget
        assert result.samples <= 1


#: planners that act from rules alone, with no sample (the floor the learners must clear)
ZERO_SAMPLE = {"rules"}


@pytest.mark.parametrize("per_task", [3, 10])
@pytest.mark.parametrize("name", sorted(available()))
def test_tiny_budgets_are_spent_and_the_best_layout_seen_is_returned(name, per_task):
    """A few samples a task against 28 candidates an agent: a planner either refuses in one line
    (exact, qp) or spends the whole budget and is scored, on every task, by a layout no worse than
    the best it evaluated there (the scoring rule: learners included)."""
    small = Problem(load_case_spec("fan_small", n_agents=3).with_tasks([0, 5]))
    budget = per_task * small.n_tasks
    try:
        result = _quick(name).solve(small, budget, seed=0)
    except FixbenchError as exc:
        assert "\n" not in str(exc) and "budget" in str(exc)
        return
    if name in ZERO_SAMPLE:
        assert result.samples == 0 and len(result.trace) == 0
        return
    # a learner trains for whole episodes (3 here: its quick setting), the others spend the budget
    assert result.samples <= budget if get(name).returns_policy else result.samples == budget
    trace = np.asarray(result.trace)
    for t in range(small.n_tasks):
        seen = trace[trace[:, 0] == t, 3]
        assert len(seen) and result.max_deformation[t] <= seen.min() * (1 + 1e-12), (t, result.max_deformation[t])


@pytest.mark.parametrize("name", sorted(n for n, c in available().items() if "shared" in c.modes))
def test_shared_mode(problem, name):
    result = _quick(name).solve(problem, budget(name), seed=2, mode="shared")
    assert (result.layouts == result.layouts[0]).all()
    assert result.samples <= budget(name)


def test_registry_refuses_a_taken_name():
    class Impostor(RandomSearch):
        name = "random"

    with pytest.raises(PlannerError, match="'random' is taken"):
        register(Impostor)


def test_registry_refuses_a_builtin_name_before_the_builtin_is_imported():
    """Built-ins are imported lazily; a plugin must not take one's name in the meantime."""
    code = ("from fixbench.solvers.base import Planner\nfrom fixbench.solvers.registry import register\n"
            "class Impostor(Planner):\n    name = 'nashq'\n"
            "try:\n    register(Impostor)\nexcept Exception as e:\n    print(e)\n"
            "import sys\nprint('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "'nashq' is taken by the built-in planner fixbench.solvers.learners.nashq:NashQ" in out
    assert out.strip().endswith("False")


def test_checking_a_matrix_of_builtin_names_imports_no_planner(tmp_path):
    """The benchmark driver stays small: it checks names without importing PyTorch, cvxpy, pymoo;
    an entry with config overrides imports its own planner only (to check the overrides)."""
    names = ["random", "exact", "greedy", "ga", "pso", "local", "qp", "optuna", "cbr", "nashq", "iql"]
    bare = tmp_path / "bare.toml"
    bare.write_text('name = "bare"\ncases = ["fan_small"]\nmaterials = ["aluminium"]\nseeds = [0]\nbudget = 60\n'
                    + "".join(f'[[planners]]\nname = "{n}"\n' for n in names))
    tuned = tmp_path / "tuned.toml"
    tuned.write_text(bare.read_text() + '[[planners]]\nname = "nashq"\nlabel = "n"\nconfig = { episodes = 2 }\n')
    code = ("import sys\nfrom fixbench.bench.running.matrix import load_matrix\n"
            "m = load_matrix(sys.argv[1])\n"
            "print(len(m.planners), sorted(k for k in ('torch', 'cvxpy', 'pymoo', 'optuna') if k in sys.modules))")
    out = [subprocess.run([sys.executable, "-c", code, str(m)], capture_output=True, text=True, check=True).stdout
           for m in (bare, tuned)]
    assert out[0].split() == ["11", "[]"]  # 11 planner entries, checked by name only
    assert out[1].split() == ["12", "['torch']"]


def test_every_planner_is_documented():
    """A one-line description, and a docstring under every config field (cleanrl style)."""
    for name, cls in available().items():
        assert cls.description and "\n" not in cls.description, name
        for field in dataclasses.fields(cls.Config):  # fields, not the ClassVar ``tunable``
            assert _has_field_doc(cls.Config, field.name), (name, field.name)


def _has_field_doc(config_cls, field: str) -> bool:
    """A docstring right under the field's line in the class (or a base class) that defines it."""
    import inspect

    for klass in config_cls.__mro__:
        if field not in getattr(klass, "__annotations__", {}):
            continue
        lines = inspect.getsource(klass).splitlines()
        for i, line in enumerate(lines[:-1]):
            if line.strip().startswith(f"{field}:"):
                return lines[i + 1].strip().startswith(('"""', "r\"\"\""))
    return False


def test_listing_reads_the_builtins_without_importing_them():
    """``fixbench solvers`` describes built-ins from their source: the same as the imported classes,
    and without PyTorch, cvxpy or pymoo in the process."""
    code = ("import sys; from fixbench.solvers.registry import listing; import json; "
            "print(json.dumps([listing(), sorted(k for k in ('torch', 'cvxpy', 'pymoo') if k in sys.modules)]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    rows, heavy = json.loads(out)
    assert heavy == []
    from fixbench.solvers.registry import BUILTIN

    imported = {n: {"planner": n, "description": c.description, "family": c.family, "modes": list(c.modes),
                     "zero_shot": c.zero_shot, "module": c.__module__}
                for n, c in available().items() if n in BUILTIN}  # this process may hold other tests' planners
    assert {r["planner"]: r for r in rows if r["planner"] in BUILTIN} == imported
    assert {r["planner"] for r in rows} >= set(BUILTIN)
