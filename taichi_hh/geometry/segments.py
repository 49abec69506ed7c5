"""The boundary as a table of oriented segments, and exact point-to-segment queries.

A :class:`Segments` table is built from rings already oriented so the interior
lies on the *left* of every segment (outer ring counter-clockwise, holes
clockwise; see :func:`~taichi_hh.geometry.rings.orient_rings`).  It holds, per
segment, the start and end points, direction, outward unit normal, the vertex
normals at both ends and the turning angle at its start vertex, all as
read-only arrays; its methods answer exact distance questions for given
(point, segment) pairs.  Which segments to ask about is the job of
:class:`~taichi_hh.geometry.locator.Locator`.

**Normals.**  The outward unit normal of a segment from ``a`` to ``b`` is the
right-hand perpendicular of ``b - a``.  At a vertex the normal is the
normalised average of the two adjacent segment normals ("normals averaged
from the boundary", Petronetto et al. 2010, Sec. 5b).
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["Segments"]


def _frozen(arr, dtype=None) -> np.ndarray:
    arr = np.ascontiguousarray(arr, dtype=dtype)
    arr.setflags(write=False)
    return arr


class Segments:
    """Segments of oriented rings, ring by ring (segment ``k`` of a ring goes
    from its vertex ``k`` to vertex ``k + 1``).

    Read-only array attributes (S segments, R rings): ``starts``, ``ends``,
    ``direction`` (ends - starts), ``length``, ``inv_len2`` (1 / length^2),
    ``normal`` (outward unit normal), ``vertex_normal_start`` and
    ``vertex_normal_end`` (averaged normals at the two ends), ``turn`` (turning
    angle at the start vertex, radians in [0, pi)), ``piece`` (ring of each
    segment) and ``ring_start`` (R + 1,: first segment of each ring, then S).

    Refuses (InputError) a ring that folds back on itself at a vertex, where
    the vertex normal would be undefined; ``names`` name the rings in messages.
    """

    def __init__(self, oriented, names):
        starts = np.concatenate(oriented)
        ends = np.concatenate([np.roll(r, -1, axis=0) for r in oriented])
        lens = np.array([len(r) for r in oriented])
        piece = np.repeat(np.arange(len(oriented)), lens)
        first = np.concatenate([[0], np.cumsum(lens)])
        idx_in_ring = np.arange(len(starts)) - first[piece]
        d = ends - starts
        len2 = np.einsum("ij,ij->i", d, d)
        seglen = np.sqrt(len2)
        normal = np.stack([d[:, 1], -d[:, 0]], axis=1) / seglen[:, None] + 0.0   # no -0.0
        # previous segment of each segment within its ring
        prev = first[piece] + (idx_in_ring - 1) % lens[piece]
        nxt = first[piece] + (idx_in_ring + 1) % lens[piece]
        # fold-back at a vertex: consecutive segments antiparallel on one line
        dp = d[prev]
        cross = dp[:, 0] * d[:, 1] - dp[:, 1] * d[:, 0]
        dot = np.einsum("ij,ij->i", dp, d)
        fold = (np.abs(cross) <= 1e-12 * seglen[prev] * seglen) & (dot < 0)
        if fold.any():
            s = int(np.flatnonzero(fold)[0])
            raise InputError(f"{names[piece[s]]} folds back on itself at vertex "
                             f"{starts[s].tolist()}: rings must not intersect themselves")
        vn = normal[prev] + normal
        vn /= np.linalg.norm(vn, axis=1)[:, None]
        vn += 0.0
        # turning angle at each vertex (start of each segment), radians in [0, pi)
        turn = np.abs(np.arctan2(cross, dot))
        self.starts = _frozen(starts)
        self.ends = _frozen(ends)
        self.direction = _frozen(d)
        self.length = _frozen(seglen)
        self.inv_len2 = _frozen(1.0 / len2)
        self.normal = _frozen(normal)
        self.vertex_normal_start = _frozen(vn)
        self.vertex_normal_end = _frozen(vn[nxt])
        self.turn = _frozen(turn)
        self.piece = _frozen(piece)
        self.ring_start = _frozen(first)
        # contiguous coordinate columns for the vectorised queries
        self.columns = {key: _frozen(arr, np.float64) for key, arr in {
            "sx": starts[:, 0], "sy": starts[:, 1], "dx": d[:, 0], "dy": d[:, 1],
            "inv": 1.0 / len2, "ex": ends[:, 0], "ey": ends[:, 1],
            "nx": normal[:, 0], "ny": normal[:, 1], "vsx": vn[:, 0], "vsy": vn[:, 1],
            "vex": vn[nxt, 0], "vey": vn[nxt, 1]}.items()}

    def __len__(self) -> int:
        return len(self.starts)

    # ---- exact (point, segment) queries -------------------------------------------------
    def pair_vector(self, px, py, segs):
        """Vectors from the closest points of segments ``segs`` to points ``(px, py)``."""
        col = self.columns
        dx = col["dx"][segs]
        dy = col["dy"][segs]
        wx = px - col["sx"][segs]
        wy = py - col["sy"][segs]
        t = (wx * dx + wy * dy) * col["inv"][segs]
        np.clip(t, 0.0, 1.0, out=t)
        wx -= t * dx
        wy -= t * dy
        return wx, wy

    def pair_distance2(self, px, py, segs):
        """Squared distances from points ``(px, py)`` to segments ``segs`` (broadcast)."""
        wx, wy = self.pair_vector(px, py, segs)
        wx *= wx
        wy *= wy
        wx += wy
        return wx

    def closest_among(self, px, py, first, count, cand):
        """Closest segment among ``cand[first[i] : first[i] + count[i]]`` for each point.

        Points are sorted by decreasing ``count`` so that candidate column ``k``
        concerns a prefix of them: no padding, no per-column point gathers."""
        n = len(px)
        order = np.argsort(-count.astype(np.int32 if count.max() > 32000 else np.int16),
                           kind="stable")
        px, py, first, count = px[order], py[order], first[order], count[order]
        # nk[k] = number of points with more than k candidates
        ncol = int(count[0])
        nk = n - np.searchsorted(count[::-1], np.arange(ncol), side="right")
        best = np.full(n, np.inf)
        bseg = np.empty(n, dtype=np.int64)
        for k in range(ncol):
            m = int(nk[k])
            s = cand[first[:m] + k]
            d2 = self.pair_distance2(px[:m], py[:m], s)
            better = d2 < best[:m]
            np.copyto(best[:m], d2, where=better)
            np.copyto(bseg[:m], s, where=better)
        out = np.empty(n, dtype=np.int64)
        out[order] = bseg
        return out

    def closest_by_scan(self, p: np.ndarray) -> np.ndarray:
        """Closest segment of each point by scanning all segments."""
        n = len(p)
        px, py = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
        best = np.full(n, np.inf)
        bseg = np.zeros(n, dtype=np.int64)
        for k in range(len(self)):
            d2 = self.pair_distance2(px, py, k)
            better = d2 < best
            np.copyto(best, d2, where=better)
            bseg[better] = k
        return bseg

    def features(self, p: np.ndarray, seg: np.ndarray, full: bool = True):
        """``(distance, closest point, normal, sign)`` of points ``p`` relative to
        segments ``seg``; the normal is the vertex normal when the closest point is
        an end, ``sign`` is +1 on the outer (normal) side.  ``full=False``: only
        distance and sign (the others are None)."""
        col = self.columns
        sx, sy = col["sx"][seg], col["sy"][seg]
        dx, dy = col["dx"][seg], col["dy"][seg]
        wx = p[:, 0] - sx
        wy = p[:, 1] - sy
        t = (wx * dx + wy * dy) * col["inv"][seg]
        np.clip(t, 0.0, 1.0, out=t)
        qx = sx + t * dx
        qy = sy + t * dy
        nx, ny = col["nx"][seg], col["ny"][seg]
        lo_end = np.flatnonzero(t <= 0.0)
        hi_end = np.flatnonzero(t >= 1.0)
        if lo_end.size:
            s = seg[lo_end]
            qx[lo_end], qy[lo_end] = sx[lo_end], sy[lo_end]
            nx[lo_end], ny[lo_end] = col["vsx"][s], col["vsy"][s]
        if hi_end.size:
            s = seg[hi_end]
            qx[hi_end], qy[hi_end] = col["ex"][s], col["ey"][s]
            nx[hi_end], ny[hi_end] = col["vex"][s], col["vey"][s]
        ex = p[:, 0] - qx
        ey = p[:, 1] - qy
        dist = np.hypot(ex, ey)
        ex *= nx
        ey *= ny
        ex += ey
        sign = np.where(ex > 0.0, 1.0, -1.0)
        if not full:
            return dist, None, None, sign
        return dist, np.stack([qx, qy], axis=1), np.stack([nx, ny], axis=1), sign
