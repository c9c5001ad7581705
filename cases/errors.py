"""Errors that fixbench reports to users.

Every user-facing problem is a :class:`FixbenchError` whose message is one line naming the file,
the key and the problem; the CLI prints it and exits with code 2 (no traceback).
"""

from __future__ import annotations


class FixbenchError(Exception):
    """Base class of every error that the CLI turns into one line and exit code 2."""


class CaseError(FixbenchError):
    """A case file (or an argument standing for one) is malformed.

    ``CaseError("wing.toml", "geometry.thickness_mm", "must be positive, got -1")`` reads
    ``wing.toml: geometry.thickness_mm: must be positive, got -1``.
    """

    def __init__(self, source: str, key: str, problem: str):
        self.source, self.key, self.problem = source, key, problem
        where = f"{source}: {key}" if key else source
        super().__init__(f"{where}: {problem}")


class NumericalError(FixbenchError):
    """Numerical trouble (singular stiffness, non-finite numbers): never a silent number."""


class BudgetExhausted(FixbenchError):
    """A counted evaluation would spend more samples than the evaluator's hard budget."""


class HeldOutTask(FixbenchError):
    """A planner asked the oracle about a task it must act on without samples (held-out track)."""
