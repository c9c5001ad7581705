"""Config values are checked when a config is made (each Config's ``__post_init__``), so that a bad
value is refused before anything runs: by the planner's constructor, by ``fixbench solve --set`` and by
``fixbench run``, which refuses the matrix before any cell runs (one line naming the matrix, the entry
and the field, exit code 2, nothing written)."""

from __future__ import annotations

from dataclasses import fields

import pytest

from fixbench.bench.cli import main
from fixbench.bench.running.matrix import load_matrix
from fixbench.cases.errors import CaseError
from fixbench.solvers import PlannerError, get
from fixbench.solvers.base import ConfigError
from fixbench.solvers.registry import BUILTIN

#: (planner, field, a value its config refuses): every built-in planner at least once
BAD = [
    ("cbr", "k", 0), ("cbr", "exclude", "parts"), ("cbr", "polish_samples", -2), ("cbr", "bootstrap", ()),
    ("exact", "chunk", 0), ("exact", "time_limit_s", 0.0),
    ("ga", "crossover_prob", 1.5), ("ga", "min_generations", 0),
    ("gp-ucb", "beta", 0.0), ("gp-ucb", "window", 0),
    ("greedy", "restarts", 0), ("greedy", "soft_power", -1.0),
    ("iql", "reward", "fancy"), ("iql", "train_fraction", 0.0),
    ("local", "start_share", 2.0), ("local", "neighbours", 0),
    ("mappo", "clip_epsilon", 1.0), ("ippo", "batch_episodes", 0),
    ("qmix", "eps_end", 0.95), ("qmix", "eps_decay", 0.0),
    ("nashq", "scale_samples", 1), ("nashq", "device", "tpu"), ("nashq", "train_tasks", (0, -1)),
    ("optuna", "stall_asks", 0),
    ("pso", "max_velocity_rate", 0.0), ("pso", "pop_size", 1),
    ("qp", "m_scales", ()), ("qp", "big_m", -1.0),
    ("random", "batch", 0),
    ("rules", "load_weight", 1.0),
    ("surrogate-ts", "ensemble", 0), ("surrogate-ts", "lr", 0.0),
    ("vdn", "eps_end", 1.5), ("vdn", "layers", 0),
]


def test_every_built_in_planner_has_a_refused_value_here():
    assert {name for name, _, _ in BAD} == set(BUILTIN)


@pytest.mark.parametrize("name,field,value", BAD, ids=[f"{n}.{f}={v!r}" for n, f, v in BAD])
def test_a_bad_value_is_refused_when_the_config_is_made(name, field, value):
    cls = get(name)
    assert field in {f.name for f in fields(cls.Config)}
    with pytest.raises(ConfigError) as made:
        cls.Config(**{field: value})
    assert made.value.field == field and repr(value) in made.value.problem
    with pytest.raises(PlannerError, match=f"^planner '{name}': {field} must be "):
        cls(**{field: value})
    cls()  # the defaults pass their own checks


@pytest.mark.parametrize("field,value,kind", [
    ("restarts", True, "int"), ("restarts", 2.0, "int"), ("soft_power", "4", "float"),
    ("soft_power", float("nan"), "float"),
])
def test_a_value_of_the_wrong_type_is_refused(field, value, kind):
    """The base class checks every field against its annotation: a bool is no number, NaN no float."""
    with pytest.raises(ConfigError, match=f"^{field} must be of type {kind}, got "):
        get("greedy").Config(**{field: value})
    assert get("greedy").Config(soft_power=4).soft_power == 4  # an int is a float


def test_tuple_fields_check_their_items():
    cfg = get("nashq").Config
    assert cfg(train_tasks=(0, 2)).train_tasks == (0, 2)
    for bad in ([0, 2], (0, "2"), (0.5,)):
        with pytest.raises(ConfigError, match="^train_tasks must be of type tuple"):
            cfg(train_tasks=bad)


def test_solve_refuses_a_bad_set_in_one_line(capsys):
    assert main(["solve", "fan_small", "--planner", "random", "--set", "batch=0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "fixbench: planner 'random': batch must be at least 1, got 0"


MATRIX = """
name = "bad config"
cases = ["fan_small"]
seeds = [0]
budget = 40
agents = 2
[[planners]]
name = "random"
[[planners]]
name = "{name}"
{label}config = {{ {field} = {value} }}
"""

MATRIX_BAD = [("cbr", "k", "0", "cbr k0", "must be at least 1, got 0"),
              ("qp", "m_scales", "[]", "", "must be positive numbers (at least one), got ()"),
              ("nashq", "reward", '"fancy"', "nashq fancy", "must be one of scaled, gaussian, bell, got 'fancy'")]


@pytest.mark.parametrize("name,field,value,label,problem", MATRIX_BAD, ids=[m[0] for m in MATRIX_BAD])
def test_run_refuses_a_matrix_with_a_bad_config_value_before_any_cell(tmp_path, capsys, name, field, value, label,
                                                                      problem):
    path = tmp_path / "bad.toml"
    path.write_text(MATRIX.format(name=name, field=field, value=value,
                                  label=f'label = "{label}"\n' if label else ""))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    entry = f"planner '{name}'" + (f", label '{label}'" if label else "")
    assert err.strip() == f"fixbench: {path}: planners[1].config.{field}: {problem} ({entry})"
    assert not out.exists(), "no cell may run, nothing may be written"
    with pytest.raises(CaseError) as refused:
        load_matrix(path)
    assert refused.value.source == str(path) and refused.value.key == f"planners[1].config.{field}"


PLUGIN = '''
from dataclasses import dataclass

from fixbench.solvers import Planner, PlannerConfig


class Odd(Planner):
    name = "odd"

    @dataclass(frozen=True)
    class Config(PlannerConfig):
        width: int = 2

        def __post_init__(self):
            super().__post_init__()
            if self.width % 2:
                raise ValueError(f"width must be even, got {self.width}")

    def plan(self, problem, ev, rng, mode):
        raise AssertionError("never reached: the matrix is refused first")
'''


def test_run_refuses_a_plugin_config_that_raises_its_own_exception(tmp_path, capsys, monkeypatch):
    (tmp_path / "odd_plugin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    path = tmp_path / "bad.toml"
    path.write_text(MATRIX.format(name="odd_plugin:Odd", field="width", value="3", label=""))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    problem = "ValueError: width must be even, got 3 (planner 'odd_plugin:Odd')"
    assert err == f"fixbench: {path}: planners[1].config: {problem}"
    assert not out.exists()
