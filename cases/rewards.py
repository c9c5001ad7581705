"""Reward functions of the MARL literature, on max deformations in metres.

The rewards are defined in docs/protocol.md#reward-functions. The literature's dx and dz are the
maximum deformations "along x" and "along z". fixbench feeds dx = the maximum in-plane magnitude
sqrt(ux^2 + uy^2) (equal to |ux| where the in-plane response runs along x; on the spar it runs
along y and plain |ux| would miss it) and dz = max |w|.
"""

from __future__ import annotations

import math

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


class LogScale:
    """The learners' scaled reward (docs/protocol.md#scaled-reward): the standardised log deformation

        r = (mu - ln u) / sd,

    with mu and sd the mean and standard deviation of ln u over the run's first ``n`` samples (the
    learner's own, counted; at the start of a run nearly every agent explores, so they are close to
    uniform random layouts), frozen after them. Before then, the statistics of the samples so far.
    One rule for every part: a layout as good as a typical random one earns 0, one standard deviation
    better earns 1, whatever the part's scale (um or mm), and no width is set by hand. The mean and
    variance are accumulated by Welford's update (one pass, no array kept)."""

    def __init__(self, n: int):
        if n < 2:
            raise ValueError(f"scale_samples must be at least 2, got {n}")
        self.n, self.count, self.mean, self._m2 = n, 0, 0.0, 0.0

    def add(self, log_u: float) -> None:
        """Take one sample's ln u into the statistics (ignored once frozen)."""
        if self.count >= self.n:
            return
        self.count += 1
        d = log_u - self.mean
        self.mean += d / self.count
        self._m2 += d * (log_u - self.mean)

    @property
    def sd(self) -> float:
        """The spread (1 until two distinct samples exist, so that the reward is always defined)."""
        var = self._m2 / (self.count - 1) if self.count > 1 else 0.0
        return math.sqrt(var) if var > 0 else 1.0

    def reward(self, log_u):
        """The scaled reward of ln u (a float, an array or a tensor)."""
        return (self.mean - log_u) / self.sd


def degenerate_share(reward: np.ndarray, low: float = 1e-3, high: float = 0.999) -> float:
    """Share of rewards in [0, 1] that carry no signal: below ``low`` or above ``high``."""
    r = np.asarray(reward, dtype=float)
    return float(np.mean((r < low) | (r > high))) if r.size else 0.0
