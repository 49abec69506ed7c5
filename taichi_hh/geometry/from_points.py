"""A domain from the data themselves, for data that do not fill the domain a
user has (issue 13): the points' bounding box or their convex hull."""
from __future__ import annotations

import numpy as np

from ..errors import InputError

#: the names :func:`domain_from_points` knows (also accepted as ``domain=`` by
#: :func:`taichi_hh.decompose`)
DOMAINS_FROM_POINTS = ("bbox", "hull")


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull of ``points``, counter-clockwise (Andrew's
    monotone chain, O(N log N)); collinear points on an edge are left out."""
    pts = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    if len(pts) < 3:
        raise InputError("the points span no area: no convex hull")

    def half(seq):
        chain = []
        for p in seq:
            while len(chain) >= 2:
                (ax, ay), (bx, by) = chain[-2], chain[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > 0:
                    break
                chain.pop()
            chain.append((p[0], p[1]))
        return chain

    lower = half(pts)
    upper = half(pts[::-1])
    hull = np.array(lower[:-1] + upper[:-1])
    if len(hull) < 3:
        raise InputError("the points span no area (all on one line): no convex hull")
    return hull


def domain_from_points(points, kind: str):
    """The Box (``"bbox"``) or convex-hull Polygon (``"hull"``) of ``points``."""
    from .box import Box
    from .polygon import Polygon
    pts = np.asarray(points, dtype=np.float64)
    if kind == "bbox":
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if not np.all(hi > lo):
            raise InputError("the points span no area (all on one line or one point)")
        return Box(lo, hi)
    if kind == "hull":
        return Polygon(convex_hull(pts))
    raise InputError(f"cannot make a domain from {kind!r}: give a Box, a Polygon, "
                     f"(x0, y0, x1, y1), an (M, 2) array of vertices, or one of "
                     f"{DOMAINS_FROM_POINTS} (a domain from the points)")
