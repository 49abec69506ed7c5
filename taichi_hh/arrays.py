"""Reductions of (N, k) numpy arrays over their short axis, column by column.

numpy reduces ``a.min(axis=0)`` of an (N, 2) array, or ``a.any(axis=1)``,
through its general strided machinery: at a million points 15-35 ms each,
10-25x one pass over each column (docs/arch.md, the seventh session on CUDA).
Input checks and set-ups run several per call, so they use these instead.
Like :mod:`taichi_hh.errors` this sits at the bottom of the package.
"""
from __future__ import annotations

import numpy as np

__all__ = ["bounds", "column_mean", "rows_any", "rows_all_finite"]


def bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(points.min(axis=0), points.max(axis=0))`` of an (N, k) array, N >= 1."""
    cols = range(points.shape[1])
    return (np.array([points[:, c].min() for c in cols]),
            np.array([points[:, c].max() for c in cols]))


def column_mean(points: np.ndarray) -> np.ndarray:
    """``points.mean(axis=0)`` of an (N, k) array."""
    return np.array([points[:, c].mean() for c in range(points.shape[1])])


def rows_any(flags: np.ndarray) -> np.ndarray:
    """``flags.any(axis=1)`` of an (N, k) boolean array."""
    out = flags[:, 0].copy()
    for c in range(1, flags.shape[1]):
        out |= flags[:, c]
    return out


def rows_all_finite(values: np.ndarray) -> np.ndarray | None:
    """``np.isfinite(values).all(axis=1)`` of an (N, k) array, or None when
    every entry is finite (one flat pass: the common case costs no row mask)."""
    if np.isfinite(values).all():
        return None
    return ~rows_any(~np.isfinite(values.reshape(len(values), -1)))
