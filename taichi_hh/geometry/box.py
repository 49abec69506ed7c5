"""Axis-aligned rectangular domains: :class:`Box`, a :class:`Polygon` that keeps
its exact corners and mirrors ghosts across its sides."""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .polygon import Polygon
from .sampling import mirror_points

__all__ = ["Box"]


def _corner(value, name):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be two coordinates (x, y): {exc}") from None
    if arr.shape != (2,):
        raise InputError(f"{name} must be two coordinates (x, y), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} must be finite, got {arr.tolist()}")
    return arr


#: sides and corner coordinates of a Box stay within [1/LIMIT, LIMIT]: its
#: geometry squares lengths (areas, projections), which overflow near 1e154
COORDINATE_LIMIT = 1e150


class Box(Polygon):
    """Axis-aligned rectangle ``[lo[0], hi[0]] x [lo[1], hi[1]]``.

    A :class:`Polygon` with four counter-clockwise vertices starting at ``lo``
    (same queries and samplers); ``lo`` and ``hi`` keep the exact corner
    coordinates as tuples of floats."""

    __slots__ = ("lo", "hi")

    def __init__(self, lo, hi):
        lo, hi = _corner(lo, "lo"), _corner(hi, "hi")
        if not (lo < hi).all():
            raise InputError(f"a Box needs lo < hi in both coordinates, got lo={lo.tolist()}, "
                             f"hi={hi.tolist()}")
        size = hi - lo
        if max(np.abs(lo).max(), np.abs(hi).max(), size.max()) > COORDINATE_LIMIT \
                or size.min() < 1.0 / COORDINATE_LIMIT:
            raise InputError(f"a Box of {size[0]:.3g} x {size[1]:.3g} at lo={lo.tolist()} is "
                             f"beyond the floating-point range of its geometry (squared "
                             f"lengths and areas must stay finite and normal: sides and "
                             f"coordinates within 1e-150 .. 1e150); rescale the coordinates")
        object.__setattr__(self, "lo", (float(lo[0]), float(lo[1])))
        object.__setattr__(self, "hi", (float(hi[0]), float(hi[1])))
        super().__init__(np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]],
                                   [lo[0], hi[1]]]))

    def __reduce__(self):
        return (Box, (self.lo, self.hi))

    def __repr__(self):
        return f"Box(lo={self.lo!r}, hi={self.hi!r})"

    def __eq__(self, other):
        if type(other) is not Box:
            return NotImplemented
        return self.lo == other.lo and self.hi == other.hi

    def __hash__(self):
        return hash(("Box", self.lo, self.hi))

    def rescaled(self, centre, length: float) -> "Box":
        """The same box in the coordinates ``(p - centre) / length``."""
        c = np.asarray(centre, dtype=np.float64)
        return Box((np.asarray(self.lo) - c) / length, (np.asarray(self.hi) - c) / length)

    def within(self, p: np.ndarray, t: float) -> np.ndarray:
        """(N,) bool: signed distance <= ``t`` for the (N, 2) float64 points
        ``p``, in closed form: the box grown (``t > 0``) or shrunk by ``t``
        side by side, its grown corners' quarter discs tested by distance.
        Comparisons of coordinates only (a 1M-point call's input checks, choice
        of condition and reach check each ask it of every point)."""
        n = len(p)
        if t == np.inf or t == -np.inf:
            return np.full(n, t > 0)
        (x0, y0), (x1, y1) = self.lo, self.hi
        x, y = p[:, 0], p[:, 1]
        ok = (x >= x0 - t) & (x <= x1 + t) & (y >= y0 - t) & (y <= y1 + t)
        if t > 0.0:
            # beyond both an x side and a y side: the grown box's round corner
            cx = np.flatnonzero(ok & ((x < x0) | (x > x1)))
            if cx.size:
                px, py = np.take(x, cx), np.take(y, cx)
                corner = (py < y0) | (py > y1)
                if corner.any():
                    k = cx[corner]
                    dx = np.maximum(x0 - px[corner], px[corner] - x1)
                    dy = np.maximum(y0 - py[corner], py[corner] - y1)
                    ok[k] = np.hypot(dx, dy) <= t
        return ok

    def classify_discs(self, p: np.ndarray, radius: float, lo: float, hi: float) -> np.ndarray:
        """:meth:`Polygon.classify_discs` in closed form (:meth:`within`): the
        polygon's exact tests (signed distance +- ``radius`` against ``lo``
        and ``hi``) on every point, without the locator; 5x faster at 1M."""
        radius = float(radius)
        if radius == 0.0:
            # 1: lo < sd <= hi; 0: sd <= lo or sd > hi
            status = self.within(p, hi).astype(np.int8)
            if lo > -np.inf:
                status[self.within(p, lo)] = 0
            return status
        status = np.full(len(p), 2, dtype=np.int8)
        status[self.within(p, lo - radius) | ~self.within(p, hi + radius)] = 0
        status[~self.within(p, lo + radius) & self.within(p, hi - radius)] = 1
        return status

    def sample_ghosts_mirror(self, points, width: float):
        """``(ghosts, source)``: reflections of interior points across every side
        within ``width`` (distance > 0), plus the corner image (reflection across
        both sides) when a point is within ``width`` of two adjacent sides."""
        p, width = mirror_points(self, points, width)
        lo, hi = np.array(self.lo), np.array(self.hi)
        dlo, dhi = p - lo, hi - p                            # (N, 2) distances to the sides
        near_lo = (dlo <= width) & (dlo > 0)
        near_hi = (dhi <= width) & (dhi > 0)
        out, src = [], []
        for axis in range(2):
            for near, wall in ((near_lo, lo), (near_hi, hi)):
                k = np.flatnonzero(near[:, axis])
                g = p[k].copy()
                g[:, axis] = 2.0 * wall[axis] - g[:, axis]
                out.append(g)
                src.append(k)
        for nx_, wx in ((near_lo, lo), (near_hi, hi)):
            for ny_, wy in ((near_lo, lo), (near_hi, hi)):
                k = np.flatnonzero(nx_[:, 0] & ny_[:, 1])
                g = np.stack([2.0 * wx[0] - p[k, 0], 2.0 * wy[1] - p[k, 1]], axis=1)
                out.append(g)
                src.append(k)
        return np.concatenate(out), np.concatenate(src)
