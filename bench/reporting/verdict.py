"""The seed's question answered a line a part and track: do learning robots beat classical planners at
equal samples? Read off the headline (:func:`fixbench.bench.reporting.comparison.headline_table`):
the best learning entry and the best other entry by the IQM of their per-position regret, and rliable's
probability P that a cell of the first ends below a cell of the second, with its 95 % interval.

The answer is the interval's: **yes** where all of it lies above 1/2 (a learner's cell beats a
classical cell more often than not, beyond the bootstrap's doubt), **no** where all of it lies below,
**level** where it holds 1/2. One rule for every line, so a rerun that moves a number moves the word
with it (``fixbench report --readme`` copies the table into the README).
"""

from __future__ import annotations

import pandas as pd

from fixbench.bench.reporting.tables import ci_text

#: the headline's line that holds P (its ``entry``: "LEARNER vs CLASSICAL")
P_LINE = "P(learner < classical)"


#: P of two entries that neither beats: yes above it, no below, level where P's interval holds it
EVEN = 0.5


def answer(lo: float, hi: float) -> str:
    """yes / level / no from P's interval [lo, hi] (see the module docstring)."""
    return "yes" if lo > EVEN else "no" if hi < EVEN else "level"


def verdict_table(head: pd.DataFrame, columns: list[tuple[str, str, str | None]]) -> pd.DataFrame:
    """One line a headline column (a part and track): the answer, the two entries with their IQM and
    interval, and P with its interval. ``columns``: the main table's (name, case, mode) of each column
    (:func:`~fixbench.bench.reporting.comparison.main_columns`; mode None in a run of one mode: "-")."""
    where = {name: (case, mode or "-") for name, case, mode in columns}
    recs = []
    for _, p in head[head["family"] == P_LINE].iterrows():
        learner, classical = p["entry"].split(" vs ", 1)
        part, track = where[p["column"]]
        rec = {"part": part, "track": track, "answer": answer(p["iqm_lo"], p["iqm_hi"])}
        for role, label in (("learner", learner), ("classical", classical)):
            row = head[(head["column"] == p["column"]) & (head["entry"] == label) & (head["family"] != P_LINE)].iloc[0]
            rec |= {role: label, f"{role}_iqm": row["iqm"], f"{role}_iqm_lo": row["iqm_lo"],
                    f"{role}_iqm_hi": row["iqm_hi"]}
        recs.append(rec | {"p": p["iqm"], "p_lo": p["iqm_lo"], "p_hi": p["iqm_hi"]})
    return pd.DataFrame(recs)


def show_verdict(table: pd.DataFrame) -> pd.DataFrame:
    """The verdict formatted: entries as ``label: IQM [lo, hi]`` (regret %), P as ``P [lo, hi]``."""
    def entry(role: str) -> list[str]:
        return [f"{r[role]}: {ci_text(r[f'{role}_iqm'], r[f'{role}_iqm_lo'], r[f'{role}_iqm_hi'])}"
                for _, r in table.iterrows()]

    return pd.DataFrame({"part": table["part"], "track": table["track"],
                         "learners beat classical?": table["answer"],
                         "best learner, IQM regret %": entry("learner"),
                         "best classical, IQM regret %": entry("classical"),
                         "P(learner < classical)": [ci_text(*v) for v in table[["p", "p_lo", "p_hi"]].values]})
