"""Exceptions raised by taichi_hh.  Every message names the problem."""
from __future__ import annotations


class TaichiHHError(Exception):
    """Base class of this package's errors."""


class InputError(TaichiHHError, ValueError):
    """Bad input data: NaN/inf, wrong shape, empty, duplicates, outside the domain."""


class NeighbourError(TaichiHHError, ValueError):
    """A particle has too few neighbours for the requested operator
    (e.g. a singular correction matrix)."""


class SolverError(TaichiHHError, RuntimeError):
    """An iterative solve failed: breakdown, stagnation, divergence, non-finite
    values or the iteration cap.  Carries ``reason``, ``iteration``, ``residual``."""

    def __init__(self, message: str, *, reason: str, iteration: int, residual: float):
        super().__init__(message)
        self.reason = reason
        self.iteration = iteration
        self.residual = residual


class AccuracyWarning(UserWarning):
    """A result was computed but fails a consistency check that an accurate one
    passes (e.g. a decomposition whose components carry far more energy than the
    field): the operators are not consistent on these points.  The result's
    ``stats["flags"]`` lists the same findings."""


class BlowUp(TaichiHHError, RuntimeError):
    """The simulation cannot go on (a :class:`TaichiHHError`: ``except
    TaichiHHError`` catches it with the rest).  ``cause``: ``"non-finite"`` (NaN/inf
    values), ``"left-box"`` (particles outside the domain), ``"solver"`` (a
    solver broke down) or ``"time-step"`` (time did not advance)."""

    CAUSES = ("non-finite", "left-box", "solver", "time-step")

    def __init__(self, message: str, *, cause: str = "solver"):
        if cause not in self.CAUSES:
            raise ValueError(f"cause must be one of {self.CAUSES}, got {cause!r}")
        super().__init__(message)
        self.cause = cause
