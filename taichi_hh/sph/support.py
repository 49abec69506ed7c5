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

from ..errors import InputError

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
    h = support_ratio * d_k * math.sqrt(math.pi / neighbours)
    if boundary is not None:
        h[boundary] *= BOUNDARY_SUPPORT_SCALE
    return h
