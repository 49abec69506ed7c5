"""The whole-cell decisions of :meth:`Polygon.classify_discs
<taichi_hh.geometry.polygon.Polygon.classify_discs>` for many points as one
Taichi kernel: each point's locator cell and the bounds its centre's signed
distance puts on the disc's.  The numpy form of the same steps (the cell of
each point, a gather, four comparisons) took 0.15-0.25 s per call at 1M
points, and a decomposition on a polygon classifies every point five times or
more (docs/arch.md).
"""
import numpy as np
import taichi as ti

from .. import runtime

#: from this many points on, the kernel (below it numpy's steps cost less
#: than a launch)
KERNEL_MIN_POINTS = 20_000


@ti.kernel
def _decide(p: ti.types.ndarray(), lx: ti.f64, ly: ti.f64, size: ti.f64, nx: ti.i32,
            ny: ti.i32, sd: ti.types.ndarray(), reach: ti.f64, lo: ti.f64, hi: ti.f64,
            has_lo: ti.i32, has_hi: ti.i32, status: ti.types.ndarray()):
    # no infinite bounds inside the kernel (fast math may assume none): a
    # missing bound is a flag
    for k in range(p.shape[0]):
        fx = (p[k, 0] - lx) / size
        fy = (p[k, 1] - ly) / size
        decided = 2
        if fx >= 0.0 and fx < ti.cast(nx, ti.f64) and fy >= 0.0 and fy < ti.cast(ny, ti.f64):
            ix = ti.min(ti.cast(fx, ti.i32), nx - 1)
            iy = ti.min(ti.cast(fy, ti.i32), ny - 1)
            s = sd[iy * nx + ix]
            out = 0
            if has_lo == 1 and s + reach <= lo:
                out = 1
            if has_hi == 1 and s - reach > hi:
                out = 1
            full = 1
            if has_lo == 1 and not s - reach > lo:
                full = 0
            if has_hi == 1 and not s + reach <= hi:
                full = 0
            if out == 1:
                decided = 0
            elif full == 1:
                decided = 1
        status[k] = ti.cast(decided, ti.i8)


def decide_cells(points: np.ndarray, locator, reach: float, lo: float, hi: float) -> np.ndarray:
    """(N,) int8 for the (N, 2) float64 ``points``: 0 where the signed distance
    of every point within ``reach`` of the point is at or below ``lo`` or
    above ``hi`` by its locator cell's centre (the distance is 1-Lipschitz:
    ``reach`` covers the cell's half diagonal and the disc's radius), 1
    where all of them lie in (lo, hi], 2 where the cell cannot tell (or the
    point lies beyond the locator's grid)."""
    runtime.ensure_init()
    pts = np.ascontiguousarray(points, dtype=np.float64)
    status = np.empty(len(pts), dtype=np.int8)
    if len(pts):
        _decide(pts, float(locator.lo[0]), float(locator.lo[1]), float(locator.size),
                int(locator.nx), int(locator.ny), np.ascontiguousarray(locator.sd, np.float64),
                float(reach), float(lo) if np.isfinite(lo) else 0.0,
                float(hi) if np.isfinite(hi) else 0.0, int(np.isfinite(lo)),
                int(np.isfinite(hi)), status)
    return status
