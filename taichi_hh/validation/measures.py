"""Scalar measures shared by the validation studies and the benchmarks: the
median of repeated timings, error norms against an exact answer, summary
statistics and convergence orders.

One definition each, so that every table and chart of the benchmarks measures
errors and orders the same way.
"""
from __future__ import annotations

import math
import statistics

import numpy as np


def as_float(x) -> float:
    """``x`` as a float; NaN when it is not a number (an empty CSV cell)."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def median(values) -> float:
    """The median of ``values``; NaN when there are none (a configuration that
    failed before its first timed run)."""
    values = list(values)
    return statistics.median(values) if values else float("nan")


def relative_errors(got, exact, scale: float) -> tuple[float, float]:
    """(mean, max) over the points of |got - exact| / scale for vector fields of
    shape (N, 2): the error measure of every decomposition table (``scale`` is
    the field's mean |v|)."""
    e = np.linalg.norm(np.asarray(got, dtype=np.float64) - exact, axis=1) / scale
    return float(e.mean()), float(e.max())


def summary_stats(values) -> dict:
    """max, mean, variance and median of ``values``: the columns of Petronetto
    et al. 2010's Fig. 12 error table."""
    x = np.asarray(values, dtype=np.float64)
    return {"max": float(x.max()), "mean": float(x.mean()), "var": float(x.var()),
            "median": float(np.median(x))}


def loglog_slope(x, y) -> float:
    """Least-squares slope p of log y against log x (y ~ x^p): the convergence
    order of an error against the spacing (or against N, where -1 is second
    order in the spacing in 2-D).  Points whose y is not finite and positive
    (a failed or exact run) are left out; NaN with fewer than two left."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    ok = np.isfinite(y) & (y > 0)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])

