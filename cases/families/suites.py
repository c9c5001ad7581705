"""Suites of generated parts: a TOML file naming, for each family, the seeds and how many parts
(docs/families.md#suites). The shipped suites are ``cases/suites/NAME.toml``; their generated parts
(``fixbench suite NAME``) sit beside them in ``cases/suites/NAME/``.

A suite file::

    name = "families-train"
    description = "..."
    [[parts]]
    family = "skin_panel"
    seed = 0
    count = 10
    set = { width_mm = "400:600" }   # optional: narrowed ranges, as `fixbench generate --set`

Every key is checked when the file is loaded, the families and narrowed ranges too, before any part
is drawn: a mistake is one line naming the file and the key.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from fixbench.cases.families import FAMILIES, FamilyError, family
from fixbench.cases.spec import SUITES
from fixbench.cases.units import file_reader

#: the shipped suites' folder: NAME.toml and its generated parts in NAME/
SUITE_DIR = SUITES
KEYS = ("name", "description", "parts")


@dataclass(frozen=True)
class Generation:
    """One family's parts in a suite: ``count`` parts from ``seed``, its ranges narrowed by ``overrides``."""

    family: str
    seed: int
    count: int
    overrides: dict[str, str] = field(default_factory=dict)

    @property
    def folder(self) -> str:
        return f"{self.family}_s{self.seed}"


@dataclass(frozen=True)
class Suite:
    name: str
    description: str
    generations: tuple[Generation, ...]
    source: str

    @property
    def families(self) -> list[str]:
        return list(dict.fromkeys(g.family for g in self.generations))


def shipped_suites() -> list[str]:
    return sorted(p.stem for p in SUITE_DIR.glob("*.toml"))


def find_suite(name_or_path: str | Path) -> Path:
    """A suite file: a path, or the name of a shipped suite."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.is_file():
        return p
    return SUITE_DIR / f"{p.name}.toml"


def load_suite(name_or_path: str | Path) -> Suite:
    """Read and check a suite file (see the module docstring)."""
    path = find_suite(name_or_path)
    r = file_reader(path, KEYS, f"no such suite file (shipped suites: {', '.join(shipped_suites())})")
    source = r.source
    name, description = r.text("name", path.stem), r.text("description", "")
    generations = []
    for g in r.tables("parts"):
        fam = g.text("family", choices=tuple(FAMILIES))
        seed, count = g.integer("seed"), g.integer("count", minimum=1)
        sets = g.raw("set", {}, (dict,))
        if not all(isinstance(v, str | int | float) and not isinstance(v, bool) for v in sets.values()):
            raise g.error("set", "each value is a range as text (\"A:B\"), a number, or choices as text (\"X,Y\")")
        overrides = {k: str(v) for k, v in sets.items()}
        try:
            family(fam, overrides)
        except FamilyError as exc:
            raise g.error(f"set.{exc.key.removeprefix('--set ')}", exc.problem) from None
        g.finish()
        generations.append(Generation(fam, seed, count, overrides))
    if not generations:
        raise r.error("parts", "a suite needs at least one [[parts]] table")
    folders = [g.folder for g in generations]
    if len(set(folders)) < len(folders):
        raise r.error("parts", "a family and seed appear twice: give each generation its own seed")
    r.finish()
    return Suite(name, description, tuple(generations), source)


def suite_cases(name: str) -> list[str] | None:
    """The case names of the generated parts of the shipped suite ``name`` (its ``suite.json``), or None
    where ``name`` is no shipped suite with its parts generated."""
    manifest = SUITE_DIR / name / "suite.json"
    if name not in shipped_suites() or not manifest.is_file():
        return None
    return [Path(p["file"]).stem for p in json.loads(manifest.read_text(encoding="utf-8"))["parts"]]


def expand_suites(names) -> list[str]:
    """``names`` with each shipped suite's name replaced by its parts' case names."""
    return [c for n in names for c in (suite_cases(n) or [n])]
