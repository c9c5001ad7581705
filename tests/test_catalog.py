"""The catalog: reference geometry counts, sizes of the small variants. Each full part's mesh
convergence (at its shipped reference's worst task) is a line of `fixbench validate` (cases/part_checks.py)."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import case_names, load_problem

PARTS = ["wing_panel", "wing_spar", "bus_panel", "fan"]


def test_every_catalog_case_loads():
    names = case_names()
    for part in PARTS:
        assert part in names and f"{part}_small" in names
    for name in names:
        p = load_problem(name)
        assert p.n_tasks >= 1 and len(p.candidates) >= p.n_agents
        sets = np.concatenate(p.action_sets)
        assert len(sets) == len(np.unique(sets)), "agents' sets must be disjoint"


def test_reference_geometry():
    """docs/geometry.md: 3,333 wing-panel candidates, 10,000 on the spar web, 500 drillings."""
    wing, spar = load_problem("wing_panel"), load_problem("wing_spar")
    assert len(wing.candidates) == 3333 and wing.n_tasks == 500
    assert len(spar.candidates) == 10000 and spar.n_tasks == 500
    drill = np.array([t.loads[0].at for t in wing.tasks]) * 1e3
    np.testing.assert_allclose(drill[:, 1], -5.6689 * drill[:, 0] + 3351.3, atol=1e-3)
    np.testing.assert_allclose(drill[[0, -1], 0], [420.0, 580.0])


@pytest.mark.parametrize("part", PARTS)
def test_small_variants_are_enumerable(part):
    small = load_problem(f"{part}_small")
    assert small.joint_size <= 10**7
    assert small.spec.part == load_problem(part).spec.part
