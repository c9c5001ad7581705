"""Laminates, thickness regions and loads in any direction (docs/materials.md,
docs/plate.md#laminates-and-thickness-regions).

Classical lamination theory against the closed forms it must reproduce, the general (anisotropic)
stiffness against the isotropic one, regions taken element by element on a mesh that follows them,
and every validation row of the laminate and region cases within its tolerance.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import shapely

from fixbench.cases.analytic import navier_ss_rectangle, validate
from fixbench.cases.fem import PlateModel
from fixbench.cases.materials import MATERIALS, PLIES, Laminate, Layer, Ply, plane_stress
from fixbench.cases.spec import STANDARD_GRAVITY, load_case_spec, parse_case, read_toml, resolve_case


@functools.cache
def rows(name: str) -> tuple[dict, ...]:
    return tuple(validate([name]))


def jones(ply: Ply, theta: float) -> np.ndarray:
    """Q-bar written out term by term (Jones, Mechanics of Composite Materials, eq. 2.85)."""
    Q = ply.on_axis()
    Q11, Q12, Q22, Q66 = Q[0, 0], Q[0, 1], Q[1, 1], Q[2, 2]
    c, s = np.cos(theta), np.sin(theta)
    b11 = Q11 * c**4 + 2 * (Q12 + 2 * Q66) * s**2 * c**2 + Q22 * s**4
    b12 = (Q11 + Q22 - 4 * Q66) * s**2 * c**2 + Q12 * (s**4 + c**4)
    b22 = Q11 * s**4 + 2 * (Q12 + 2 * Q66) * s**2 * c**2 + Q22 * c**4
    b16 = (Q11 - Q12 - 2 * Q66) * s * c**3 + (Q12 - Q22 + 2 * Q66) * s**3 * c
    b26 = (Q11 - Q12 - 2 * Q66) * s**3 * c + (Q12 - Q22 + 2 * Q66) * s * c**3
    b66 = (Q11 + Q22 - 2 * Q12 - 2 * Q66) * s**2 * c**2 + Q66 * (s**4 + c**4)
    return np.array([[b11, b12, b16], [b12, b22, b26], [b16, b26, b66]])


@pytest.mark.parametrize("degrees", [0, 30, 45, 90, -60, 135])
def test_rotated_ply_matches_the_closed_forms(degrees):
    ply = PLIES["T300/5208"]
    theta = np.radians(degrees)
    np.testing.assert_allclose(ply.rotated(theta), jones(ply, theta), rtol=1e-12, atol=1e-12 * ply.E1)


def test_on_axis_stiffness_of_the_ply_library():
    ply = PLIES["T300/5208"]
    Q = ply.on_axis()
    nu21 = 0.28 * 10.3 / 181
    assert Q[0, 0] == pytest.approx(181e9 / (1 - 0.28 * nu21), rel=1e-14)
    assert Q[0, 1] == pytest.approx(0.28 * 10.3e9 / (1 - 0.28 * nu21), rel=1e-14)
    assert Q[2, 2] == 7.17e9


def test_an_isotropic_ply_is_isotropic_at_any_angle():
    m = MATERIALS["steel"]
    ply = Ply("iso", m.E, m.E, m.E / (2 * (1 + m.nu)), m.nu, m.density)
    for theta in np.radians([0, 17, 45, 90, 123]):
        np.testing.assert_allclose(ply.rotated(theta), plane_stress(m.E, m.nu), rtol=1e-12, atol=1e-3)


def _stack(degrees, thickness=0.125e-3, ply="T300/5208") -> Laminate:
    return Laminate("test", tuple(Layer(PLIES[ply], np.radians(a), thickness) for a in degrees))


def test_clt_of_symmetric_and_unsymmetric_stacks():
    qi = _stack([0, 45, -45, 90, 90, -45, 45, 0])
    A, B, D = qi.abd()
    assert qi.coupling() < 1e-12
    # quasi-isotropic: A is isotropic in the plane (A11 = A22, A16 = A26 = 0, A66 = (A11 - A12) / 2)
    assert A[0, 0] == pytest.approx(A[1, 1], rel=1e-12)
    assert abs(A[0, 2]) < 1e-9 * A[0, 0] and abs(A[1, 2]) < 1e-9 * A[0, 0]
    assert A[2, 2] == pytest.approx((A[0, 0] - A[0, 1]) / 2, rel=1e-12)
    # angle plies: D16, D26 are not zero, cross-plies: they are
    assert abs(D[0, 2]) > 1e-3 * D[0, 0]
    _, _, Dc = _stack([0, 90, 90, 0]).abd()
    assert abs(Dc[0, 2]) < 1e-12 * Dc[0, 0]
    # one ply of thickness t: A = Q t, D = Q t^3 / 12
    one = _stack([30], thickness=2e-3)
    A1, B1, D1 = one.abd()
    Q = PLIES["T300/5208"].rotated(np.radians(30))
    np.testing.assert_allclose(A1, Q * 2e-3, rtol=1e-12)
    np.testing.assert_allclose(D1, Q * 8e-9 / 12, rtol=1e-12)
    assert np.abs(B1).max() < 1e-12 * np.abs(A1).max() * 2e-3
    assert _stack([0, 90]).coupling() > 1e-3


def test_orthotropic_navier_reduces_to_the_isotropic_series():
    m = MATERIALS["steel"]
    D = m.E * 0.01**3 / (12 * (1 - m.nu**2))
    Dm = plane_stress(m.E, m.nu) * 0.01**3 / 12
    for load in [("uniform", 1e4), ("point", 1e3, (0.3, 0.2))]:
        a = navier_ss_rectangle(1.0, 0.6, D, load, 0.4, 0.25)
        b = navier_ss_rectangle(1.0, 0.6, Dm, load, 0.4, 0.25)
        assert b == pytest.approx(a, rel=1e-12)
    with pytest.raises(ValueError, match="D16 = D26 = 0"):
        navier_ss_rectangle(1.0, 0.6, _stack([45, -45, -45, 45]).abd()[2], ("uniform", 1.0), 0.5, 0.3)


def test_an_inclined_load_loads_both_fields():
    """The stepped strip's one edge load (F along, P down) gives both its rows, each within 1 %."""
    spec = load_case_spec("stepped_strip")
    (ld,) = spec.tasks[0].loads
    assert ld.force[0] != 0 and ld.force[2] != 0
    assert {r["quantity"] for r in rows("stepped_strip")} == {"ux", "w"}


def _max_w(name: str) -> float:
    spec = load_case_spec(name)
    model = PlateModel(spec)
    w = model.solve_direct(0, np.zeros((0, 2)))["bending"]
    return float(np.abs(model.nodal({"bending": w})["w"]).max())


def test_turned_and_mirrored_plates_have_the_same_largest_deflection():
    base = _max_w("angleply_plate")
    assert _max_w("angleply_turned") == pytest.approx(base, rel=0.01)
    assert _max_w("angleply_mirror") == pytest.approx(base, rel=0.01)


def test_mesh_follows_the_regions_and_sections_are_per_element():
    spec = load_case_spec("cfrp_wing_panel_small")
    model = PlateModel(spec)
    (region,) = spec.regions
    inside = model.section == 1
    assert 0 < inside.sum() < len(inside)
    # no element straddles the region's outline: all three corners of an element on its side
    pts = model.mesh.p[:, model.mesh.t]  # (2, 3, elements)
    grown, shrunk = region.polygon.buffer(1e-9), region.polygon.buffer(-1e-9)
    for k in range(3):
        assert shapely.covers(grown, shapely.points(pts[0, k, inside], pts[1, k, inside])).all()
        assert not shapely.contains(shrunk, shapely.points(pts[0, k, ~inside], pts[1, k, ~inside])).any()
    # the region's elements cover its area
    (ux, uy), (vx, vy) = pts[:, 1] - pts[:, 0], pts[:, 2] - pts[:, 0]
    area = np.abs(ux * vy - uy * vx) / 2
    assert area[inside].sum() == pytest.approx(region.polygon.area, rel=1e-9)


def test_weight_follows_each_regions_mass(plate_toml):
    """A weight load on a plate with a pad-up: its total is g times the plate's mass, region by region."""
    path = plate_toml(("outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]\n",
                       "outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]\n"
                       '[[regions]]\nname = "pad"\nrectangle_mm = [200, 0, 300, 200]\nthickness_mm = 9\n'),
                      ('force_N = [10, 0, -100]\nradius_mm = 8\n',
                       'force_N = [10, 0, -100]\nradius_mm = 8\n[[loads]]\nkind = "weight"\n'))
    spec = load_case_spec(path)
    model = PlateModel(spec)
    weight = next(ld for ld in spec.tasks[0].loads if ld.kind == "weight")
    F = model.load_vector("bending", (weight,))
    total = F[model.fields["bending"].basis.nodal_dofs[0]].sum()  # Morley's vertex functions sum to 1
    rho = MATERIALS["aluminium"].density
    mass = rho * (0.005 * 0.4 * 0.2 + (0.009 - 0.005) * 0.1 * 0.2)
    assert total == pytest.approx(-STANDARD_GRAVITY * mass, rel=1e-12)


def test_a_pad_up_stiffens_and_a_grade_override_keeps_it(plate_toml):
    plain = plate_toml(name="plain.toml")
    padded = plate_toml(("outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]\n",
                         "outline_mm = [[0, 0], [400, 0], [400, 200], [0, 200]]\n"
                         '[[regions]]\nname = "pad"\nrectangle_mm = [0, 0, 150, 200]\nthickness_mm = 8\n'),
                        name="padded.toml")
    w = {}
    for label, path in (("plain", plain), ("padded", padded)):
        model = PlateModel(load_case_spec(path))
        w[label] = np.abs(model.solve_direct(0, np.zeros((0, 2)))["bending"]).max()
    assert w["padded"] < 0.8 * w["plain"]
    steel = load_case_spec(padded, material="steel")
    assert steel.regions[0].material == MATERIALS["steel"] and steel.regions[0].thickness == 0.008


def test_a_laminate_case_names_its_own_layup_as_its_material():
    spec = load_case_spec("cfrp_wing_panel_small", material="cfrp_qi")
    assert spec.material.name == "cfrp_qi" and len(spec.material.layers) == 80
    assert spec.thickness == pytest.approx(0.010, rel=1e-12)
    assert spec.regions[0].thickness == pytest.approx(0.012, rel=1e-12)
    assert spec.thinnest == spec.thickness
    al = load_case_spec("cfrp_wing_panel_small", material="aluminium")  # the same part in a grade
    assert al.material == MATERIALS["aluminium"] and al.regions[0].material == MATERIALS["aluminium"]
    assert al.regions[0].thickness == spec.regions[0].thickness and al.thickness == spec.thickness


def test_the_cfrp_panel_extends_the_wing_panel():
    data, source = read_toml(resolve_case("cfrp_wing_panel"))
    spec, base = parse_case(data, source), load_case_spec("wing_panel")
    np.testing.assert_array_equal(spec.candidates, base.candidates)
    assert len(spec.tasks) == len(base.tasks) == 500
    A, D, _ = spec.material.stiffness()
    D_al = MATERIALS["aluminium"].stiffness(0.01)[1]
    assert 0.85 < D[0, 0] / D_al[0, 0] < 1.0 and 0.85 < D[1, 1] / D_al[1, 1] < 1.0
