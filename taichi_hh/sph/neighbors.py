"""Dense-grid neighbour search.

Two steps, kept apart:

1. :class:`CellGrid` bins points into square cells of side = kernel support
   with a counting sort (count per cell, prefix sum, stable scatter) and gives
   the permutation that sorts points by cell.  :func:`bin_particles` applies it
   to a :class:`~taichi_hh.sph.particles.Particles` set, so that afterwards the
   particles of cell ``c`` occupy the contiguous slots
   ``cell_start[c] : cell_start[c+1]``.
2. :class:`PairList` stores, for every query point, the indices of the source
   points closer than the support (compressed rows: ``offsets``, ``neighbours``),
   found by scanning the 3x3 cells around it.  Operators then loop over these
   rows and never search again.

The scatter is stable (particles keep their relative order inside a cell),
so the ordering, and every sum over neighbours, is deterministic: serial on
the CPU, on a GPU parallel with each cell's slots put back in input order
afterwards (:func:`~taichi_hh.sph.cell_sort.order_run`); the prefix sums
likewise serial on the CPU and blocked in parallel on a GPU.
"""

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import InputError
from .cell_sort import order_run

# Cells are a hair larger than the support so that a pair closer than the
# support can never land two cells apart through rounding of (x - lo) / size.
CELL_PAD = 1.0 + 1e-9


@ti.func
def cell_coords(p, lo_x, lo_y, inv_cell, nx, ny):
    # clamp in floating point before the cast: far-away points would overflow i32
    fx = ti.math.clamp(ti.floor((p[0] - lo_x) * inv_cell), 0.0, ti.cast(nx - 1, float))
    fy = ti.math.clamp(ti.floor((p[1] - lo_y) * inv_cell), 0.0, ti.cast(ny - 1, float))
    return ti.cast(fx, ti.i32), ti.cast(fy, ti.i32)


@ti.kernel
def _count_cells(pos: ti.types.ndarray(), n: ti.i32, lo_x: float, lo_y: float, inv_cell: float,
                 nx: ti.i32, ny: ti.i32, cell_of: ti.types.ndarray(), count: ti.types.ndarray(),
                 ncells: ti.i32):
    for c in range(ncells + 1):
        count[c] = 0
    for i in range(n):
        cx, cy = cell_coords(pos[i], lo_x, lo_y, inv_cell, nx, ny)
        c = cy * nx + cx
        cell_of[i] = c
        ti.atomic_add(count[c], 1)


#: entries per block of the GPU's prefix sum: a thread per block, then one
#: serial pass over the blocks' totals
SCAN_BLOCK = 256
_block_totals = {}


def exclusive_scan(count, start, m: int) -> int:
    """start[k] = sum(count[:k]) for k <= m; returns the total (an int: an i64
    sum, so that the caller can detect an overflow of i32)."""
    if not runtime.on_gpu():
        return int(_serial_scan(count, start, m))
    blocks = max((m + SCAN_BLOCK - 1) // SCAN_BLOCK, 1)
    totals = _block_totals.get("array")
    if totals is None or totals.shape[0] < blocks or _block_totals.get("gen") != runtime.generation():
        totals = runtime.array(ti.i64, max(blocks, 1024))
        _block_totals.update(array=totals, gen=runtime.generation())
    return int(_blocked_scan(count, start, m, totals))


@ti.kernel
def _serial_scan(count: ti.types.ndarray(), start: ti.types.ndarray(), m: ti.i32) -> ti.i64:
    total = ti.i64(0)
    ti.loop_config(serialize=True)
    for k in range(m):
        start[k] = ti.cast(total, ti.i32)
        total += ti.cast(count[k], ti.i64)
    start[m] = ti.cast(total, ti.i32)
    return total


@ti.kernel
def _blocked_scan(count: ti.types.ndarray(), start: ti.types.ndarray(), m: ti.i32,
                  totals: ti.types.ndarray()) -> ti.i64:
    """The same in three passes: each block's own prefix sums and total in
    parallel, the totals' prefix sums serially, each entry's offset added in
    parallel."""
    # no i32 kernel-scope local beside the i64 one: Taichi 1.7 on CUDA keeps
    # them in one buffer, where a misaligned i64 faults
    for b in range((m + SCAN_BLOCK - 1) // SCAN_BLOCK):
        run = ti.i64(0)
        for k in range(b * SCAN_BLOCK, ti.min((b + 1) * SCAN_BLOCK, m)):
            c = count[k]
            start[k] = ti.cast(run, ti.i32)
            run += ti.cast(c, ti.i64)
        totals[b] = run
    total = ti.i64(0)
    ti.loop_config(serialize=True)
    for b in range((m + SCAN_BLOCK - 1) // SCAN_BLOCK):
        t = totals[b]
        totals[b] = total
        total += t
    for k in range(m):
        start[k] = ti.cast(ti.cast(start[k], ti.i64) + totals[k // SCAN_BLOCK], ti.i32)
    start[m] = ti.cast(total, ti.i32)
    return total


@ti.kernel
def _sample_descents(cell_of: ti.types.ndarray(), n: ti.i32, samples: ti.i32) -> ti.i32:
    """Among ``samples`` evenly spaced neighbours (i, i+1) of the input, how many
    have cell_of[i+1] < cell_of[i]: about half of them for shuffled input, none
    for input already sorted by cell."""
    down = 0
    ti.loop_config(serialize=True)
    for t in range(samples):
        i = ti.cast(ti.cast(t, ti.i64) * (n - 1) // samples, ti.i32)
        down += ti.select(cell_of[i + 1] < cell_of[i], 1, 0)
    return down


@ti.kernel
def _stable_scatter(cell_of: ti.types.ndarray(), n: ti.i32, start: ti.types.ndarray(),
                    cursor: ti.types.ndarray(), order: ti.types.ndarray(), ncells: ti.i32,
                    rank: ti.types.ndarray(), with_rank: ti.i32, parallel: ti.template()):
    """Each point to the next free slot of its cell, in input order: serially
    on the CPU; on a GPU (``parallel``) all at once, then each cell's slots in
    input order (:func:`~taichi_hh.sph.cell_sort.order_run`): the same result."""
    for c in range(ncells):
        cursor[c] = start[c]
    if ti.static(parallel):
        for i in range(n):
            order[ti.atomic_add(cursor[cell_of[i]], 1)] = i
        for c in range(ncells):
            order_run(order, start[c], start[c + 1])
        for k in range(n):
            if with_rank != 0:
                rank[order[k]] = k
    else:
        ti.loop_config(serialize=True)
        for i in range(n):
            c = cell_of[i]
            slot = cursor[c]
            order[slot] = i
            cursor[c] = slot + 1
            if with_rank != 0:
                rank[i] = slot


@dataclass
class GridSpec:
    lo_x: float
    lo_y: float
    cell_size: float
    nx: int
    ny: int

    @property
    def ncells(self) -> int:
        return self.nx * self.ny

    @property
    def inv_cell(self) -> float:
        return 1.0 / self.cell_size

    def args(self):
        return self.lo_x, self.lo_y, self.inv_cell, self.nx, self.ny

    @classmethod
    def covering(cls, lo, hi, support: float) -> "GridSpec":
        """A grid of cells of side ~support covering the box [lo, hi] (with a margin)."""
        if not (support > 0 and math.isfinite(support)):
            raise InputError(f"kernel support must be a positive finite number, got {support}")
        size = support * CELL_PAD
        lo = np.asarray(lo, float) - 0.5 * size
        hi = np.asarray(hi, float) + 0.5 * size
        nx = max(1, int(math.ceil((hi[0] - lo[0]) / size)))
        ny = max(1, int(math.ceil((hi[1] - lo[1]) / size)))
        if nx * ny > 2**31 - 2:
            raise InputError(
                f"neighbour grid of {nx} x {ny} cells is too large: the kernel support "
                f"({support:g}) is tiny compared with the extent of the points")
        return cls(float(lo[0]), float(lo[1]), size, nx, ny)


class CellGrid:
    """Counting-sort binning of points into a dense grid of cells."""

    #: from this many points on, :meth:`sort` checks how far from sorted the
    #: input is and, when far, records the inverse permutation too (see
    #: :func:`bin_particles`); smaller sets stay in cache and gain nothing
    RANK_MIN_N = 1 << 16
    #: input neighbour pairs sampled for that check
    SAMPLES = 4096

    def __init__(self, spec: GridSpec):
        runtime.ensure_init()
        self.spec = spec
        self.cell_start = runtime.array(ti.i32, spec.ncells + 1)
        self._count = runtime.array(ti.i32, spec.ncells + 1)
        self._capacity = 0
        self.cell_of = None
        self.order = None
        self._rank = None         # point i -> its slot, when the last sort recorded it
        self._rank_nd = None
        self.n_points = 0         # points binned by the last sort

    def _ensure(self, n: int) -> None:
        if n > self._capacity:
            cap = max(n, 1)
            self.cell_of = runtime.array(ti.i32, cap)
            self.order = runtime.array(ti.i32, cap)
            self._capacity = cap
            self._rank_nd = None

    @property
    def rank(self):
        """The inverse of ``order`` (point i -> its slot) when the last
        :meth:`sort` recorded it (input far from sorted), else None."""
        return self._rank

    def sort(self, pos, n: int):
        """Bin ``pos[:n]``; returns ``order`` (slot k holds point ``order[k]``).

        ``cell_start`` then describes the cells of the *sorted* sequence.
        """
        self._ensure(n)
        self.n_points = n
        s = self.spec
        _count_cells(pos, n, *s.args(), self.cell_of, self._count, s.ncells)
        exclusive_scan(self._count, self.cell_start, s.ncells)
        # Far from sorted (over 1/8 of the sampled neighbours in decreasing
        # cells; shuffled input gives 1/2): record the inverse permutation too.
        self._rank = None
        if n >= self.RANK_MIN_N and _sample_descents(self.cell_of, n, self.SAMPLES) * 8 > self.SAMPLES:
            if self._rank_nd is None:
                self._rank_nd = runtime.array(ti.i32, self._capacity)
            self._rank = self._rank_nd
        _stable_scatter(self.cell_of, n, self.cell_start, self._count, self.order, s.ncells,
                        self.order if self._rank is None else self._rank,
                        int(self._rank is not None), runtime.on_gpu())
        return self.order


def bin_particles(particles, spec: GridSpec, grid: CellGrid | None = None) -> CellGrid:
    """Sort ``particles`` physically by cell of ``spec``; returns the grid (``grid``,
    a previous result on the same ``spec``, is reused: no new arrays)."""
    if grid is None or grid.spec != spec:
        grid = CellGrid(spec)
    order = grid.sort(particles.position, particles.n)
    if grid.rank is not None:
        # input far from sorted: writing each particle to its slot (sequential
        # reads, scattered writes) beats gathering them (scattered reads);
        # the result is the same
        particles.permute(order, inverse=grid.rank)
    else:
        particles.permute(order)
    return grid


# ---------------------------------------------------------------------------
# Pair lists

# The three cells (cx-1..cx+1, gy) of one row of the 3x3 block are consecutive
# cell indices, so their points are one contiguous slot range: a query scans
# three ranges, in the same order as cell by cell.  The distance test is
# branch-free (a mispredicted branch per candidate cost more than the test):
# the count pass adds 0/1; the fill pass writes every candidate at the next
# free position of the row and advances only past the accepted ones.

@ti.func
def _row_ranges(p, lo_x, lo_y, inv_cell, nx, ny):
    cx, cy = cell_coords(p, lo_x, lo_y, inv_cell, nx, ny)
    return ti.max(cx - 1, 0), ti.min(cx + 1, nx - 1), ti.max(cy - 1, 0), ti.min(cy + 1, ny - 1)


@ti.func
def _reach_block(p, hi, reach: ti.template(), lo_x, lo_y, inv_cell, nx, ny):
    """The block of cells a query at p with support hi scans when supports vary
    (:mod:`taichi_hh.sph.support`): as far as its own support or the largest
    one reaching its cell (``reach``) goes."""
    cx, cy = cell_coords(p, lo_x, lo_y, inv_cell, nx, ny)
    r = ti.max(hi, reach[cy * nx + cx])
    k = ti.cast(ti.ceil(r * CELL_PAD * inv_cell), ti.i32)
    return ti.max(cx - k, 0), ti.min(cx + k, nx - 1), ti.max(cy - k, 0), ti.min(cy + k, ny - 1)


@ti.func
def _scan_block(by_reach: ti.template(), p, i, hq: ti.template(), reach: ti.template(), lo_x,
                lo_y, inv_cell, nx, ny):
    """The cells query i scans: its 3 x 3 block, or (``by_reach``) :func:`_reach_block`."""
    if ti.static(by_reach):
        return _reach_block(p, hq[i], reach, lo_x, lo_y, inv_cell, nx, ny)
    else:
        return _row_ranges(p, lo_x, lo_y, inv_cell, nx, ny)


@ti.func
def _pair_support2(adaptive: ti.template(), hq: ti.template(), hs: ti.template(), i, j,
                   support2):
    # squared pair support: fixed, or max(H_i, H_j) (taichi_hh.sph.support)
    h2 = support2
    if ti.static(adaptive):
        h = ti.max(hq[i], hs[j])
        h2 = h * h
    return h2


@ti.kernel
def _candidate_pairs(qpos: ti.types.ndarray(), nq: ti.i32, cell_start: ti.types.ndarray(),
                     lo_x: float, lo_y: float, inv_cell: float, nx: ti.i32,
                     ny: ti.i32) -> ti.i64:
    """How many (query, source) candidates the pair passes examine: the sources
    in the 3 x 3 cells around every query (one cheap pass over the queries)."""
    total = ti.i64(0)
    for i in range(nq):
        x0, x1, y0, y1 = _row_ranges(qpos[i], lo_x, lo_y, inv_cell, nx, ny)
        k = ti.i64(0)
        for gy in range(y0, y1 + 1):
            row = gy * nx
            k += ti.i64(cell_start[row + x1 + 1] - cell_start[row + x0])
        total += k
    return total


#: the pair passes examine every source in the 3 x 3 cells around each query;
#: more candidates than this are refused before the search.  Uniform points
#: give about 9/pi candidates per pair, so this is far beyond the 2^31 pairs a
#: pair list holds.  A support much larger than the points' spacing with a
#: band of fake particles as wide as it (petronetto2010, support_ratio=1e3, 150
#: points: 2e6 fake particles) once asked for 3e12 candidates: the count pass
#: ran for hours
MAX_CANDIDATES = 16 * 2 ** 31


@ti.kernel
def _pair_pass(fill: ti.template(), qpos: ti.types.ndarray(), nq: ti.i32,
               spos: ti.types.ndarray(), cell_start: ti.types.ndarray(), lo_x: float,
               lo_y: float, inv_cell: float, nx: ti.i32, ny: ti.i32, support2: float,
               exclude_self: ti.i32, adaptive: ti.template(), hq: ti.types.ndarray(),
               hs: ti.types.ndarray(), reach: ti.types.ndarray(), by_reach: ti.template(),
               count: ti.types.ndarray(), dup_tol2: float, dup: ti.types.ndarray(),
               offsets: ti.types.ndarray(), neighbours: ti.types.ndarray()):
    """One pass over every query's candidates: counting its pairs into
    ``count`` (and the highest query with a pair within the duplicate
    tolerance into ``dup``), or, with ``fill``, writing them from
    ``offsets``.  Branch-free fill: every candidate is written at the next
    free position of the row, which advances only past the accepted ones;
    rows come out sorted by source slot (cell rows in increasing order, each
    a run of slots)."""
    for i in range(nq):
        p = qpos[i]
        x0, x1, y0, y1 = _scan_block(by_reach, p, i, hq, reach, lo_x, lo_y, inv_cell, nx, ny)
        skip = -1
        if exclude_self != 0:
            skip = i
        k = 0
        end = 0
        if ti.static(fill):
            k = offsets[i]
            end = offsets[i + 1]
        ndup = 0
        for gy in range(y0, y1 + 1):
            row = gy * nx
            for j in range(cell_start[row + x0], cell_start[row + x1 + 1]):
                d = spos[j] - p
                r2 = d.dot(d)
                ok = (r2 < _pair_support2(adaptive, hq, hs, i, j, support2)) & (j != skip)
                if ti.static(fill):
                    if k < end:      # never past the row: the next row is another thread's
                        neighbours[k] = j
                else:
                    ndup += ti.select(ok & (r2 <= dup_tol2), 1, 0)
                k += ti.select(ok, 1, 0)
        if ti.static(not fill):
            if ndup > 0:
                ti.atomic_max(dup[0], i)
            count[i] = k


@ti.kernel
def _reverse_pairs(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                   reverse: ti.types.ndarray(), missing: ti.types.ndarray()):
    # rows are sorted by neighbour index (cells are scanned in increasing order
    # and slots are sorted by cell), so the reverse pair is found by bisection
    for i in range(n):
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            lo = offsets[j]
            hi = offsets[j + 1]
            while lo < hi:
                mid = (lo + hi) // 2
                if nbrs[mid] < i:
                    lo = mid + 1
                else:
                    hi = mid
            if lo < offsets[j + 1] and nbrs[lo] == i:
                reverse[k] = lo
            else:
                reverse[k] = -1
                ti.atomic_max(missing[0], k)


class PairList:
    """Neighbour rows: for query i, sources ``neighbours[offsets[i]:offsets[i+1]]``.

    Sources are the binned (cell-sorted) points of ``grid``; queries may be the
    same points (``exclude_self=True`` drops the i == j pair) or other points.
    Row order inside a neighbourhood follows the cells' order, deterministic.
    """

    def __init__(self):
        runtime.ensure_init()
        self.offsets = None
        self.neighbours = None
        self.n_queries = 0
        self.n_pairs = 0
        self._cap_q = 0
        self._cap_p = 0
        self._count = None
        self._dup = runtime.array(ti.i32, 1)
        self._no_supports = runtime.array(runtime.real_dtype(), 1)   # fixed support
        self._reverse = None
        #: the grid whose cell-sorted points are both the queries and the sources
        #: (every pair then joins a cell to its 3 x 3 block); None for other queries
        self.grid = None

    def build(self, qpos, nq: int, spos, grid: CellGrid, support: float, *,
              exclude_self: bool = True, duplicate_tolerance: float = 0.0,
              supports=None, reach=None) -> "PairList":
        """Find all source points within ``support`` of each query point.

        supports: optional per-point supports ``(query, source)`` (Taichi
        arrays): pair (i, j) is then kept within ``max(H_i, H_j)``
        (:mod:`taichi_hh.sph.support`), and ``support`` (the grid's cell
        size) must be at least the largest of them, unless ``reach`` (per
        cell, the largest support reaching it: cells smaller than the
        supports, :func:`~taichi_hh.sph.support.adaptive_pairs`) widens each
        query's block of cells to its support.
        duplicate_tolerance: pairs closer than this raise :class:`InputError`
        (coincident points make every SPH operator singular).
        """
        if nq + 1 > self._cap_q:
            self._cap_q = nq + 1
            self.offsets = runtime.array(ti.i32, self._cap_q)
            self._count = runtime.array(ti.i32, self._cap_q)
        s = grid.spec
        if supports is None:
            hq = hs = self._no_supports
            adaptive = 0
        else:
            (hq, hs), adaptive = supports, 1
        by_reach = reach is not None
        args = (s.lo_x, s.lo_y, s.inv_cell, s.nx, s.ny, support * support, int(exclude_self),
                adaptive, hq, hs, reach if by_reach else self._no_supports, by_reach)
        # (the 3 x 3 blocks' candidates; per-point supports bound their own)
        candidates = 0 if by_reach else _candidate_pairs(qpos, nq, grid.cell_start, *s.args())
        if candidates > MAX_CANDIDATES:
            raise InputError(
                f"the kernel support ({support:.3g}) is too large for these points: it holds "
                f"about {candidates / max(nq, 1):.3g} points around each of the {nq} "
                f"particles ({candidates:.3g} pairs to examine, more than "
                f"{MAX_CANDIDATES:.3g}); an SPH operator needs a few tens. Reduce the kernel "
                "support (support_ratio)")
        self._dup.fill(-1)
        tol2 = duplicate_tolerance ** 2 if duplicate_tolerance > 0 else -1.0
        _pair_pass(False, qpos, nq, spos, grid.cell_start, *args, self._count, tol2, self._dup,
                   self._count, self._count)
        total = exclusive_scan(self._count, self.offsets, nq)
        if total > 2**31 - 1:
            raise InputError(f"{total} neighbour pairs exceed the 2^31 limit of one pair list: "
                             "reduce the kernel support or split the points")
        dup = int(self._dup.to_numpy()[0])
        if dup >= 0:
            self.duplicate_query = dup
            raise InputError(f"duplicate points: query point {dup} has a neighbour closer than "
                             f"{duplicate_tolerance:g}")
        if total > self._cap_p or self.neighbours is None:
            self._cap_p = max(int(total), int(self._cap_p * 1.25), 1)
            self.neighbours = runtime.array(ti.i32, self._cap_p)
        _pair_pass(True, qpos, nq, spos, grid.cell_start, *args, self._count, tol2, self._dup,
                   self.offsets, self.neighbours)
        self.n_queries = nq
        self.n_pairs = int(total)
        self._reverse = None
        # the grid's cells as the multilevel's level 0 need every pair in a 3 x 3 block
        self.grid = grid if qpos is spos and nq == grid.n_points and not by_reach else None
        return self

    def reverse_index(self):
        """``reverse[k]``: the index of pair (j, i) for pair k = (i, j), for
        transposed gathers (built on first use, kept until the next build).
        Raises RuntimeError if the relation is not symmetric (other query points)."""
        if self._reverse is None:
            reverse = runtime.array(ti.i32, max(self.n_pairs, 1))
            missing = runtime.array(ti.i32, 1)
            missing.fill(-1)
            _reverse_pairs(self.n_queries, self.offsets, self.neighbours, reverse, missing)
            if int(missing.to_numpy()[0]) >= 0:
                raise RuntimeError("neighbour relation is not symmetric: cannot transpose")
            self._reverse = reverse
        return self._reverse

    def to_numpy(self):
        """(offsets, neighbours) as numpy arrays (for tests and inspection)."""
        off = self.offsets.to_numpy()[: self.n_queries + 1].copy()
        nb = self.neighbours.to_numpy()[: self.n_pairs].copy()
        return off, nb

    def counts(self) -> np.ndarray:
        off = self.offsets.to_numpy()[: self.n_queries + 1]
        return np.diff(off)
