"""``ga``: pymoo's genetic algorithm, one integer gene per agent; the budget, fitness, restarts and transfer
every evolutionary planner shares are :mod:`fixbench.solvers.search.evolutionary`'s.

Encoding (:func:`~fixbench.solvers.search.pymoo_problem.integer_encoding`): one integer gene per agent, the
position in that agent's own action set (``0..len(set)-1``); integer random sampling, SBX
crossover and polynomial mutation with rounding repair (pymoo's recipe for integer variables),
duplicates eliminated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pymoo.algorithms.soo.nonconvex.ga import GA
from pymoo.core.algorithm import Algorithm
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.pm import PM
from pymoo.operators.repair.rounding import RoundingRepair
from pymoo.operators.sampling.rnd import IntegerRandomSampling

from fixbench.solvers.base import at_least, require
from fixbench.solvers.search.evolutionary import EvolutionaryPlanner, EvolutionConfig, Seeded
from fixbench.solvers.search.pymoo_problem import integer_encoding


@dataclass(frozen=True)
class GAConfig(EvolutionConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "pop_size": ("int", 20, 400),
        "crossover_eta": ("log", 1.0, 20.0),
        "mutation_eta": ("log", 1.0, 20.0),
        "soft_power": ("float", 1.0, 8.0),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    pop_size: int = 200
    """Population size; also the offspring per generation (layouts per counted call)."""

    crossover_prob: float = 0.9
    """Probability that a mating pair is recombined by SBX (else the parents are copied)."""

    crossover_eta: float = 3.0
    """SBX distribution index: small spreads children far from their parents."""

    mutation_eta: float = 3.0
    """Polynomial-mutation distribution index: small makes large jumps in a gene."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 2, "pop_size")
        require(self, "crossover_prob", 0 <= self.crossover_prob <= 1, "in [0, 1]")
        require(self, "crossover_eta", self.crossover_eta > 0, "positive")
        require(self, "mutation_eta", self.mutation_eta > 0, "positive")


class GeneticPlanner(EvolutionaryPlanner):
    name = "ga"
    description = "pymoo genetic algorithm, one integer gene per agent (index into its set)"
    Config = GAConfig
    encoding = staticmethod(integer_encoding)

    def _algorithm(self, size: int, seeds: np.ndarray | None) -> Algorithm:
        cfg = self.config
        return GA(pop_size=size, sampling=Seeded(IntegerRandomSampling(), seeds),
                  crossover=SBX(prob=cfg.crossover_prob, eta=cfg.crossover_eta, vtype=float,
                                repair=RoundingRepair()),
                  mutation=PM(eta=cfg.mutation_eta, vtype=float, repair=RoundingRepair()),
                  eliminate_duplicates=True)
