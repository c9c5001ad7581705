"""The import structure of fixbench: no circle, and dependencies point studies -> bench -> solvers -> cases
(studies/: the repository's scripts, not installed, on top of the library).

Every ``import`` of a fixbench module counts, wherever it is written (module level, inside a
function, under ``TYPE_CHECKING``): a lazy import still ties the two modules together.
"""

from __future__ import annotations

import ast
import graphlib
import importlib
from pathlib import Path

import pytest

#: the layers, lowest first: a module may import its own layer and the ones before it; the studies
#: (folder studies/, not installed) import the library as any user code does
LAYERS = ("fixbench.cases", "fixbench.solvers", "fixbench.bench", "studies")
STUDIES = "studies"


def modules(packages: dict[str, Path]) -> dict[str, Path]:
    """Dotted name -> source file of every module of ``packages`` (name -> folder), packages included."""
    out = {}
    for pkg, folder in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [p for p in path.relative_to(folder).with_suffix("").parts if p != "__init__"]
            out[".".join([pkg, *parts])] = path
    return out


def import_graph(packages: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the modules of ``packages`` it imports (``from P import x`` is module P.x when that
    is a module, else package P)."""
    mods = modules(packages)

    def known(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for mod, path in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [f"{node.module}.{a.name}" for a in node.names]
            else:
                continue
            deps |= {m for m in map(known, names) if m not in (None, mod)}
        graph[mod] = deps
    return graph


def cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (its modules in order, the first repeated at the end), or None."""
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as exc:
        return exc.args[1]
    return None


def layer(mod: str) -> int:
    return next(i for i, pkg in enumerate(LAYERS) if mod == pkg or mod.startswith(pkg + "."))


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph({pkg: Path(importlib.import_module(pkg).__path__[0]) for pkg in LAYERS})


def test_the_graph_sees_every_kind_of_import(graph):
    """The parse finds module-level, function-level and package imports (else the checks below pass
    on an empty graph): the CLI imports its helpers at module level and the runner inside commands."""
    assert len(graph) > 60
    assert "fixbench.bench.cli_common" in graph["fixbench.bench.cli"]
    assert "fixbench.bench.running.runner" in graph["fixbench.bench.cli"]  # inside the `run` command
    assert "fixbench.solvers" in graph["studies.small_benchmark"]  # `from fixbench.solvers import get`
    assert "studies.marl" in graph["studies.gpu_check"]


def test_no_import_circle(graph):
    assert cycle(graph) is None, " -> ".join(cycle(graph))


def test_dependencies_point_bench_solvers_cases(graph):
    wrong = sorted(f"{a} imports {b}" for a, deps in graph.items() for b in deps if layer(b) > layer(a))
    assert not wrong, "; ".join(wrong)


def test_the_library_does_not_import_the_studies_nor_the_cli(graph):
    """The studies (not installed) and the ``fixbench`` command sit on top: nothing in the library
    imports them."""
    wrong = sorted(f"{a} imports {b}" for a, deps in graph.items() for b in deps
                   if (b.startswith(STUDIES) and not a.startswith(STUDIES)) or b == "fixbench.bench.cli")
    assert not wrong, "; ".join(wrong)


def test_cli_common_is_a_leaf_of_the_harness(graph):
    assert not {m for m in graph["fixbench.bench.cli_common"] if layer(m) == 2}


#: the harness's rooms, lowest first: a room imports its own and the ones before it; the modules at
#: the top of ``fixbench.bench`` (the commands: cli, check, verify, tune; the BenchMARL task) may use all
ROOMS = ("fixbench.bench.records", "fixbench.bench.references", "fixbench.bench.running", "fixbench.bench.reporting",
         "fixbench.bench.analysis")


def room(mod: str) -> int | None:
    return next((i for i, r in enumerate(ROOMS) if mod == r or mod.startswith(r + ".")), None)


def test_the_harness_rooms_point_one_way(graph):
    """records <- references <- running <- reporting <- analysis, and no room imports a module at the top
    of the harness."""
    bench = {a: deps for a, deps in graph.items() if a.startswith("fixbench.bench.")}
    wrong = sorted(f"{a} imports {b}" for a, deps in bench.items() if room(a) is not None
                   for b in deps if b.startswith("fixbench.bench") and (room(b) is None or room(b) > room(a)))
    assert not wrong, "; ".join(wrong)
    assert {room(m) for m in bench} == {None, *range(len(ROOMS))}  # every room has modules (else the check is empty)


def test_a_circle_and_a_lazy_wrong_way_import_are_found(tmp_path):
    """The checks fail on what they are meant to catch: a circle closed by an import inside a function
    under TYPE_CHECKING, and a cases module importing bench inside a function."""
    for folder, files in {"bench": {"a.py": "from fixbench.bench import b\n",
                                    "b.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                            "    from fixbench.bench.a import x\n"},
                          "cases": {"__init__.py": "", "c.py": "def f():\n    import fixbench.bench.a\n"}}.items():
        (tmp_path / folder).mkdir()
        for name, text in files.items():
            (tmp_path / folder / name).write_text(text)
    g = import_graph({"fixbench.cases": tmp_path / "cases", "fixbench.bench": tmp_path / "bench"})
    assert set(cycle(g)) == {"fixbench.bench.a", "fixbench.bench.b"}
    assert g["fixbench.cases.c"] == {"fixbench.bench.a"} and layer("fixbench.bench.a") > layer("fixbench.cases.c")
