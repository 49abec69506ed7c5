"""Boundary particles of the default boundary method ``collocation``: samples
along the boundary carrying the outward normal, whose rows enforce the Neumann
condition d phi/dn = 0 (Petronetto Eq. 6) where no data point already sits."""
from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..checks import check_spread
from ..sph.knn import KNearest
from ..sph.pointset import check_distinct

#: the data's local spacing at a boundary sample is measured from its this
#: many nearest data points (k = 8 left the spacing noisy on uniformly random
#: points: 200k, 14/12 iterations against 9/10 with 16; docs/notes/scattered.md)
SPACING_NEIGHBOURS = 16
#: ... of each of the sample's this many nearest data points, averaged
NEAREST_AVERAGED = 4
#: a boundary longer than this many mean spacings per data point is refused:
#: the domain is far narrower than the points' spacing (mean width
#: 2 area / perimeter below 1/32 of it), and sampling it once took hours
#: (a square's boundary takes 4 sqrt(N) samples, a 1000:1 strip's 63 sqrt(N))
MAX_SAMPLES_PER_POINT = 64


def collocation_particles(domain, points, spacing: float, local: bool = False):
    """Boundary samples and their outward normals, without those within a
    quarter spacing of a data point (data points on the boundary take over).

    Next to a re-entrant corner a sample's neighbours reach around the
    corner, beyond its wall's tangent line: its Neumann row's fit leaves
    them out (:func:`~taichi_hh.sph.fits.beyond_wall`), so that every sample
    is kept.

    The samples are ``spacing`` apart, or with ``local`` as far apart as the
    data next to the boundary: where the data are denser or sparser than on
    average (a density gradient, clusters), samples at the mean spacing leave
    Neumann rows over lopsided neighbourhoods, and the solver's iterations
    grew with N (1:10 gradient, 500k points: 36/28 iterations, 11/12 with
    local spacing; docs/notes/scattered.md).

    Points that span no area (:func:`~taichi_hh.checks.check_spread`)
    and domains too narrow for the points are refused before any sample is
    made, copies of a point before the local spacing (zero there) is used."""
    check_spread(points)
    check_not_too_narrow(domain, len(points), spacing)
    if not local:
        bpts, bnrm, _ = domain.sample_boundary(spacing)
        keep = far_from(bpts, points, 0.25 * spacing, domain)
        return _kept(bpts, bnrm, keep, len(points))
    pts = np.asarray(points, dtype=np.float64)
    k = min(SPACING_NEIGHBOURS, len(pts) - 1)
    search = KNearest(pts)

    def data_spacing(q):
        # the spacing of the data points nearest q: k others in the half disc
        # of radius r on the domain's side of a point at the wall, a spacing
        # of r sqrt(pi / 2k).  The nearest points', not q's own k nearest:
        # where the data stop short of the wall, the samples keep the data's
        # spacing and the gap is found (check_data_reach_boundary).  Their
        # mean tapered at the m-th (KNearest.nearest_weights): a plain mean
        # jumps where the m-th and (m+1)-th are tied (a lattice), and every
        # sample after that place with it (r moved 1e-4 under a 4e-16 move)
        m = min(NEAREST_AVERAGED, len(pts))
        nearest, weight = search.nearest_weights(q, m)
        own = search.query(pts[nearest.ravel()], k + 1)[0][:, -1].reshape(nearest.shape)
        local = (weight * own).sum(axis=1) * math.sqrt(math.pi / (2 * k))
        if not (local > 0).all():       # k + 1 copies of a point: name them
            check_distinct(pts)
        return local

    bpts, bnrm, _ = domain.sample_boundary(spacing, spacing_at=data_spacing)
    nearest = search.query(bpts, 1)[0][:, 0]
    local_spacing = data_spacing(bpts)
    keep = nearest >= 0.25 * local_spacing
    return _kept(bpts, bnrm, keep, len(points))


def check_not_too_narrow(domain, n: int, spacing: float) -> None:
    """Refuse a domain whose boundary takes more than
    :data:`MAX_SAMPLES_PER_POINT` samples per data point at ``spacing``."""
    samples = domain.perimeter / spacing
    if samples > MAX_SAMPLES_PER_POINT * max(n, 1):
        raise InputError(
            f"the domain is too narrow for the points: its boundary, {domain.perimeter:.3g} "
            f"long around an area of {domain.area:.3g}, is {samples:.3g} times the points' "
            f"mean spacing ({spacing:.3g}) long, more than {MAX_SAMPLES_PER_POINT} per point "
            f"({n} points); a domain thinner than the spacing between the points holds no 2D "
            "field: give a domain the points fill (domain='bbox', domain='hull' or domain='alpha')")


def _kept(bpts, bnrm, keep, n: int):
    """The boundary samples ``keep`` selects, refused when none is left."""
    if not keep.any():
        raise InputError(
            f"the domain's boundary is covered by the points: each of its {len(bpts)} samples "
            f"lies within a quarter spacing of one of the {n} points, so no boundary condition "
            "can be placed; the points crowd the boundary, or the domain is as narrow as the "
            "points' spacing: give a domain the points fill with room inside")
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
