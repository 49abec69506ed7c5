"""Critical points of a decomposition: sources, sinks and vortices
(Petronetto Sec. 6c: the extrema of the potentials phi and psi).

With d = grad phi, a source (div v > 0, lap phi > 0) is a minimum of phi and a
sink a maximum; with r = J grad psi, curl v = -lap psi, so a counter-clockwise
vortex is a maximum of psi and a clockwise one a minimum.

Measured data (issue 28) add three kinds of extremum that are no critical
point of the flow, filtered by default (``filter=False`` keeps them):

* boundary artefacts: extrema on the data's outermost row, where the
  operators are one-sided and the data do not surround the point
  (:data:`EDGE`);
* noise: extrema of the potential that noise in the data makes, of a size
  the noise explains: the derivative's mean over a disc of a few spacings
  must stand far above what the data's noise gives it
  (:data:`SIGNIFICANCE`);
* outliers: a wrong vector makes a dipole of divergence and curl (a source
  beside a sink, a vortex beside one turning the other way) within a kernel
  support; a real source or vortex keeps its sign over a disc of several
  spacings (:data:`COHERENCE`).

Strengths are relative to a robust scale of the field's derivatives (the
:data:`SCALE_PERCENTILE` th percentile of |div v| and |curl v| away from the
boundary): on measured data the largest derivative sits at one wrong vector
or a corner, tens of times the typical one (docs/notes/hhd.md).
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

#: the default ``threshold``: a critical point's |div d| or |curl r| at least
#: this times the field's robust derivative scale (:func:`strength_scale`)
THRESHOLD = 0.1
#: the robust scale: this percentile of |div v| and |curl v| (the larger) ...
SCALE_PERCENTILE = 99.0
#: ... over the points at least this many local spacings inside the boundary
#: (all points where fewer than a quarter are): the one-sided operators at
#: the boundary and wrong vectors there make the largest derivatives
SCALE_EDGE = 2.0
#: derivatives below this times max |v| / spacing are rounding or discretisation
#: noise, whatever their size relative to the field's own (a harmonic field's
#: div v and curl v of 1e-15 are no sources or vortices): the scale's floor
NOISE_FLOOR = 1e-3
#: boundary artefacts: candidates closer than this many local spacings to the
#: domain's boundary are left out (on a grid: the outermost row of nodes, half
#: a spacing from the outline)
EDGE = 1.0
#: noise: the mean of div d (or curl r) over a disc around a candidate, of
#: one of ``SIGNIFICANCE_RADII`` local spacings, must be this many times the
#: standard deviation that white noise of the data's size gives that mean
#: (:func:`noise_sigma`, the operator's rows).  Three times a white-noise
#: test's 5 because measured noise is not white: PIV's overlapping windows
#: correlate neighbouring vectors, and the white model then underestimates
#: the noise of a disc mean 2-4 times.  Measured (docs/notes/hhd.md): noise
#: extrema below 3 (white noise) and up to 14 (noise correlated as 50%
#: window overlap makes it; rarely 16-23, and up to 42 with noise correlated
#: over 3 x 3 nodes); Gaussian vortices 40-270 on a 64 x 64 grid with 5-20%
#: noise, 18-41 on 4000 random points with 5-10%; pivpy's samples 16-230.
#: Several radii: a weak but wide structure (a cavity's recirculation) gains
#: with the disc, a noise blob as wide as its correlation does not
SIGNIFICANCE = 15.0
SIGNIFICANCE_RADII = (2.0, 3.0, 4.0, 5.0)
#: outliers: over the disc of ``COHERENCE_RADIUS`` local spacings, sum(c) /
#: sum(|c|) of the candidate's derivative c, signed by the kind, at least this
#: (1: one sign throughout; about 0 for the dipole of a wrong vector)
COHERENCE = 0.75
COHERENCE_RADIUS = 3.0
#: the data's noise is estimated at this many points at most (a median)
NOISE_SAMPLES = 2000
#: on a grid (the grid-native natural path), the binomial passes
#: (:func:`~taichi_hh.hhd.natural_grid.smoothed`) over the potentials before
#: their extrema are sought, and one over div v, curl v, div d and curl r: the
#: scattered path smooths the data's derivatives by its MLS operators (one pass
#: matches its divergence on pivpy's noisy samples, 16-22% apart against
#: 31-54% unsmoothed) and its potentials' density once more by the MLS
#: reconstruction onto its cells; with fewer passes the extrema that PIV's
#: correlated noise makes in the potentials pass as weak vortices
#: (tests/test_critical.py, the "piv" layout: two at significance 17-21)
POT_PASSES = 3


class CriticalPoint(namedtuple("CriticalPoint", "x y kind")):
    """A source, sink or vortex: unpacks as ``(x, y, kind)``.

    ``strength``: its |div d| (sources, sinks) or |curl r| (vortices) at the
    point over the field's robust derivative scale (:func:`strength_scale`;
    a vortex as strong as the strongest 1% of the field's vorticity has about
    1, more for a peak above them): rank points by it.  ``significance``: the
    mean derivative over a disc around it (the best of ``SIGNIFICANCE_RADII``
    local spacings) over the standard deviation that white noise of the
    data's size would give that mean (inf for data without noise).
    ``coherence``: sum(c) / sum(|c|) of the derivative c over the disc of
    ``COHERENCE_RADIUS`` local spacings, signed by the kind (1: one sign
    throughout).  NaN where not measured (``filter=False``)."""

    def __new__(cls, x, y, kind, strength=float("nan"), significance=float("nan"),
                coherence=float("nan")):
        self = super().__new__(cls, x, y, kind)
        self.strength = float(strength)
        self.significance = float(significance)
        self.coherence = float(coherence)
        return self

    def __repr__(self):
        return (f"CriticalPoint(x={self.x:.6g}, y={self.y:.6g}, kind={self.kind!r}, "
                f"strength={self.strength:.3g})")


def critical_points(result, threshold: float = THRESHOLD, radius: float | None = None,
                    **filters):
    """:func:`find_critical_points` of a decomposition in the caller's units:
    an :class:`~taichi_hh.hhd.decompose.HHDResult` (run in its unit frame,
    positions mapped back; ``radius`` in the points' units) or a
    :class:`~taichi_hh.hhd.grid.GridResult` (its scattered decomposition, or
    on the grid where the grid-native path ran:
    :func:`~.critical_grid.find_grid_critical_points`)."""
    lattice = getattr(result, "lattice", None)
    if lattice is not None:              # the grid-native natural path: on the grid
        # the grid's path imports this module's tests and constants
        from .critical_grid import find_grid_critical_points
        return find_grid_critical_points(lattice, threshold, radius, **filters)
    result = getattr(result, "scattered", None) or result
    unit, frame = getattr(result, "unit", None), getattr(result, "frame", None)
    if unit is None or frame is None:
        return find_critical_points(result, threshold, radius, **filters)
    found = find_critical_points(unit, threshold,
                                 None if radius is None else radius / frame.length, **filters)
    out = []
    for c in found:
        x, y = frame.points_from_unit([c.x, c.y])
        out.append(CriticalPoint(float(x), float(y), c.kind, c.strength, c.significance,
                                 c.coherence))
    return out


def find_critical_points(res, threshold: float = THRESHOLD, radius: float | None = None, *,
                         filter: bool = True, edge: float | None = EDGE,
                         significance: float | None = SIGNIFICANCE,
                         coherence: float | None = COHERENCE):
    """``[CriticalPoint(x, y, kind, strength)]`` with kind in source | sink |
    cw_vortex | ccw_vortex, strongest first.

    A point is a candidate when its potential is the strict extremum among all
    data points within ``radius`` (default: twice its kernel support, local
    with the adaptive support).  Its strength is the derivative of the
    component the potential makes, |div d| for phi and |curl r| for psi (so a
    potential that carries nothing, e.g. psi of a rigid rotation under the
    Neumann condition, which puts the rotation into h, has no vortex), over
    the field's robust scale S (:func:`strength_scale`: the 99th percentile of
    |div v| and |curl v| away from the boundary, not their maximum, which on
    measured data sits at a wrong vector or a corner).  It is kept when

    - the strength is at least ``threshold``;
    - its sign is the kind's (div d > 0 at a source, curl r > 0 at a
      counter-clockwise vortex);
    - the component is a zero there: |d| (or |r|) at the point at most the
      derivative times ``radius`` (what a linear zero within ``radius`` gives).
      A potential with Dirichlet data (normal-parallel) or none (natural) has
      extrema at the boundary where the component is no zero, just tangent or
      normal to the boundary: not critical points;

    and, with ``filter`` (the default; ``filter=False`` skips these three
    filters for measured data, ``None`` for one of them skips that one):

    - it lies at least ``edge`` local spacings inside the domain's boundary
      (boundary artefacts: the data do not surround it; on a grid the
      outermost row of nodes);
    - the mean derivative over a disc around it, of radius 2, 3, 4 or 5 local
      spacings (:data:`SIGNIFICANCE_RADII`, the best), is at least
      ``significance`` times the standard deviation that white noise of the
      data's size (:func:`noise_sigma`) gives that mean through the
      operator's rows (noise-level extrema; a weak but wide vortex passes on
      its wider discs, where the noise averages down and it does not);
    - the derivative keeps the kind's sign over the disc of
      ``COHERENCE_RADIUS`` local spacings: sum(c) / sum(|c|) at least
      ``coherence`` (a wrong vector's dipole, a source beside a sink, gives
      about 0).

    The discs hold the data points within ``radius`` of the candidate only
    (a smaller ``radius`` than 5 local spacings clips them) and inside the
    domain.

    Local spacing: the mean spacing sqrt(area / N) scaled by the point's
    adaptive support over the median one (the mean spacing with a fixed
    support).  The position is refined to the stationary point of a
    quadratic least-squares fit of the potential over the point's kernel
    neighbours (kept at the point if the fit's stationary point falls
    outside ``radius`` or the domain).
    """
    pts = np.asarray(res.points, dtype=np.float64)
    n = len(pts)
    if n < 4:
        return []
    if not filter:
        edge = significance = coherence = None
    ps = res.pointset
    domain = getattr(res, "domain", None)
    variant = res.options.divergence
    spacing = float(res.stats["spacing"])
    sup = np.asarray(ps.supports, dtype=np.float64)[:n]
    ell = spacing * sup / float(np.median(sup))
    rad = 2.0 * sup if radius is None else np.full(n, float(radius))
    dist = None
    if domain is not None:
        dist = domain.closest_boundary(pts)[0]
    scale = strength_scale(res, None if dist is None else dist / ell)
    if scale == 0.0 or not math.isfinite(scale):
        return []
    rows = _Rows(ps, n, variant)
    near = None                  # points within rad of a candidate, built on demand
    sigma = None                 # the data's noise, estimated on demand
    out = []
    for pot, field, component, kinds, signs in (
            (res.phi, res.curl_free, lambda: ps.divergence(res.curl_free, variant),
             ("source", "sink"), (1, -1)),
            (res.psi, res.div_free, lambda: ps.curl(res.div_free, variant),
             ("cw_vortex", "ccw_vortex"), (-1, 1))):
        pot = np.asarray(pot, dtype=np.float64)
        comp = np.asarray(component(), dtype=np.float64)
        strength = np.abs(comp) / scale
        # the vectorised tests: extremum among the kernel neighbours (a
        # necessary condition: they lie within radius), sign, zero, threshold
        lo, hi = rows.neighbour_range(pot)
        lowest = (pot < lo) & (comp * signs[0] > 0)
        highest = (pot > hi) & (comp * signs[1] > 0)
        cand = (lowest | highest) & (strength >= threshold) & (rows.count >= 2) & \
            (np.linalg.norm(field, axis=1) <= np.abs(comp) * rad)
        if dist is not None and edge is not None and edge > 0:
            cand &= dist >= edge * ell
        idx = np.flatnonzero(cand)
        if idx.size == 0:
            continue
        if near is None:
            near = _NeighbourRows(pts, float(rad.max()))
        for i in idx[np.argsort(-strength[idx], kind="stable")]:
            nb = near.within(i, rad[i])
            others = nb[nb != i]
            if others.size < 2:
                continue
            if lowest[i] and pot[i] < pot[others].min():
                kind = kinds[0]          # minimum: source / clockwise vortex
            elif highest[i] and pot[i] > pot[others].max():
                kind = kinds[1]          # maximum: sink / counter-clockwise vortex
            else:
                continue
            sign = 1.0 if comp[i] > 0 else -1.0
            r = np.hypot(pts[nb, 0] - pts[i, 0], pts[nb, 1] - pts[i, 1])
            z = c = math.nan
            if significance is not None:
                if sigma is None:
                    sigma = noise_sigma(pts, res.vectors)
                z = -math.inf
                for radius_i in SIGNIFICANCE_RADII:
                    disc = nb[r <= radius_i * ell[i]]
                    mean = sign * float(comp[disc].mean())      # > 0: the kind's sign
                    spread = sigma * rows.mean_row_norm(disc)
                    z = max(z, mean / spread if spread > 0 else
                            (math.inf if mean > 0 else -math.inf))
                if z < significance:
                    continue
            if coherence is not None:
                disc = comp[nb[r <= COHERENCE_RADIUS * ell[i]]]
                total = float(np.abs(disc).sum())
                c = sign * float(disc.sum()) / total if total > 0 else 1.0
                if c < coherence:
                    continue
            x, y = _refine(pts, pot, i, rows.neighbours(i), rad[i])
            if domain is not None and (x, y) != tuple(pts[i]) and \
                    not domain.contains(np.array([[x, y]]))[0]:
                x, y = pts[i]            # the fit's stationary point left the domain
            out.append(CriticalPoint(float(x), float(y), kind, strength[i], z, c))
    out.sort(key=lambda p: -p.strength)
    return out


def strength_scale(res, edge_distance=None) -> float:
    """The field's robust derivative scale S: the larger of the
    :data:`SCALE_PERCENTILE` th percentiles of |div v| and |curl v| over the
    points at least :data:`SCALE_EDGE` local spacings from the boundary
    (``edge_distance``, in local spacings; all points where it is None or
    fewer than a quarter are that far in), and at least :data:`NOISE_FLOOR`
    max |v| / spacing.  Not the maximum: on measured data that sits at a
    wrong vector or an isolated corner node, 36 times the median in pivpy's
    cavity sample, and would make every real vortex look weak."""
    div = np.abs(np.asarray(res.divergence, dtype=np.float64))
    curl = np.abs(np.asarray(res.curl, dtype=np.float64))
    ok = np.isfinite(div) & np.isfinite(curl)
    if edge_distance is not None:
        inside = ok & (np.asarray(edge_distance) >= SCALE_EDGE)
        if inside.sum() >= 0.25 * ok.sum():
            ok = inside
    if not ok.any():
        return 0.0
    v = np.asarray(res.vectors, dtype=np.float64)
    return scale_of(np.stack([div[ok], curl[ok]]), v[:, 0], v[:, 1], float(res.stats["spacing"]))


def scale_of(abs_div_curl: np.ndarray, u: np.ndarray, v: np.ndarray, spacing: float) -> float:
    """:func:`strength_scale` of the rows |div v|, |curl v| (2, n) already
    chosen and the field's components ``u``, ``v`` (the points it reads)."""
    # the largest speed by the squares (np.hypot's guard costs five times as
    # much; a speed near 1e154 in any units is not data)
    speed = float(np.sqrt(np.nanmax(u * u + v * v))) if len(u) else 0.0
    both = linear_percentile(abs_div_curl, SCALE_PERCENTILE)
    return max(float(both[0]), float(both[1]), NOISE_FLOOR * speed / spacing)


def linear_percentile(values: np.ndarray, q: float) -> np.ndarray:
    """``np.percentile(values, q, axis=-1)`` (its default, linear
    interpolation: the same arithmetic, the same result) by one partition,
    without the general function's per-call cost (a tenth of a millisecond,
    half the strength scale's time on a small grid)."""
    m = values.shape[-1]
    virtual = (m - 1) * (q / 100.0)
    lo = int(math.floor(virtual))
    hi = min(lo + 1, m - 1)
    gamma = virtual - lo
    part = np.partition(values, (lo, hi), axis=-1)
    below, above = part[..., lo], part[..., hi]
    diff = above - below
    # numpy's _lerp: from the nearer end
    return np.where(gamma >= 0.5, above - diff * (1.0 - gamma), below + diff * gamma)


def noise_sigma(points, vectors, samples: int = NOISE_SAMPLES) -> float:
    """The data's noise: 1.4826 x the median absolute deviation of each
    component of v from the quadratic moving-least-squares fit to its 20
    nearest neighbours (itself left out), at ``samples`` points spread over
    the input; about the noise's standard deviation for noisy data and the
    fit's third-order error for smooth data."""
    from .mls_reconstruct import mls_at
    pts = np.asarray(points, dtype=np.float64)
    v = np.asarray(vectors, dtype=np.float64)
    if len(pts) < 8:
        return 0.0
    step = max(1, -(-len(pts) // samples))
    at = np.arange(0, len(pts), step)
    fit = mls_at(pts, v, pts[at], k=min(20, len(pts) - 1), exclude_self=True)
    return 1.4826 * float(np.median(np.abs(v[at] - fit)))


def derivative_noise(res) -> np.ndarray:
    """Per point, the standard deviation of div v (and of curl v) that white
    noise of the data's size (:func:`noise_sigma`) makes: sigma times the
    2-norm of the divergence operator's row at the point (its response to
    unit white noise; large near the boundary, where the operator is
    one-sided)."""
    n = len(res.points)
    rows = _Rows(res.pointset, n, res.options.divergence)
    return noise_sigma(res.points, res.vectors) * rows.row_norms()


class _Rows:
    """The kernel neighbours of each data point among the data points (the
    pair list, kept in its slot order: no sort), and the divergence
    operator's coefficients on demand."""

    def __init__(self, ps, n, variant):
        self.ps, self.n, self.variant = ps, n, variant
        self.off, nb = ps.pairs.to_numpy()
        self.slot_of = ps.slot_of[:n]
        order = ps.order
        self.row = np.repeat(np.arange(len(self.off) - 1), np.diff(self.off))
        self.dst = order[nb]                       # data index of each pair's neighbour
        self.ok = (self.dst < n) & (nb != self.row)
        counts = np.bincount(self.row[self.ok], minlength=len(self.off) - 1)
        self.count = counts[self.slot_of]
        self._G = self._own = None

    def neighbours(self, i):
        s = self.slot_of[i]
        a, b = self.off[s], self.off[s + 1]
        return self.dst[a:b][self.ok[a:b]]

    def neighbour_range(self, values):
        """(min, max) of ``values`` over each data point's neighbours (inf,
        -inf where it has none)."""
        ext = np.concatenate([values, [np.nan]])
        vals = ext[np.where(self.ok, self.dst, self.n)]
        lo_s = np.full(len(self.off) - 1, np.inf)
        hi_s = np.full(len(self.off) - 1, -np.inf)
        full = np.diff(self.off) > 0
        if full.any():
            starts = self.off[:-1][full]
            lo_s[full] = np.fmin.reduceat(vals, starts)
            hi_s[full] = np.fmax.reduceat(vals, starts)
        lo, hi = lo_s[self.slot_of], hi_s[self.slot_of]
        lo[np.isnan(lo)] = np.inf
        hi[np.isnan(hi)] = -np.inf
        return lo, hi

    def _coefficients(self):
        """G (pairs, 2) on each neighbour and own (slots, 2) on the point
        itself: the divergence row of point i is own_i . v_i + sum_j G_ij . v_j."""
        if self._G is None:
            st = self.ps.gradient_stencil(self.variant)
            nslots = len(self.off) - 1
            G = st.G.to_numpy()[: self.off[-1]].astype(np.float64)
            own = st.s.to_numpy()[:nslots].astype(np.float64)
            for c in range(2):
                own[:, c] -= np.bincount(self.row, weights=G[:, c], minlength=nslots)
            self._G, self._own = G, own
        return self._G, self._own

    def row_norms(self):
        """Per data point, the 2-norm of its divergence row (data columns)."""
        G, own = self._coefficients()
        g2 = (own ** 2).sum(axis=1)
        g2 += np.bincount(self.row[self.ok], weights=(G[self.ok] ** 2).sum(axis=1),
                          minlength=len(g2))
        return np.sqrt(g2[self.slot_of])

    def mean_row_norm(self, disc):
        """2-norm of the mean of the divergence rows of the data points
        ``disc``: the response of the mean divergence over them to unit
        white noise."""
        G, own = self._coefficients()
        slots = self.slot_of[disc]
        starts, ends = self.off[slots], self.off[slots + 1]
        lengths = ends - starts
        pos = np.repeat(ends - lengths.cumsum(), lengths) + np.arange(lengths.sum())
        pos = pos[self.ok[pos]]
        keys = np.concatenate([self.dst[pos], disc])
        coef = np.concatenate([G[pos], own[slots]])
        uniq, inv = np.unique(keys, return_inverse=True)
        cx = np.bincount(inv, weights=coef[:, 0], minlength=len(uniq))
        cy = np.bincount(inv, weights=coef[:, 1], minlength=len(uniq))
        return math.sqrt(float((cx ** 2 + cy ** 2).sum())) / len(disc)


class _NeighbourRows:
    """The indices of the points within ``radius`` of point i, from a grid
    hash of cell ``radius`` built once (the candidates are few)."""

    def __init__(self, pts, radius):
        key = np.floor((pts - pts.min(axis=0)) / radius).astype(np.int64)
        self.nx = int(key[:, 0].max()) + 1
        cell = key[:, 1] * self.nx + key[:, 0]
        self.order = np.argsort(cell, kind="stable")
        self.sorted_cells = cell[self.order]
        self.pts, self.key, self.radius = pts, key, radius

    def within(self, i, radius=None):
        radius = self.radius if radius is None else radius
        kx, ky = self.key[i]
        cells = np.array([(ky + dy) * self.nx + kx + dx
                          for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                          if 0 <= kx + dx < self.nx])
        lo = np.searchsorted(self.sorted_cells, cells)
        hi = np.searchsorted(self.sorted_cells, cells + 1)
        cand = np.concatenate([self.order[a:b] for a, b in zip(lo, hi)])
        d2 = ((self.pts[cand] - self.pts[i]) ** 2).sum(axis=1)
        return cand[d2 < radius * radius]

    __getitem__ = within


def _refine(pts, pot, i, nb, radius):
    """Stationary point of a least-squares quadratic fit of pot around point i."""
    nb = np.append(nb, i)
    if len(nb) < 6:
        return tuple(pts[i])
    x = pts[nb] - pts[i]
    A = np.c_[np.ones(len(nb)), x[:, 0], x[:, 1], x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2]
    coef, *_ = np.linalg.lstsq(A, pot[nb], rcond=None)
    g = coef[1:3]
    H = np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])
    try:
        step = -np.linalg.solve(H, g)
    except np.linalg.LinAlgError:
        return tuple(pts[i])
    if not np.all(np.isfinite(step)) or np.linalg.norm(step) > radius:
        return tuple(pts[i])
    return tuple(pts[i] + step)
