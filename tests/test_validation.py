"""The plate FEA against analytic references (docs/plate.md; cases/analytic.py).

Each validation case of the catalog must land within 1 % of its textbook value at its default mesh;
Navier's series (exact for simply supported rectangles) must reproduce the printed coefficients and
independent single-series (Levy) forms of the same solutions; and the Morley element must converge
to Navier's value as the mesh is refined.
"""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path

import numpy as np
import pytest

from fixbench.cases.analytic import (
    flexural_rigidity,
    navier_ss_rectangle,
    reference,
    series_reference,
    validate,
    validate_spec,
    validation_names,
)
from fixbench.cases.errors import CaseError
from fixbench.cases.spec import load_case_spec, parse_case, read_toml, resolve_case

CASES = ["plate_ss_uniform", "plate_ss_point", "plate_clamped_uniform", "plate_clamped_point",
         "plate_ss_rect_uniform", "membrane_strip"]
SS_CASES = ["plate_ss_uniform", "plate_ss_point", "plate_ss_rect_uniform"]


#: the laminate, region and inclined-load cases: (case, tolerance of each of its rows)
LAMINATE_ROWS = {"ortho_ss_uniform": 0.01, "ortho_ss_point": 0.01, "ortho_membrane_strip": 0.01,
                 "angleply_plate": 0.01, "angleply_mirror": 0.01, "angleply_turned": 0.01, "stepped_strip": 0.01,
                 "plate_ss_uniform_ply": 1e-10}
ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def rows(name: str) -> tuple[dict, ...]:
    """A case's validation rows, solved once per test session."""
    return tuple(validate([name]))


def row(name: str) -> dict:
    (out,) = rows(name)
    return out


def test_catalog_has_the_six_validation_cases():
    assert set(CASES) <= set(validation_names())


@pytest.mark.parametrize("name", CASES)
def test_within_one_percent_of_the_table(name):
    r = row(name)
    assert {"name", "computed", "reference", "rel_error", "quantity"} <= set(r)
    assert r["name"] == name
    assert r["computed"] > 0 and r["reference"] > 0
    assert r["rel_error"] < 0.01, f"{name}: {r['computed']:.6g} vs {r['reference']:.6g}"


@pytest.mark.parametrize("name", sorted(LAMINATE_ROWS))
def test_laminate_and_region_rows(name):
    """Orthotropic Navier, the laminate strip, the stepped strip under an inclined load, the angle-ply
    plate against its mirror image and turned, the one-ply layup against the isotropic plate."""
    out = rows(name)
    assert out
    for r in out:
        assert r["computed"] > 0 and r["reference"] > 0
        assert r["rel_error"] < LAMINATE_ROWS[name], r


def test_the_table_in_plate_md_is_what_validate_gives():
    """docs/plate.md's validation table lists every row, each value as a fresh solve gives it here (to
    the 4-5 digits printed; errors to 5 % of themselves, and below 1e-10 where they are round-off)."""
    text = (ROOT / "docs/plate.md").read_text(encoding="utf-8")
    table = text.split("### Validation table", 1)[1].split("\n## ", 1)[0]
    doc = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 6 and re.fullmatch(r"`[^`]+`", cells[0]):
            doc[cells[0].strip("`")] = [float(c) for c in cells[3:]]
    fresh = {r["name"]: r for name in validation_names() for r in rows(name)}
    assert set(doc) == set(fresh)
    for name, (computed, expected, error) in doc.items():
        r = fresh[name]
        assert computed == pytest.approx(1e3 * r["computed"], rel=1e-4), name
        assert expected == pytest.approx(1e3 * r["reference"], rel=1e-4), name
        if error < 1e-9:
            assert r["rel_error"] < 1e-10, name
        else:
            assert error == pytest.approx(r["rel_error"], rel=0.05), name


@pytest.mark.parametrize("name", SS_CASES)
def test_simply_supported_within_half_a_percent_of_navier(name):
    r = row(name)
    assert r["series"] is not None
    assert r["series_rel_error"] < 0.005


@pytest.mark.parametrize("name", CASES)
def test_displacement_points_along_the_load(name):
    spec = load_case_spec(name)
    (ld,) = spec.tasks[0].loads
    along = ld.magnitude if ld.kind == "pressure" else ld.force[2 if spec.validations[0].quantity == "w" else 0]
    assert np.sign(row(name)["value"]) == np.sign(along)


def test_reference_uses_the_cases_own_parameters():
    spec = load_case_spec("plate_ss_uniform")
    D = 210e9 * 0.01**3 / (12 * (1 - 0.3**2))
    assert flexural_rigidity(spec) == pytest.approx(D, rel=1e-12)
    assert reference(spec) == pytest.approx(0.00406 * 10e3 * 1.0**4 / D, rel=1e-12)
    spec = load_case_spec("plate_ss_point")
    assert reference(spec) == pytest.approx(0.01160 * 1000 * 1.0**2 / D, rel=1e-12)
    spec = load_case_spec("membrane_strip")
    assert reference(spec) == pytest.approx(10e3 * 1.0 / (210e9 * 0.1 * 0.01), rel=1e-12)
    # the series only applies to simply supported rectangles
    assert series_reference(load_case_spec("plate_clamped_uniform")) is None
    assert series_reference(spec) is None


def test_reference_names_a_missing_length():
    data, source = read_toml(resolve_case("plate_ss_uniform"))
    del data["validation"]["a_mm"]
    with pytest.raises(CaseError, match="validation.a_"):
        reference(parse_case(data, source))


# ---- Navier's series -----------------------------------------------------------------------
@pytest.mark.parametrize("b, load, coefficient", [
    (1.0, "uniform", 0.00406), (1.0, "point", 0.01160), (2.0, "uniform", 0.01013)])
def test_navier_matches_the_printed_coefficients(b, load, coefficient):
    w = navier_ss_rectangle(1.0, b, 1.0, (load, 1.0), 0.5, b / 2, terms=2001)
    digits = 5  # all three are printed to 1e-5
    assert round(w, digits) == pytest.approx(coefficient, abs=1e-12)


def _levy_centre(b_over_a: float, load: str, terms: int = 20000) -> float:
    """Centre deflection of a simply supported a x b plate (a = D = q = P = 1), Levy's single series.

    Timoshenko & Woinowsky-Krieger: uniform w = 5/384 - 4/pi^5 sum_m odd (-1)^((m-1)/2) / m^5
    (alpha tanh alpha + 2) / (2 cosh alpha); central point w = 1/(2 pi^3) sum_m odd (tanh alpha -
    alpha / cosh^2 alpha) / m^3, alpha = m pi b / (2 a). An independent form of the same solution.
    """
    total = 0.0
    for m in range(1, 2 * terms, 2):
        al = m * math.pi * b_over_a / 2
        e = math.exp(-2 * al)
        sech = 2 * math.sqrt(e) / (1 + e)  # 1 / cosh(alpha), without overflow
        if load == "uniform":
            total += (-1) ** ((m - 1) // 2) / m**5 * (al * math.tanh(al) + 2) * sech / 2
        else:
            total += (math.tanh(al) - al * sech**2) / m**3
    if load == "uniform":
        return 5 / 384 - 4 / math.pi**5 * total
    return total / (2 * math.pi**3)


@pytest.mark.parametrize("b", [1.0, 2.0, 3.0])
@pytest.mark.parametrize("load", ["uniform", "point"])
def test_navier_agrees_with_levy(b, load):
    w = navier_ss_rectangle(1.0, b, 1.0, (load, 1.0), 0.5, b / 2, terms=2001)
    # the point load's double series has an O(terms^-2) tail; the uniform one converges fast
    assert w == pytest.approx(_levy_centre(b, load), rel=1e-5 if load == "point" else 1e-10)


def test_navier_scales_and_is_symmetric():
    a, b, D = 0.8, 1.3, 2.5e4
    w = navier_ss_rectangle(a, b, D, ("uniform", 7e3), 0.2, 0.4)
    assert w == pytest.approx(navier_ss_rectangle(a, b, D, ("uniform", 7e3), a - 0.2, b - 0.4))
    assert w == pytest.approx(7e3 / D * navier_ss_rectangle(a, b, 1.0, ("uniform", 1.0), 0.2, 0.4))
    # Maxwell-Betti: deflection at x under a unit load at y equals that at y under a load at x
    p, q = (0.2, 0.3), (0.6, 0.9)
    assert navier_ss_rectangle(a, b, D, ("point", 1.0, p), *q) == pytest.approx(
        navier_ss_rectangle(a, b, D, ("point", 1.0, q), *p), rel=1e-12)
    assert navier_ss_rectangle(a, b, D, ("uniform", 1.0), 0.0, 0.4) == pytest.approx(0.0, abs=1e-18)
    with pytest.raises(ValueError):
        navier_ss_rectangle(a, b, D, ("line", 1.0), 0.1, 0.1)


# ---- convergence ---------------------------------------------------------------------------
def test_morley_converges_to_navier_under_refinement():
    """Halving h cuts the error to Navier's value by about 4 (Morley: O(h^2) in deflection)."""
    spec = load_case_spec("plate_ss_uniform")
    errors = [validate_spec(spec.with_mesh_scale(f))[0]["series_rel_error"] for f in (4.0, 2.0)]
    errors.append(row("plate_ss_uniform")["series_rel_error"])  # default mesh (f = 1)
    assert errors[0] > errors[1] > errors[2]
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > 1.5), f"errors {errors}, observed orders {rates}"
    assert errors[-1] < 0.005
