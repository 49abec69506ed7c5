"""A screen for points closer than a tolerance, in O(N): the points binned in
cells about a mean spacing wide (the counting sort of :mod:`.cell_sort`),
each point tested against the later points of its cell and, where it lies
within the tolerance of its cell's side or corner, against the neighbour
cell's points.  :func:`~taichi_hh.sph.pointset.close_pair` asks it first for
many points and sorts them only where it finds a pair: on 1M points the sort
(``argsort`` of a projection) was 90 ms of every call's input checks.
"""
import math

import numpy as np
import taichi as ti

from .. import runtime
from .cell_sort import cells_of, counting_sort

#: a cell holding more points than this (a cluster, whose pairs are
#: quadratic in its points) leaves the question to the sort
MAX_CELL_POINTS = 64


@ti.func
def _close_in(pos: ti.template(), a, b, x, y, tol2):
    """How many of the points pos[a:b] lie within sqrt(tol2) of (x, y)."""
    hits = 0
    for t in range(a, b):
        dx = pos[t, 0] - x
        dy = pos[t, 1] - y
        if dx * dx + dy * dy <= tol2:
            hits += 1
    return hits


@ti.kernel
def _close_pairs(pos: ti.types.ndarray(), cell: ti.types.ndarray(),
                 start: ti.types.ndarray(), lx: ti.f64,
                 ly: ti.f64, h: ti.f64, nx: ti.i32, ny: ti.i32, tol2: ti.f64,
                 reach: ti.f64) -> ti.i32:
    # pos and cell in the cells' order (random reads of the points in input
    # order were 6x slower on the CPU)
    found = 0
    for s in range(pos.shape[0]):
        x = pos[s, 0]
        y = pos[s, 1]
        c = cell[s]
        i = c // ny
        j = c - i * ny
        # the later points of its own cell (each pair once)
        hits = _close_in(pos, s + 1, start[c + 1], x, y, tol2)
        # the cells beside it, where the point is within reach of their side
        # (reach: the tolerance and the cells' rounding)
        ox = x - (lx + i * h)
        oy = y - (ly + j * h)
        low_x, high_x, low_y, high_y = 0, 0, 0, 0
        if ox <= reach and i > 0:
            low_x = 1
        if h - ox <= reach and i < nx - 1:
            high_x = 1
        if oy <= reach and j > 0:
            low_y = 1
        if h - oy <= reach and j < ny - 1:
            high_y = 1
        for di in ti.static(range(-1, 2)):
            for dj in ti.static(range(-1, 2)):
                if ti.static(di != 0 or dj != 0):
                    side_x = 1
                    if ti.static(di == -1):
                        side_x = low_x
                    if ti.static(di == 1):
                        side_x = high_x
                    side_y = 1
                    if ti.static(dj == -1):
                        side_y = low_y
                    if ti.static(dj == 1):
                        side_y = high_y
                    if side_x * side_y == 1:
                        b = c + di * ny + dj
                        hits += _close_in(pos, start[b], start[b + 1], x, y, tol2)
        found += hits
    return found


def screen(points: np.ndarray, lo, hi, tolerance: float):
    """False when no two of the (N, 2) float64 ``points`` (within the box
    ``lo``, ``hi``) lie within ``tolerance`` of each other; True when some
    may; None when the screen cannot tell cheaply (a box without area, a
    tolerance near the cells' size, a cell of more than
    :data:`MAX_CELL_POINTS`): the caller then sorts."""
    n = len(points)
    width, height = float(hi[0] - lo[0]), float(hi[1] - lo[1])
    if n < 2 or width <= 0.0 or height <= 0.0:
        return None
    h = math.sqrt(width * height / n)
    scale = max(abs(float(lo[0])), abs(float(lo[1])), abs(float(hi[0])), abs(float(hi[1])))
    # the cells' sides rounded: 1e-12 of the coordinates covers them
    reach = float(tolerance) + 1e-12 * max(scale, h)
    if not reach < 0.25 * h:
        return None
    nx, ny = int(width / h) + 1, int(height / h) + 1
    if nx * ny > 4 * n + 16:
        return None
    runtime.ensure_init()
    pos = np.ascontiguousarray(points, dtype=np.float64)
    lx, ly = float(lo[0]), float(lo[1])
    cell = cells_of(pos, (lx, ly), h, h, nx, ny)
    order, start = counting_sort(cell, nx * ny)
    if int(np.diff(start).max()) > MAX_CELL_POINTS:
        return None
    order = order.astype(np.int64)
    return _close_pairs(np.take(pos, order, axis=0), np.take(cell, order), start, lx, ly, h,
                        nx, ny, float(tolerance) ** 2, reach) > 0
