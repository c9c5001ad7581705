"""``pso``: pymoo's particle swarm, a point in the plane per agent snapped to its nearest candidate; the
budget, fitness, restarts and transfer every evolutionary planner shares are
:mod:`fixbench.solvers.search.evolutionary`'s.

Encoding (:func:`~fixbench.solvers.search.pymoo_problem.plane_encoding`): mapping (a), continuous
positions in the plane. Each agent has a point ``(x, y)`` (2 variables an agent) bounded by its
set's bounding box, padded by half the median nearest-neighbour spacing of all candidates (so
border candidates get cells of the usual size and a set on a line still has a box of positive
width). A point is snapped to the agent's nearest candidate with a KD-tree per agent. Why not (b),
a continuous index rounded: the candidate order is not spatially meaningful (a grid is numbered
row by row, so index i+1 can be across the part), and a velocity in index space would jump between
rows; in the plane, neighbours in space are neighbours in the search, which is what the
deformation field is smooth in. A robot that places m pads has 2 m variables (its pads' centre
and offsets, from ``Problem.points``), snapped to its nearest action.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pymoo.algorithms.soo.nonconvex.pso import PSO
from pymoo.core.algorithm import Algorithm
from pymoo.operators.sampling.lhs import LHS

from fixbench.solvers.base import at_least, require
from fixbench.solvers.search.evolutionary import EvolutionaryPlanner, EvolutionConfig, Seeded
from fixbench.solvers.search.pymoo_problem import plane_encoding


@dataclass(frozen=True)
class PSOConfig(EvolutionConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "pop_size": ("int", 20, 400),
        "w": ("float", 0.3, 1.0),
        "c1": ("float", 0.5, 3.0),
        "c2": ("float", 0.5, 3.0),
        "soft_power": ("float", 1.0, 8.0),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    pop_size: int = 200
    """Swarm size (particles); also the layouts per counted call."""

    w: float = 0.9
    """Inertia weight (the start value when ``adaptive``)."""

    c1: float = 2.0
    """Cognitive weight: pull towards the particle's own best."""

    c2: float = 2.0
    """Social weight: pull towards the swarm's best."""

    adaptive: bool = True
    """Adapt w, c1, c2 from the swarm's spread each generation (pymoo's fuzzy rules)."""

    max_velocity_rate: float = 0.2
    """Largest step per generation as a fraction of the agent's box side."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 2, "pop_size")
        at_least(self, 0, "w", "c1", "c2")
        require(self, "max_velocity_rate", self.max_velocity_rate > 0, "positive")


class SwarmPlanner(EvolutionaryPlanner):
    name = "pso"
    description = "pymoo particle swarm, a point in the plane per agent snapped to its nearest candidate"
    Config = PSOConfig
    encoding = staticmethod(plane_encoding)

    def _algorithm(self, size: int, seeds: np.ndarray | None) -> Algorithm:
        cfg = self.config
        return PSO(pop_size=size, sampling=Seeded(LHS(), seeds), w=cfg.w, c1=cfg.c1, c2=cfg.c2,
                   adaptive=cfg.adaptive, max_velocity_rate=cfg.max_velocity_rate)
