"""Reward functions of the MARL literature, on max deformations in metres.

The rewards are defined in docs/protocol.md#reward-functions. The literature's dx and dz are the
maximum deformations "along x" and "along z". fixbench feeds dx = the maximum in-plane magnitude
sqrt(ux^2 + uy^2) (equal to |ux| where the in-plane response runs along x; on the spar it runs
along y and plain |ux| would miss it) and dz = max |w|.
"""

from __future__ import annotations

import numpy as np

#: The reference code's stand-in for the optimal step reward (about pi/4): its regret of an episode of
#: T steps with N agents is N T REFERENCE_OPTIMAL_REWARD - N sum(step rewards)
#: (docs/protocol.md#reference-regret).
REFERENCE_OPTIMAL_REWARD = 0.7854


def gaussian(dx: np.ndarray, dz: np.ndarray, sigma_x: float, sigma_z: float) -> np.ndarray:
    """Seed paper: exp(-dx^2 / (2 sx^2) - dz^2 / (2 sz^2)), in [0, 1]."""
    return np.exp(-(dx**2) / (2 * sigma_x**2) - dz**2 / (2 * sigma_z**2))


def bell(dx: np.ndarray, dz: np.ndarray) -> np.ndarray:
    """Reference code: (1 / (1 + x^2) + 1 / (1 + z^2)) / 2 with x, z in micrometres."""
    x, z = dx * 1e6, dz * 1e6
    return 0.5 * (1.0 / (1.0 + x**2) + 1.0 / (1.0 + z**2))
