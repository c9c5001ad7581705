"""Bandit learners: ``surrogate-ts`` and ``gp-ucb``, on the rounds loop they share
(:mod:`fixbench.solvers.bandits.bandit`)."""
