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

The data say which: the flow next to the boundary, its normal and its
tangential components relative to v's size (:func:`boundary_flow`).  The
flow crosses a window's edges: its normal part 0.35-0.78 on every window and
real PIV field tried (pivpy's seven samples, the synthetic windows,
Petronetto's fields, a rigid rotation).  A container's flow runs along its
walls: normal part 0.02-0.09 and tangential 0.19-1.1 on closed cavity flows
sampled at 900-15k random points (0.19: a no-slip cavity at 900 points, whose
flow dies towards the walls), with 2% noise normal 0.07.  A field calm next
to the boundary (both parts below :data:`CLOSED_FLUX`: isolated vortices and
sources with calm air at the region's edges) shows no wall: it is taken as a
window, whose natural split is the split of the field continued by zero
beyond the boundary (the free-space one, what a global method gives), and
where the potentials vanish at the boundary every condition's answer.  Read
as a container it had cost accuracy for nothing: no-flux errs 2.7-3.0% on 15k
random points where the natural split errs 0.5-0.6% on the same compact
bumps (docs/notes/lonlat.md).

A window's natural split is kept unless its parts cancel
(:func:`natural_cancels`): when the free-space flow of the vorticity and
divergence inside carries much more energy than the field itself, what
bounds the flow (walls, shear layers, the opposite vorticity) lies at or
beyond the window's edges, and the natural d and r are large opposite fields
whose sum h undoes.  The split is then made again under ``normal-parallel``,
whose parts are L2-orthogonal (phi = psi = 0 on the boundary: the cross
terms integrate to zero) and so cannot cancel, and that split is kept if its
parts' energy is closer to the field's (:func:`energy_closer`; data with gaps
along the boundary can serve the Dirichlet rows worse).  Measured: the natural
split's parts carry 0.92-1.04 of the energy on the synthetic windows (exact
parts), 0.71-1.17 on six of pivpy's seven samples, and 1.69 on the soap film
(TSI Insight), whose boundary-layer vorticity runs along both side edges of
the frame (0.89 under normal-parallel).
"""
from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

__all__ = ["boundary_flux", "boundary_flow", "band_flow", "is_closed", "flux_band",
           "choose_boundary_condition", "natural_cancels", "energy_closer",
           "window_split",
           "CLOSED_FLUX", "FLUX_BAND", "CANCELLING_RATIO", "ORTHOGONAL_CONDITION"]

#: below this :func:`boundary_flux` the flow does not cross the boundary; a
#: closed container's flow also runs along it, its tangential part next to the
#: boundary (relative to v's size, :func:`boundary_flow`) at least this much
CLOSED_FLUX = 0.15
#: the natural split's parts carrying more than this many times the field's
#: energy (|d|^2 + |r|^2 + |h|^2 over |v|^2) cancel each other: a third of
#: their energy or more is in opposite parts
CANCELLING_RATIO = 1.5
#: the condition ``auto`` falls back to where the natural parts cancel
ORTHOGONAL_CONDITION = "normal-parallel"
#: the band next to the boundary whose points measure the flux, in mean spacings
FLUX_BAND = 1.5


def flux_band(points: np.ndarray, domain, spacing: float, band: float = FLUX_BAND) -> tuple:
    """``(near, normal)``: the indices of the points within ``band * spacing``
    of the boundary and the outward normals at their closest boundary points
    (what :func:`boundary_flux` reads of the points alone: a series on fixed
    points makes it once)."""
    reach = band * spacing
    # the closest boundary point only for the points that can be in the band:
    # the locator's cells clear the rest at once (a distance per point is
    # most of this function's cost at 1M points: docs/notes/hhd.md)
    candidates = np.flatnonzero(domain.classify_discs(points, 0.0, -np.inf, -reach) != 1)
    dist, _, normal, _ = domain.closest_boundary(points[candidates])
    keep = dist < reach
    return candidates[keep], normal[keep]


def band_flow(band_vectors: np.ndarray, normal: np.ndarray, size) -> tuple:
    """``(flux, along)``: the RMS of the normal part v.n and of the tangential
    part v - (v.n) n of the vectors ``band_vectors`` next to the boundary
    (``normal``: the outward normals there), each over the square root of
    ``size`` (the mean of abs(v)^2 over all points); ``(0, 0)`` for a field
    that is zero, ``(nan, nan)`` with no vector in the band (the flow next to
    the boundary unknown).  Several fields at once: ``band_vectors`` (k, M,
    2) and ``size`` (k,) give (k,) arrays."""
    bv = np.asarray(band_vectors)
    size = np.asarray(size, dtype=np.float64)
    m = bv.shape[-2]
    if m == 0:
        flux = along = np.full(size.shape, np.nan)
    else:
        # einsum: one pass each, no temporaries (a series pays this per snapshot)
        normal_part = np.einsum("...ij,ij->...i", bv, normal)
        tangential = bv - normal_part[..., None] * normal
        zero = size == 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            flux = np.where(zero, 0.0, np.sqrt(
                np.einsum("...i,...i->...", normal_part, normal_part) / m / size))
            along = np.where(zero, 0.0, np.sqrt(
                np.einsum("...ij,...ij->...", tangential, tangential) / m / size))
    if flux.ndim == 0:
        return float(flux), float(along)
    return flux, along


def boundary_flow(points: np.ndarray, vectors: np.ndarray, domain, spacing: float,
                  band: float = FLUX_BAND, *, near=None) -> tuple:
    """``(flux, along)`` of :func:`band_flow` over the points within ``band *
    spacing`` of the boundary (n: the outward normal at the closest boundary
    point).  ``near``: :func:`flux_band`'s answer for these points, if made
    already."""
    near = flux_band(points, domain, spacing, band) if near is None else near
    flux, along = boundary_flows([vectors], near)
    return float(flux[0]), float(along[0])


def boundary_flows(fields, near) -> tuple:
    """``(flux, along)``, (k,) arrays: :func:`boundary_flow` of each of the k
    ``fields`` ((N, 2) each) on the same points, ``near`` their
    :func:`flux_band`: one :func:`band_flow` of their bands (a series'
    batch)."""
    idx, normal = near
    band = np.stack([np.take(v, idx, axis=0) for v in fields])
    # mean abs(v)^2 over all points
    size = np.array([np.einsum("ij,ij->", v, v) for v in fields]) / max(len(fields[0]), 1)
    return band_flow(band, normal, size)


def boundary_flux(points: np.ndarray, vectors: np.ndarray, domain, spacing: float,
                  band: float = FLUX_BAND, *, near=None) -> float:
    """RMS of v.n over the points within ``band * spacing`` of the boundary
    (n: the outward normal at the closest boundary point) over the RMS of
    abs(v) over all points; 0 for a field that is zero.  With no point in the
    band (data far from the boundary) the flux is unknown: NaN.  ``near``:
    :func:`flux_band`'s answer for these points, if made already."""
    return boundary_flow(points, vectors, domain, spacing, band, near=near)[0]


def is_closed(flux: float, along: float, boundary: str) -> bool:
    """Whether :func:`boundary_flow`'s ``(flux, along)`` read as a closed
    container: the flow next to the boundary runs along it (flux below
    :data:`CLOSED_FLUX`, the tangential part not), with boundary samples to
    carry no-flux's rows (``boundary="collocation"``).  Calm next to the
    boundary (both below) is no wall (module doc)."""
    return bool(np.isfinite(flux) and flux < CLOSED_FLUX and along >= CLOSED_FLUX
                and boundary == "collocation")


def choose_boundary_condition(points, vectors, domain, spacing: float, boundary: str, *,
                              near=None, flow=None) -> tuple:
    """``(condition, flux, along)``: ``"no-flux"`` for a closed container
    (:func:`is_closed` of :func:`boundary_flow`), else ``"natural"``.
    ``flow``: that ``(flux, along)``, made already (:func:`boundary_flows`)."""
    flux, along = boundary_flow(points, vectors, domain, spacing, near=near) \
        if flow is None else flow
    return ("no-flux" if is_closed(flux, along, boundary) else "natural"), flux, along


def natural_cancels(energy_ratio: float) -> bool:
    """Whether a natural split whose parts carry ``energy_ratio`` times the
    field's energy should give way to :data:`ORTHOGONAL_CONDITION` (module
    doc): above :data:`CANCELLING_RATIO`, or not finite."""
    return not (np.isfinite(energy_ratio) and energy_ratio <= CANCELLING_RATIO)


def energy_closer(ratio: float, other: float) -> bool:
    """Whether parts carrying ``ratio`` times the field's energy are closer to
    an exact decomposition's 1 than parts carrying ``other`` (by the factor:
    2 and 0.5 are as far), a finite ratio closer than a non-finite one."""
    if not np.isfinite(ratio) or ratio <= 0:
        return False
    if not np.isfinite(other) or other <= 0:
        return True
    return abs(np.log(ratio)) < abs(np.log(other))


def window_split(attempt, opts, chosen: dict) -> tuple:
    """``(unit result, options, chosen)`` of ``auto``'s window split:
    ``attempt(options)`` (a unit-frame decomposition) under the natural
    condition, kept unless its parts cancel (:func:`natural_cancels`), then
    under :data:`ORTHOGONAL_CONDITION`, kept if its parts' energy is closer
    to the field's (:func:`energy_closer`).  The warnings of the attempt not
    kept are not the answer's and are dropped with it."""
    def run(options):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            return attempt(options), caught

    def answer(unit, caught):
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return unit

    natural, natural_warnings = run(opts)
    ratio = natural.stats["energy_ratio"]
    if not natural_cancels(ratio):
        return answer(natural, natural_warnings), opts, chosen
    orthogonal_opts = replace(opts, boundary_condition=ORTHOGONAL_CONDITION)
    orthogonal, orthogonal_warnings = run(orthogonal_opts)
    seconds = {"natural": natural.stats["seconds"]["total"],
               "orthogonal": orthogonal.stats["seconds"]["total"]}
    if not energy_closer(orthogonal.stats["energy_ratio"], ratio):
        # data the orthogonal condition serves worse (gaps at the boundary):
        # the natural split stands, with its own flags
        natural.stats["seconds"]["auto_attempts"] = seconds
        return answer(natural, natural_warnings), opts, {
            **chosen, "orthogonal_energy_ratio": orthogonal.stats["energy_ratio"]}
    orthogonal.stats["seconds"]["auto_attempts"] = seconds
    return answer(orthogonal, orthogonal_warnings), orthogonal_opts, {
        **chosen, "boundary_condition": ORTHOGONAL_CONDITION, "natural_energy_ratio": ratio}
