"""What the natural set-up reads of the points cell by cell: each cell's share
of the points (cloud in cell), the node fits' local spacing and edge flags,
each point's area.

Taichi kernels over the grid of :class:`~.free_space.Grid`, on the points
sorted by cell (:class:`~.node_fits.PointBins`): every cell gathers from its
neighbours (no atomics, the same sums in the same order on every arch), and
the box sums are separable, a pass along y then one along x.  At 1M points
the numpy forms of these (bincounts, summed-area tables, scatters) took
0.45 s of a 2.5 s call on 2 cores (docs/arch.md).
"""
import numpy as np
import taichi as ti

from .. import runtime

#: the local spacing of the fits: sqrt(inside area / points) over the
#: (2 LOCAL_CELLS + 1)^2 cells around a cell, where it exceeds SPARSE_RATIO
#: cells (sparse data), else the cell (the block counts' fluctuations on
#: uniform data would only add noise)
LOCAL_CELLS = 3
SPARSE_RATIO = 1.3
#: the fits' edge flags: the cells within this many of a cell not wholly inside
EDGE_CELLS = LOCAL_CELLS + 2
#: the points' areas: over the cells within this many of their own (3 x 3)
VOLUME_CELLS = 1


@ti.kernel
def _grid_coordinates(nx: ti.i32, ny: ti.i32, ox: ti.f64, oy: ti.f64, hx: ti.f64, hy: ti.f64,
                      pos: ti.types.ndarray(), t: ti.types.ndarray()):
    # each point in units of cells from the first centre, clamped to the
    # outermost centres (the cloud in cell's share of a point beyond them
    # stays on them)
    top_x = ti.cast(nx - 1, ti.f64)
    top_y = ti.cast(ny - 1, ti.f64)
    for s in range(pos.shape[0]):
        t[s, 0] = ti.math.clamp((pos[s, 0] - ox) / hx, 0.0, top_x)
        t[s, 1] = ti.math.clamp((pos[s, 1] - oy) / hy, 0.0, top_y)


@ti.kernel
def _shared_counts(nx: ti.i32, ny: ti.i32, start: ti.types.ndarray(), t: ti.types.ndarray(),
                   count: ti.types.ndarray()):
    # cloud in cell: each point shared between the four centres around it,
    # bilinearly; centre (i, j) reads the points of the 3 x 3 cells around
    # its own
    for c in range(nx * ny):
        i = c // ny
        j = c - i * ny
        fi = ti.cast(i, ti.f64)
        fj = ti.cast(j, ti.f64)
        acc = ti.f64(0.0)
        j0 = ti.max(j - 1, 0)
        j1 = ti.min(j + 2, ny)
        for bi in range(ti.max(i - 1, 0), ti.min(i + 2, nx)):
            # the three cells of a row along y are one run of the sorted points
            for s in range(start[bi * ny + j0], start[bi * ny + j1]):
                wx = 1.0 - ti.abs(t[s, 0] - fi)
                wy = 1.0 - ti.abs(t[s, 1] - fj)
                if wx > 0.0 and wy > 0.0:
                    acc += wx * wy
        count[c] = acc


@ti.kernel
def _sums_along_y(nx: ti.i32, ny: ti.i32, frac: ti.types.ndarray(),
                  count: ti.types.ndarray(), start: ti.types.ndarray(),
                  along: ti.types.ndarray(), partial_cells: ti.types.ndarray()):
    # along[c, :]: the sums over j - k .. j + k (zero beyond the grid) of the
    # inside fraction (k = LOCAL_CELLS, then VOLUME_CELLS), the shared counts
    # (LOCAL_CELLS) and the binned counts (VOLUME_CELLS); partial_cells[c]:
    # the cells not wholly inside within EDGE_CELLS.  A row a thread, the
    # windows slid along it (O(1) a cell; the float sums' rounding drifts by
    # ~1e-13 of their size over a row, the counts are exact)
    K = ti.static(LOCAL_CELLS)
    E = ti.static(EDGE_CELLS)
    V = ti.static(VOLUME_CELLS)
    for i in range(nx):
        row = i * ny
        f_local, n_local, f_near = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        n_near, partial = 0, 0
        for j in range(-E, ny):
            # the windows of cell j gain cell j + k and lose cell j - k - 1
            if j + K < ny and j + K >= 0:
                f_local += frac[row + j + K]
                n_local += count[row + j + K]
            if j - K - 1 >= 0 and j - K - 1 < ny:
                f_local -= frac[row + j - K - 1]
                n_local -= count[row + j - K - 1]
            if j + V < ny and j + V >= 0:
                f_near += frac[row + j + V]
                n_near += start[row + j + V + 1] - start[row + j + V]
            if j - V - 1 >= 0 and j - V - 1 < ny:
                f_near -= frac[row + j - V - 1]
                n_near -= start[row + j - V] - start[row + j - V - 1]
            if j + E < ny and frac[row + j + E] < 1.0:
                partial += 1
            if j - E - 1 >= 0 and frac[row + j - E - 1] < 1.0:
                partial -= 1
            if j >= 0:
                along[row + j, 0] = f_local
                along[row + j, 1] = n_local
                along[row + j, 2] = f_near
                along[row + j, 3] = ti.cast(n_near, ti.f64)
                partial_cells[row + j] = partial


@ti.kernel
def _boxes_along_x(nx: ti.i32, ny: ti.i32, cell_area: ti.f64, cell: ti.f64,
                   along: ti.types.ndarray(), partial_cells: ti.types.ndarray(),
                   start: ti.types.ndarray(), order: ti.types.ndarray(),
                   spacing: ti.types.ndarray(), edge: ti.types.ndarray(),
                   volume: ti.types.ndarray()):
    # the sums of _sums_along_y's over i - k .. i + k, summed out (not slid:
    # a thread a cell reads the rows above and below where its neighbours
    # read, which a column a thread did not, 4x slower on the CPU)
    K = ti.static(LOCAL_CELLS)
    E = ti.static(EDGE_CELLS)
    V = ti.static(VOLUME_CELLS)
    for i, j in ti.ndrange(nx, ny):
        f_local, n_local, f_near, n_near = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        partial = 0
        for d in ti.static(range(-E, E + 1)):
            if 0 <= i + d < nx:
                b = (i + d) * ny + j
                partial += partial_cells[b]
                if ti.static(-K <= d <= K):
                    f_local += along[b, 0]
                    n_local += along[b, 1]
                if ti.static(-V <= d <= V):
                    f_near += along[b, 2]
                    n_near += along[b, 3]
        c = i * ny + j
        h = ti.sqrt(ti.max(f_local, 0.0) * cell_area / ti.max(n_local, 1.0))
        spacing[c] = h if h > SPARSE_RATIO * cell else cell
        edge[c] = ti.cast(partial > 0, ti.i8)
        # each point of the cell: the 3 x 3 cells' inside area over their points
        per = ti.max(f_near, 0.0) * cell_area / ti.max(n_near, 1.0)
        for s in range(start[c], start[c + 1]):
            volume[order[s]] = per


def shared_counts(grid, binned) -> np.ndarray:
    """(nx, ny) the points per cell, each point shared between the four cell
    centres around it bilinearly (cloud in cell): a count that moves
    continuously with the points.  Binned whole, a point on a cell's edge (the
    extreme points of data whose bounding box is the domain lie on the
    outermost cells' edges) moved the local spacing by 4% under a move of
    1e-16, and the fits' radii with it (the fuzz suite's units property)."""
    runtime.ensure_init()
    count = np.zeros(grid.nx * grid.ny)
    if len(binned.order):
        t = runtime.array(ti.f64, binned.points.shape, zeroed=False)
        _grid_coordinates(grid.nx, grid.ny, float(grid.origin[0]), float(grid.origin[1]),
                          grid.hx, grid.hy, binned.points, t)
        _shared_counts(grid.nx, grid.ny, binned.start, t, count)
    return count.reshape(grid.shape)


def spacing_edge_volume(grid, frac: np.ndarray, binned) -> tuple:
    """``(spacing, edge, volume)`` of the points ``binned`` on ``grid`` whose
    cells' inside fractions are ``frac`` (nx * ny,):

    * ``spacing`` (nx * ny,): the data's local spacing at each cell, sqrt of
      the inside area over the points (:func:`shared_counts`) of the
      (2 LOCAL_CELLS + 1)^2 cells around it, where it exceeds SPARSE_RATIO
      cells (sparse data), else the cell (the node fits' radii are in these
      units: about 38 points in 3.5 of them where the data are uniform or
      sparse, as the SPH operators' adaptive supports);
    * ``edge`` (nx * ny,) bool: the cells within EDGE_CELLS of a cell not
      wholly inside the domain;
    * ``volume`` (N,): each point's area (input order), the inside area of
      the 3 x 3 cells around its own over the points in them."""
    runtime.ensure_init()
    m = grid.nx * grid.ny
    frac = np.ascontiguousarray(frac, dtype=np.float64)
    count = shared_counts(grid, binned).ravel()
    # the first pass's sums stay Taichi's (on a GPU, on the device)
    along = runtime.array(ti.f64, (m, 4), zeroed=False)
    partial_cells = runtime.array(ti.i32, m, zeroed=False)
    _sums_along_y(grid.nx, grid.ny, frac, count, binned.start, along, partial_cells)
    spacing = np.empty(m)
    edge = np.empty(m, dtype=np.int8)
    volume = np.empty(len(binned.order))
    _boxes_along_x(grid.nx, grid.ny, grid.hx * grid.hy, max(grid.hx, grid.hy), along,
                   partial_cells, binned.start, binned.order, spacing, edge, volume)
    return spacing, edge.view(bool), volume
