"""Acceleration grid for closest-segment queries and signed distances.

Every grid cell stores the few boundary segments that can be closest to any
point in the cell (built coarse to fine, so building stays cheap for large
polygons), and the exact signed distance of its centre, which lets
``contains`` and the samplers decide whole cells at once (signed distance is
1-Lipschitz).  Points outside the grid fall back to a scan over all segments.
"""
from __future__ import annotations

import math

import numpy as np

from .rings import CHUNK
from .segments import Segments

__all__ = ["Locator", "CELLS_PER_SEGMENT", "MAX_CELLS"]

#: grid size: cells per boundary segment, and the cap (sizes the grid for
#: short candidate lists at a build cost that stays small, see docs/notes/geometry.md)
CELLS_PER_SEGMENT = 256
MAX_CELLS = 1 << 18


class Locator:
    """Uniform grid over ``[lo, hi]`` whose cells list the segments that can be
    closest to any point in the cell, plus the exact signed distance of every
    cell centre (attributes ``lo``, ``hi``, ``size``, ``nx``, ``ny``,
    ``half_diag``, ``count``, ``start``, ``cand``, ``sd``).

    Built coarse to fine: a segment that can be closest somewhere in a cell is
    a candidate of the cell's parent, so each level filters its parent's lists.
    With ``f_s`` the distance from the cell centre ``c`` to segment ``s``,
    ``u_s`` its gradient (unit vector from the segment to ``c``), ``s*`` the
    closest segment of ``c``, ``a`` half the cell size and ``h`` its half
    diagonal, ``s`` is dropped when either

    * ``f_s - f_s* > 2 h`` (distances are 1-Lipschitz), or
    * ``f_s - f_s* > |u_s - u_s*|_1 a + a^2 / f_s*``: ``f_s`` is convex, so
      ``f_s(c + e) >= f_s + u_s.e``, and ``f_s*(c + e) <= |c + e - q*| <=
      f_s* + u_s*.e + |e|^2 / (2 f_s*)`` with ``q*`` the closest point of
      ``s*``; so ``s`` is farther than ``s*`` everywhere in the cell.

    The second test keeps the lists short deep inside smooth (finely
    subdivided) boundaries, where many segments are nearly equidistant.

    ``tol``: slack added to the pruning tests and to ``half_diag`` (a tiny
    multiple of the domain's coordinate scale, for rounding)."""

    def __init__(self, segments: Segments, lo, hi, tol: float):
        S = len(segments)
        lo = np.asarray(lo, dtype=np.float64)
        span = np.asarray(hi, dtype=np.float64) - lo
        span = np.maximum(span, 1e-12 * max(1.0, float(span.max())))
        target = int(np.clip(CELLS_PER_SEGMENT * S, 16384, MAX_CELLS))
        c = math.sqrt(float(span[0] * span[1]) / target)
        c = max(c, float(span.max()) / 1024.0)
        L = max(0, math.ceil(math.log2(max(1.0, float(span.max()) / (4.0 * c)))))
        root = c * 2 ** L
        n0 = np.maximum(1, np.ceil(span / root - 1e-9)).astype(np.int64)
        cix, ciy = np.meshgrid(np.arange(n0[0]), np.arange(n0[1]))
        cix, ciy = cix.ravel(), ciy.ravel()
        ncell = cix.size
        cand = np.tile(np.arange(S), ncell)
        cnt = np.full(ncell, S, dtype=np.int64)
        size = root
        for level in range(L + 1):
            if level > 0:                 # split every cell into 4 children (ids 4k + ch)
                size *= 0.5
                pstart = np.cumsum(cnt) - cnt
                cnt = np.repeat(cnt, 4)
                start = np.cumsum(cnt) - cnt
                owner = np.repeat(np.arange(4 * ncell), cnt)
                cand = cand[pstart[owner >> 2] + (np.arange(owner.size) - start[owner])]
                ch = np.tile(np.arange(4), ncell)
                cix = 2 * np.repeat(cix, 4) + (ch & 1)
                ciy = 2 * np.repeat(ciy, 4) + (ch >> 1)
                ncell *= 4
            else:
                start = np.cumsum(cnt) - cnt
                owner = np.repeat(np.arange(ncell), cnt)
            cx = lo[0] + (cix + 0.5) * size
            cy = lo[1] + (ciy + 0.5) * size
            cand, owner, best = self._prune(segments, cx, cy, cand, owner, start, size, tol)
            cnt = np.bincount(owner, minlength=ncell)
        # closest segment of every centre -> signed distance of the centres
        centers = np.stack([cx, cy], axis=1)
        dist, _, _, sign = segments.features(centers, best, full=False)
        # reorder cells (and their lists) to row-major order
        nx, ny = int(n0[0] * 2 ** L), int(n0[1] * 2 ** L)
        gid = ciy * nx + cix
        count = np.zeros(nx * ny, dtype=np.int64)
        count[gid] = cnt
        gstart = np.cumsum(count) - count
        start = np.cumsum(cnt) - cnt
        pos = gstart[gid[owner]] + (np.arange(cand.size) - start[owner])
        gcand = np.empty_like(cand)
        gcand[pos] = cand
        sd = np.empty(nx * ny)
        sd[gid] = sign * dist
        self.segments = segments
        self.lo = lo
        self.size = size
        self.nx, self.ny = nx, ny
        self.hi = lo + np.array([nx, ny]) * size
        self.half_diag = size * math.sqrt(0.5) * (1 + 1e-12) + tol
        self.count, self.start, self.cand, self.sd = count, gstart, gcand, sd

    @staticmethod
    def _prune(segments, cx, cy, cand, owner, start, size, tol):
        """One level of the build: keep the candidates (``cand``, listed per cell
        ``owner`` from ``start``) that can be closest somewhere in their cell of
        side ``size`` centred at ``(cx, cy)``; also returns each cell's closest
        segment of its centre."""
        ux = np.empty(cand.size)
        uy = np.empty(cand.size)
        for a in range(0, cand.size, CHUNK):
            o = owner[a:a + CHUNK]
            ux[a:a + CHUNK], uy[a:a + CHUNK] = segments.pair_vector(cx[o], cy[o],
                                                                  cand[a:a + CHUNK])
        d = np.hypot(ux, uy)
        np.divide(ux, d, out=ux, where=d > 0)
        np.divide(uy, d, out=uy, where=d > 0)
        ux[d == 0] = 0.0
        uy[d == 0] = 0.0
        dmin = np.minimum.reduceat(d, start)
        first = np.flatnonzero(d == dmin[owner])          # the closest pair of each cell
        first = first[np.r_[True, owner[first][1:] != owner[first][:-1]]]
        best = cand[first]
        gap = d - dmin[owner]
        a = 0.5 * size
        with np.errstate(divide="ignore"):
            curv = np.where(dmin > 0, a * a / dmin, np.inf)[owner]
        bound = (np.abs(ux - ux[first][owner]) + np.abs(uy - uy[first][owner])) * a + curv
        keep = (gap <= np.minimum(math.sqrt(2.0) * size, bound) + tol)
        return cand[keep], owner[keep], best

    def covers(self, lo, hi) -> bool:
        """Whether the grid covers the rectangle ``[lo, hi]``."""
        return bool((self.lo <= lo).all() and (self.hi >= hi).all())

    def cell_of(self, p):
        """(cell id, inside-grid mask) of every point."""
        fx = (p[:, 0] - self.lo[0]) / self.size
        fy = (p[:, 1] - self.lo[1]) / self.size
        ing = (fx >= 0) & (fx < self.nx) & (fy >= 0) & (fy < self.ny)
        ix = np.clip(fx, 0, self.nx - 1).astype(np.int64)
        iy = np.clip(fy, 0, self.ny - 1).astype(np.int64)
        return iy * self.nx + ix, ing

    def closest_segments(self, p: np.ndarray) -> np.ndarray:
        """Index of a closest boundary segment for every point."""
        n = len(p)
        seg = np.empty(n, dtype=np.int64)
        if n == 0:
            return seg
        segments = self.segments
        cell, ing = self.cell_of(p)
        allin = bool(ing.all())
        if not allin:
            out = np.flatnonzero(~ing)
            seg[out] = segments.closest_by_scan(p[out])
            idx = np.flatnonzero(ing)
            cell = cell[idx]
            p = p[idx]
        step = 1 << 17
        for a in range(0, len(p), step):
            c = cell[a:a + step]
            q = p[a:a + step]
            res = segments.closest_among(np.ascontiguousarray(q[:, 0]),
                                         np.ascontiguousarray(q[:, 1]),
                                         self.start[c], self.count[c], self.cand)
            if allin:
                seg[a:a + step] = res
            else:
                seg[idx[a:a + step]] = res
        return seg
