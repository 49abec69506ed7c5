"""Boundary particles of the default boundary method ``collocation``: samples
along the boundary carrying the outward normal, whose rows enforce the Neumann
condition d phi/dn = 0 (Petronetto Eq. 6) where no data point already sits."""
from __future__ import annotations

import math

import numpy as np

from ..sph.knn import KNearest

#: the data's local spacing at a boundary sample is measured from its this
#: many nearest data points (k = 8 left the spacing noisy on uniformly random
#: points: 200k, 14/12 iterations against 9/10 with 16; docs/notes/scattered.md)
SPACING_NEIGHBOURS = 16
#: ... of each of the sample's this many nearest data points, averaged
NEAREST_AVERAGED = 4


def collocation_particles(domain, points, spacing: float, local: bool = False):
    """Boundary samples and their outward normals, without those within a
    quarter spacing of a data point (data points on the boundary take over).

    The samples are ``spacing`` apart, or with ``local`` as far apart as the
    data next to the boundary: where the data are denser or sparser than on
    average (a density gradient, clusters), samples at the mean spacing leave
    Neumann rows over lopsided neighbourhoods, and the solver's iterations
    grew with N (1:10 gradient, 500k points: 36/28 iterations, 11/12 with
    local spacing; docs/notes/scattered.md)."""
    if not local:
        bpts, bnrm, _ = domain.sample_boundary(spacing)
        keep = far_from(bpts, points, 0.25 * spacing, domain)
        return bpts[keep], bnrm[keep]
    pts = np.asarray(points, dtype=np.float64)
    k = min(SPACING_NEIGHBOURS, len(pts) - 1)
    search = KNearest(pts)

    def data_spacing(q):
        # the spacing of the data points nearest q: k others in the half disc
        # of radius r on the domain's side of a point at the wall, a spacing
        # of r sqrt(pi / 2k).  The nearest points', not q's own k nearest:
        # where the data stop short of the wall, the samples keep the data's
        # spacing and the gap is found (check_data_reach_boundary)
        m = min(NEAREST_AVERAGED, len(pts))
        nearest = search.query(q, m)[1]
        own = search.query(pts[nearest.ravel()], k + 1)[0][:, -1].reshape(nearest.shape)
        return own.mean(axis=1) * math.sqrt(math.pi / (2 * k))

    bpts, bnrm, _ = domain.sample_boundary(spacing, spacing_at=data_spacing)
    nearest = search.query(bpts, 1)[0][:, 0]
    keep = nearest >= 0.25 * data_spacing(bpts)
    return bpts[keep], bnrm[keep]


def far_from(candidates, points, radius, domain):
    """Mask of candidates (boundary samples) farther than ``radius`` from every point.
    Only points within ``radius`` of the boundary can be that close."""
    keep = np.ones(len(candidates), dtype=bool)
    # points whose disc (a hair wider) lies inside the domain are decided by the
    # locator's cells at once; the distances of the others are computed
    inside = domain.classify_discs(points, radius * (1 + 1e-9), -np.inf, 0.0) == 1
    rest = points[~inside]
    near = rest[domain.closest_boundary(rest)[0] < radius]
    for start in range(0, len(near), 2048):
        block = near[start:start + 2048]
        d2 = ((candidates[:, None, :] - block[None, :, :]) ** 2).sum(axis=2)
        keep &= (d2 >= radius * radius).all(axis=1)
    return keep
