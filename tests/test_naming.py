"""What fixbench calls things: planner families, robots by their region names, cases by their names."""

from __future__ import annotations

import json

import matplotlib
import pytest

from fixbench.bench.cli import main
from fixbench.bench.reporting.plots import candidate_groups, case_figure
from fixbench.bench.reporting.report import case_names, make_report
from fixbench.bench.running.runner import run_matrix
from fixbench.cases.problem import load_problem
from fixbench.solvers.registry import BUILTIN

#: the README's groups of planners (section Planners)
FAMILIES = {"marl": {"nashq", "iql", "vdn", "mappo", "ippo", "qmix"}, "bandit": {"surrogate-ts", "gp-ucb"},
            "evolutionary": {"ga", "pso"},
            "local-search": {"local", "greedy"}, "case-based": {"cbr"}, "qp": {"qp"},
            "bayesian-optimisation": {"optuna"}, "rules": {"rules"}, "random": {"random"}, "exact": {"exact"}}

REGIONS = ('count = 2\n', 'count = 2\n[[agents.regions]]\nname = "root side"\n'
           'polygon_mm = [[0, 0], [150, 0], [150, 200], [0, 200]]\n'
           '[[agents.regions]]\nname = "tip side"\npolygon_mm = [[150, 0], [400, 0], [400, 200], [150, 200]]\n')


def test_solvers_json_gives_each_planners_family(capsys):
    assert main(["solvers", "--json"]) == 0
    rows = {r["planner"]: r["family"] for r in json.loads(capsys.readouterr().out)}
    assert {name: rows[name] for name in BUILTIN} == {n: f for f, names in FAMILIES.items() for n in names}
    assert main(["solvers"]) == 0
    assert "bayesian-optimisation" in capsys.readouterr().out  # the table shows it too


def test_show_names_robots_by_their_regions_and_lists_them_beside_the_part(plate_toml):
    problem = load_problem(plate_toml(REGIONS))
    labels = [label for label, _ in candidate_groups(problem)]
    assert labels == ["root side: 2 candidates", "tip side: 4 candidates"]
    fig = case_figure(problem)
    ax = fig.axes[0]
    legend = ax.get_legend()
    assert [t.get_text() for t in legend.get_texts()][:2] == labels
    fig.canvas.draw()
    box, frame = legend.get_window_extent(), ax.get_window_extent()
    assert box.x0 >= frame.x1  # beside the axes: it hides no candidate
    matplotlib.pyplot.close(fig)


def test_robots_without_regions_are_numbered(plate_toml):
    assert [label for label, _ in candidate_groups(load_problem(plate_toml()))] == [
        "robot 0: 3 candidates", "robot 1: 3 candidates"]


def test_a_report_names_a_case_file_by_its_case_name(tmp_path, plate_toml):
    plate_toml(("[case]\n", '[case]\nname = "bracket"\n'), name="my_part_v3.toml")
    m = tmp_path / "m.toml"
    m.write_text('cases = ["my_part_v3.toml"]\nplanners = ["random"]\nseeds = [0]\nbudget = 6\n')
    out = tmp_path / "run"
    run_matrix(m, out, workers=1, progress=False)
    res = make_report(out)
    main_md = (out / "report" / "tables" / "main.md").read_text()
    assert "bracket" in main_md and "my_part_v3" not in main_md
    assert "my_part_v3" not in (out / "report" / "tables" / "references.md").read_text()
    assert "field_bracket" in res["figures"]  # the field figure rebuilt the case from its file
    assert "cases bracket," in res["report"].read_text()


@pytest.mark.parametrize("give_name", [True, False])
def test_two_case_files_of_one_name_keep_their_file_names(tmp_path, plate_toml, give_name):
    edit = ("[case]\n", '[case]\nname = "bracket"\n') if give_name else ("[case]\n", "[case]\n")
    a, b = plate_toml(edit, name="a.toml"), plate_toml(edit, name="b.toml")
    named = case_names([a, b, "fan_small"])
    assert named["fan_small"] == "fan_small"
    if give_name:
        assert named == {a: "bracket (a.toml)", b: "bracket (b.toml)", "fan_small": "fan_small"}
    else:  # no name given: the file's stem, as the case's own default name
        assert (named[a], named[b]) == ("a", "b")
