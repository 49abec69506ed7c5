"""Boundary particles of the default boundary method ``collocation``: samples
along the boundary carrying the outward normal, whose rows enforce the Neumann
condition d phi/dn = 0 (Petronetto Eq. 6) where no data point already sits."""
from __future__ import annotations

import numpy as np


def collocation_particles(domain, points, spacing: float):
    """Boundary samples at ``spacing`` and their outward normals, without those
    within a quarter spacing of a data point (data points on the boundary take over)."""
    bpts, bnrm, _ = domain.sample_boundary(spacing)
    keep = far_from(bpts, points, 0.25 * spacing, domain)
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
