"""The on-disk oracle cache: same numbers as without it, a new key for every change, damage rebuilt."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixbench.bench.cli import main
from fixbench.cases import cache, problem
from fixbench.cases.problem import load_problem


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("FIXBENCH_CACHE_DIR", str(d))
    monkeypatch.setattr(problem, "_ORACLES", type(problem._ORACLES)())  # no in-process oracle either
    return d


def _fresh(path, **kw):
    problem._ORACLES.clear()
    return load_problem(path, **kw)


def _layouts(p, k=6):
    rng = np.random.default_rng(0)
    return np.column_stack([rng.choice(s, k) for s in p.action_sets])


def test_second_process_opens_the_cache_with_identical_results(plate_toml, cache_dir, monkeypatch):
    path = plate_toml()
    p = _fresh(path)
    assert not p.oracle.from_cache and p.oracle.prepare() and p.oracle.complete
    assert len(cache.entries()) == 1
    built = [p.oracle.evaluate(t, _layouts(p)) for t in range(p.n_tasks)]
    q = _fresh(path)
    assert q.oracle.from_cache and q.oracle.complete
    assert all(fo.lu is None for fo in q.oracle.fields.values())  # nothing factorised or solved
    cached = [q.oracle.evaluate(t, _layouts(q)) for t in range(q.n_tasks)]
    monkeypatch.setenv("FIXBENCH_CACHE_DIR", "off")
    r = _fresh(path)  # lazy, no cache: columns as layouts use them
    assert not r.oracle.from_cache and not r.oracle.complete
    lazy = [r.oracle.evaluate(t, _layouts(r)) for t in range(r.n_tasks)]
    for a, b, c in zip(built, cached, lazy):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    d = q.direct_deformation(1, _layouts(q)[:1])
    assert abs(cached[1][0, 3] - d.max_u[0]) <= 1e-9 * d.max_u[0]


@pytest.mark.parametrize("edit", [
    ("size_mm = 40", "size_mm = 35"),  # mesh
    ("[300, 50], [300, 150]]", "[300, 50], [310, 150]]"),  # candidates
    ('name = "aluminium"', 'name = "steel"'),  # material
    ("force_N = [10, 0, -100]", "force_N = [10, 0, -90]"),  # loads
])
def test_any_change_of_the_model_gets_a_new_entry(plate_toml, cache_dir, edit):
    p = _fresh(plate_toml())
    p.oracle.prepare()
    q = _fresh(plate_toml(edit, name="edited.toml"))
    assert not q.oracle.from_cache
    q.oracle.prepare()
    assert len(cache.entries()) == 2


def test_a_damaged_entry_is_rebuilt_not_trusted(plate_toml, cache_dir, capsys):
    path = plate_toml()
    p = _fresh(path)
    p.oracle.prepare()
    good = p.oracle.evaluate(0, _layouts(p))
    (entry,) = cache.entries()
    f = next(f for f in sorted((cache_dir / entry["key"]).glob("*.C.npy")))
    raw = bytearray(f.read_bytes())
    raw[-8:] = np.float64(1e30).tobytes()  # one wrong number, header intact
    f.write_bytes(bytes(raw))
    q = _fresh(path)
    assert not q.oracle.from_cache
    assert "damaged" in capsys.readouterr().err
    assert q.oracle.prepare()
    np.testing.assert_array_equal(q.oracle.evaluate(0, _layouts(q)), good)
    assert _fresh(path).oracle.from_cache  # rebuilt entry is good


def test_eviction_keeps_the_cache_under_its_limit(plate_toml, cache_dir, monkeypatch):
    p = _fresh(plate_toml())
    p.oracle.prepare()
    size = cache.entries()[0]["bytes"]
    monkeypatch.setenv("FIXBENCH_CACHE_MAX_GB", str(1.5 * size / 2**30))  # room for one entry
    q = _fresh(plate_toml(("size_mm = 40", "size_mm = 38"), name="other.toml"))
    q.oracle.prepare()
    es = cache.entries()
    assert len(es) == 1 and es[0]["key"] == q.oracle.cache_key


def test_an_unwritable_cache_costs_only_the_cache(plate_toml, tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("FIXBENCH_CACHE_DIR", str(blocker / "cache"))
    p = _fresh(plate_toml())
    assert p.oracle.prepare()  # computed, not stored
    assert "cannot store" in capsys.readouterr().err
    assert np.isfinite(p.oracle.evaluate(0, _layouts(p))[:, :5]).all()


def test_cli_cache_info_and_clear(plate_toml, cache_dir, capsys):
    _fresh(plate_toml()).oracle.prepare()
    assert main(["cache", "info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["root"] == str(cache_dir) and len(info["entries"]) == 1
    assert "plate" in info["entries"][0]["description"]
    assert main(["cache", "clear"]) == 0
    assert "removed 1 entries" in capsys.readouterr().out
    assert cache.entries() == []


def test_no_disk_cache_unless_named(monkeypatch):
    monkeypatch.delenv("FIXBENCH_CACHE_DIR", raising=False)
    assert cache.root() is None
    monkeypatch.setenv("FIXBENCH_CACHE_DIR", "off")
    assert cache.root() is None


def test_a_run_keeps_its_cache_in_its_run_directory(tmp_path, monkeypatch, capsys):
    """Nothing is written outside the run directory: the workers' cache is OUT/oracle-cache, and
    neither the home directory nor the working directory gains a file."""
    from fixbench.bench.running.runner import run_matrix

    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    monkeypatch.delenv("FIXBENCH_CACHE_DIR", raising=False)
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("XDG_CACHE_HOME", str(home / ".cache"))
    monkeypatch.chdir(work)
    m = work / "m.toml"
    m.write_text('name = "c"\ncases = ["fan_small"]\nplanners = ["random"]\nseeds = [0]\nbudget = 20\ntasks = 1\n')
    out = tmp_path / "run"
    summary = run_matrix(m, out, workers=1, progress=False)
    assert summary["run"] == 1
    (entry,) = cache.entries(out / "oracle-cache")
    assert "fan_small" in entry["description"]
    assert not any(home.rglob("*")) and [p.name for p in work.iterdir()] == ["m.toml"]
    assert main(["cache", "info", "--dir", str(out / "oracle-cache"), "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["entries"]) == 1
