"""Checks of the user's input to :func:`~taichi_hh.hhd.decompose.decompose`
and :func:`~taichi_hh.hhd.project.project`."""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..sph.pointset import check_points, check_values


def validate_input(points, vectors, domain):
    """``(points, vectors, domain)`` checked: (N, 2) finite arrays without
    duplicates, every point inside ``domain`` (default: the points' bounding box).
    Raises :class:`~taichi_hh.errors.InputError`."""
    pts = check_points(points)
    vec = check_values(vectors, len(pts), 2, "vectors")
    if domain is None:
        from ..geometry.domain import Box
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if not np.all(hi > lo):
            raise InputError("the points span no area (all on one line or one point)")
        domain = Box(lo, hi)
    scale = float(np.max(np.abs(np.asarray(domain.bounds)))) or 1.0
    inside = domain.contains(pts, tol=1e-9 * scale)
    if not inside.all():
        bad = np.flatnonzero(~inside)
        raise InputError(f"{bad.size} point(s) lie outside the domain {domain!r}, first index "
                         f"{bad[0]} at {pts[bad[0]].tolist()}")
    return pts, vec, domain
