"""Domains: axis-aligned boxes and polygons with holes (host side, numpy only).

A domain is a closed region bounded by straight segments: one outer ring and
any number of holes.  Everything here is computed from one list of boundary
segments, oriented so that the domain's interior lies on the *left* of each
segment (outer ring counter-clockwise, holes clockwise), which gives

* geometry: :attr:`~Polygon.area`, :attr:`~Polygon.perimeter`,
  :attr:`~Polygon.bounds`, :meth:`~Polygon.segments`;
* queries on many points at once: :meth:`~Polygon.contains`,
  :meth:`~Polygon.signed_distance` (negative inside, positive outside) and
  :meth:`~Polygon.closest_boundary` (distance, closest point, outward unit
  normal, segment index);
* samplers: boundary particles with normals (Colin et al. 2006, Sec. 3.4-3.6),
  Poisson-disk "fake" particles outside the domain (Petronetto et al. 2010,
  Sec. 5b), mirror ghosts, and interior points (blue noise, jittered lattice,
  uniform random).

**Normals.**  The outward unit normal of a segment from ``a`` to ``b`` is the
right-hand perpendicular of ``b - a``.  At a vertex the normal is the
normalised average of the two adjacent segment normals ("normals averaged
from the boundary", Petronetto Sec. 5b).  :meth:`~Polygon.closest_boundary`
returns the segment normal when the closest point lies strictly inside a
segment and the vertex normal when it is a vertex.

**Boundary tolerance.**  Points within ``1e-12 * diameter + 1e-14 * max|x|``
of the boundary (:attr:`~Polygon.boundary_tolerance`; the second term covers
rounding of far-from-origin coordinates) count as *on* the boundary: :meth:`~Polygon.contains` says they are
inside, samplers that must stay strictly inside or strictly outside keep
farther away than that.

**Speed.**  Distance queries use a lazily built, cached acceleration grid:
every grid cell stores the few segments that can be closest to any point in
the cell (built coarse to fine, so building stays cheap for large polygons),
and the exact signed distance of its centre, which lets ``contains`` and the
samplers decide whole cells at once (signed distance is 1-Lipschitz).  Points
far outside the domain's neighbourhood fall back to a chunked brute-force scan.
"""
from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np

from ..errors import InputError

__all__ = ["Polygon", "Box", "as_domain"]

#: points within BOUNDARY_RTOL * diameter + BOUNDARY_ATOL_COORD * max|coordinate|
#: of the boundary are "on" it
BOUNDARY_RTOL = 1e-12
BOUNDARY_ATOL_COORD = 1e-14
#: boundary vertices turning by more than this (degrees) are always sampled
DEFAULT_CORNER_ANGLE = 10.0
#: blue-noise calibration (measured): a maximal Poisson-disk sample of radius r
#: in a region of area A and perimeter P holds about ALPHA * (A + BETA * P * r) / r**2
#: points (points can sit right at the edge, so the boundary adds a little)
_POISSON_ALPHA = 0.633
_POISSON_BETA = 0.18
#: refuse samplers whose background grid would exceed this many cells
_MAX_CELLS = 60_000_000
#: acceleration grid size: cells per boundary segment, and the cap
_LOCATOR_CELLS_PER_SEGMENT = 256
_LOCATOR_MAX_CELLS = 1 << 18
#: work arrays are chunked to about this many elements
_CHUNK = 1 << 20


# --------------------------------------------------------------------------- checks
def _as_points(points, name: str = "points") -> np.ndarray:
    """Validate an (N, 2) array of finite coordinates (N may be 0); float64."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric (N, 2) array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must have shape (N, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        raise InputError(f"{name} contains {bad.size} non-finite (NaN or inf) entries, "
                         f"first at index {bad[0]}: {arr[bad[0]].tolist()}")
    return arr


def _as_real(value, name: str, *, positive: bool = True, allow_zero: bool = False) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise InputError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name} must be finite, got {v}")
    if positive and (v < 0 or (v == 0 and not allow_zero)):
        raise InputError(f"{name} must be {'non-negative' if allow_zero else 'positive'}, got {v}")
    return v


def _as_seed(seed):
    if seed is None or isinstance(seed, (np.random.SeedSequence, np.random.Generator)):
        return np.random.default_rng(seed)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer (or None), got {seed!r}")
    return np.random.default_rng(int(seed))


def _check_ring(ring, name: str) -> np.ndarray:
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


def _ring_area(ring: np.ndarray) -> float:
    """Signed (shoelace) area: positive for counter-clockwise rings."""
    c = ring - ring.mean(axis=0)
    x, y = c[:, 0], c[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _point_in_ring(p, ring: np.ndarray) -> bool:
    """Crossing-number test for one point (validation only)."""
    a, b = ring, np.roll(ring, -1, axis=0)
    cond = (a[:, 1] > p[1]) != (b[:, 1] > p[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a[:, 0] + (p[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return bool(np.count_nonzero(cond & (p[0] < x)) % 2)


def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def _find_crossing(starts, ends, ring_of, index_in_ring, ring_len):
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
    # generate the candidate pairs in chunks of about _CHUNK
    cum = np.concatenate([[0], np.cumsum(npart)])
    a0 = 0
    while a0 < S and total > 0:
        a1 = int(np.searchsorted(cum, cum[a0] + _CHUNK, side="right"))
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


# ------------------------------------------------------------------------ the domain
class Polygon:
    """A polygonal domain: one outer ring and optional holes.

    Parameters
    ----------
    outer: (M, 2) vertices of the outer boundary, in either orientation
        (stored counter-clockwise).  A repeated closing vertex is dropped.
    holes: sequence of (M_k, 2) rings, each strictly inside ``outer`` and
        disjoint from the others (stored clockwise).

    Raises :class:`~taichi_hh.errors.InputError` for fewer than 3 vertices,
    repeated consecutive vertices, non-finite coordinates, zero-area rings,
    rings that cross or touch themselves or each other, holes outside the outer
    ring or inside another hole.  Instances are immutable.
    """

    __slots__ = ("_rings", "_starts", "_ends", "_dir", "_inv_len2", "_seg_normal",
                 "_vn_start", "_vn_end", "_turn", "_piece", "_first_seg",
                 "_area", "_perimeter", "_lo", "_hi", "_scale", "_eps", "_cache", "_col")

    def __init__(self, outer, holes=()):
        rings = [_check_ring(outer, "outer")]
        if holes is None:
            holes = ()
        if isinstance(holes, np.ndarray) and holes.ndim == 2:
            raise InputError("holes must be a sequence of (M, 2) rings, got one (M, 2) array; "
                             "wrap a single hole in a list: holes=[ring]")
        try:
            holes = list(holes)
        except TypeError:
            raise InputError(f"holes must be a sequence of (M, 2) rings, got {holes!r}") from None
        rings += [_check_ring(h, f"holes[{k}]") for k, h in enumerate(holes)]
        self._setup(rings)

    # ---- construction ----------------------------------------------------------------
    def _setup(self, rings):
        set_ = object.__setattr__
        names = ["outer"] + [f"holes[{k}]" for k in range(len(rings) - 1)]
        oriented = []
        for k, (ring, name) in enumerate(zip(rings, names)):
            a = _ring_area(ring)
            span = float(np.ptp(ring, axis=0).max())
            if not abs(a) > 1e-14 * span * span:
                raise InputError(f"{name} is degenerate: it encloses no net area "
                                 f"(vertices on one line, or a ring crossing itself)")
            if (a < 0) == (k == 0):          # outer must be CCW, holes CW
                ring = np.roll(ring[::-1], 1, axis=0)   # reverse, keep vertex 0 first
            oriented.append(np.ascontiguousarray(ring))
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
        hit = _find_crossing(starts, ends, piece, idx_in_ring, lens)
        if hit is not None:
            i, j = hit
            what = (f"{names[piece[i]]} intersects itself" if piece[i] == piece[j]
                    else f"{names[piece[i]]} and {names[piece[j]]} intersect or touch")
            raise InputError(f"{what}: segment {starts[i].tolist()}->{ends[i].tolist()} meets "
                             f"segment {starts[j].tolist()}->{ends[j].tolist()}")
        # with no crossings, one vertex decides where a whole hole lies
        for k in range(1, len(oriented)):
            v = oriented[k][0]
            if not _point_in_ring(v, oriented[0]):
                raise InputError(f"{names[k]} lies outside the outer ring "
                                 f"(vertex {v.tolist()}): holes must be inside it")
            for m in range(1, len(oriented)):
                if m != k and _point_in_ring(v, oriented[m]):
                    raise InputError(f"{names[k]} lies inside {names[m]}: holes must not "
                                     f"overlap or nest")
        lo = starts.min(axis=0)
        hi = starts.max(axis=0)
        diam = float(np.hypot(*(hi - lo)))
        scale = max(diam, float(np.abs(starts).max()))
        for arr in oriented:
            arr.setflags(write=False)
        set_(self, "_rings", tuple(oriented))
        for name, arr in (("_starts", starts), ("_ends", ends), ("_dir", d),
                          ("_inv_len2", 1.0 / len2), ("_seg_normal", normal),
                          ("_vn_start", vn), ("_vn_end", vn[nxt]), ("_turn", turn),
                          ("_piece", piece), ("_first_seg", first)):
            arr = np.ascontiguousarray(arr)
            arr.setflags(write=False)
            set_(self, name, arr)
        cols = {"sx": starts[:, 0], "sy": starts[:, 1], "dx": d[:, 0], "dy": d[:, 1],
                "inv": 1.0 / len2, "ex": ends[:, 0], "ey": ends[:, 1],
                "nx": normal[:, 0], "ny": normal[:, 1], "vsx": vn[:, 0], "vsy": vn[:, 1],
                "vex": vn[nxt, 0], "vey": vn[nxt, 1]}
        for key, arr in cols.items():
            arr = np.ascontiguousarray(arr, dtype=np.float64)
            arr.setflags(write=False)
            cols[key] = arr
        set_(self, "_col", cols)
        set_(self, "_area", float(sum(_ring_area(r) for r in oriented)))
        set_(self, "_perimeter", float(seglen.sum()))
        set_(self, "_lo", (float(lo[0]), float(lo[1])))
        set_(self, "_hi", (float(hi[0]), float(hi[1])))
        set_(self, "_scale", scale)
        set_(self, "_eps", BOUNDARY_RTOL * diam + BOUNDARY_ATOL_COORD * float(np.abs(starts).max()))
        set_(self, "_cache", {})

    @classmethod
    def circle(cls, center=(0.0, 0.0), radius: float = 1.0, n: int = 64, phase: float = 0.0):
        """Regular ``n``-gon inscribed in the circle (vertices on it), as a Polygon."""
        c = _as_points([center], "center")[0]
        radius = _as_real(radius, "radius")
        if isinstance(n, bool) or not isinstance(n, Integral) or n < 3:
            raise InputError(f"n must be an integer >= 3, got {n!r}")
        a = float(phase) + 2.0 * np.pi * np.arange(int(n)) / int(n)
        return Polygon(c + radius * np.stack([np.cos(a), np.sin(a)], axis=1))

    # ---- immutability, equality, repr --------------------------------------------------
    def __setattr__(self, name, value):
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __delattr__(self, name):
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __reduce__(self):
        return (Polygon, (self._rings[0], list(self._rings[1:])))

    def __eq__(self, other):
        if type(other) is not type(self):
            return NotImplemented
        return len(self._rings) == len(other._rings) and all(
            a.shape == b.shape and np.array_equal(a, b) for a, b in zip(self._rings, other._rings))

    def __hash__(self):
        return hash((type(self).__name__,) + tuple(r.tobytes() for r in self._rings))

    def __repr__(self):
        def fmt(r):
            return "[" + ", ".join(f"({x:g}, {y:g})" for x, y in r) + "]"
        if sum(len(r) for r in self._rings) <= 16:
            holes = ", ".join(fmt(r) for r in self._rings[1:])
            return f"Polygon({fmt(self._rings[0])}, holes=[{holes}])"
        holes = ", ".join(f"<{len(r)} vertices>" for r in self._rings[1:])
        return (f"Polygon(<{len(self._rings[0])} vertices>, holes=[{holes}]; "
                f"area={self._area:.6g}, bounds={self.bounds})")

    # ---- geometry ----------------------------------------------------------------------
    @property
    def outer(self) -> np.ndarray:
        """(M, 2) outer ring, counter-clockwise (read-only)."""
        return self._rings[0]

    @property
    def holes(self) -> tuple:
        """The holes, each an (M_k, 2) clockwise ring (read-only)."""
        return self._rings[1:]

    @property
    def rings(self) -> tuple:
        """All boundary pieces: ``(outer,) + holes``; the piece id is the index here."""
        return self._rings

    @property
    def area(self) -> float:
        """Area of the outer ring minus the holes."""
        return self._area

    @property
    def perimeter(self) -> float:
        """Total boundary length (outer ring plus holes)."""
        return self._perimeter

    @property
    def bounds(self):
        """``((xmin, ymin), (xmax, ymax))`` of the domain."""
        return self._lo, self._hi

    @property
    def boundary_tolerance(self) -> float:
        """Distance below which a point counts as on the boundary."""
        return self._eps

    def segments(self):
        """``(starts, ends)``, two (S, 2) arrays: every boundary segment, interior on the left.

        Segments run ring by ring (outer first, then the holes in order), segment
        ``k`` of a ring going from its vertex ``k`` to vertex ``k + 1``."""
        return self._starts.copy(), self._ends.copy()

    def segment_normals(self) -> np.ndarray:
        """(S, 2) outward unit normal of each segment (right of its direction)."""
        return self._seg_normal.copy()

    def segment_piece(self) -> np.ndarray:
        """(S,) piece id of each segment: 0 for the outer ring, k for ``holes[k-1]``."""
        return self._piece.copy()

    # ---- point queries -----------------------------------------------------------------
    def contains(self, points, tol: float = 0.0) -> np.ndarray:
        """(N,) bool: point inside or on the boundary; ``tol > 0`` widens by ``tol``."""
        p = _as_points(points)
        tol = _as_real(tol, "tol", allow_zero=True)
        return self._classify(p, 0.0, -np.inf, max(tol, self._eps)) == 1

    def signed_distance(self, points) -> np.ndarray:
        """(N,) exact distance to the boundary: negative inside, positive outside."""
        p = _as_points(points)
        dist, _, _, _, sign = self._closest(p, full=False)
        dist *= sign
        return dist

    def closest_boundary(self, points):
        """``(distance, closest, normal, segment)`` for every point.

        ``distance`` (N,) unsigned; ``closest`` (N, 2) the closest boundary point;
        ``normal`` (N, 2) the outward unit normal there (the segment's, or the
        normalised average of the two adjacent segment normals when the closest
        point is a vertex); ``segment`` (N,) index into :meth:`segments` (at a
        vertex either adjacent segment may be reported)."""
        p = _as_points(points)
        dist, q, n, seg, _ = self._closest(p)
        return dist, q, n, seg

    # ---- samplers ----------------------------------------------------------------------
    def sample_boundary(self, spacing: float, corner_angle: float = DEFAULT_CORNER_ANGLE):
        """``(points, normals, piece)``: points about ``spacing`` apart along every ring.

        Every vertex whose boundary turns by more than ``corner_angle`` degrees
        is a sample (all vertices with ``corner_angle=0``); between those, points
        are equally spaced by arc length at a spacing in (spacing/2, spacing]
        (shorter only where two such vertices are closer than ``spacing``).
        ``normals`` are outward unit normals, averaged at vertices; ``piece`` is
        the ring index (0 outer, k for ``holes[k-1]``)."""
        spacing = _as_real(spacing, "spacing")
        corner_angle = _as_real(corner_angle, "corner_angle", allow_zero=True)
        if corner_angle >= 180.0:
            raise InputError(f"corner_angle must be below 180 degrees, got {corner_angle}")
        if self._perimeter / spacing > 5e7:
            raise InputError(f"spacing {spacing:g} is too small: it would give more than "
                             f"5e7 boundary points")
        pts, nrm, pieces = [], [], []
        thresh = math.radians(corner_angle)
        for k in range(len(self._rings)):
            s0, s1 = self._first_seg[k], self._first_seg[k + 1]
            m = s1 - s0
            seglen = np.sqrt(1.0 / self._inv_len2[s0:s1])
            cum = np.concatenate([[0.0], np.cumsum(seglen)])     # arc length at vertex j
            total = cum[-1]
            corners = np.flatnonzero(self._turn[s0:s1] > thresh) if corner_angle > 0 \
                else np.arange(m)
            if corners.size == 0:
                corners = np.array([0])
            # arcs between consecutive corners (cyclic)
            a_start = cum[corners]
            a_len = np.diff(np.concatenate([a_start, [a_start[0] + total]]))
            nsub = np.maximum(1, np.ceil(a_len / spacing * (1 - 1e-12)).astype(np.int64))
            owner = np.repeat(np.arange(corners.size), nsub)
            j = np.arange(nsub.sum()) - np.repeat(np.cumsum(nsub) - nsub, nsub)
            arc = a_start[owner] + a_len[owner] * j / nsub[owner]
            arc = np.where(arc >= total, arc - total, arc)
            seg = np.clip(np.searchsorted(cum, arc, side="right") - 1, 0, m - 1)
            t = (arc - cum[seg]) / seglen[seg]
            # snap to vertices where the arc position is (numerically) one
            at_start = (j == 0) | (t <= 1e-12)
            at_end = ~at_start & (t >= 1 - 1e-12)
            g = s0 + seg
            p = self._starts[g] + t[:, None] * self._dir[g]
            n = self._seg_normal[g].copy()
            p[at_start] = self._starts[g[at_start]]
            n[at_start] = self._vn_start[g[at_start]]
            p[at_end] = self._ends[g[at_end]]
            n[at_end] = self._vn_end[g[at_end]]
            pts.append(p)
            nrm.append(n)
            pieces.append(np.full(len(p), k, dtype=np.int64))
        return np.concatenate(pts), np.concatenate(nrm), np.concatenate(pieces)

    def sample_ghosts(self, spacing: float, width: float, seed=0, avoid=None) -> np.ndarray:
        """(G, 2) Poisson-disk points outside the domain with ``0 < signed_distance <= width``.

        The band includes the inside of holes near their boundary.  Any two
        points are at least ``spacing`` apart and every point of the band lies
        within about ``2 * spacing`` of one (a maximal sample, built by
        vectorised dart throwing on a background grid).  With ``avoid`` (an
        (N, 2) array, e.g. the interior particles) the ghosts also keep
        ``spacing`` away from those points.  Deterministic for a given seed."""
        spacing = _as_real(spacing, "spacing")
        width = _as_real(width, "width")
        rng = _as_seed(seed)
        av = None if avoid is None else _as_points(avoid, "avoid")
        return self._poisson(spacing, self._eps, width, rng, avoid=av)

    def sample_ghosts_mirror(self, points, width: float):
        """``(ghosts, source)``: mirror images of interior points near the boundary.

        Every point of ``points`` (which must lie in the domain) within
        ``width`` of the boundary is reflected across the line of its closest
        boundary segment; images that do not land strictly outside the domain
        (e.g. near concave corners, or from points on the boundary) are dropped.
        ``source`` (G,) holds the index of each image's source point.
        :class:`Box` reflects across every side within ``width`` and adds the
        corner images."""
        p, width = self._mirror_args(points, width)
        dist, _, _, seg, sign = self._closest(p)
        sel = np.flatnonzero((dist <= width) & (dist > self._eps))
        s = self._starts[seg[sel]]
        n = self._seg_normal[seg[sel]]
        off = np.einsum("ij,ij->i", p[sel] - s, n)
        g = p[sel] - 2.0 * off[:, None] * n
        keep = self._classify(g, 0.0, self._eps, np.inf) == 1
        return g[keep], sel[keep]

    def _mirror_args(self, points, width):
        p = _as_points(points)
        width = _as_real(width, "width")
        outside = ~self.contains(p)
        if outside.any():
            k = int(np.flatnonzero(outside)[0])
            raise InputError(f"points must lie in the domain to be mirrored: {int(outside.sum())} "
                             f"do not, first at index {k}: {p[k].tolist()}")
        return p, width

    def sample_interior(self, n_or_spacing, kind: str = "poisson", seed=0, *,
                        jitter: float = 0.5, margin: float = 0.0) -> np.ndarray:
        """(N, 2) points strictly inside the domain.

        ``n_or_spacing``: an integer is the wanted number of points (met
        roughly for ``poisson`` and ``jittered``, exactly for ``random``); a
        float is the spacing (Poisson-disk radius, lattice step, or the mean
        spacing ``sqrt(area / N)`` for ``random``).

        ``kind``: ``"poisson"`` blue noise (maximal Poisson-disk sample: no two
        points closer than the radius), ``"jittered"`` a square lattice whose
        points are each moved uniformly within a square of side
        ``jitter * step`` (``jitter`` in [0, 1]; 0 = regular lattice), or
        ``"random"`` uniform.  ``margin``: keep at least this distance from the
        boundary.  Deterministic for a given seed."""
        if kind not in ("poisson", "jittered", "random"):
            raise InputError(f"kind must be 'poisson', 'jittered' or 'random', got {kind!r}")
        rng = _as_seed(seed)
        jitter = _as_real(jitter, "jitter", allow_zero=True)
        if jitter > 1.0:
            raise InputError(f"jitter must be in [0, 1], got {jitter}")
        margin = _as_real(margin, "margin", allow_zero=True)
        if isinstance(n_or_spacing, (bool, np.bool_)):
            raise InputError(f"n_or_spacing must be a point count (int) or a spacing (float), "
                             f"got {n_or_spacing!r}")
        if isinstance(n_or_spacing, Integral):
            count = int(n_or_spacing)
            if count < 1:
                raise InputError(f"the number of points must be at least 1, got {count}")
            if count > 5e7:
                raise InputError(f"{count} points is more than this sampler supports (5e7)")
            spacing = None
        else:
            spacing = _as_real(n_or_spacing, "spacing")
            count = None
        hi = -max(margin, self._eps)
        # area available to the points (outer offset inwards by the margin)
        avail = self._area - margin * self._perimeter
        if margin > 0:
            loc = self._locator()
            depth = -float(loc.sd.min()) + loc.half_diag     # upper bound on the inradius
            if margin >= depth:
                raise InputError(f"margin {margin:g} leaves no room inside the domain "
                                 f"(no point is farther than {depth:.6g} from the boundary)")
        avail = max(avail, 1e-3 * self._area)
        if kind == "random":
            if count is None:
                count = max(1, int(round(avail / spacing ** 2)))
                if count > 5e7:
                    raise InputError(f"spacing {spacing:g} is too small: it would give {count:.3g} "
                                     f"points (limit 5e7)")
            return self._random_inside(count, hi, rng)
        if kind == "jittered":
            if count is not None:
                return self._calibrate(
                    lambda h: self._jittered(h, jitter, hi, rng_state=rng.bit_generator.state),
                    math.sqrt(avail / count), count)
            return self._jittered(spacing, jitter, hi, rng_state=rng.bit_generator.state)
        # poisson
        if count is not None:
            # solve count = ALPHA (avail + BETA P r) / r^2 for x = 1 / r
            qa, qb = _POISSON_ALPHA * avail, _POISSON_ALPHA * _POISSON_BETA * self._perimeter
            r0 = 2.0 * qa / (-qb + math.sqrt(qb * qb + 4.0 * qa * count))
            state = rng.bit_generator.state
            return self._calibrate(
                lambda r: self._poisson(r, -np.inf, hi, _rng_from(state)), r0, count)
        return self._poisson(spacing, -np.inf, hi, rng)

    # ---- internals: exact closest-segment queries ---------------------------------------
    def _locator(self, lo=None, hi=None) -> "_Locator":
        """The cached acceleration grid, rebuilt if it must cover [lo, hi]."""
        dlo, dhi = np.array(self._lo), np.array(self._hi)
        loc = self._cache.get("loc")
        if lo is None:
            if loc is not None:
                return loc
            pad = 0.25 * float((dhi - dlo).max())
            lo, hi = dlo - pad, dhi + pad
        else:
            lo, hi = np.minimum(lo, dlo), np.maximum(hi, dhi)
            if loc is not None and (loc.lo <= lo).all() and (loc.hi >= hi).all():
                return loc
            if loc is not None:
                lo, hi = np.minimum(lo, loc.lo), np.maximum(hi, loc.hi)
        loc = _Locator(self, lo, hi)
        self._cache["loc"] = loc
        return loc

    def _pair_vec(self, px, py, segs):
        """Vectors from the closest points of segments ``segs`` to points ``(px, py)``."""
        col = self._col
        dx = col["dx"][segs]
        dy = col["dy"][segs]
        wx = px - col["sx"][segs]
        wy = py - col["sy"][segs]
        t = (wx * dx + wy * dy) * col["inv"][segs]
        np.clip(t, 0.0, 1.0, out=t)
        wx -= t * dx
        wy -= t * dy
        return wx, wy

    def _pair_d2(self, px, py, segs):
        """Squared distances from points ``(px, py)`` to segments ``segs`` (broadcast)."""
        col = self._col
        dx = col["dx"][segs]
        dy = col["dy"][segs]
        wx = px - col["sx"][segs]
        wy = py - col["sy"][segs]
        t = (wx * dx + wy * dy) * col["inv"][segs]
        np.clip(t, 0.0, 1.0, out=t)
        wx -= t * dx
        wy -= t * dy
        wx *= wx
        wy *= wy
        wx += wy
        return wx

    def _scan(self, px, py, first, count, cand):
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
            d2 = self._pair_d2(px[:m], py[:m], s)
            better = d2 < best[:m]
            np.copyto(best[:m], d2, where=better)
            np.copyto(bseg[:m], s, where=better)
        out = np.empty(n, dtype=np.int64)
        out[order] = bseg
        return out

    def _brute_segments(self, p: np.ndarray) -> np.ndarray:
        """Closest segment of each point by scanning all segments."""
        S = len(self._starts)
        n = len(p)
        px, py = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
        best = np.full(n, np.inf)
        bseg = np.zeros(n, dtype=np.int64)
        for k in range(S):
            d2 = self._pair_d2(px, py, k)
            better = d2 < best
            np.copyto(best, d2, where=better)
            bseg[better] = k
        return bseg

    def _closest_segments(self, p: np.ndarray) -> np.ndarray:
        """Index of a closest boundary segment for every point."""
        n = len(p)
        seg = np.empty(n, dtype=np.int64)
        if n == 0:
            return seg
        loc = self._locator()
        cell, ing = loc.cell_of(p)
        allin = bool(ing.all())
        if not allin:
            out = np.flatnonzero(~ing)
            seg[out] = self._brute_segments(p[out])
            idx = np.flatnonzero(ing)
            cell = cell[idx]
            p = p[idx]
        step = 1 << 17
        for a in range(0, len(p), step):
            c = cell[a:a + step]
            q = p[a:a + step]
            res = self._scan(np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]),
                             loc.start[c], loc.count[c], loc.cand)
            if allin:
                seg[a:a + step] = res
            else:
                seg[idx[a:a + step]] = res
        return seg

    def _features(self, p: np.ndarray, seg: np.ndarray, full: bool = True):
        """Distance, closest point, normal and sign of ``p`` relative to segments ``seg``."""
        col = self._col
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

    def _closest(self, p: np.ndarray, full: bool = True):
        seg = self._closest_segments(p)
        dist, q, n, sign = self._features(p, seg, full)
        return dist, q, n, seg, sign

    def _classify(self, p: np.ndarray, radius: float, lo: float, hi: float) -> np.ndarray:
        """For discs of ``radius`` around ``p``: 1 if every point has lo < sd <= hi,
        0 if none has, 2 if undecided (only possible for radius > 0)."""
        n = len(p)
        status = np.full(n, 2, dtype=np.int8)
        if n == 0:
            return status
        loc = self._locator()
        cell, ing = loc.cell_of(p)
        sdc = np.where(ing, loc.sd[np.where(ing, cell, 0)], np.nan)
        R = loc.half_diag + radius
        with np.errstate(invalid="ignore"):
            out = (sdc + R <= lo) | (sdc - R > hi)
            full = (sdc - R > lo) & (sdc + R <= hi)
        status[out] = 0
        status[full] = 1
        und = np.flatnonzero(~(out | full))
        if und.size:
            sd = self.signed_distance(p[und])
            st = np.full(und.size, 2, dtype=np.int8)
            st[(sd + radius <= lo) | (sd - radius > hi)] = 0
            st[(sd - radius > lo) & (sd + radius <= hi)] = 1
            status[und] = st
        return status

    # ---- internals: samplers --------------------------------------------------------
    def _check_cells(self, cell_area: float, name: str):
        lo, hi = np.array(self._lo), np.array(self._hi)
        ncell = float(np.prod(hi - lo)) / cell_area
        if ncell > _MAX_CELLS:
            raise InputError(f"{name} is too small for this domain: sampling would need "
                             f"{ncell:.3g} grid cells (limit {_MAX_CELLS:.0e})")

    def _calibrate(self, make, size0: float, count: int):
        """Run ``make(size)`` and rescale size until the point count is near ``count``."""
        size = size0
        best = None
        for _ in range(3):
            pts = make(size)
            if best is None or abs(len(pts) - count) < abs(len(best) - count):
                best = pts
            if len(pts) == 0:
                size *= 0.5
                continue
            ratio = len(pts) / count
            if abs(ratio - 1.0) <= 0.03:
                break
            size *= math.sqrt(ratio)
        return best

    def _random_inside(self, count: int, hi: float, rng) -> np.ndarray:
        lo_b, hi_b = np.array(self._lo), np.array(self._hi)
        frac = max(self._area / float(np.prod(hi_b - lo_b)), 1e-6)
        out, have = [], 0
        for _ in range(1000):
            m = int(1.2 * (count - have) / frac) + 16
            cand = lo_b + rng.random((m, 2)) * (hi_b - lo_b)
            cand = cand[self._classify(cand, 0.0, -np.inf, hi) == 1]
            out.append(cand[: count - have])
            have += len(out[-1])
            if have >= count:
                return np.concatenate(out)
        raise InputError("could not place the random points: the domain (minus the margin) "
                         "is too thin")

    def _jittered(self, h: float, jitter: float, hi: float, rng_state) -> np.ndarray:
        rng = _rng_from(rng_state)
        self._check_cells(h * h, "the lattice step")
        lo_b, hi_b = np.array(self._lo), np.array(self._hi)
        span = hi_b - lo_b
        nxy = np.maximum(1, np.floor(span / h + 1e-9).astype(np.int64))
        off = lo_b + 0.5 * (span - (nxy - 1) * h)        # lattice centred in the bounds
        ix, iy = np.meshgrid(np.arange(nxy[0]), np.arange(nxy[1]))
        pts = off + h * np.stack([ix.ravel(), iy.ravel()], axis=1).astype(np.float64)
        if jitter > 0:
            pts += jitter * h * (rng.random(pts.shape) - 0.5)
        return pts[self._classify(pts, 0.0, -np.inf, hi) == 1]

    def _poisson(self, r: float, band_lo: float, band_hi: float, rng, avoid=None,
                 dart_rounds: int = 3) -> np.ndarray:
        """Maximal Poisson-disk sample of radius ``r`` in {band_lo < sd <= band_hi}.

        Background grid of cell size r / sqrt(2) (at most one point per cell);
        cells are processed in 9 phase groups ((i mod 3, j mod 3)) whose darts
        cannot conflict with each other, so each phase is one vectorised step.
        A few rounds of plain darts are followed by rounds over jittered
        candidate positions (3 x 3 per empty cell) that are still free, until
        none is left."""
        ext = max(band_hi, 0.0) if np.isfinite(band_hi) else 0.0
        lo = np.array(self._lo) - ext
        hi = np.array(self._hi) + ext
        c = r / math.sqrt(2.0)
        nx, ny = (np.maximum(1, np.ceil((hi - lo) / c))).astype(np.int64)
        if nx * ny > _MAX_CELLS:
            raise InputError(f"spacing {r:g} is too small for this domain: the sampler would "
                             f"need {nx * ny:.3g} grid cells (limit {_MAX_CELLS:.0e})")
        self._locator(lo, hi)
        P = 2
        nxp, nyp = int(nx + 2 * P), int(ny + 2 * P)
        r2 = r * r
        px = np.full(nxp * nyp, np.inf)       # sample in each cell (inf: none)
        py = np.full(nxp * nyp, np.inf)
        occ = np.zeros(nxp * nyp, dtype=bool)
        offs = np.array([dy * nxp + dx for dy in range(-2, 3) for dx in range(-2, 3)
                         if not (abs(dx) == 2 and abs(dy) == 2)], dtype=np.int64)
        tree = None
        if avoid is not None and len(avoid):
            from scipy.spatial import cKDTree
            near = np.all((avoid >= lo - r) & (avoid <= hi + r), axis=1)
            if near.any():
                tree = cKDTree(avoid[near])

        # classify the cells (whole cell inside the band / outside / partly)
        status = np.empty(int(nx * ny), dtype=np.int8)
        rows = max(1, _CHUNK // int(nx))
        xs = lo[0] + (np.arange(nx) + 0.5) * c
        for y0 in range(0, int(ny), rows):
            y1 = min(int(ny), y0 + rows)
            ys = lo[1] + (np.arange(y0, y1) + 0.5) * c
            cx, cy = np.meshgrid(xs, ys)
            status[y0 * nx:y1 * nx] = self._classify(
                np.stack([cx.ravel(), cy.ravel()], axis=1), c / math.sqrt(2.0), band_lo, band_hi)
        act = np.flatnonzero(status > 0)
        aix, aiy = act % nx, act // nx
        pid = (aiy + P) * nxp + (aix + P)                 # padded flat cell id
        full = status[act] == 1
        phase = (aix % 3) * 3 + (aiy % 3)

        def conflict(cells, q):
            qx, qy = q[:, 0], q[:, 1]
            bad = np.zeros(len(q), dtype=bool)
            for o in offs:
                nb = cells + o
                dx = px[nb] - qx
                dy = py[nb] - qy
                dx *= dx
                dy *= dy
                dx += dy
                bad |= dx < r2
            if tree is not None and len(q):
                dd, _ = tree.query(q, k=1, distance_upper_bound=r)
                bad |= dd < r
            return bad

        def in_region(q, isfull):
            ok = isfull.copy()
            part = np.flatnonzero(~isfull)
            if part.size:
                ok[part] = self._classify(q[part], 0.0, band_lo, band_hi) == 1
            return ok

        groups = [np.flatnonzero(phase == g) for g in range(9)]
        # plain dart throwing
        for _ in range(dart_rounds):
            for g in rng.permutation(9):
                sel = groups[g]
                sel = sel[~occ[pid[sel]]]
                groups[g] = sel
                if sel.size == 0:
                    continue
                q = lo + (np.stack([aix[sel], aiy[sel]], axis=1) + rng.random((sel.size, 2))) * c
                ok = in_region(q, full[sel])
                ok[ok] = ~conflict(pid[sel[ok]], q[ok])
                acc = pid[sel[ok]]
                px[acc], py[acc] = q[ok, 0], q[ok, 1]
                occ[acc] = True
        # finish with free candidate positions: m x m jittered per empty cell,
        # tested against the cell's neighbourhood gathered once per cell
        m = 3
        sub = np.stack(np.meshgrid(np.arange(m), np.arange(m)), axis=-1).reshape(1, -1, 2)
        quad = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]])
        offs8 = np.array([dy * nxp + dx for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                          if dx or dy], dtype=np.int64)
        sel = np.flatnonzero(~occ[pid])
        u = rng.random((sel.size, m * m, 2))
        keep_cell, keep_xy = [], []
        step = max(1, _CHUNK // (m * m * len(offs)))
        for a in range(0, sel.size, step):
            cs = sel[a:a + step]
            uu = u[a:a + step]
            # skip cells lying wholly inside one sample's disc (all 4 corners);
            # only the 8 adjacent cells can hold such a sample
            nb = pid[cs][:, None] + offs8[None, :]
            corner = lo + (np.stack([aix[cs], aiy[cs]], axis=1)[:, None, :] + quad) * c
            dx = px[nb][:, None, :] - corner[:, :, 0:1]
            dy = py[nb][:, None, :] - corner[:, :, 1:2]
            dx *= dx
            dy *= dy
            dx += dy
            covered = (dx < r2).all(axis=1).any(axis=1)
            cs, uu = cs[~covered], uu[~covered]
            nb = pid[cs][:, None] + offs[None, :]                           # (k, 21)
            nbx, nby = px[nb][:, None, :], py[nb][:, None, :]
            q = lo + (np.stack([aix[cs], aiy[cs]], axis=1)[:, None, :]
                      + (sub + uu) / m) * c                                  # (k, m*m, 2)
            dx = nbx - q[:, :, 0:1]
            dy = nby - q[:, :, 1:2]
            dx *= dx
            dy *= dy
            dx += dy
            ok = ~(dx < r2).any(axis=2)                                      # (k, m*m)
            cc = np.repeat(cs, m * m)[ok.ravel()]
            qq = q.reshape(-1, 2)[ok.ravel()]
            keep_cell.append(cc)
            keep_xy.append(qq)
        cand_cell = np.concatenate(keep_cell) if keep_cell else np.zeros(0, np.int64)
        cand = np.concatenate(keep_xy) if keep_xy else np.zeros((0, 2))
        ok = in_region(cand, full[cand_cell])
        cand_cell, cand = cand_cell[ok], cand[ok]
        if tree is not None and cand_cell.size:
            dd, _ = tree.query(cand, k=1, distance_upper_bound=r)
            cand_cell, cand = cand_cell[dd >= r], cand[dd >= r]
        while cand_cell.size:
            perm = rng.permutation(cand_cell.size)
            cc = cand_cell[perm]
            first = np.unique(cc, return_index=True)[1]
            pick = perm[first]                                   # one random candidate per cell
            ph = phase[cand_cell[pick]]
            drop = np.zeros(cand_cell.size, dtype=bool)
            for g in rng.permutation(9):
                pk = pick[ph == g]
                if pk.size == 0:
                    continue
                bad = conflict(pid[cand_cell[pk]], cand[pk])
                acc = pk[~bad]
                cid = pid[cand_cell[acc]]
                px[cid], py[cid] = cand[acc, 0], cand[acc, 1]
                occ[cid] = True
                drop[pk[bad]] = True
            keep = ~drop & ~occ[pid[cand_cell]]
            cand_cell, cand = cand_cell[keep], cand[keep]
            if cand_cell.size:
                ok = ~conflict(pid[cand_cell], cand)
                cand_cell, cand = cand_cell[ok], cand[ok]
        k = np.flatnonzero(occ)
        return np.stack([px[k], py[k]], axis=1)


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


def _rng_from(state):
    g = np.random.default_rng()
    g.bit_generator.state = state
    return g


class _Locator:
    """Uniform grid whose cells list the segments that can be closest to any point
    in the cell, plus the exact signed distance of every cell centre.

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
    subdivided) boundaries, where many segments are nearly equidistant."""

    def __init__(self, poly: Polygon, lo, hi):
        S = len(poly._starts)
        lo = np.asarray(lo, dtype=np.float64)
        span = np.asarray(hi, dtype=np.float64) - lo
        span = np.maximum(span, 1e-12 * max(1.0, float(span.max())))
        target = int(np.clip(_LOCATOR_CELLS_PER_SEGMENT * S, 16384, _LOCATOR_MAX_CELLS))
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
        tol = 1e-9 * poly._scale
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
            ux = np.empty(cand.size)
            uy = np.empty(cand.size)
            for a in range(0, cand.size, _CHUNK):
                o = owner[a:a + _CHUNK]
                ux[a:a + _CHUNK], uy[a:a + _CHUNK] = poly._pair_vec(cx[o], cy[o],
                                                                    cand[a:a + _CHUNK])
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
            cand, owner = cand[keep], owner[keep]
            cnt = np.bincount(owner, minlength=ncell)
        # closest segment of every centre -> signed distance of the centres
        centers = np.stack([cx, cy], axis=1)
        dist, _, _, sign = poly._features(centers, best, full=False)
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
        self.lo = lo
        self.size = size
        self.nx, self.ny = nx, ny
        self.hi = lo + np.array([nx, ny]) * size
        self.half_diag = size * math.sqrt(0.5) * (1 + 1e-12) + tol
        self.count, self.start, self.cand, self.sd = count, gstart, gcand, sd

    def cell_of(self, p):
        """(cell id, inside-grid mask) of every point."""
        fx = (p[:, 0] - self.lo[0]) / self.size
        fy = (p[:, 1] - self.lo[1]) / self.size
        ing = (fx >= 0) & (fx < self.nx) & (fy >= 0) & (fy < self.ny)
        ix = np.clip(fx, 0, self.nx - 1).astype(np.int64)
        iy = np.clip(fy, 0, self.ny - 1).astype(np.int64)
        return iy * self.nx + ix, ing

    def center(self, k):
        return self.lo + (np.array([k % self.nx, k // self.nx]) + 0.5) * self.size


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
        object.__setattr__(self, "lo", (float(lo[0]), float(lo[1])))
        object.__setattr__(self, "hi", (float(hi[0]), float(hi[1])))
        self._setup([np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])])

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

    def sample_ghosts_mirror(self, points, width: float):
        """``(ghosts, source)``: reflections of interior points across every side
        within ``width`` (distance > 0), plus the corner image (reflection across
        both sides) when a point is within ``width`` of two adjacent sides."""
        p, width = self._mirror_args(points, width)
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


def as_domain(domain):
    """A Box or Polygon from a domain, a 4-sequence ``(x0, y0, x1, y1)`` (a Box) or an
    (M, 2) vertex array (a Polygon without holes)."""
    if isinstance(domain, Polygon):
        return domain
    try:
        arr = np.asarray(domain, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is not None and arr.shape == (4,):
        return Box(arr[:2], arr[2:])
    if arr is not None and arr.ndim == 2 and arr.shape[1] == 2:
        return Polygon(arr)
    raise InputError(f"cannot make a domain from {domain!r}: give a Box, a Polygon, "
                     f"(x0, y0, x1, y1) or an (M, 2) array of vertices")
