"""The distribution: one import name, data files packaged, runs from any directory when installed."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: one xdist worker builds the wheel once for every test here (the module's fixture): two workers building
#: from the same tree at once share its build/ folder, and one deletes what the other is copying
pytestmark = pytest.mark.xdist_group("wheel")


def source_tree(dest: Path) -> Path:
    """The repository's tracked files copied to ``dest`` (the tree itself outside a git checkout): the wheel
    is built from a copy that no test running beside it writes into, with a build/ folder of its own."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z"], capture_output=True)
    if listed.returncode != 0:
        return ROOT
    for name in filter(None, listed.stdout.decode().split("\0")):
        if (ROOT / name).is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, dest / name)
    return dest


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    tree = source_tree(tmp_path_factory.mktemp("tree"))
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(out), str(tree)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    (path,) = out.glob("fixbench-*.whl")
    return path


def test_wheel_has_one_top_level_package_and_its_data(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"fixbench"}
    for needed in ("fixbench/__main__.py", "fixbench/cases/catalog/wing_panel.toml",
                   "fixbench/cases/catalog/references/wing_panel__aluminium__a5.json",
                   "fixbench/bench/matrices/default.toml", "fixbench/bench/matrices/paper.toml",
                   "fixbench/bench/cli_common.py", "fixbench/cases/suites/families-test.toml",
                   "fixbench/cases/suites/families-test/suite.json",
                   "fixbench/cases/suites/families-test/cfrp_skin_s1000/cfrp_skin_s1000_000.toml"):
        assert needed in names, needed
    # every module of the three folders, subpackages included (pyproject.toml lists the packages one by one),
    # and none the tree no longer has (a stale build/ would ship a moved module at its old path)
    tree = {f"fixbench/{folder}/{p.relative_to(ROOT / folder).as_posix()}" for folder in ("cases", "solvers", "bench")
            for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts}
    packaged = {n for n in names if n.endswith(".py") and n.split("/")[1:2] in (["cases"], ["solvers"], ["bench"])}
    assert packaged == tree, f"missing: {sorted(tree - packaged)}; not in the tree: {sorted(packaged - tree)}"
    assert not [n for n in names if "studies" in n.split("/")], "studies/ are the repository's scripts, not the package"
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    meta = next(n for n in names if n.endswith(".dist-info/METADATA"))
    text = zipfile.ZipFile(wheel).read(meta).decode()
    assert "License-Expression: MIT" in text


@pytest.mark.slow
def test_installed_wheel_runs_from_any_directory(wheel, tmp_path):
    """Installed (not editable) into a folder of its own and run from an unrelated directory: the
    catalog, references and matrices come from the package; the bare folder names do not import."""
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(wheel)],
                   check=True, capture_output=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(target), "FIXBENCH_CACHE_DIR": "off"}

    def py(*args):
        return subprocess.run([sys.executable, *args], cwd=work, env=env, capture_output=True, text=True)

    where = py("-c", "import fixbench.cases, fixbench.bench.running.matrix as m; print(fixbench.cases.__file__); "
                     "print(m.find_matrix('default'))")
    assert where.returncode == 0, where.stderr
    assert all(line.startswith(str(target)) for line in where.stdout.split()), where.stdout
    for bare in ("cases", "solvers", "bench"):
        assert py("-c", f"import {bare}").returncode != 0, bare
    cases = py("-m", "fixbench", "cases", "--json")
    assert cases.returncode == 0, cases.stderr
    assert "wing_panel" in {c["case"] for c in json.loads(cases.stdout)}
    solved = py("-m", "fixbench", "solve", "fan_small", "--planner", "greedy", "--budget", "30", "--json")
    assert solved.returncode == 0, solved.stderr
    assert json.loads(solved.stdout)["samples"] <= 30
    version = py("-m", "fixbench", "--version")
    from fixbench import __version__

    assert version.stdout.strip() == f"fixbench {__version__}"


def test_shipped_matrices_by_name_from_any_directory(tmp_path, monkeypatch):
    from fixbench.bench.running.matrix import SHIPPED, find_matrix, load_matrix
    from fixbench.cases.errors import CaseError

    monkeypatch.chdir(tmp_path)
    assert find_matrix("default") == find_matrix("default.toml") == SHIPPED / "default.toml"
    assert load_matrix("paper").name == "paper"
    (tmp_path / "default.toml").write_text('name = "mine"\ncases = ["fan_small"]\n[[planners]]\nname = "random"\n')
    assert find_matrix("default") == Path("default.toml")  # a file of the user's wins
    with pytest.raises(CaseError, match="shipped matrices: default, families, paper, sweep"):
        load_matrix("nosuch")
