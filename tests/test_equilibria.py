"""Person-by-person optima, best-response basins and the robots count (bench/analysis/equilibria.py,
bench/analysis/robots.py).

The PBP count is checked against the definition, layout by layout: a layout is counted if and only
if no single agent's move gives a strictly lower max deformation (synthetic tables with ties, and a
tiny plate whose every layout and every single-agent move is evaluated through the counted evaluator).
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from fixbench.bench.analysis.equilibria import best_response_descent, joint_table, landscape, pbp_mask
from fixbench.bench.analysis.robots import best_per_task, robots_needed, robots_table
from fixbench.bench.cli import main
from fixbench.cases.problem import load_problem
from fixbench.cases.references import load_reference

#: 12 pads on the conftest plate: 3 agents x 4 (64 layouts) or 2 x 6 (36)
POINTS = ("points_mm = [[100, 50], [100, 150], [200, 50], [200, 150], [300, 50], [300, 150]]",
          "points_mm = [[80, 40], [80, 160], [140, 40], [140, 160], [200, 40], [200, 160], [260, 40], "
          "[260, 160], [320, 40], [320, 160], [360, 60], [360, 140]]")


def brute_force_pbp(value, shape) -> set[tuple]:
    """Layouts (index tuples) from which no single agent's move strictly lowers ``value``."""
    out = set()
    for s in itertools.product(*map(range, shape)):
        moves = (s[:a] + (i,) + s[a + 1:] for a in range(len(shape)) for i in range(shape[a]))
        if all(value(m) >= value(s) for m in moves):
            out.add(s)
    return out


@pytest.mark.parametrize("seed", range(5))
def test_pbp_mask_is_the_definition_on_tables_with_ties(seed):
    rng = np.random.default_rng(seed)
    table = rng.integers(0, 6, size=(4, 3, 5)).astype(float)  # few values: many ties
    expected = brute_force_pbp(lambda s: table[s], table.shape)
    assert set(zip(*np.nonzero(pbp_mask(table)))) == expected
    assert pbp_mask(table)[np.unravel_index(np.argmin(table), table.shape)]  # a global optimum is PBP


def test_pbp_count_on_a_tiny_plate_matches_brute_force(plate_toml):
    problem = load_problem(plate_toml(POINTS), agents=3)
    sets = problem.action_sets
    ev = problem.evaluator()
    task = 1
    cache = {}

    def value(s):  # one counted evaluation per distinct layout: a path independent of joint_table
        if s not in cache:
            cache[s] = float(ev.evaluate(task, [[int(sets[a][i]) for a, i in enumerate(s)]]).max_u[0])
        return cache[s]

    table = joint_table(problem, task)
    shape = tuple(len(a) for a in sets)
    assert table.shape == shape == (4, 4, 4)
    expected = brute_force_pbp(value, shape)
    assert ev.samples == 64
    assert all(table[s] == pytest.approx(v, rel=1e-12) for s, v in cache.items())
    assert set(zip(*np.nonzero(pbp_mask(table)))) == expected
    assert len(expected) >= 2  # a PBP optimum besides the global one: the check is not trivial


def test_descent_on_a_coordination_trap():
    table = np.array([[1.0, 5.0], [5.0, 2.0]])  # two PBP optima: (0, 0) and the trap (1, 1)
    assert set(zip(*np.nonzero(pbp_mask(table)))) == {(0, 0), (1, 1)}
    end, moves, samples = best_response_descent(table, np.arange(4))  # from (0,0), (0,1), (1,0), (1,1)
    # agent 0 moves first: from (0, 1) it takes row 1 (2 < 5), from (1, 0) row 0 (1 < 5)
    assert np.unravel_index(end, table.shape)[0].tolist() == [0, 1, 0, 1]
    assert moves.tolist() == [0, 1, 1, 0]
    assert samples.tolist() == [3, 4, 4, 3]  # the start, then one alternative a turn (2 or 3 turns)
    land = landscape(table, starts=1000, seed=3)
    assert land.values_m.tolist() == [1.0, 2.0] and land.regret.tolist() == [0.0, 1.0]
    assert land.basin.sum() == 1000 and 400 < land.basin[0] < 600  # half the starts each
    assert land.global_share == land.basin[0] / 1000
    assert land.samples_to(0.0) == pytest.approx(land.samples.mean() / land.global_share)
    single = landscape(np.array([[1.0, 5.0], [5.0, 9.0]]), 10, 0)  # one PBP optimum: every descent ends there
    assert single.samples_to(0.0) == single.samples.mean() and set(single.samples) <= {3, 4, 5}


@pytest.mark.parametrize("seed", range(3))
def test_descents_end_at_pbp_optima_and_never_rise(seed):
    rng = np.random.default_rng(seed)
    table = rng.random((6, 5, 4, 3))
    starts = rng.integers(0, table.size, 500)
    end, moves, _ = best_response_descent(table, starts)
    assert pbp_mask(table).ravel()[end].all()
    assert (table.ravel()[end] <= table.ravel()[starts]).all()
    assert ((moves == 0) == (end == starts)).all()
    a, b = landscape(table, 300, seed), landscape(table, 300, seed)
    assert (a.basin == b.basin).all() and (np.diff(a.values_m) >= 0).all() and a.regret[0] == 0


def _row(n, within, proven=True):
    return {"agents": n, "within": within, "proven": proven}


def test_robots_needed_says_how_sure_it_is():
    rows = [_row(1, 0.0), _row(2, 0.5), _row(3, 1.0), _row(4, 1.0)]
    assert robots_needed(rows) == {"fraction": 1.0, "agents": 3, "proven": True, "unknown_below": []}
    assert robots_needed(rows, 0.5)["agents"] == 2
    rows[1] = _row(2, None, False)  # unavailable: N = 3 suffices, N = 2 might
    assert robots_needed(rows) == {"fraction": 1.0, "agents": 3, "proven": False, "unknown_below": [2]}
    rows[1] = _row(2, 0.5, False)  # best-known only: it may do better than shown
    assert robots_needed(rows)["unknown_below"] == [2]
    assert robots_needed([_row(1, 0.0), _row(2, 0.5)])["agents"] is None


def test_robots_table_enumerates_or_says_unavailable(plate_toml):
    path = plate_toml(POINTS)
    rows = robots_table(path, None, 3, tolerance_m=1.0)
    assert [r["agents"] for r in rows] == [1, 2, 3] and all(r["source"] == "enumeration" for r in rows)
    for r in rows:
        problem = load_problem(path, agents=r["agents"])
        best = [joint_table(problem, t).min() for t in range(problem.n_tasks)]
        assert r["per_task_m"] == pytest.approx(best, rel=1e-12) and r["within"] == 1.0
    capped = robots_table(path, None, 3, tolerance_m=1.0, max_evaluations=100)  # 2 x 6^2 x 3 tasks > 100
    assert [r["per_task_m"] is None for r in capped] == [False, True, True]
    assert capped[2]["source"].startswith("unavailable") and capped[2]["within"] is None


def test_robots_falls_back_to_the_shipped_reference_and_nothing_else():
    ref = load_reference("wing_panel", "aluminium", 5)
    rec = best_per_task("wing_panel", "aluminium", 5)  # 1.3e14 layouts x 500 tasks: not enumerated
    assert rec["source"] == "shipped reference wing_panel__aluminium__a5.json"
    assert rec["per_task_m"] == [t["max_deformation_m"] for t in ref["tasks"]] and not rec["proven"]
    rec = best_per_task("wing_panel", "aluminium", 4)  # no reference at 4 agents
    assert rec["per_task_m"] is None and rec["source"].startswith("unavailable")


def test_cli_equilibria_and_robots(plate_toml, tmp_path, capsys):
    path = plate_toml(POINTS)
    assert main(["equilibria", path, "--agents", "2", "--task", "0", "--starts", "200", "--json",
                 "--out", str(tmp_path / "f3.png")]) == 0
    res = json.loads(capsys.readouterr().out)
    (rec,) = res["tasks"]
    table = np.array(rec["table_m"])
    assert table.shape == (6, 6) and rec["pbp_optima"] == pbp_mask(table).sum() == len(rec["optima"])
    assert rec["optimum_m"] == table.min() and sum(o["basin_share"] for o in rec["optima"]) == pytest.approx(1)
    assert (tmp_path / "f3.png").stat().st_size > 5000
    assert main(["equilibria", path, "--agents", "3", "--out", str(tmp_path / "x.png")]) == 2  # Figure 3: 2 agents
    assert "--out" in capsys.readouterr().err
    assert main(["robots", path, "--tolerance-um", "1e6", "--max-agents", "2", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["answers"][0]["agents"] == 1 and res["answers"][0]["proven"] and res["tolerance_m"] == 1.0
