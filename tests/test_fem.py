"""Plate FEA building blocks: loads keep their resultant, rigid motions are refused, units."""

from __future__ import annotations

import numpy as np
import pytest

from fixbench.cases import CaseError, load_case_spec, load_problem
from fixbench.cases.fem import PlateModel, disc_cloud
from fixbench.cases.units import Reader


def test_disc_cloud_is_a_mean():
    pts, w = disc_cloud(np.array([1.0, 2.0]), 0.01)
    assert w.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(w @ pts, [1.0, 2.0], atol=1e-15)
    assert np.linalg.norm(pts - [1.0, 2.0], axis=1).max() == pytest.approx(0.01)


def test_patch_load_keeps_its_resultant(plate_toml):
    """Shape functions sum to one, so the load vector's entries sum to the applied force."""
    model = PlateModel(load_case_spec(plate_toml()))
    f_w = model.load_vector("bending", model.spec.tasks[0].loads)
    nodal = model.fields["bending"].basis.nodal_dofs[0]
    assert f_w[nodal].sum() == pytest.approx(-100.0, rel=1e-12)
    f_m = model.load_vector("membrane", model.spec.tasks[0].loads)
    ux, uy = model.fields["membrane"].basis.split_indices()
    assert f_m[ux].sum() == pytest.approx(10.0, rel=1e-12)
    assert abs(f_m[uy].sum()) < 1e-12


def test_centrifugal_resultant():
    """Spinning about the centroid of a symmetric part: the body forces cancel."""
    model = load_problem("fan").model
    task = next(t for t in model.spec.tasks if any(ld.kind == "centrifugal" for ld in t.loads))
    f = model.load_vector("membrane", task.loads)
    ux, uy = model.fields["membrane"].basis.split_indices()
    scale = np.abs(f).sum()
    assert abs(f[ux].sum()) < 1e-6 * scale and abs(f[uy].sum()) < 1e-6 * scale


def test_supports_stop_rigid_motion(plate_toml):
    # two pins on the left edge hold w but not the rotation about that edge
    path = plate_toml(('kind = "clamped"', 'holds = ["ux", "uy", "w"]'))
    with pytest.raises(CaseError, match="free to move rigidly out of plane"):
        PlateModel(load_case_spec(path))


def test_reader_units():
    r = Reader({"length_mm": 5, "speed_rpm": 60, "E_GPa": 2}, "f.toml", "t")
    assert r.number("length", "length") == pytest.approx(5e-3)
    assert r.number("speed", "angular_speed") == pytest.approx(2 * np.pi)
    assert r.number("E", "pressure") == pytest.approx(2e9)
    r.finish()
    with pytest.raises(CaseError, match=r"t.length_ft: unknown unit 'ft'"):
        Reader({"length_ft": 5}, "f.toml", "t").number("length", "length")


def test_mesh_refines_where_asked(plate_toml):
    spec = load_case_spec(plate_toml())
    coarse = PlateModel(spec).mesh.t.shape[1]
    fine = PlateModel(spec.with_mesh_scale(0.5)).mesh.t.shape[1]
    assert 3.0 < fine / coarse < 5.0


def test_dof_count_equals_the_assembled_bases():
    """``fixbench cases`` counts DOFs from the mesh numbering alone; the same as assembling."""
    from fixbench.cases.fem import PlateModel, dof_count
    from fixbench.cases.spec import load_case_spec

    for name in ("fan_small", "wing_panel_small", "membrane_strip", "plate_ss_point"):
        spec = load_case_spec(name)
        model = PlateModel(spec)
        assert dof_count(spec, model.mesh) == sum(int(fs.basis.N) for fs in model.fields.values()), name
