"""Validation of boundary rings: vertex arrays, orientation, and the checks
that make a set of rings a valid polygon with holes (no ring crosses or touches
itself or another, every hole lies inside the outer ring and outside the other
holes).  Every refusal raises :class:`~taichi_hh.errors.InputError` naming the
ring (``outer`` or ``holes[k]``) and the offending vertex or segments."""
from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["check_ring", "ring_area", "point_in_ring", "orient_rings", "find_crossing",
           "check_no_crossing", "check_holes_placed", "CHUNK"]

#: work arrays are chunked to about this many elements
CHUNK = 1 << 20


def check_ring(ring, name: str) -> np.ndarray:
    """Validate one ring of vertices; drops an explicit closing vertex."""
    try:
        arr = np.array(ring, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be an (M, 2) array of vertex coordinates: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must be an (M, 2) array of vertex coordinates, "
                         f"got shape {arr.shape}")
    if not np.isfinite(arr).all():
        bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        raise InputError(f"{name} has non-finite (NaN or inf) coordinates at vertex {bad[0]}: "
                         f"{arr[bad[0]].tolist()}")
    if len(arr) >= 2 and np.array_equal(arr[0], arr[-1]):
        arr = arr[:-1]                       # an explicitly closed ring: drop the repeat
    if len(arr) < 3:
        raise InputError(f"{name} needs at least 3 distinct vertices, got {len(arr)}")
    same = np.all(arr == np.roll(arr, -1, axis=0), axis=1)
    if same.any():
        k = int(np.flatnonzero(same)[0])
        raise InputError(f"{name} repeats vertex {k} {arr[k].tolist()} as vertex "
                         f"{(k + 1) % len(arr)}: consecutive vertices must differ")
    return arr


def ring_area(ring: np.ndarray) -> float:
    """Signed (shoelace) area: positive for counter-clockwise rings."""
    c = ring - ring.mean(axis=0)
    x, y = c[:, 0], c[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def point_in_ring(p, ring: np.ndarray) -> bool:
    """Crossing-number test for one point (validation only)."""
    a, b = ring, np.roll(ring, -1, axis=0)
    cond = (a[:, 1] > p[1]) != (b[:, 1] > p[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a[:, 0] + (p[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return bool(np.count_nonzero(cond & (p[0] < x)) % 2)


def orient_rings(rings, names) -> list:
    """The rings oriented so the interior lies on the left of every segment:
    outer counter-clockwise, holes clockwise (vertex 0 stays first); refuses
    rings that enclose no net area."""
    oriented = []
    for k, (ring, name) in enumerate(zip(rings, names)):
        a = ring_area(ring)
        span = float(np.ptp(ring, axis=0).max())
        if not abs(a) > 1e-14 * span * span:
            raise InputError(f"{name} is degenerate: it encloses no net area "
                             f"(vertices on one line, or a ring crossing itself)")
        if (a < 0) == (k == 0):          # outer must be CCW, holes CW
            ring = np.roll(ring[::-1], 1, axis=0)   # reverse, keep vertex 0 first
        oriented.append(np.ascontiguousarray(ring))
    return oriented


def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def find_crossing(starts, ends, ring_of, index_in_ring, ring_len):
    """First pair of non-adjacent segments that intersect or touch, else None.

    A sweep over x prunes the pairs (only x-overlapping pairs are tested), so
    ordinary polygons cost about O(S log S)."""
    S = len(starts)
    xmin = np.minimum(starts[:, 0], ends[:, 0])
    xmax = np.maximum(starts[:, 0], ends[:, 0])
    order = np.argsort(xmin, kind="stable")
    xs = xmin[order]
    stop = np.searchsorted(xs, xmax[order], side="right")
    npart = stop - np.arange(S) - 1
    total = int(npart.sum())
    ymin = np.minimum(starts[:, 1], ends[:, 1])
    ymax = np.maximum(starts[:, 1], ends[:, 1])
    # generate the candidate pairs in chunks of about CHUNK
    cum = np.concatenate([[0], np.cumsum(npart)])
    a0 = 0
    while a0 < S and total > 0:
        a1 = int(np.searchsorted(cum, cum[a0] + CHUNK, side="right"))
        a1 = min(max(a1, a0 + 1), S)
        cnt = npart[a0:a1]
        n = int(cnt.sum())
        if n:
            ia = np.repeat(np.arange(a0, a1), cnt)
            first = np.repeat(cum[a0:a1] - cum[a0], cnt)
            ib = ia + 1 + (np.arange(n) - first)
            i, j = order[ia], order[ib]
            keep = (ymin[i] <= ymax[j]) & (ymin[j] <= ymax[i])
            same = ring_of[i] == ring_of[j]
            di = np.abs(index_in_ring[i] - index_in_ring[j])
            adjacent = same & ((di == 1) | (di == ring_len[ring_of[i]] - 1))
            keep &= ~adjacent
            i, j = i[keep], j[keep]
            if i.size:
                p, q, r, s = starts[i], ends[i], starts[j], ends[j]
                o1 = _orient(p[:, 0], p[:, 1], q[:, 0], q[:, 1], r[:, 0], r[:, 1])
                o2 = _orient(p[:, 0], p[:, 1], q[:, 0], q[:, 1], s[:, 0], s[:, 1])
                o3 = _orient(r[:, 0], r[:, 1], s[:, 0], s[:, 1], p[:, 0], p[:, 1])
                o4 = _orient(r[:, 0], r[:, 1], s[:, 0], s[:, 1], q[:, 0], q[:, 1])
                hit = (np.sign(o1) * np.sign(o2) <= 0) & (np.sign(o3) * np.sign(o4) <= 0)
                # all four collinear: intersect only if the 1-D projections overlap
                col = (o1 == 0) & (o2 == 0) & (o3 == 0) & (o4 == 0)
                if col.any():
                    ax = np.where(np.abs(q[:, 0] - p[:, 0]) >= np.abs(q[:, 1] - p[:, 1]), 0, 1)
                    rows = np.arange(len(i))
                    lo1 = np.minimum(p[rows, ax], q[rows, ax])
                    hi1 = np.maximum(p[rows, ax], q[rows, ax])
                    lo2 = np.minimum(r[rows, ax], s[rows, ax])
                    hi2 = np.maximum(r[rows, ax], s[rows, ax])
                    hit = np.where(col, (lo1 <= hi2) & (lo2 <= hi1), hit)
                if hit.any():
                    k = int(np.flatnonzero(hit)[0])
                    return int(i[k]), int(j[k])
        a0 = a1
    return None


def check_no_crossing(starts, ends, piece, ring_start, names) -> None:
    """Refuse rings that cross or touch themselves or each other.

    ``piece`` (S,) is each segment's ring, ``ring_start`` (R + 1,) the first
    segment of each ring (segments run ring by ring)."""
    lens = np.diff(ring_start)
    idx_in_ring = np.arange(len(starts)) - ring_start[piece]
    hit = find_crossing(starts, ends, piece, idx_in_ring, lens)
    if hit is not None:
        i, j = hit
        what = (f"{names[piece[i]]} intersects itself" if piece[i] == piece[j]
                else f"{names[piece[i]]} and {names[piece[j]]} intersect or touch")
        raise InputError(f"{what}: segment {starts[i].tolist()}->{ends[i].tolist()} meets "
                         f"segment {starts[j].tolist()}->{ends[j].tolist()}")


def check_holes_placed(oriented, names) -> None:
    """Refuse holes outside the outer ring or inside another hole.  With no
    crossings (checked first), one vertex decides where a whole hole lies."""
    for k in range(1, len(oriented)):
        v = oriented[k][0]
        if not point_in_ring(v, oriented[0]):
            raise InputError(f"{names[k]} lies outside the outer ring "
                             f"(vertex {v.tolist()}): holes must be inside it")
        for m in range(1, len(oriented)):
            if m != k and point_in_ring(v, oriented[m]):
                raise InputError(f"{names[k]} lies inside {names[m]}: holes must not "
                                 f"overlap or nest")
