"""The multilevel hierarchy's structure and Galerkin operators.

Two ways to aggregate, one result (:class:`Galerkin`): :func:`cell_levels`
aggregates the particles by the non-empty cells of a grid of any side (CSR
rows, :func:`~.galerkin.csr_galerkin`), :func:`grid_levels` takes the pair
list's own neighbour grid, whose every level is a dense grid of nine-slot
rows (its structure follows from the grid's shape and is handed on from one
matrix to the next).  :class:`ArrayPool` keeps the set-up's Taichi arrays
by name, reusing a previous preconditioner's; :class:`CellMatrix` is a
level's operator on the host (inspection and tests)."""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import runtime
from ...errors import InputError
from ...sph.neighbors import CELL_PAD
from . import galerkin
from .cycle import CellLevels, FineLevel

#: cells of the coarsest level at most, solved by a dense pseudo-inverse
COARSEST = 16


class ArrayPool:
    """The set-up's Taichi arrays by name: a previous preconditioner's
    (``previous``, no longer needed) where large enough, else new ones."""

    def __init__(self, previous: "ArrayPool | None" = None):
        self.arrays = {}
        self.old = dict(previous.arrays) if previous is not None else {}

    def vector(self, name: str, dtype, values=None, size: int | None = None):
        """A 1-D Taichi array ``name`` holding ``values`` (or ``size`` entries
        uninitialised): the previous preconditioner's when it is large enough
        (its tail then holds zeros: the kernels read within their ranges), else
        a new one with a quarter more room when reusing (the flow's counts grow
        and shrink a little from step to step)."""
        real = dtype is None
        dtype = runtime.real_dtype() if real else dtype
        np_dtype = runtime.np_real() if real else np.int32
        need = max(size if values is None else len(values), 1)
        old = self.old.get(name)
        if old is not None and old.shape[0] >= need:
            nd = old
        else:
            # not zero-filled: written in full below or, uninitialised, by the
            # set-up's kernels before the cycle reads them (a serial fill of
            # 10-30 ms an array at 1M particles)
            nd = runtime.array(dtype, need + need // 4 if self.old else need, zeroed=False)
        if values is not None:
            buf = np.zeros(nd.shape[0], dtype=np_dtype)
            buf[:len(values)] = values
            nd.from_numpy(buf)
        self.arrays[name] = nd
        return nd

    def array(self, name: str, dtype, shape: tuple, values=None):
        """A Taichi array of exactly ``shape``: the previous one when the shape
        is the same."""
        old = self.old.get(name)
        nd = old if old is not None and tuple(old.shape) == tuple(shape) \
            else runtime.array(dtype, shape)
        if values is not None:
            nd.from_numpy(values)
        self.arrays[name] = nd
        return nd


@dataclass
class Galerkin:
    """A hierarchy's aggregation and operators: the particle level
    (:class:`~.cycle.FineLevel`), the cell levels (:class:`~.cycle.CellLevels`,
    before the Jacobi scales and the coarse inverse: those two None), each
    level's rows (``sizes``) and entries (``level_nnz``)."""
    fine: FineLevel
    cells: CellLevels
    sizes: list
    level_nnz: list


def unique_keys(keys: np.ndarray, size: int):
    """``np.unique(keys, return_inverse=True)`` for keys in ``0 .. size - 1``:
    by a presence table when it is not much larger than the keys (no sort)."""
    if size <= 8 * len(keys) + 4096:
        present = np.zeros(size, dtype=bool)
        present[keys] = True
        rank = np.cumsum(present, dtype=np.int64) - 1
        return np.flatnonzero(present), rank[keys]
    uniq, inverse = np.unique(keys, return_inverse=True)
    return uniq, inverse.reshape(-1)


def aggregates(pos, lo, extent, size: float) -> tuple:
    """The aggregation maps of every cell level: level 0's maps each particle
    to its row, level k >= 1's each row of level k - 1 to its row of level k.

    Level k aggregates the particles by the non-empty cells of side
    ``size 2^k`` of a grid from ``lo`` (nested: level k+1 aggregates 2 x 2
    level-k cells), down to the first grid of at most COARSEST cells (and at
    least two levels).  Also each level's cells: their keys ``iy nx + ix``
    (ascending, as its rows) and ``nx``.  A level's cell indices are its
    finer level's halved (floor(floor(x / s) / 2) = floor(x / 2s), exact in
    floating point: the division by a power of two is), so only level 0
    reads the particles."""
    maps = []
    cells = []
    ij = np.floor((pos - lo) / size).astype(np.int64)
    k = 0
    while True:
        shape = np.floor(extent / (size * 2.0 ** k)).astype(np.int64) + 1
        ij = np.minimum(ij, shape - 1)
        keys, agg = unique_keys(ij[:, 1] * shape[0] + ij[:, 0], int(shape[0] * shape[1]))
        maps.append(agg)
        cells.append((keys, int(shape[0])))
        k += 1
        if shape[0] * shape[1] <= COARSEST and k >= 2:
            return maps, cells
        ij = np.stack([keys % shape[0], keys // shape[0]], axis=1) // 2


def grid_level_dims(nx: int, ny: int) -> list:
    """The cell counts (nx, ny) of the dense levels from a grid of nx x ny
    cells, each joining 2 x 2 cells of the one before, down to the first of
    at most COARSEST cells (and at least two levels)."""
    dims = [(int(nx), int(ny))]
    while not (dims[-1][0] * dims[-1][1] <= COARSEST and len(dims) >= 2):
        nx, ny = dims[-1]
        dims.append(((nx + 1) // 2, (ny + 1) // 2))
    return dims


def aggregation_positions(rows, cells: float | None, weak: float):
    """The positions the particles are aggregated by, the grid's origin and
    extent, and the first level's cell side: the largest support (``cells``
    None) or ``cells`` times the median support, padded as the neighbour
    grid's; with ``weak`` > 0, every particle whose row is far from diagonally
    dominant (``|a_ii| < weak sum_j |a_ij|``) takes the position of its most
    strongly coupled neighbour, so that it shares that neighbour's cell on
    every level: Jacobi barely moves such a row, and a cell of its own would
    leave its error to the Krylov method."""
    n = rows.n
    pos = rows.positions.to_numpy()[:n].astype(np.float64)
    lo = pos.min(axis=0)
    extent = pos.max(axis=0) - lo
    if cells is None:
        size = rows.support * CELL_PAD
    else:
        hs = rows.supports
        median = rows.support if hs is None else float(np.median(hs.to_numpy()[:n]))
        size = cells * median * CELL_PAD
    if weak > 0:
        strongest = runtime.array(ti.i32, max(n, 1))
        galerkin.strongest_neighbour(n, weak, rows.offsets, rows.neighbours, rows.values,
                                     rows.diagonal, strongest)
        partner = strongest.to_numpy()[:n]
        joined = np.flatnonzero(partner >= 0)
        if joined.size:
            pos = pos.copy()
            pos[joined] = pos[partner[joined]]
    return pos, lo, extent, size


def cell_levels(rows, pool: ArrayPool, maps, cells, l1: bool) -> Galerkin:
    """The Galerkin operators of every cell level, in kernels: B = D^-1 A on
    the particles, S_0 = P_0^T B P_0, S_k+1 = P_k^T S_k P_k, with the
    piecewise-constant aggregations P (``maps``: particle -> row of level 0,
    then row of level k - 1 -> row of level k; ``cells``: each level's cell
    keys, for the rows' coordinates); each level by
    :func:`~.galerkin.csr_galerkin`, straight into one flat CSR (level k's
    rows read the rows of level k - 1 already written there).  ``l1``: the
    particles' Jacobi scale from the rows' absolute sums
    (:func:`~.galerkin.scaled_diagonal`)."""
    n = rows.n
    dinv = pool.vector("dinv", None, size=n)
    galerkin.scaled_diagonal(l1, n, rows.offsets, rows.values, rows.diagonal, dinv)
    cell_of = maps[0]
    ncell = int(cell_of.max()) + 1
    porder = pool.vector("porder", ti.i32, np.argsort(cell_of, kind="stable"))
    pstart = pool.vector("pstart", ti.i32, np.concatenate(
        [[0], np.cumsum(np.bincount(cell_of, minlength=ncell))]))
    cell_of_nd = pool.vector("cell_of", ti.i32, cell_of)
    sizes = [len(keys) for keys, _ in cells]
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    total = int(starts[-1])
    parent = np.full(total, -1, dtype=np.int64)
    kid_count = np.zeros(total, dtype=np.int64)
    kids = []
    for k in range(len(maps) - 1):
        par = maps[k + 1]               # level k's rows -> level k + 1's
        parent[starts[k]:starts[k + 1]] = par + starts[k + 1]
        kid_count[starts[k + 1]:starts[k + 2]] = np.bincount(par, minlength=sizes[k + 1])
        kids.append(np.argsort(par, kind="stable") + starts[k])
    kid_start = np.concatenate([[0], np.cumsum(kid_count)])
    bounds = pool.array("lvl", ti.i32, (len(sizes), 2),
                        np.c_[starts[:-1], starts[1:]].astype(np.int32))
    parent = pool.vector("parent", ti.i32, parent)
    kid_start = pool.vector("kid_start", ti.i32, kid_start)
    kids = pool.vector("kids", ti.i32, np.concatenate(kids) if kids else [])
    cix = pool.vector("cix", ti.i32, np.concatenate([keys % nx for keys, nx in cells]))
    ciy = pool.vector("ciy", ti.i32, np.concatenate([keys // nx for keys, nx in cells]))
    reach = galerkin.pair_reach(n, rows.offsets, rows.neighbours, cell_of_nd, cix, ciy) + 1
    real = runtime.real_dtype()
    dummy = runtime.array(real, 1)
    S_off = pool.vector("S_off", ti.i32, size=total + 1)
    S_col = S_val = None

    def below(k: int) -> tuple:
        """The rows level k aggregates: (first child row, kid_start, kids,
        their CSR offsets, columns, values, map up)."""
        if k == 0:       # the particle rows: pairs and diagonal, up by cell_of
            return (0, pstart, porder, 0, rows.offsets, rows.neighbours, rows.values,
                    rows.diagonal, dinv, cell_of_nd)
        return (int(starts[k]), kid_start, kids, 0, S_off, S_col, S_val, rows.diagonal, dinv,
                parent)

    level_nnz = []
    end = 0
    for k, nrows in enumerate(sizes):
        chunks = max(1, min(nrows // galerkin.GALERKIN_CHUNK_ROWS, galerkin.GALERKIN_MAX_CHUNKS))
        if k == 0:      # the widest window and the most runs: level 0's, reused above
            stride = -(-(2 * reach + 1) ** 2 // 32) * 32
            mark = runtime.array(ti.i32, chunks * stride)
            where = runtime.array(ti.i32, chunks * stride)
        window = (cix, ciy, reach, chunks, stride, mark, where, S_off)
        mark.fill(-1)
        galerkin.csr_galerkin(k == 0, False, nrows, int(starts[k]), *below(k), *window, mark,
                              dummy)
        base = end
        end = int(galerkin.running_sum(S_off, int(starts[k]), nrows, base))
        level_nnz.append(end - base)
        if S_col is None or end > S_col.shape[0]:
            # the coarser levels together hold about a third of level 0's
            # entries on the decomposition's cells (13k random points: 27%,
            # 3.6%, 0.7%, ...): 35% more is room for all of them; a regrowth
            # keeps a quarter more, so that it happens once, not per level
            room = max(end + (7 * end // 20 if k == 0 else end // 4), 1)
            new_col = runtime.array(ti.i32, room, zeroed=False)
            new_val = runtime.array(real, room, zeroed=False)
            if S_col is not None and base > 0:
                galerkin.copy_prefix(base, S_col, new_col)
                galerkin.copy_prefix(base, S_val, new_val)
            S_col, S_val = new_col, new_val
            pool.arrays["S_col"], pool.arrays["S_val"] = S_col, S_val
        mark.fill(-1)
        galerkin.csr_galerkin(k == 0, True, nrows, int(starts[k]), *below(k), *window, S_col,
                              S_val)
        reach = reach // 2 + 1          # the next level's cells are twice as wide
    fine = FineLevel(rows.offsets, rows.neighbours, rows.values, rows.diagonal, dinv, pstart,
                     porder, cell_of_nd)
    cells = CellLevels(bounds, S_off, S_col, S_val, parent, kid_start, kids, None, None)
    return Galerkin(fine, cells, sizes, level_nnz)


def grid_levels(rows, pool: ArrayPool, serial: bool) -> Galerkin:
    """Cell levels as dense grids when the particles are sorted by the pair
    list's own grid (cells as wide as the supports; the flow's particles and a
    fixed-support :class:`~taichi_hh.sph.pointset.PointSet`'s are): level 0 is
    that grid's cells, and every level's structure (nine slots a cell: its
    3 x 3 block; empty cells are zero rows) follows from the grid's shape, so
    it is built once and handed on through the pool; the values are one
    kernel launch (:func:`~.galerkin.grid_values`), with no sort and no host
    copy of the pairs.  The operators are those of :func:`cell_levels` on the
    same cells (tests/test_multilevel.py)."""
    n, grid = rows.n, rows.grid
    dims = grid_level_dims(grid.spec.nx, grid.spec.ny)
    sizes = [nx * ny for nx, ny in dims]
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    total = int(starts[-1])
    key = ("grid", tuple(dims))
    old = pool.old
    if old.get("structure") == key:
        for name in ("lvl", "dims", "S_off", "S_col", "parent", "kid_start", "kids"):
            pool.arrays[name] = old[name]
    else:
        S_col, parent, kid_count, kids = [], [], [np.zeros(sizes[0], np.int64)], []
        for k, (nx, ny) in enumerate(dims):
            iy, ix = np.divmod(np.arange(nx * ny), nx)
            cols = np.empty((nx * ny, 9), dtype=np.int64)
            for s in range(9):
                jx, jy = ix + s % 3 - 1, iy + s // 3 - 1
                inside = (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny)
                # a slot outside the grid points at its own row (its value is 0)
                cols[:, s] = np.where(inside, jy * nx + jx, iy * nx + ix) + starts[k]
            S_col.append(cols.reshape(-1))
            if k + 1 < len(dims):
                par = (iy // 2) * dims[k + 1][0] + ix // 2
                parent.append(par + starts[k + 1])
                kids.append(np.argsort(par, kind="stable") + starts[k])
                kid_count.append(np.bincount(par, minlength=sizes[k + 1]))
            else:
                parent.append(np.full(nx * ny, -1))
        kid_start = np.concatenate([[0], np.cumsum(np.concatenate(kid_count))])
        pool.array("lvl", ti.i32, (len(dims), 2), np.c_[starts[:-1], starts[1:]].astype(np.int32))
        pool.array("dims", ti.i32, (len(dims), 2), np.asarray(dims, dtype=np.int32))
        pool.vector("S_off", ti.i32, 9 * np.arange(total + 1))
        pool.vector("S_col", ti.i32, np.concatenate(S_col))
        pool.vector("parent", ti.i32, np.concatenate(parent))
        pool.vector("kid_start", ti.i32, kid_start)
        pool.vector("kids", ti.i32, np.concatenate(kids) if kids else [])
    pool.arrays["structure"] = key
    # level 0's cells hold their particles in order: the identity permutation
    if old.get("identity_n", 0) >= n:
        porder = pool.arrays["porder"] = old["porder"]
        pool.arrays["identity_n"] = old["identity_n"]
    else:
        porder = pool.vector("porder", ti.i32, np.arange(n))
        pool.arrays["identity_n"] = n
    cell_of = pool.vector("cell_of", ti.i32, size=n)
    dinv = pool.vector("dinv", None, size=n)
    S_val = pool.vector("S_val", None, size=9 * total)
    a = pool.arrays
    on_gpu = runtime.on_gpu()
    beyond = galerkin.grid_values(serial, not on_gpu, len(dims), grid.cell_start, rows.offsets,
                                  rows.neighbours, rows.values, rows.diagonal, a["dims"],
                                  a["lvl"], cell_of, dinv, S_val)
    if on_gpu:
        for k in range(1, len(dims)):
            galerkin.coarsen_level(k, a["dims"], a["lvl"], S_val)
    if beyond > 0:
        raise InputError(f"multilevel: {int(beyond)} pairs reach beyond a cell's 3 x 3 "
                         "block of the neighbour grid")
    fine = FineLevel(rows.offsets, rows.neighbours, rows.values, rows.diagonal, dinv,
                     grid.cell_start, porder, cell_of)
    cells = CellLevels(a["lvl"], a["S_off"], a["S_col"], S_val, a["parent"], a["kid_start"],
                       a["kids"], None, None)
    return Galerkin(fine, cells, sizes, [9 * m for m in sizes])


class CellMatrix:
    """A level's Galerkin operator in CSR form, built from (row, column, value)
    entries with the duplicates summed (a piecewise-constant aggregation's
    P^T S P is the entries of S summed by the cells of their row and column),
    columns sorted per row."""

    def __init__(self, rows, cols, values, size: int):
        key = np.asarray(rows, dtype=np.int64) * size + np.asarray(cols, dtype=np.int64)
        order = np.argsort(key, kind="stable")
        key = key[order]
        first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
        self.data = np.add.reduceat(np.asarray(values, dtype=np.float64)[order], first) \
            if len(key) else np.zeros(0)
        unique = key[first]
        self.indices = unique % size
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(unique // size,
                                                                 minlength=size))])
        self.shape = (size, size)

    @property
    def nnz(self) -> int:
        return len(self.data)

    def entries(self):
        """(rows, columns, values)."""
        return np.repeat(np.arange(self.shape[0]), np.diff(self.indptr)), self.indices, self.data

    def diagonal(self) -> np.ndarray:
        r, c, v = self.entries()
        out = np.zeros(self.shape[0])
        on = r == c
        out[r[on]] = v[on]
        return out

    def toarray(self) -> np.ndarray:
        r, c, v = self.entries()
        out = np.zeros(self.shape)
        out[r, c] = v
        return out
