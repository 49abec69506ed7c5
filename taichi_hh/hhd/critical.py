"""Critical points of a decomposition: sources, sinks and vortices
(Petronetto Sec. 6c: the extrema of the potentials phi and psi).

With d = grad phi, a source (div v > 0, lap phi > 0) is a minimum of phi and a
sink a maximum; with r = J grad psi, curl v = -lap psi, so a counter-clockwise
vortex is a maximum of psi and a clockwise one a minimum.
"""
from __future__ import annotations

import numpy as np



def find_critical_points(res, threshold: float = 0.1, radius: float | None = None):
    """``[(x, y, kind)]`` with kind in source | sink | cw_vortex | ccw_vortex.

    A point is a candidate when its potential is the strict extremum among all
    data points within ``radius`` (default: twice the kernel support).  It is
    kept when its feature strength (|div v| for phi extrema, |curl v| for psi
    extrema) is at least ``threshold`` times the largest |div v| or |curl v| of
    the whole field, so that noise-level wiggles of a flat potential do not
    count.  The position is refined to the stationary point of a quadratic
    least-squares fit of the potential around the candidate (kept at the
    particle if the fit's stationary point falls outside ``radius``).
    """
    pts = res.points
    ps = res.pointset
    radius = 2.0 * ps.support if radius is None else float(radius)
    strength_scale = max(np.abs(res.divergence).max(), np.abs(res.curl).max())
    if strength_scale == 0.0:
        return []
    rows = _rows_within(pts, radius)
    out = []
    for pot, strength, kinds in ((res.phi, res.divergence, ("source", "sink")),
                                 (res.psi, res.curl, ("cw_vortex", "ccw_vortex"))):
        strong = np.abs(strength) >= threshold * strength_scale
        for i in np.flatnonzero(strong):
            nb = rows[i]
            if nb.size < 3:
                continue
            others = pot[nb[nb != i]]
            if pot[i] < others.min():
                kind = kinds[0]          # minimum: source / clockwise vortex
            elif pot[i] > others.max():
                kind = kinds[1]          # maximum: sink / counter-clockwise vortex
            else:
                continue
            x, y = _refine(pts, pot, i, nb, radius)
            out.append((float(x), float(y), kind))
    return out


def _rows_within(pts, radius):
    """Neighbour index lists within radius (grid hashing, vectorised by cell)."""
    key = np.floor(pts / radius).astype(np.int64)
    key -= key.min(axis=0)
    nx = key[:, 0].max() + 1
    cell = key[:, 1] * nx + key[:, 0]
    order = np.argsort(cell, kind="stable")
    sorted_cells = cell[order]
    rows = []
    for i in range(len(pts)):
        cand = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                c = (key[i, 1] + dy) * nx + key[i, 0] + dx
                lo, hi = np.searchsorted(sorted_cells, [c, c + 1])
                cand.append(order[lo:hi])
        cand = np.concatenate(cand)
        d2 = ((pts[cand] - pts[i]) ** 2).sum(axis=1)
        rows.append(cand[d2 < radius * radius])
    return rows


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
