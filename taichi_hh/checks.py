"""Input validation shared by every layer: point arrays, per-point values, real
parameters, random seeds, and the argparse value types of the command lines.

Every check either returns the value in canonical form (float64 arrays, a
float, a numpy Generator) or raises :class:`~taichi_hh.errors.InputError`
(``argparse.ArgumentTypeError`` for the argparse types) with a message that
names the argument and the problem.  This module sits at the bottom of the
package next to :mod:`taichi_hh.errors`: it imports nothing else from it.
"""
from __future__ import annotations

import argparse
import math
from numbers import Integral, Real

import numpy as np

from .errors import InputError

__all__ = ["check_points", "check_values", "check_real", "check_seed",
           "positive_float", "nonnegative_float", "positive_int", "nonnegative_int"]


# --------------------------------------------------------------------------- arrays
def check_points(points, name: str = "points", *, allow_empty: bool = False) -> np.ndarray:
    """Validate an (N, 2) array of finite coordinates; returns it as float64.

    ``allow_empty``: accept N = 0 (queries on no points); by default an empty
    array is refused, since a point set needs at least one point."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric (N, 2) array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must have shape (N, 2), got {arr.shape}")
    if arr.shape[0] == 0 and not allow_empty:
        raise InputError(f"{name} is empty: at least one point is needed")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise InputError(f"{name} contains {idx.size} non-finite (NaN or inf) entries, "
                         f"first at index {idx[0]}: {arr[idx[0]].tolist()}")
    return arr


def check_values(values, n: int, ncomp: int, name: str = "values") -> np.ndarray:
    """Validate per-point values: shape (n,) for ncomp = 1 or (n, ncomp); finite."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric: {exc}") from None
    want = (n,) if ncomp == 1 else (n, ncomp)
    if arr.shape != want:
        raise InputError(f"{name} must have shape {want} (one per point), got {arr.shape}")
    bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise InputError(f"{name} contains {idx.size} non-finite (NaN or inf) entries, "
                         f"first at point {idx[0]}")
    return arr


# --------------------------------------------------------------------------- scalars
def check_real(value, name: str, *, positive: bool = True, allow_zero: bool = False) -> float:
    """A finite real number (not a bool) as float; ``positive``: also > 0
    (>= 0 with ``allow_zero``)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise InputError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name} must be finite, got {v}")
    if positive and (v < 0 or (v == 0 and not allow_zero)):
        raise InputError(f"{name} must be {'non-negative' if allow_zero else 'positive'}, got {v}")
    return v


def check_seed(seed) -> np.random.Generator:
    """A numpy Generator from a seed: None, a non-negative integer, a
    SeedSequence or a Generator (used as is, so its stream continues)."""
    if seed is None or isinstance(seed, (np.random.SeedSequence, np.random.Generator)):
        return np.random.default_rng(seed)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer (or None), got {seed!r}")
    return np.random.default_rng(int(seed))


# --------------------------------------------------------------------------- argparse types
def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a non-negative number, got {text!r}")
    return v


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return v


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}")
    return v
