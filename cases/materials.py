"""Materials (docs/materials.md): isotropic grades, and laminates built from a ply library.

A plate's stiffness is what the FE model needs of its material: the membrane stiffness A (N/m) and
the bending stiffness D (N m), 3 x 3 matrices in Voigt order (xx, yy, xy with engineering shear),
and the mass per unit area for body forces. An isotropic material of thickness t gives
A = Q t and D = Q t^3 / 12 with Q its plane-stress stiffness. A laminate gives them by classical
lamination theory (:meth:`Laminate.abd`).

Classical lamination theory is written out here (thirty lines of textbook algebra: Jones, Mechanics
of Composite Materials, ch. 2 and 4; Daniel & Ishai, ch. 7) because no well-kept Python library
provides it: the CLT packages on PyPI are small single-author projects, and fixbench needs only A,
B and D of a ply stack.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def plane_stress(E: float, nu: float) -> np.ndarray:
    """The isotropic plane-stress stiffness Q (Pa), Voigt order with engineering shear strain."""
    c = E / (1.0 - nu**2)
    return np.array([[c, c * nu, 0.0], [c * nu, c, 0.0], [0.0, 0.0, E / (2.0 * (1.0 + nu))]])


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

    def stiffness(self, thickness: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(A, D, mass per area) of a plate of this material and ``thickness``."""
        Q = plane_stress(self.E, self.nu)
        return Q * thickness, Q * thickness**3 / 12.0, self.density * thickness


@dataclass(frozen=True)
class Ply:
    """A unidirectional ply material: E1 along the fibres, E2 across, in-plane shear G12, major
    Poisson's ratio nu12 (strain across over strain along, loaded along), density."""

    name: str
    E1: float
    E2: float
    G12: float
    nu12: float
    density: float

    def on_axis(self) -> np.ndarray:
        """Reduced stiffness Q in the ply's own axes (plane stress; nu21 = nu12 E2 / E1)."""
        nu21 = self.nu12 * self.E2 / self.E1
        d = 1.0 - self.nu12 * nu21
        return np.array([[self.E1 / d, self.nu12 * self.E2 / d, 0.0],
                         [self.nu12 * self.E2 / d, self.E2 / d, 0.0],
                         [0.0, 0.0, self.G12]])

    def rotated(self, angle: float) -> np.ndarray:
        """Q-bar: the reduced stiffness of the ply laid at ``angle`` (rad, from x towards y).

        Q-bar = T^-1 Q R T R^-1 (Jones, ch. 2), T the stress transformation for c = cos, s = sin and
        R = diag(1, 1, 2) (Reuter's matrix, for engineering shear strain).
        """
        c, s = np.cos(angle), np.sin(angle)
        T = np.array([[c * c, s * s, 2 * s * c], [s * s, c * c, -2 * s * c], [-s * c, s * c, c * c - s * s]])
        R = np.diag([1.0, 1.0, 2.0])
        return np.linalg.inv(T) @ self.on_axis() @ R @ T @ np.linalg.inv(R)


@dataclass(frozen=True)
class Layer:
    """One ply of a stack: its material, angle (rad) and thickness (m)."""

    ply: Ply
    angle: float
    thickness: float


#: |B| below this fraction of |A| t (the stiffness scale of B) counts as B = 0: a symmetric layup
SYMMETRY_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Laminate:
    """A stack of plies, listed from the bottom face (z = -t/2) to the top (z = +t/2)."""

    name: str
    layers: tuple[Layer, ...]

    @property
    def thickness(self) -> float:
        return float(sum(layer.thickness for layer in self.layers))

    @property
    def density(self) -> float:
        """Mean density (kg/m^3): mass per area over thickness."""
        return float(sum(layer.ply.density * layer.thickness for layer in self.layers)) / self.thickness

    def abd(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A = sum Q-bar_k (z_k - z_k-1), B = sum Q-bar_k (z_k^2 - z_k-1^2) / 2,
        D = sum Q-bar_k (z_k^3 - z_k-1^3) / 3, z measured from the mid-plane."""
        z = np.concatenate([[0.0], np.cumsum([layer.thickness for layer in self.layers])]) - self.thickness / 2
        A, B, D = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
        for k, layer in enumerate(self.layers):
            Q = layer.ply.rotated(layer.angle)
            A += Q * (z[k + 1] - z[k])
            B += Q * (z[k + 1] ** 2 - z[k] ** 2) / 2.0
            D += Q * (z[k + 1] ** 3 - z[k] ** 3) / 3.0
        return A, B, D

    def coupling(self) -> float:
        """|B| relative to its scale |A| t: 0 for a symmetric layup (membrane and bending apart)."""
        A, B, _ = self.abd()
        return float(np.abs(B).max() / (np.abs(A).max() * self.thickness))

    def stiffness(self, thickness: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(A, D, mass per area); a laminate's thickness is its plies' (``thickness`` is ignored)."""
        A, _, D = self.abd()
        return A, D, self.density * self.thickness


def engineering_constants(material: Material | Laminate) -> tuple[float, float, float]:
    """(E, nu, density): a grade's own; a laminate's in-plane modulus E_x = 1 / (t a11) and Poisson's
    ratio nu_xy = -a12 / a11 (a = A^-1), the moduli a test of the laminate along x would measure."""
    if isinstance(material, Material):
        return material.E, material.nu, material.density
    a = np.linalg.inv(material.abd()[0])
    return float(1.0 / (material.thickness * a[0, 0])), float(-a[0, 1] / a[0, 0]), material.density


#: The isotropic grades fixbench ships with (docs/materials.md).
MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        Material("aluminium", 73.1e9, 0.33, 2780.0),
        Material("steel", 210e9, 0.30, 7850.0),
        Material("titanium", 113.8e9, 0.342, 4430.0),
    )
}

#: The ply materials a laminate may use (docs/materials.md#ply-materials, with their sources).
PLIES: dict[str, Ply] = {
    p.name: p
    for p in (
        Ply("T300/5208", 181e9, 10.3e9, 7.17e9, 0.28, 1600.0),
        Ply("AS4/3501-6", 147e9, 10.3e9, 7.0e9, 0.27, 1580.0),
    )
}
