"""Per-particle kernel support from the local spacing (adaptive support).

On points of varying density (uniformly random data, clusters, a density
gradient) one support radius cannot suit every point: where the points are
sparse it leaves a particle with too few, or one-sided, neighbours (its
corrected operators become singular or inaccurate), where they are dense it
wastes work.  Here every particle gets its own support

    H_i = support_ratio * s_i,   s_i = d_k(i) * sqrt(pi / k),

with ``d_k(i)`` the distance to its k-th nearest neighbour: ``s_i`` is the
local mean spacing (k points fill the disc of radius d_k at the local
density), so ``support_ratio`` keeps its meaning of "supports in spacings"
and a uniform point set gets about the fixed support.  A pair uses the
larger support of the two (symmetric, so the neighbour relation stays
symmetric, and every particle keeps at least its own k nearest neighbours):

    H_ij = max(H_i, H_j).

The kernels take the pair support through :func:`pair_support`, a static
switch: with fixed support they compile to the scalar ``H`` as before.
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import InputError
from .neighbors import CELL_PAD  # supports rounded up as the cells are

#: default number of nearest neighbours of the local spacing estimate
#: (docs/notes/scattered.md)
DEFAULT_NEIGHBOURS = 12
#: the largest k accepted (the k-th distance keeps k values per thread)
MAX_NEIGHBOURS = 24
#: boundary samples' supports are this much larger than their k-th-distance
#: estimate: their Neumann rows then reach more data points, which made the
#: solver's iterations fewer on random and clustered points (clusters 53k: 13/14
#: against 32/31) at unchanged errors (docs/notes/scattered.md)
BOUNDARY_SUPPORT_SCALE = 1.2


@ti.func
def pair_support(adaptive: ti.template(), hs: ti.template(), i, j, H):
    """The kernel support of pair (i, j): ``H`` (fixed support) or
    ``max(hs[i], hs[j])`` (adaptive); ``i == j`` gives the particle's own."""
    h = H
    if ti.static(adaptive):
        h = ti.max(hs[i], hs[j])
    return h


def kth_neighbour_distance(points: np.ndarray, k: int, area: float) -> np.ndarray:
    """Distance from every point to its k-th nearest other point (input order),
    by the exact k-nearest search of :mod:`taichi_hh.sph.knn`.  ``area`` is
    unused (kept for callers that pass it)."""
    from .knn import KNearest

    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if not 1 <= k <= MAX_NEIGHBOURS:
        raise InputError(f"neighbours for the adaptive support must be 1..{MAX_NEIGHBOURS}, "
                         f"got {k}")
    if n <= k:
        raise InputError(f"{n} points are too few for an adaptive support from {k} nearest "
                         "neighbours")
    return KNearest(pts).kth_distance_among(k)


def adaptive_supports(points: np.ndarray, support_ratio: float, neighbours: int,
                      area: float, boundary=None) -> np.ndarray:
    """Per-point support ``support_ratio * d_k * sqrt(pi / k)`` (module doc);
    the points ``boundary`` (an index or mask: boundary samples) get
    ``BOUNDARY_SUPPORT_SCALE`` times that."""
    d_k = kth_neighbour_distance(points, neighbours, area)
    if not (d_k > 0).all():
        # k + 1 copies of a point: its k-th neighbour is itself, its support zero
        # (and its pairs none: the copies would pass unseen); name them
        from .pointset import check_distinct
        check_distinct(points, 0.0)
    h = support_ratio * d_k * math.sqrt(math.pi / neighbours)
    if boundary is not None:
        h[boundary] *= BOUNDARY_SUPPORT_SCALE
    return h


# ---------------------------------------------------------------------------
# Pair list for adaptive supports
#
# With one support a 3 x 3 block of cells as wide as the support holds every
# neighbour; with adaptive supports those cells must be as wide as the largest
# support (boundary samples', sparse patches'), and each query then tests many
# times the candidates it keeps (clusters: ~10x).  Instead the particles are
# binned in cells a fraction of the median support wide, and each query scans
# the block of cells its own reach needs: the larger of its support and the
# largest support that can reach its cell from any cell around (``reach``).

#: cells per median support of the adaptive pair search
CELLS_PER_SUPPORT = 2.0
#: but never more cells per largest support than this (the reach of each cell
#: gathers over that many cells around it), nor more cells than this many per
#: particle (points in a tiny cluster and a few far away)
MAX_CELLS_PER_LARGEST = 8.0
MAX_CELLS_PER_PARTICLE = 4.0


@ti.kernel
def _cell_reach(cell_start: ti.types.ndarray(), hs: ti.types.ndarray(), nx: ti.i32, ny: ti.i32,
                inv_cell: float, k_max: ti.i32, cmax: ti.types.ndarray(),
                reach: ti.types.ndarray()):
    """reach[c]: the largest support of a particle whose support can cover a point
    of cell c (the particles of the cells within that support's cell count)."""
    for c in range(nx * ny):
        m = 0.0
        for k in range(cell_start[c], cell_start[c + 1]):
            m = ti.max(m, hs[k])
        cmax[c] = m
    for c in range(nx * ny):
        cy = c // nx
        cx = c - cy * nx
        r = 0.0
        for gy in range(ti.max(cy - k_max, 0), ti.min(cy + k_max, ny - 1) + 1):
            for gx in range(ti.max(cx - k_max, 0), ti.min(cx + k_max, nx - 1) + 1):
                h = cmax[gy * nx + gx]
                kc = ti.cast(ti.ceil(h * CELL_PAD * inv_cell), ti.i32)
                if ti.abs(gx - cx) <= kc and ti.abs(gy - cy) <= kc:
                    r = ti.max(r, h)
        reach[c] = r


def adaptive_grid_spec(points: np.ndarray, supports: np.ndarray):
    """The binning grid of :func:`adaptive_pairs`: cells of the median support
    over :data:`CELLS_PER_SUPPORT` covering ``points``, widened where the
    supports or the points' extent would make too many (module constants)."""
    from .neighbors import GridSpec
    lo, hi = points.min(axis=0), points.max(axis=0)
    area = float(np.prod(hi - lo + float(supports.max())))
    cell = max(float(np.median(supports)) / CELLS_PER_SUPPORT,
               float(supports.max()) / MAX_CELLS_PER_LARGEST,
               math.sqrt(area / (MAX_CELLS_PER_PARTICLE * len(points))))
    return GridSpec.covering(lo, hi, cell)


def adaptive_pairs(pairs, particles, grid, hs, duplicate_tolerance: float = 0.0):
    """Fill ``pairs`` (a new :class:`~taichi_hh.sph.neighbors.PairList`) with the
    pairs of ``particles`` (binned by ``grid``, of :func:`adaptive_grid_spec`)
    under the per-slot supports ``hs``: pair (i, j) when |x_i - x_j| < max(H_i,
    H_j), rows sorted by slot: the rows ``PairList.build`` gives for the same
    slots.  Pairs closer than ``duplicate_tolerance`` raise :class:`InputError`
    (``pairs.duplicate_query`` then names the query, as ``build`` does)."""
    s = grid.spec
    n = particles.n
    h_max = float(hs.to_numpy()[:n].max()) if n else 0.0
    k_max = int(math.ceil(h_max * CELL_PAD / s.cell_size))
    cmax = runtime.array(runtime.real_dtype(), s.ncells)
    reach = runtime.array(runtime.real_dtype(), s.ncells)
    _cell_reach(grid.cell_start, hs, s.nx, s.ny, s.inv_cell, k_max, cmax, reach)
    pairs.build(particles.position, n, particles.position, grid, s.cell_size, exclude_self=True,
                duplicate_tolerance=duplicate_tolerance, supports=(hs, hs), reach=reach)
