"""Domains from gridded data: the outline of the cells marked inside on a
rectilinear grid, as polygons with holes.

The outline is the 0.5 level of the inside indicator (1 inside, 0 outside,
the grid padded by one ring of outside nodes), traced by contourpy (the
contour generator matplotlib uses): it runs half way between an inside node
and an outside neighbour, and cuts a cell diagonally where one of its four
nodes differs from the other three.  So every inside node lies strictly
inside, at least a third of a cell from the outline, corners of masked
regions are cut at 45 degrees (interior angles of 135 and 225 degrees, not the
staircase's 90 and 270: milder corner singularities for Neumann potentials),
and a full grid gives its bounding box grown by half a cell, chamfered at the
corners.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["cell_outlines", "padded_axis", "check_axis"]


def check_axis(values, name: str) -> np.ndarray:
    """A grid axis: a 1-D float64 array of at least 2 finite, strictly
    increasing or strictly decreasing values (returned as given)."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a 1-D array of numbers") from None
    if arr.ndim != 1 or arr.size < 2:
        raise InputError(f"{name} must be a 1-D array of at least 2 coordinates, got shape "
                         f"{arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} must be finite (a missing value belongs in u and v, not in "
                         f"the coordinates)")
    step = np.diff(arr)
    if not ((step > 0).all() or (step < 0).all()):
        raise InputError(f"{name} must be strictly increasing or strictly decreasing (a "
                         f"rectilinear grid's axis)")
    return arr


def padded_axis(values: np.ndarray) -> np.ndarray:
    """An increasing axis with one more node at each end, one end step out."""
    return np.concatenate([[2 * values[0] - values[1]], values, [2 * values[-1] - values[-2]]])


def cell_outlines(x, y, inside) -> list:
    """The outline of the nodes ``inside`` (bool (ny, nx)) of the grid with
    increasing axes ``x`` (nx,), ``y`` (ny,): a list of ``(outer, holes)``, one
    per connected piece, ``outer`` an (M, 2) ring and ``holes`` a list of rings,
    largest piece first (by the inside nodes it holds, then its area)."""
    import contourpy
    inside = np.asarray(inside, dtype=bool)
    z = np.zeros((inside.shape[0] + 2, inside.shape[1] + 2))
    z[1:-1, 1:-1] = inside
    gen = contourpy.contour_generator(padded_axis(x), padded_axis(y), z,
                                      fill_type="OuterOffset")
    rings_list, offsets_list = gen.filled(0.5, 2.0)
    pieces = []
    for points, offsets in zip(rings_list, offsets_list):
        rings = [_simplified(points[a:b]) for a, b in zip(offsets[:-1], offsets[1:])]
        pieces.append((rings[0], rings[1:]))
    if len(pieces) < 2:
        return pieces
    X, Y = np.meshgrid(x, y)
    nodes = np.c_[X[inside], Y[inside]]

    def weight(piece):
        from .polygon import Polygon
        poly = Polygon(piece[0])
        return (int(poly.contains(nodes).sum()) if len(nodes) else 0, poly.area)
    return sorted(pieces, key=weight, reverse=True)


def _simplified(ring: np.ndarray) -> np.ndarray:
    """A closed contour ring without its closing vertex and without vertices
    that lie on the straight line through their neighbours (a straight edge of
    many cells is one segment)."""
    ring = np.asarray(ring, dtype=np.float64)
    if len(ring) > 1 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    prev, nxt = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
    a, b = ring - prev, nxt - ring
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    scale = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    keep = np.abs(cross) > 1e-9 * scale
    return ring[keep] if keep.sum() >= 3 else ring
