"""Shared test helpers: a small valid case file that bad-input tests break one key at a time."""

from __future__ import annotations

import json

import pytest


def strict_json_loads(text: str):
    """``json.loads`` as an RFC 8259 parser reads: ``NaN``, ``Infinity`` and ``-Infinity`` refused."""
    def refuse(token):
        raise ValueError(f"not strict JSON: {token}")

    return json.loads(text, parse_constant=refuse)

PLATE = """
[case]
description = "tiny test plate"

[material]
name = "aluminium"

[geometry]
thickness_mm = 5
outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]

[mesh]
size_mm = 40

[[supports]]
name = "left"
segment_mm = [[0, 0], [0, 200]]
kind = "clamped"

[fixtures]
radius_mm = 10
points_mm = [[100, 50], [100, 150], [200, 50], [200, 150], [300, 50], [300, 150]]

[agents]
count = 2

[[tasks]]
kind = "drilling"
line_mm = [[350, 100], [380, 100]]
count = 3
force_N = [10, 0, -100]
radius_mm = 8
"""

#: edits of PLATE that give it what the bus panel has beside edge clamps and pads, at toy size: a window
#: (a hole) whose edge is simply supported (held in w only, as the bus panel's window locators), a
#: simply supported edge (its jig rail) and a background pressure (its own weight). Tests of a property
#: that such supports or loads could break (the oracle against a direct solve, the certified bounds)
#: run on this plate instead of the full bus panel's 307k DOFs.
WINDOWED = (
    ("outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]",
     '[[geometry.shapes]]\nrectangle_mm = [0, 0, 400, 200]\n'
     '[[geometry.shapes]]\nop = "difference"\nrectangle_mm = [20, 70, 80, 130]'),
    ("[fixtures]",
     '[[supports]]\nname = "window locator"\nhole = 0\nkind = "simple"\n\n'
     '[[supports]]\nname = "top rail"\nsegment_mm = [[0, 200], [400, 200]]\nkind = "simple"\n\n'
     '[[loads]]\nkind = "pressure"\npressure_Pa = -200\n\n[fixtures]'),
)


def windowed(text: str = PLATE) -> str:
    """``text`` (PLATE or an edit of it) with the :data:`WINDOWED` edits."""
    for old, new in WINDOWED:
        assert old in text, old
        text = text.replace(old, new)
    return text


@pytest.fixture
def plate_toml(tmp_path):
    """Write PLATE, optionally edited by (old, new) replacements; returns the path."""

    def make(*edits: tuple[str, str], name: str = "plate.toml") -> str:
        text = PLATE
        for old, new in edits:
            assert old in text, old
            text = text.replace(old, new)
        path = tmp_path / name
        path.write_text(text)
        return str(path)

    return make


@pytest.fixture(autouse=True)
def _registry_left_as_found():
    """Planners a test registers (plugins written to tmp_path, ``module:Class`` specs) leave the
    registry when the test ends, so no later test in the same worker sees them. Built-ins stay: the
    registry registers each once, when it is first asked for by name (its BUILTIN line)."""
    from fixbench.solvers import registry

    before = set(registry._REGISTRY)
    yield
    for name in set(registry._REGISTRY) - before - set(registry.BUILTIN):
        del registry._REGISTRY[name]


def pytest_configure(config):
    """Tests never touch the user's oracle cache: a test session gets an empty one of its own, made by
    the process that starts the session and shared by its xdist workers (they inherit it through the
    environment, as subprocesses of CLI tests do). Entries are written atomically (cases/cache.py),
    so a part's compliance data is computed once a session, not once a worker."""
    import os
    import tempfile

    if not _is_xdist_worker():
        os.environ["FIXBENCH_CACHE_DIR"] = tempfile.mkdtemp(prefix="fixbench-test-cache-")
        # room for every part a session prepares: an entry evicted while another worker reads it
        # would be rebuilt there, not shared
        os.environ["FIXBENCH_CACHE_MAX_GB"] = "32"


def pytest_unconfigure(config):
    import os
    import shutil

    if not _is_xdist_worker():
        shutil.rmtree(os.environ.get("FIXBENCH_CACHE_DIR", ""), ignore_errors=True)


def _is_xdist_worker() -> bool:
    import os

    return "PYTEST_XDIST_WORKER" in os.environ
