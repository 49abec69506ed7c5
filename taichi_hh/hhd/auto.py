"""The default boundary condition, ``boundary_condition="auto"``, chosen from
the data.

Two kinds of data call for two different splits:

* a **window** of a larger flow (a PIV field of view, a radar scan, a regional
  model, a grid cut from a simulation): the flow crosses the window's edges.
  The split a scientist expects is the natural HHD's (Bhatia et al. 2014):
  what the sources and vortices inside induce is d and r, the stream and
  everything from outside is h.  Neumann's Eq. 6 forces d and r to carry no
  flux through edges the flow crosses, so large opposite d and r appear along
  them (20-30% errors on the windows of ``benchmarks/windows.py``);
* a **closed container** (a cavity, a tank, a simulation with walls): the
  flow does not cross the boundary, v.n = 0 there, and what circulates inside
  belongs to r however close to a wall it is, what its sources induce to d.
  The natural HHD would put the walls' influence (the image vortices) into
  h; the ``no-flux`` condition (d phi/dn = 0, psi = 0 on the boundary: d and
  r tangent to the walls) gives that split with h = 0.

The data say which: the normal component of v next to the boundary, relative
to v's size (:func:`boundary_flux`).  Measured (docs/notes/hhd.md): 0.35-0.78
on every window and real PIV field tried (pivpy's seven samples, the
synthetic windows, Petronetto's fields, a rigid rotation), 0.02-0.06 on a
closed cavity flow sampled at 1k-15k random points, with 2% noise 0.07.
"""
from __future__ import annotations

import numpy as np

__all__ = ["boundary_flux", "choose_boundary_condition", "CLOSED_FLUX", "FLUX_BAND"]

#: below this :func:`boundary_flux` the data are a closed container
CLOSED_FLUX = 0.15
#: the band next to the boundary whose points measure the flux, in mean spacings
FLUX_BAND = 1.5


def boundary_flux(points: np.ndarray, vectors: np.ndarray, domain, spacing: float,
                  band: float = FLUX_BAND) -> float:
    """RMS of v.n over the points within ``band * spacing`` of the boundary
    (n: the outward normal at the closest boundary point) over the RMS of
    abs(v) over all points; 0 for a field that is zero.  With no point in the
    band (data far from the boundary) the flux is unknown: NaN."""
    reach = band * spacing
    # the closest boundary point only for the points that can be in the band
    # (the locator's cells decide the rest: 0.05 s instead of 0.3 s at 1M)
    candidates = np.flatnonzero(domain.classify_discs(points, 0.0, -np.inf, -reach) != 1)
    dist, _, normal, _ = domain.closest_boundary(points[candidates])
    keep = dist < reach
    near = candidates[keep]
    size = float(np.mean((vectors ** 2).sum(axis=1)))
    if not keep.any():
        return float("nan")
    if size == 0.0:
        return 0.0
    normal_part = (vectors[near] * normal[keep]).sum(axis=1)
    return float(np.sqrt(np.mean(normal_part ** 2) / size))


def choose_boundary_condition(points, vectors, domain, spacing: float, boundary: str) -> tuple:
    """``(condition, flux)``: ``"no-flux"`` for a closed container
    (:func:`boundary_flux` below :data:`CLOSED_FLUX`, with boundary samples to
    carry its rows: ``boundary="collocation"``), else ``"natural"``."""
    flux = boundary_flux(points, vectors, domain, spacing)
    closed = np.isfinite(flux) and flux < CLOSED_FLUX and boundary == "collocation"
    return ("no-flux" if closed else "natural"), flux
