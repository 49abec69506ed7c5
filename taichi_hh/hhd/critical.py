"""Critical points of a decomposition: sources, sinks and vortices
(Petronetto Sec. 6c: the extrema of the potentials phi and psi).

With d = grad phi, a source (div v > 0, lap phi > 0) is a minimum of phi and a
sink a maximum; with r = J grad psi, curl v = -lap psi, so a counter-clockwise
vortex is a maximum of psi and a clockwise one a minimum.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

#: derivatives below this times max |v| / spacing are rounding or discretisation
#: noise, whatever their size relative to the field's own (a harmonic field's
#: div v and curl v of 1e-15 are no sources or vortices): measured in
#: docs/notes/hhd.md
NOISE_FLOOR = 1e-3
#: a candidate's |div d| or |curl r| must exceed this many times the noise that
#: the data's own noise makes there (:func:`derivative_noise`): noise in the
#: data makes potentials with many extrema of noise-level strength
#: (docs/notes/hhd.md)
SIGNIFICANCE = 5.0



class CriticalPoint(namedtuple("CriticalPoint", "x y kind")):
    """A source, sink or vortex: unpacks as ``(x, y, kind)``; ``strength`` is
    its |div d| (sources, sinks) or |curl r| (vortices) at the point relative to
    the field's largest |div v| or |curl v|: rank points by it."""

    def __new__(cls, x, y, kind, strength=float("nan")):
        self = super().__new__(cls, x, y, kind)
        self.strength = float(strength)
        return self

    def __repr__(self):
        return (f"CriticalPoint(x={self.x:.6g}, y={self.y:.6g}, kind={self.kind!r}, "
                f"strength={self.strength:.3g})")


def find_critical_points(res, threshold: float = 0.1, radius: float | None = None):
    """``[CriticalPoint(x, y, kind, strength)]`` with kind in source | sink |
    cw_vortex | ccw_vortex, strongest first.

    A point is a candidate when its potential is the strict extremum among all
    data points within ``radius`` (default: twice the kernel support).  Its
    strength is the derivative of the component the potential makes, |div d| for
    phi and |curl r| for psi (so a potential that carries nothing, e.g. psi of
    a rigid rotation under the Neumann condition, which puts the rotation into
    h, has no vortex), over the field's scale S, the largest |div v| or |curl
    v| but at least ``NOISE_FLOOR`` max |v| / spacing.  It is kept when

    - the strength is at least ``threshold``;
    - the derivative is at least ``SIGNIFICANCE`` times the noise level that
      the data's noise gives it there (:func:`derivative_noise`): noise-level
      wiggles of a flat potential do not count;
    - its sign is the kind's (div d > 0 at a source, curl r > 0 at a
      counter-clockwise vortex);
    - the component is a zero there: |d| (or |r|) at the point at most the
      derivative times ``radius`` (what a linear zero within ``radius`` gives).
      A potential with Dirichlet data (normal-parallel) or none (natural) has
      extrema at the boundary where the component is no zero, just tangent or
      normal to the boundary: not critical points.

    The position is refined to the stationary point of a quadratic
    least-squares fit of the potential around the candidate (kept at the
    particle if the fit's stationary point falls outside ``radius``).
    """
    pts = res.points
    ps = res.pointset
    domain = getattr(res, "domain", None)
    radius = 2.0 * ps.support if radius is None else float(radius)
    variant = res.options.divergence
    speed = float(np.linalg.norm(res.vectors, axis=1).max()) if len(pts) else 0.0
    strength_scale = max(np.abs(res.divergence).max(), np.abs(res.curl).max(),
                         NOISE_FLOOR * speed / res.stats["spacing"])
    if strength_scale == 0.0:
        return []
    noise = derivative_noise(res)
    rows = None
    out = []
    for pot, field, component, kinds, signs in (
            (res.phi, res.curl_free, ps.divergence(res.curl_free, variant), ("source", "sink"),
             (1, -1)),
            (res.psi, res.div_free, ps.curl(res.div_free, variant), ("cw_vortex", "ccw_vortex"),
             (-1, 1))):
        strength = np.abs(component) / strength_scale
        strong = (strength >= threshold) & \
            (np.linalg.norm(field, axis=1) <= np.abs(component) * radius)
        if not strong.any():
            continue
        strong &= np.abs(component) >= SIGNIFICANCE * noise
        if not strong.any():
            continue
        if rows is None:
            rows = _NeighbourRows(pts, radius)
        for i in np.flatnonzero(strong):
            nb = rows[i]
            if nb.size < 3:
                continue
            others = pot[nb[nb != i]]
            # the extremum must have the sign its derivative says (a minimum of phi
            # has div d > 0; of psi, curl r < 0): a potential held at the boundary
            # has extrema there of either sign
            if pot[i] < others.min() and component[i] * signs[0] > 0:
                kind = kinds[0]          # minimum: source / clockwise vortex
            elif pot[i] > others.max() and component[i] * signs[1] > 0:
                kind = kinds[1]          # maximum: sink / counter-clockwise vortex
            else:
                continue
            x, y = _refine(pts, pot, i, nb, radius)
            if domain is not None and not domain.contains(np.array([[x, y]]))[0]:
                x, y = pts[i]            # the fit's stationary point left the domain
            out.append(CriticalPoint(float(x), float(y), kind, strength[i]))
    out.sort(key=lambda c: -c.strength)
    return out


def derivative_noise(res) -> np.ndarray:
    """Per point, the standard deviation of div v (and of curl v) that the noise
    of the data makes: sigma x gain.  sigma: the data's noise, 1.4826 x the
    median absolute deviation of each component of v from the quadratic
    least-squares fit to its 20 nearest neighbours (itself left out), about
    the noise's standard deviation for noisy data and the fit's third-order
    error for smooth data.  gain: the 2-norm of the divergence operator's row
    at the point (its response to unit white noise; large near the boundary,
    where the operator is one-sided)."""
    from .natural import mls_at
    pts, v, ps = res.points, res.vectors, res.pointset
    if len(pts) < 8:
        return np.zeros(len(pts))
    fit = mls_at(pts, v, pts, k=min(20, len(pts) - 1), exclude_self=True)
    sigma = 1.4826 * float(np.median(np.abs(v - fit)))
    # the row of point i: s_i - sum_k G_k on v_i, G_k on each neighbour v_j
    st = ps.gradient_stencil(res.options.divergence)
    off, _ = ps.pairs.to_numpy()
    G = st.G.to_numpy()[: off[-1]].astype(np.float64)
    rows = np.repeat(np.arange(len(off) - 1), np.diff(off))
    own = st.s.to_numpy()[: len(off) - 1].astype(np.float64)
    np.subtract.at(own, rows, G)
    gain2 = (own ** 2).sum(axis=1)
    np.add.at(gain2, rows, (G ** 2).sum(axis=1))
    return sigma * np.sqrt(gain2[ps.slot_of])


class _NeighbourRows:
    """The indices of the points within ``radius`` of point i, ``rows[i]``,
    computed on demand (the candidates are few) from a grid hash."""

    def __init__(self, pts, radius):
        key = np.floor(pts / radius).astype(np.int64)
        key -= key.min(axis=0)
        self.nx = int(key[:, 0].max()) + 1
        cell = key[:, 1] * self.nx + key[:, 0]
        self.order = np.argsort(cell, kind="stable")
        self.sorted_cells = cell[self.order]
        self.pts, self.key, self.radius = pts, key, radius

    def __getitem__(self, i):
        cand = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                c = (self.key[i, 1] + dy) * self.nx + self.key[i, 0] + dx
                lo, hi = np.searchsorted(self.sorted_cells, [c, c + 1])
                cand.append(self.order[lo:hi])
        cand = np.concatenate(cand)
        d2 = ((self.pts[cand] - self.pts[i]) ** 2).sum(axis=1)
        return cand[d2 < self.radius * self.radius]


def _refine(pts, pot, i, nb, radius):
    """Stationary point of a least-squares quadratic fit of pot around point i."""
    x = pts[nb] - pts[i]
    A = np.c_[np.ones(len(nb)), x[:, 0], x[:, 1], x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2]
    coef, *_ = np.linalg.lstsq(A, pot[nb], rcond=None)
    g = coef[1:3]
    H = np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])
    try:
        step = -np.linalg.solve(H, g)
    except np.linalg.LinAlgError:
        return pts[i]
    if np.linalg.norm(step) > radius:
        return pts[i]
    return pts[i] + step
