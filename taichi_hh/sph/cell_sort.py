"""The counting sort of points by grid cell: the one piece every binned search
shares (the k-nearest search of :mod:`taichi_hh.sph.knn`, the natural
decomposition's node fits, the close-point screen).  The caller bins its
points (each its own grid and its own rounding; :func:`cells_of` for a
plain grid of cells); this sorts them, stable: the order of
``np.argsort(cell, kind="stable")`` in O(N).
"""
import numpy as np
import taichi as ti

from .. import runtime


@ti.kernel
def _cells_of(pts: ti.types.ndarray(), lx: ti.f64, ly: ti.f64, hx: ti.f64, hy: ti.f64,
              nx: ti.i32, ny: ti.i32, cell: ti.types.ndarray()):
    for p in range(pts.shape[0]):
        fx = ti.math.clamp(ti.floor((pts[p, 0] - lx) / hx), 0.0, ti.cast(nx - 1, ti.f64))
        fy = ti.math.clamp(ti.floor((pts[p, 1] - ly) / hy), 0.0, ti.cast(ny - 1, ti.f64))
        cell[p] = ti.cast(fx, ti.i32) * ny + ti.cast(fy, ti.i32)


def cells_of(points: np.ndarray, lower, hx: float, hy: float, nx: int, ny: int) -> np.ndarray:
    """(N,) int32: the flat index ``i * ny + j`` of the cell of a grid of nx x ny
    cells of hx x hy from ``lower`` holding each of the (N, 2) float64
    ``points`` (points beyond the grid in its edge cells)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    cell = np.empty(len(pts), dtype=np.int32)
    if len(pts):
        runtime.ensure_init()
        _cells_of(pts, float(lower[0]), float(lower[1]), float(hx), float(hy), int(nx),
                  int(ny), cell)
    return cell


@ti.func
def order_run(order: ti.template(), lo, hi):
    """Sort ``order[lo:hi]`` ascending in place (insertion sort: a cell's few
    points).  After a parallel scatter, whose atomic cursors put a cell's
    points in any order, this restores input order within each cell: the
    stable sort's result, on every arch."""
    for a in range(lo + 1, hi):
        value = order[a]
        b = a - 1
        while b >= lo and order[b] > value:
            order[b + 1] = order[b]
            b -= 1
        order[b + 1] = value


@ti.kernel
def _stable_scatter(cell: ti.types.ndarray(), cursor: ti.types.ndarray(),
                    order: ti.types.ndarray()):
    """Point p to the next free slot of its cell (``cursor``: the cells' starts,
    advanced), in input order: one serial pass, stable (the CPU's way)."""
    ti.loop_config(serialize=True)
    for p in range(cell.shape[0]):
        c = cell[p]
        k = cursor[c]
        cursor[c] = k + 1
        order[k] = p


@ti.kernel
def _parallel_scatter(cell: ti.types.ndarray(), cursor: ti.types.ndarray(),
                      order: ti.types.ndarray(), start: ti.types.ndarray()):
    """The same on a GPU, where one thread is slow: every point to a slot of
    its cell at once (integer atomics), then each cell's slots put in input
    order (:func:`order_run`)."""
    for p in range(cell.shape[0]):
        order[ti.atomic_add(cursor[cell[p]], 1)] = p
    for c in range(start.shape[0] - 1):
        order_run(order, start[c], start[c + 1])


def counting_sort(cell: np.ndarray, ncells: int) -> tuple[np.ndarray, np.ndarray]:
    """``(order, start)`` of points binned in ``cell`` (int32, each in
    ``0 .. ncells - 1``): ``order`` (int32) lists the points cell by cell, in
    input order within a cell; the points of cell c are
    ``order[start[c]:start[c + 1]]`` (``start``: int32, ``ncells + 1``)."""
    cell = np.ascontiguousarray(cell, dtype=np.int32)
    start = np.zeros(ncells + 1, dtype=np.int32)
    order = np.empty(len(cell), dtype=np.int32)
    if len(cell):
        runtime.ensure_init()
        start[1:] = np.bincount(cell, minlength=ncells)
        np.cumsum(start, out=start)
        if runtime.on_gpu():
            _parallel_scatter(cell, start[:-1].copy(), order, start)
        else:
            _stable_scatter(cell, start[:-1].copy(), order)
    return order, start
