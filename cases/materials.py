"""Isotropic linear-elastic materials (docs/materials.md); a case may override any property."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Material:
    """An isotropic material in SI units."""

    name: str
    #: Young's modulus (Pa).
    E: float
    #: Poisson's ratio (-).
    nu: float
    #: Density (kg/m^3); drives centrifugal loads.
    density: float


#: The grades fixbench ships with (docs/materials.md).
MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        Material("aluminium", 73.1e9, 0.33, 2780.0),
        Material("steel", 210e9, 0.30, 7850.0),
        Material("titanium", 113.8e9, 0.342, 4430.0),
    )
}
