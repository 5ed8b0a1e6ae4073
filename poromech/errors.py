"""Errors that end a run with a clear message and a specific exit status."""

from __future__ import annotations

__all__ = ["ConfigError", "OutputError", "SolverError"]


class ConfigError(ValueError):
    """An invalid scene or scene input; the message is a single line naming the key."""


class OutputError(RuntimeError):
    """An output file could not be written (disk full, quota, permissions); one-line message.

    The files of the steps completed before it stay readable (see :mod:`poromech.io.xdmf`).
    """


class SolverError(RuntimeError):
    """A solver that did not converge.

    Attributes:
        reason: PETSc converged reason (name).
        history: Residual norms, one per iteration.
        record: Optional JSON-ready details of the failed solve.
    """

    def __init__(self, message: str, reason: str = "", history=(), record: dict | None = None):
        super().__init__(message)
        self.reason = reason
        self.history = list(history)
        self.record = record or {}
