"""The documentation is self-contained and its citations resolve.

- every ``docs/<name>.md`` or ``docs/<name>.md#<anchor>`` named in a tracked text file exists, and the
  anchor is the GitHub slug of a heading in that file (so does every relative link between docs/ pages);
- no tracked file cites a document outside the repository (the former external reference notes);
- docs/rows.md lists the same row fields, with the same meanings, as ``ROW_SCHEMA``;
- ``CITATION.cff`` parses and carries the package's version.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

import fixbench
from fixbench.bench.records.rows import ROW_SCHEMA

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TEXT_SUFFIXES = (".py", ".md", ".toml", ".cff")
#: a citation of a docs page, optionally with an anchor; not part of a longer path (``foo/docs/x.md``)
CITATION = re.compile(r"(?<![\w./-])docs/([A-Za-z0-9_.-]+\.md)(?:#([A-Za-z0-9_-]+))?")
#: a relative Markdown link to a page, optionally with an anchor: ``](plate.md#point-loads)``, ``](#x)``
LINK = re.compile(r"\]\((?!\w+://)([A-Za-z0-9_./-]*\.md)?(?:#([A-Za-z0-9_-]+))?\)")
#: what a file outside results/ must not mention (this file excepted)
FORBIDDEN = ("REFERENCE section", "REFERENCE.md", "../shared")


def tracked() -> list[str]:
    """Paths of the tracked files (relative to the repository root) that exist in the working tree."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [p for p in out.decode().split("\0") if p and (ROOT / p).is_file()]


def text_files() -> list[str]:
    """Tracked text files to search for citations: results/ run data left out, results/README.md kept."""
    return [p for p in tracked() if p.endswith(TEXT_SUFFIXES)
            and (not p.startswith("results/") or p == "results/README.md")]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: link text kept, lower case, punctuation removed, spaces -> '-'."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip())
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Anchors of every heading of a Markdown file (fenced code skipped; repeats get -1, -2, ...)."""
    seen: dict[str, int] = {}
    out = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
            continue
        m = None if fenced else re.match(r"^ {0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            s = slug(m.group(1))
            n = seen.get(s, 0)
            seen[s] = n + 1
            out.add(s if n == 0 else f"{s}-{n}")
    return out


def test_slug_follows_github():
    assert slug("Analytic references") == "analytic-references"
    assert slug("Flat shell: membrane plus bending") == "flat-shell-membrane-plus-bending"
    assert slug("Wing panel: fixbench's choices") == "wing-panel-fixbenchs-choices"
    assert slug("The `.info` file") == "the-info-file"
    assert slug("See [plate.md](plate.md) first") == "see-platemd-first"


def test_docs_index_lists_every_page():
    index = (DOCS / "README.md").read_text(encoding="utf-8")
    pages = sorted(p.name for p in DOCS.glob("*.md") if p.name != "README.md")
    assert pages, "docs/ has no pages"
    missing = [p for p in pages if f"]({p})" not in index]
    assert not missing, f"docs/README.md does not list {missing}"


def test_every_docs_citation_resolves():
    """(a) Each docs/ page or page#anchor named anywhere in the tracked text exists."""
    cache: dict[Path, set[str]] = {}
    bad = []

    def check(where: str, target: Path, anchor: str | None, shown: str) -> None:
        if not target.is_file():
            bad.append(f"{where}: {shown}: no such file")
        elif anchor:
            if target not in cache:
                cache[target] = anchors(target)
            if anchor not in cache[target]:
                bad.append(f"{where}: {shown}: no heading with anchor #{anchor} in {target.relative_to(ROOT)}")

    n = 0
    for rel in text_files():
        lines = (ROOT / rel).read_text(encoding="utf-8", errors="replace").splitlines()
        for i, line in enumerate(lines, 1):
            for m in CITATION.finditer(line):
                n += 1
                check(f"{rel}:{i}", DOCS / m.group(1), m.group(2), m.group(0))
            if rel.startswith("docs/") and rel.endswith(".md"):  # links between docs pages
                for m in LINK.finditer(line):
                    page, anchor = m.group(1), m.group(2)
                    target = (ROOT / rel).parent / page if page else ROOT / rel
                    if page and not (target.resolve().is_relative_to(DOCS)):
                        continue  # a link out of docs/ (e.g. to the repository root) is not a docs page
                    n += 1
                    check(f"{rel}:{i}", target.resolve(), anchor, m.group(0)[2:-1])
    assert n > 0, "no docs/ citation found at all"
    assert not bad, "unresolved docs citations:\n" + "\n".join(bad)


def test_no_citation_outside_the_repository():
    """(b) No tracked file outside results/ cites the former external reference notes."""
    me = Path(__file__).resolve().relative_to(ROOT).as_posix()
    bad = []
    for rel in tracked():
        if rel.startswith("results/") or rel == me:
            continue
        text = (ROOT / rel).read_bytes().decode("utf-8", errors="replace")
        for i, line in enumerate(text.splitlines(), 1):
            for word in FORBIDDEN:
                if word in line:
                    bad.append(f"{rel}:{i}: {line.strip()[:160]}")
                    break
    assert not bad, (f"{len(bad)} line(s) mention {' / '.join(FORBIDDEN)}; cite a docs/ page instead "
                     "(docs/README.md lists them):\n" + "\n".join(bad))


def documented_row_fields() -> list[tuple[str, str]]:
    """(name, meaning) of each bullet ``- `name`: meaning`` of docs/rows.md."""
    text = (DOCS / "rows.md").read_text(encoding="utf-8")
    fields = []
    for item in re.split(r"\n(?=- `)", text):
        b = re.match(r"- `([a-z0-9_]+)`: (.*)", item, re.S)
        if b:
            meaning = b.group(2).split("\n\n")[0]  # a bullet ends at a blank line
            fields.append((b.group(1), " ".join(meaning.split())))
    return fields


def test_documented_row_schema_matches_code():
    documented = documented_row_fields()
    names = [n for n, _ in documented]
    code = list(ROW_SCHEMA)
    assert names == code, (
        "docs/rows.md and bench/records/rows.py ROW_SCHEMA list different row fields"
        f"\n  only in docs/rows.md: {[n for n in names if n not in code]}"
        f"\n  only in ROW_SCHEMA: {[n for n in code if n not in names]}"
        f"\n  order: docs  {names}\n         code   {code}")
    differ = [f"{n}: docs/rows.md {m!r} vs code {ROW_SCHEMA[n]!r}"
              for n, m in documented if m != " ".join(ROW_SCHEMA[n].split())]
    assert not differ, "row field meanings differ:\n" + "\n".join(differ)


def test_citation_cff():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    assert cff["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors", "license"):
        assert cff.get(key), key
    assert str(cff["version"]) == fixbench.__version__
    assert cff["license"] == "MIT"
    dois = {r.get("doi") for r in cff["references"]}
    assert {"10.1109/TASE.2024.3424677", "10.38124/ijisrt/25apr1710"} <= dois
    for ref in cff["references"]:
        assert ref["type"] and ref["title"] and ref["authors"], ref
