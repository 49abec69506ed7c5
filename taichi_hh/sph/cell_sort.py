"""The counting sort of points by grid cell: the one piece every binned search
shares (the k-nearest search of :mod:`taichi_hh.sph.knn`, the natural
decomposition's node fits).  The caller bins its points (each its own grid
and its own rounding); this sorts them, stable: the order of
``np.argsort(cell, kind="stable")`` in O(N).
"""
import numpy as np
import taichi as ti

from .. import runtime


@ti.kernel
def _stable_scatter(cell: ti.types.ndarray(), cursor: ti.types.ndarray(),
                    order: ti.types.ndarray()):
    """Point p to the next free slot of its cell (``cursor``: the cells' starts,
    advanced), in input order: one serial pass, stable."""
    ti.loop_config(serialize=True)
    for p in range(cell.shape[0]):
        c = cell[p]
        k = cursor[c]
        cursor[c] = k + 1
        order[k] = p


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
        _stable_scatter(cell, start[:-1].copy(), order)
    return order, start
