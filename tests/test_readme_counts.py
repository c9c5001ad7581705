"""The counts the README and the results pages state are the ones the code and results/ give.

Every "N cells", "N cases" or "N planners" in README.md, docs/*.md or results/README.md must be one of
the claims below, each compared with what a command computes: the catalog (``case_names``), a
matrix's expansion (``load_matrix(...).cells()``) or a committed run's rows. The README's tables of
planners and catalog cases, and docs/layout.md, must name every planner, case and module.
"""

from __future__ import annotations

import fnmatch
import json
import re
from functools import cache
from pathlib import Path

import pytest

from fixbench.bench.running.matrix import Matrix, find_matrix, load_matrix
from fixbench.cases.spec import case_names
from fixbench.solvers.registry import BUILTIN

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
    """The default matrix's cells without local, optuna and the fixture pairs (docs/references.md's
    worker timings were measured on those)."""
    return sum(c.planner not in ("local", "optuna") and c.case != "wing_panel_pairs_small"
               for c in matrix("default").cells())


#: (page, pattern whose group n is the stated count, what the code gives)
CLAIMS = [
    ("README.md", r"default matrix \(`bench/matrices/default\.toml`: (?P<n>[\d,]+) cells",
     lambda: len(matrix("default").cells())),
    ("README.md", r"`bench/matrices/default\.toml`: [\d,]+ cells, (?P<n>\d+) planners",
     lambda: len({p.name for p in matrix("default").planners})),
    ("README.md", r"The catalog's (?P<n>\d+) cases", lambda: len(case_names())),
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
