"""The counts the README and the results pages state are the ones the code and results/ give, and every
number of the README's prose is one of its checked facts.

Every "N cells", "N cases" or "N planners" in README.md, docs/*.md or results/README.md must be one of
the claims below, each compared with what a command computes: the catalog (``case_names``), a
matrix's expansion (``load_matrix(...).cells()``) or a committed run's rows. The README's tables of
planners and catalog cases, and docs/layout.md, must name every planner, case and module.
"""

from __future__ import annotations

import fnmatch
import json
import math
import re
import tomllib
from functools import cache
from pathlib import Path

import click
import numpy as np
import pytest

from fixbench.bench.check import CheckSettings
from fixbench.bench.cli_common import run_command
from fixbench.bench.reporting.stats import LEVEL
from fixbench.bench.reporting.verdict import EVEN
from fixbench.bench.running.matrix import Matrix, find_matrix, load_matrix
from fixbench.cases.errors import CaseError
from fixbench.cases.linearity import LIMIT
from fixbench.cases.problem import load_problem
from fixbench.cases.rewards import gaussian
from fixbench.cases.spec import case_names, load_case_spec
from fixbench.solvers.registry import BUILTIN, get

ROOT = Path(__file__).resolve().parents[1]
PAGES = ("README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")), "results/README.md")
#: a stated count: every match must lie inside a claim's match
COUNT = re.compile(r"\b\d[\d,]*(?: of (?:its|the))? cells\b|\b\d+ (?:catalog )?cases\b|\b\d+ (?:built-in )?planners\b")


@cache
def matrix(name: str) -> Matrix:
    return load_matrix(find_matrix(name))


@cache
def rows(run: str) -> tuple[dict, ...]:
    return tuple(json.loads(p.read_text()) for p in sorted((ROOT / "results" / run / "rows").glob("*.json")))


def failed(run: str) -> int:
    return sum(bool(r["error"]) for r in rows(run))  # "" when the cell finished


def timing_subset() -> int:
    """The default matrix's cells without local, optuna, the fixture pairs and the CFRP panel
    (docs/references.md's worker timings were measured on those)."""
    return sum(c.planner not in ("local", "optuna")
               and c.case not in ("wing_panel_pairs_small", "cfrp_wing_panel_small")
               for c in matrix("default").cells())


#: (page, pattern whose group n is the stated count, what the code gives)
CLAIMS = [
    ("README.md", r"default matrix \(`bench/matrices/default\.toml`: (?P<n>[\d,]+) cells",
     lambda: len(matrix("default").cells())),
    ("README.md", r"`bench/matrices/default\.toml`: [\d,]+ cells, (?P<n>\d+) planners",
     lambda: len({p.name for p in matrix("default").planners})),
    ("README.md", r"The catalog's (?P<n>\d+) cases", lambda: len(case_names())),
    ("docs/families.md", r"five seeds \((?P<n>[\d,]+) cells; `fixbench run families",
     lambda: len(matrix("families").cells())),
    ("docs/families.md", r"holds \(all (?P<n>[\d,]+) cells", lambda: len(matrix("families").cells())),
    ("docs/families.md", r"holds \(all (?P<n>[\d,]+) cells", lambda: len(rows("families"))),
    ("docs/families.md", r"holds \(all [\d,]+ cells, (?P<n>\d+) failed", lambda: failed("families")),
    ("docs/references.md", r"(?P<n>[\d,]+) of its [\d,]+ cells", timing_subset),
    ("docs/references.md", r"[\d,]+ of its (?P<n>[\d,]+) cells", lambda: len(matrix("default").cells())),
    ("docs/results.md", r"All (?P<n>[\d,]+) cells of the paper matrix", lambda: len(matrix("paper").cells())),
    ("docs/results.md", r"All (?P<n>[\d,]+) cells of the paper matrix", lambda: len(rows("paper"))),
    ("docs/results.md", r"cells of the paper matrix, (?P<n>\d+) failed", lambda: failed("paper")),
    ("docs/results.md", r"The sweep holds all (?P<n>[\d,]+) of its cells", lambda: len(matrix("sweep").cells())),
    ("docs/results.md", r"The sweep holds all (?P<n>[\d,]+) of its cells", lambda: len(rows("sweep"))),
    ("docs/results.md", r"The sweep holds all [\d,]+ of its cells, (?P<n>\d+) failed", lambda: failed("sweep")),
]


@cache
def text(page: str) -> str:
    """A page with its line breaks as spaces (a count may be wrapped onto the next line)."""
    return re.sub(r"\s+", " ", (ROOT / page).read_text(encoding="utf-8"))


def section(page: str, heading: str) -> str:
    """The lines of ``page`` under ``## heading``, to the next ``## `` heading."""
    body = (ROOT / page).read_text(encoding="utf-8").split(f"\n## {heading}\n", 1)[1]
    return body.split("\n## ", 1)[0]


def table_names(block: str) -> set[str]:
    """The backticked names in the first column of every row of the Markdown tables in ``block``."""
    return {name for line in block.splitlines() if line.startswith("| `")
            for name in re.findall(r"`([^`]+)`", line.split("|")[1])}


@pytest.mark.parametrize(("page", "pattern", "truth"), CLAIMS, ids=[f"{c[0]}:{c[1][:40]}" for c in CLAIMS])
def test_stated_count_is_what_the_code_gives(page, pattern, truth):
    found = [int(m["n"].replace(",", "")) for m in re.finditer(pattern, text(page))]
    assert found, f"{page} no longer says /{pattern}/: update the claim"
    assert set(found) == {truth()}, f"{page} says {found}, the code gives {truth()}"


def test_every_stated_count_is_checked():
    """A new "N cells" (or cases, planners) in the prose needs a claim above, so that it cannot go
    stale. Fenced code is left out: its commands run in tests of their own, which check what they
    print (tests/test_join.py: the README's join-example and its cell counts)."""
    unchecked = []
    for page in PAGES:
        prose = re.sub(r"```.*?```", "", text(page))
        covered = [m.span() for p, pattern, _ in CLAIMS if p == page for m in re.finditer(pattern, prose)]
        unchecked += [f"{page}: '{m[0]}'" for m in COUNT.finditer(prose)
                      if not any(a <= m.start() and m.end() <= b for a, b in covered)]
    assert not unchecked, "; ".join(unchecked)


def test_planner_table_names_every_builtin():
    assert table_names(section("README.md", "Planners")) == set(BUILTIN)


def test_catalog_table_covers_every_case():
    """Each row's name or pattern (``*_small``) matches some case, and every case matches a row."""
    patterns = table_names(section("README.md", "Case files and the catalog"))
    cases = case_names()
    assert not [p for p in patterns if not fnmatch.filter(cases, p)]
    assert not [c for c in cases if not any(fnmatch.fnmatch(c, p) for p in patterns)]


def listed_modules() -> set[str]:
    """Paths of the ``.py`` files "Layout of the code" lists (:func:`tree_paths` of its tree)."""
    return tree_paths((ROOT / "docs/layout.md").read_text(encoding="utf-8").split("```")[1])


def tree_paths(block: str) -> set[str]:
    """Paths of the ``.py`` files of an indented tree (two spaces a level; a line whose first word is no
    file or folder continues the description above it)."""
    out, folders = set(), []
    for line in block.splitlines():
        name = line.split()[0] if line.strip() else ""
        if not name.endswith(("/", ".py")):
            continue
        del folders[(len(line) - len(line.lstrip())) // 2:]
        if name.endswith("/"):
            folders.append(name.rstrip("/"))
        else:
            out.add("/".join([*folders, name]))
    return out


def test_layout_lists_every_module():
    on_disk = {str(p.relative_to(ROOT)) for folder in ("cases", "solvers", "bench", "studies")
               for p in (ROOT / folder).rglob("*.py") if p.name != "__init__.py"}
    listed = listed_modules()
    assert {m for m in listed if m.startswith("studies/")}, "the parse found no studies/"
    # the parse follows nested folders in and out (bench/running/ and its siblings rely on it)
    assert tree_paths("a/  x\n  b/\n    c.py  y\n  more words\n  d.py\ne.py\n") == {"a/b/c.py", "a/d.py", "e.py"}
    assert not on_disk - listed, f"not in docs/layout.md: {sorted(on_disk - listed)}"
    assert not listed - on_disk, f"listed but not in the tree: {sorted(listed - on_disk)}"


# every number of the README ------------------------------------------------------------------------------

#: a number written as a word
WORDS = {w: i for i, w in enumerate("zero one two three four five six seven eight nine ten eleven twelve".split())}


def number(s: str) -> float:
    """A stated number: digits (with thousands commas), a fraction ``a/b`` or a word."""
    s = s.replace(",", "")
    if "/" in s:
        a, b = s.split("/")
        return float(a) / float(b)
    return WORDS[s.lower()] if s.lower() in WORDS else float(s)


@cache
def spec(case: str):
    return load_case_spec(case)


def paper_cells(case: str, key: str) -> set:
    return {getattr(c, key) for c in matrix("paper").cells() if c.case == case}


def tuned_trials() -> set[int]:
    return {tomllib.loads(p.read_text())["planners"][0]["tuning"]["trials"]
            for p in (ROOT / "results" / "tune").rglob("*.toml")}


def smallest_power_above(values) -> int:
    """The least e with 10^e >= every value."""
    return math.ceil(math.log10(max(values)))


#: (pattern on README.md, with its whitespace as single spaces; {group: what the code or results/ give}).
#: A group holds a number (digits or a word); a truth may give a set when every value must be it
README_FACTS = [
    (r"torch==(?P<v>[\d.]+)`\) on first use",
     {"v": lambda: re.search(r"torch==([\d.]+)", (ROOT / "Makefile").read_text())[1]}),
    (r"the small variants of the (?P<parts>\w+) parts and of the wing panel held by fixture pairs in "
     r"(?P<materials>\w+) materials and of the CFRP wing panel in its layup, (?P<seeds>\w+) seeds",
     {"parts": lambda: len(matrix("paper").cases), "materials": lambda: len(matrix("default").materials),
      "seeds": lambda: len(matrix("default").seeds)}),
    (r"rliable's (?P<level>\d+) % interval", {"level": lambda: 100 * LEVEL}),
    (r"lies above (?P<a>[\d/]+)\*?\*?, \*\*no\*\* below, \*\*level\*\* where it holds (?P<b>[\d/]+)",
     {"a": lambda: EVEN, "b": lambda: EVEN}),
    (r"whose (?P<n>\w+) operating conditions", {"n": lambda: len(spec("fan").tasks)}),
    (r"The wing panel and spar \((?P<wa>\d+) robots, (?P<wt>\d+) drilling positions\), the bus panel "
     r"\((?P<bm>\w+), (?P<ba>\d+) robots, (?P<bt>\d+) positions\) and the fan \((?P<fa>\d+) robots, "
     r"(?P<ft>\d+) operating conditions\), \*\*(?P<spt>\d+) samples a position\*\* for every planner, "
     r"seeds (?P<s0>\d+)-(?P<s1>\d+),.*?held-out\* \(train on every (?P<k>\d+)th position",
     {"wa": lambda: paper_cells("wing_panel", "agents") | paper_cells("wing_spar", "agents"),
      "wt": lambda: {len(spec("wing_panel").tasks), len(spec("wing_spar").tasks)},
      "bm": lambda: paper_cells("bus_panel", "material"), "ba": lambda: paper_cells("bus_panel", "agents"),
      "bt": lambda: len(spec("bus_panel").tasks), "fa": lambda: paper_cells("fan", "agents"),
      "ft": lambda: len(spec("fan").tasks), "spt": lambda: set(matrix("paper").samples_per_task),
      "s0": lambda: min(matrix("paper").seeds), "s1": lambda: max(matrix("paper").seeds),
      "k": lambda: matrix("paper").heldout_every}),
    (r"tuned per track with (?P<n>\d+) Optuna trials", {"n": tuned_trials}),
    (r"enumeration up to 10\^(?P<e>\d+) layouts a position", {"e": lambda: math.log10(exact_limit())}),
    (r"proven where a position has at most 10\^(?P<e>\d+) layouts", {"e": lambda: math.log10(exact_limit())}),
    (r"\(wing panel: (?P<n>\d+) candidates an agent\)",
     {"n": lambda: get("qp").Config().max_rows // (3 * spec("wing_panel").n_agents)}),
    (r"mesh convergence \((?P<n>\w+) refinements\), deflection over thickness "
     r"against (?P<wt>[\d.]+)", {"n": lambda: len(CheckSettings().mesh_scales) - 1, "wt": lambda: LIMIT}),
    (r"share of random layouts whose Gaussian reward is (?P<lo>\d) or (?P<hi>\d), and warns where it is over half",
     {"lo": lambda: round(gaussian(np.array([1.0]), np.array([1.0]), 1e-3, 1e-3)[0], 12),
      "hi": lambda: gaussian(np.zeros(1), np.zeros(1), 1e-3, 1e-3)[0]}),
    (r"exit (?P<n>\d) \(docs/check\.md\)", {"n": lambda: 0}),
    (r"the problem, and exit code (?P<n>\d)\.", {"n": lambda: user_error_exit()}),
    (r"`fan_small`, (?P<s>\d+) seeds, (?P<n>\d+) samples\)",
     {"s": lambda: len(tiny().seeds), "n": lambda: set(tiny().budgets)}),
    (r"(?P<t>\d+) drilling positions on the rivet line, (?P<c>[\d,]+) candidates, (?P<a>\d+) agents",
     {"t": lambda: len(spec("wing_panel").tasks), "c": lambda: len(spec("wing_panel").candidates),
      "a": lambda: spec("wing_panel").n_agents}),
    (r"(?P<t>\d+) flange drillings as in-plane edge patches, (?P<c>[\d,]+) candidates",
     {"t": lambda: len(spec("wing_spar").tasks), "c": lambda: len(spec("wing_spar").candidates)}),
    (r"joint action spaces of at most 10\^(?P<e>\d+) layouts a position",
     {"e": lambda: smallest_power_above(load_problem(c).joint_size for c in case_names() if c.endswith("_small"))}),
    (r"\(the seed's fixture pairs\): (?P<a>\d+) \(small: (?P<sa>\d+)\) robots, pads (?P<lo>\d+)-(?P<hi>\d+) mm apart",
     {"a": lambda: spec("wing_panel_pairs").n_agents, "sa": lambda: spec("wing_panel_pairs_small").n_agents,
      "lo": lambda: {round(2e3 * spec(c).fixture_radius) for c in ("wing_panel_pairs", "wing_panel_pairs_small")},
      "hi": lambda: {round(1e3 * spec(c).effector.span) for c in ("wing_panel_pairs", "wing_panel_pairs_small")}}),
    (r"`wing_panel_pads_small` \| (?P<a>\d+) robots sharing (?P<m>\d+) pads",
     {"a": lambda: spec("wing_panel_pads_small").n_agents, "m": lambda: spec("wing_panel_pads_small").effector.pads}),
    (r"names the first difference \(exit (?P<n>\d)\)", {"n": lambda: user_error_exit()}),
    (r"held by (?P<n>\w+)-pad end effectors", {"n": lambda: spec("wing_panel_pairs").effector.per_agent}),
]

#: numbers that are names, not quantities: nothing to compare them with
NAMES = (r"the seed's Figure 4", r"N-2-1")


def user_error_exit() -> int:
    """The exit code of a command line that meets bad input (a CaseError)."""
    @click.command()
    def fail() -> None:
        raise CaseError("case.toml", "key", "the problem")

    return run_command(fail, [], "fixbench")


def tiny() -> Matrix:
    return load_matrix(ROOT / "results" / "tiny" / "matrix.toml")


def exact_limit() -> int:
    return get("exact").Config().max_enumeration


def same(stated: str, truth) -> bool:
    truths = truth if isinstance(truth, set) else {truth}
    return all(stated == t if isinstance(t, str) else number(stated) == float(t) for t in truths)


@pytest.mark.parametrize(("pattern", "truths"), README_FACTS, ids=[f[0][:40] for f in README_FACTS])
def test_readme_fact_is_what_the_code_gives(pattern, truths):
    found = list(re.finditer(pattern, text("README.md")))
    assert found, f"README.md no longer says /{pattern}/: update the fact"
    for m in found:
        for group, truth in truths.items():
            if m[group] is not None:
                assert same(m[group], truth()), f"README.md says {group} = {m[group]}, the code gives {truth()}"


def test_every_number_of_the_readme_is_checked():
    """Outside the tables `fixbench report --readme` writes, fenced code and code spans (commands, whose
    tests check what they print) and the citation, every number in the README (digits, or a word from two
    to twelve) lies in a checked fact: a count above, or one of README_FACTS."""
    page = text("README.md")
    skipped = [m.span() for m in re.finditer(r"<!-- table: .*?<!-- /table -->|```.*?```|`[^`]*`|## Citing.*", page)]
    checked = [m.span() for pattern in (*(f[0] for f in README_FACTS), *NAMES) for m in re.finditer(pattern, page)]
    checked += [m.span() for p, pattern, _ in CLAIMS if p == "README.md" for m in re.finditer(pattern, page)]
    words = "|".join(w for w in WORDS if WORDS[w] >= 2)
    numbers = re.finditer(rf"\d(?:[\d,.]*\d)?|\b(?:{words})\b", page, re.I)
    unchecked = [page[max(0, m.start() - 30):m.end() + 10] for m in numbers
                 if not any(a <= m.start() and m.end() <= b for a, b in skipped + checked)]
    assert not unchecked, "numbers in README.md that no test checks: " + " | ".join(unchecked)
