"""The README's headline (best entry of each family, learners against the rest) and ranks over the
problems every entry ran on, on the committed results/tiny (random, greedy, local on fan_small)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from fixbench.bench.records.rows import in_matrix_order
from fixbench.bench.reporting.comparison import (
    common_ranks,
    headline_table,
    iqm_table,
    main_table,
    scored_cells,
    show_headline,
)
from fixbench.bench.reporting.merge import load_runs
from fixbench.bench.reporting.stats import probability_of_improvement

#: greedy stands in for a learner, so that the last line has two sides
FAMILY = {"random": "random", "greedy": "marl", "local": "local-search"}


@pytest.fixture(scope="module")
def tiny():
    runs = load_runs(["results/tiny"])
    return runs.rows, runs.refs


def test_headline_takes_each_familys_best_and_compares_learner_with_the_rest(tiny):
    rows, refs = tiny
    iq = iqm_table(rows, refs)
    head = headline_table(rows, iq, FAMILY)
    column = "fan_small"
    families = head[head["family"] != "P(learner < classical)"]
    assert list(families["family"]) == ["marl", "local-search", "random"]  # the headline's order
    for _, line in families.iterrows():
        mine = iq[iq["planner"].map(FAMILY) == line["family"]]
        assert line["entry"] == mine.loc[mine[column].idxmin(), "planner"]
        assert line["iqm"] == pytest.approx(mine[column].min())
    p = head[head["family"] == "P(learner < classical)"].iloc[0]
    others = iq[iq["planner"] != "greedy"]
    best_other = others.loc[others[column].idxmin(), "planner"]
    assert p["entry"] == f"greedy vs {best_other}"  # the best learner against the best of the other families
    scored = scored_cells(rows)
    want = probability_of_improvement(scored.loc[scored["label"] == "greedy", "regret_pct"],
                                      scored.loc[scored["label"] == best_other, "regret_pct"])
    assert (p["iqm"], p["iqm_lo"], p["iqm_hi"]) == pytest.approx(want)
    shown = show_headline(head)
    assert list(shown.iloc[:, 0]) == ["MARL learners", "local and greedy search", "random", "P(learner < classical)"]


def test_ranks_use_only_the_problems_every_entry_ran_on(tiny):
    rows, _ = tiny
    full = main_table(rows)
    assert full.attrs["ranked_on"] == (2, 2) and (full["problems"] == 2).all()
    # drop one seed of one planner: that seed's problem leaves every entry's rank
    gone = rows[~((rows["label"] == "local") & (rows["seed"] == 1))]
    part = main_table(gone)
    assert part.attrs["ranked_on"] == (1, 2) and (part["problems"] == 1).all()
    used, n_used, n_all = common_ranks(gone)
    assert (n_used, n_all) == (1, 2) and set(used["seed"]) == {0}
    assert np.isclose(part.set_index("planner")["mean_rank"].sum(), 6)  # 1 + 2 + 3 on the one problem left


def test_the_headline_keeps_the_families_order_when_the_first_column_lacks_one(tiny):
    """A part where a family has no entry yet (its first column) does not move that family down."""
    rows, refs = tiny
    head = headline_table(rows, iqm_table(rows, refs), FAMILY)
    other = head.assign(column="a_part_first")
    other = other[other["family"] != "marl"]  # no learner on the first part
    shown = show_headline(pd.concat([other, head], ignore_index=True))
    assert list(shown.iloc[:, 0]) == ["MARL learners", "local and greedy search", "random", "P(learner < classical)"]
    assert list(shown.columns[1:]) == ["a_part_first", "fan_small"]


def test_rows_follow_the_matrix_order_of_the_cases(tmp_path):
    rows = pd.DataFrame({"case": ["b", "a", "c", "b"], "seed": [0, 1, 2, 3]})
    (tmp_path / "matrix.toml").write_text('cases = ["c", "b"]\n')
    assert in_matrix_order(rows, tmp_path)["seed"].tolist() == [2, 0, 3, 1]  # a case not listed: after
    assert in_matrix_order(rows, tmp_path / "nowhere")["seed"].tolist() == [0, 1, 2, 3]


def test_the_verdict_is_the_interval_of_p():
    """bench/reporting/verdict.py: yes above 1/2, no below, level where P's interval holds 1/2; a line a
    headline column, with the two entries the P line names and their IQMs."""
    import pandas as pd

    from fixbench.bench.reporting.verdict import answer, verdict_table

    assert (answer(0.51, 1), answer(0, 0.49), answer(0.2, 0.6), answer(0.5, 0.5)) == ("yes", "no", "level", "level")
    head = pd.DataFrame([
        ("marl", "panel (per-task)", "vdn", 3.0, 2.0, 4.0),
        ("evolutionary", "panel (per-task)", "pso", 9.0, 8.0, 10.0),
        ("P(learner < classical)", "panel (per-task)", "vdn vs pso", 0.9, 0.7, 1.0),
        ("marl", "fan", "qmix", 90.0, 80.0, 99.0),
        ("local-search", "fan", "local", 0.0, 0.0, 0.0),
        ("P(learner < classical)", "fan", "qmix vs local", 0.1, 0.0, 0.3),
    ], columns=["family", "column", "entry", "iqm", "iqm_lo", "iqm_hi"])
    v = verdict_table(head, [("panel (per-task)", "panel", "per-task"), ("fan", "fan", None)])
    assert v[["part", "track", "answer", "learner", "classical"]].values.tolist() == [
        ["panel", "per-task", "yes", "vdn", "pso"], ["fan", "-", "no", "qmix", "local"]]
    assert v["classical_iqm"].tolist() == [9.0, 0.0] and v["p_hi"].tolist() == [1.0, 0.3]
