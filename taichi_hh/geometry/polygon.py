"""Polygonal domains with holes (host side, numpy only).

A domain is a closed region bounded by straight segments: one outer ring and
any number of holes, validated by :mod:`~taichi_hh.geometry.rings` and stored
as one :class:`~taichi_hh.geometry.segments.Segments` table oriented so that
the interior lies on the *left* of each segment.  :class:`Polygon` offers

* geometry: :attr:`~Polygon.area`, :attr:`~Polygon.perimeter`,
  :attr:`~Polygon.bounds`, :meth:`~Polygon.segments`;
* queries on many points at once: :meth:`~Polygon.contains`,
  :meth:`~Polygon.signed_distance` (negative inside, positive outside),
  :meth:`~Polygon.closest_boundary` (distance, closest point, outward unit
  normal, segment index) and :meth:`~Polygon.classify_discs`, all answered
  through a lazily built, cached :class:`~taichi_hh.geometry.locator.Locator`;
* samplers (implemented in :mod:`~taichi_hh.geometry.sampling`): boundary
  particles with normals (Colin et al. 2006, Sec. 3.4-3.6), Poisson-disk
  "fake" particles outside the domain (Petronetto et al. 2010, Sec. 5b),
  mirror ghosts, and interior points (blue noise, jittered lattice, uniform
  random).

**Boundary tolerance.**  Points within ``1e-12 * diameter + 1e-14 * max|x|``
of the boundary (:attr:`~Polygon.boundary_tolerance`; the second term covers
rounding of far-from-origin coordinates) count as *on* the boundary:
:meth:`~Polygon.contains` says they are inside, samplers that must stay
strictly inside or strictly outside keep farther away than that.
"""
from __future__ import annotations

from numbers import Integral

import numpy as np

from ..checks import check_points, check_real
from ..errors import InputError
from . import cell_decisions, sampling
from .locator import Locator
from .rings import check_holes_placed, check_no_crossing, check_ring, orient_rings, ring_area
from .segments import Segments

__all__ = ["Polygon", "BOUNDARY_RTOL", "BOUNDARY_ATOL_COORD", "WALL_TIE_RTOL"]

#: points within BOUNDARY_RTOL * diameter + BOUNDARY_ATOL_COORD * max|coordinate|
#: of the boundary are "on" it
BOUNDARY_RTOL = 1e-12
BOUNDARY_ATOL_COORD = 1e-14
#: a point is equally close to two adjacent walls (on the bisector of their
#: corner) when its distances to them differ by less than WALL_TIE_RTOL *
#: diameter + 100 * BOUNDARY_ATOL_COORD * max|coordinate|.  Such points are
#: made, not met by chance: the hull's data points at its vertices lie on the
#: bisectors (the ring is moved out along them), a lattice's corner point in a
#: box with equal margins too; which wall the closest-segment search reports
#: for them is a rounding decision, so the tie is resolved by a rule that is
#: not (a band of 1e-9 diameters is far wider than any rounding of the
#: coordinates and far narrower than anything a spacing resolves)
WALL_TIE_RTOL = 1e-9


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

    __slots__ = ("_rings", "_segments", "_area", "_perimeter", "_lo", "_hi", "_scale", "_eps",
                 "_tie", "_cache")

    def __init__(self, outer, holes=()):
        rings = [check_ring(outer, "outer")]
        if holes is None:
            holes = ()
        if isinstance(holes, np.ndarray) and holes.ndim == 2:
            raise InputError("holes must be a sequence of (M, 2) rings, got one (M, 2) array; "
                             "wrap a single hole in a list: holes=[ring]")
        try:
            holes = list(holes)
        except TypeError:
            raise InputError(f"holes must be a sequence of (M, 2) rings, got {holes!r}") from None
        rings += [check_ring(h, f"holes[{k}]") for k, h in enumerate(holes)]
        names = ["outer"] + [f"holes[{k}]" for k in range(len(rings) - 1)]
        oriented = orient_rings(rings, names)
        segs = Segments(oriented, names)
        check_no_crossing(segs.starts, segs.ends, segs.piece, segs.ring_start, names)
        check_holes_placed(oriented, names)
        starts = segs.starts
        lo = starts.min(axis=0)
        hi = starts.max(axis=0)
        diam = float(np.hypot(*(hi - lo)))
        scale = max(diam, float(np.abs(starts).max()))
        for arr in oriented:
            arr.setflags(write=False)
        set_ = object.__setattr__
        set_(self, "_rings", tuple(oriented))
        set_(self, "_segments", segs)
        set_(self, "_area", float(sum(ring_area(r) for r in oriented)))
        set_(self, "_perimeter", float(segs.length.sum()))
        set_(self, "_lo", (float(lo[0]), float(lo[1])))
        set_(self, "_hi", (float(hi[0]), float(hi[1])))
        set_(self, "_scale", scale)
        set_(self, "_eps", BOUNDARY_RTOL * diam + BOUNDARY_ATOL_COORD * float(np.abs(starts).max()))
        set_(self, "_tie", WALL_TIE_RTOL * diam
             + 100.0 * BOUNDARY_ATOL_COORD * float(np.abs(starts).max()))
        set_(self, "_cache", {})

    @classmethod
    def circle(cls, center=(0.0, 0.0), radius: float = 1.0, n: int = 64, phase: float = 0.0):
        """Regular ``n``-gon inscribed in the circle (vertices on it), as a Polygon."""
        c = check_points([center], "center")[0]
        radius = check_real(radius, "radius")
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

    def rescaled(self, centre, length: float) -> "Polygon":
        """The same domain in the coordinates ``(p - centre) / length`` (a change of
        units and origin, as :class:`~taichi_hh.hhd.units.Frame` makes)."""
        c = np.asarray(centre, dtype=np.float64)
        return Polygon((self._rings[0] - c) / length, [(h - c) / length for h in self._rings[1:]])

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

    @property
    def segment_table(self) -> Segments:
        """The boundary's :class:`~taichi_hh.geometry.segments.Segments` (read-only arrays)."""
        return self._segments

    def segments(self):
        """``(starts, ends)``, two (S, 2) arrays: every boundary segment, interior on the left.

        Segments run ring by ring (outer first, then the holes in order), segment
        ``k`` of a ring going from its vertex ``k`` to vertex ``k + 1``."""
        return self._segments.starts.copy(), self._segments.ends.copy()

    def segment_normals(self) -> np.ndarray:
        """(S, 2) outward unit normal of each segment (right of its direction)."""
        return self._segments.normal.copy()

    def segment_piece(self) -> np.ndarray:
        """(S,) piece id of each segment: 0 for the outer ring, k for ``holes[k-1]``."""
        return self._segments.piece.copy()

    # ---- point queries -----------------------------------------------------------------
    def contains(self, points, tol: float = 0.0) -> np.ndarray:
        """(N,) bool: point inside or on the boundary; ``tol > 0`` widens by ``tol``."""
        p = check_points(points, allow_empty=True)
        tol = check_real(tol, "tol", allow_zero=True)
        return self.classify_discs(p, 0.0, -np.inf, max(tol, self._eps)) == 1

    def signed_distance(self, points) -> np.ndarray:
        """(N,) exact distance to the boundary: negative inside, positive outside."""
        p = check_points(points, allow_empty=True)
        seg = self.locator().closest_segments(p)
        dist, _, _, sign = self._segments.features(p, seg, full=False)
        dist *= sign
        return dist

    def closest_boundary(self, points):
        """``(distance, closest, normal, segment)`` for every point.

        ``distance`` (N,) unsigned; ``closest`` (N, 2) the closest boundary point;
        ``normal`` (N, 2) the outward unit normal there (the segment's, or the
        normalised average of the two adjacent segment normals when the closest
        point is a vertex); ``segment`` (N,) index into :meth:`segments` (at a
        vertex either adjacent segment may be reported).  A point equally close to two
        adjacent segments (on the bisector of their corner, within
        :data:`WALL_TIE_RTOL`) gets their corner's averaged normal too, whichever
        of the two the search reports with its closest point: the choice between
        the two walls' normals would otherwise be made by rounding."""
        p = check_points(points, allow_empty=True)
        seg = self.locator().closest_segments(p)
        dist, q, n, _ = self._segments.features(p, seg)
        tied, _, corner_normal = self._tied_corners(p, dist, seg)
        n[tied] = corner_normal[tied]
        return dist, q, n, seg

    def _tied_corners(self, p: np.ndarray, dist: np.ndarray, seg: np.ndarray):
        """``(tied, corner, corner_normal)``: which points (N,) are as close (within
        the tie tolerance) to their closest segment ``seg`` (at distance ``dist``)
        as to one of its two neighbours in the ring, the closest points on both
        inside the segments (on the shared vertex there is no choice to make), and
        that shared vertex (N, 2) and its averaged outward normal (N, 2).  A point
        tied with both neighbours (the incentre of a triangle) is left untied: no
        one corner is closest there."""
        segs = self._segments
        n = len(p)
        if n == 0:
            return np.zeros(0, dtype=bool), np.zeros((0, 2)), np.zeros((0, 2))
        piece = segs.piece[seg]
        first = segs.ring_start[piece]
        count = segs.ring_start[piece + 1] - first
        px, py = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
        col = segs.columns

        def within(s):
            # the closest point strictly inside segment s (not at an end)
            t = ((px - col["sx"][s]) * col["dx"][s] + (py - col["sy"][s]) * col["dy"][s]) \
                * col["inv"][s]
            return (t > 0.0) & (t < 1.0)

        def tie(s):
            return within(s) & (np.abs(np.sqrt(segs.pair_distance2(px, py, s)) - dist)
                                <= self._tie)

        inside = within(seg)
        tie_prev = inside & tie(first + (seg - first - 1) % count)
        tie_next = inside & tie(first + (seg - first + 1) % count)
        tied = tie_prev != tie_next
        at_start = tie_prev[:, None]
        corner = np.where(at_start, segs.starts[seg], segs.ends[seg])
        normal = np.where(at_start, segs.vertex_normal_start[seg], segs.vertex_normal_end[seg])
        return tied, corner, normal

    def closest_wall(self, points, parallel: float = 0.999):
        """``(distance, normal)``: for every point, the distance (N,) to the one
        wall it is closest to and that wall's outward unit normal (N, 2); NaN
        where the closest boundary point is a corner, the direction to it more
        than ``acos(parallel)`` off the vertex normal, so that no single wall's
        boundary condition describes the solution between the point and the
        boundary (vertices of a finely segmented curve pass).

        A point equally close to two adjacent walls (on the bisector of their corner,
        within :data:`WALL_TIE_RTOL`: e.g. the data point at each vertex of
        ``domain="hull"``, whose ring is moved out along the bisectors) gets the
        corner itself: the distance to the vertex and the vertex normal (the
        normalised sum of the two walls' normals).  Both walls' conditions hold
        at the corner (a homogeneous Neumann condition on both makes the gradient
        vanish there, a Dirichlet one the value), so the averaged normal's
        condition holds there too; and the answer no longer depends on which of
        the two walls rounding makes the closer (the positive Laplacian rows'
        wall term, and a decomposition's d and r with it, changed by up to 10%
        when such points moved by 2e-16)."""
        p = check_points(points, allow_empty=True)
        seg = self.locator().closest_segments(p)
        dist, foot, normal, _ = self._segments.features(p, seg)
        tied, corner, corner_normal = self._tied_corners(p, dist, seg)
        foot[tied] = corner[tied]
        normal[tied] = corner_normal[tied]
        towards = foot - p
        length = np.linalg.norm(towards, axis=1)
        dist = np.where(tied, length, dist)
        on_wall = length <= self._eps
        along = (towards * normal).sum(axis=1) / np.where(on_wall, 1.0, length)
        single = on_wall | (along >= parallel)
        return np.where(single, dist, np.nan), np.where(single[:, None], normal, np.nan)

    def classify_discs(self, p: np.ndarray, radius: float, lo: float, hi: float) -> np.ndarray:
        """For discs of ``radius`` around the (N, 2) float64 points ``p``: 1 if every
        point of the disc has ``lo < signed_distance <= hi``, 0 if none has, 2 if
        undecided (only possible for radius > 0).  Whole grid cells are decided
        from the locator's cell-centre distances; the rest exactly."""
        n = len(p)
        status = np.full(n, 2, dtype=np.int8)
        if n == 0:
            return status
        loc = self.locator()
        R = loc.half_diag + radius
        if n >= cell_decisions.KERNEL_MIN_POINTS and lo < np.inf and hi > -np.inf:
            status = cell_decisions.decide_cells(p, loc, R, lo, hi)
            und = np.flatnonzero(status == 2)
        else:
            cell, ing = loc.cell_of(p)
            sdc = np.where(ing, loc.sd[np.where(ing, cell, 0)], np.nan)
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

    def locator(self, lo=None, hi=None) -> Locator:
        """The cached acceleration grid; rebuilt (widened) if it must cover ``[lo, hi]``.
        By default it covers the bounds padded by a quarter of their larger side."""
        dlo, dhi = np.array(self._lo), np.array(self._hi)
        loc = self._cache.get("loc")
        if lo is None:
            if loc is not None:
                return loc
            pad = 0.25 * float((dhi - dlo).max())
            lo, hi = dlo - pad, dhi + pad
        else:
            lo, hi = np.minimum(lo, dlo), np.maximum(hi, dhi)
            if loc is not None and loc.covers(lo, hi):
                return loc
            if loc is not None:
                lo, hi = np.minimum(lo, loc.lo), np.maximum(hi, loc.hi)
        loc = Locator(self._segments, lo, hi, 1e-9 * self._scale)
        self._cache["loc"] = loc
        return loc

    # ---- samplers (see taichi_hh.geometry.sampling) -------------------------------------
    def sample_boundary(self, spacing: float,
                        corner_angle: float = sampling.DEFAULT_CORNER_ANGLE, spacing_at=None):
        """``(points, normals, piece)``: points about ``spacing`` apart along every ring.

        Every vertex whose boundary turns by more than ``corner_angle`` degrees
        is a sample (all vertices with ``corner_angle=0``); between those, points
        are equally spaced by arc length at a spacing in (spacing/2, spacing]
        (shorter only where two such vertices are closer than ``spacing``).
        ``normals`` are outward unit normals, averaged at vertices; ``piece`` is
        the ring index (0 outer, k for ``holes[k-1]``).  ``spacing_at``: an
        optional function giving the wanted spacing at (M, 2) boundary points
        (e.g. the local spacing of data near the boundary), which the samples
        then follow; ``spacing`` is then the finest resolved."""
        return sampling.sample_boundary(self, spacing, corner_angle, spacing_at)

    def sample_ghosts(self, spacing: float, width: float, seed=0, avoid=None) -> np.ndarray:
        """(G, 2) Poisson-disk points outside the domain with ``0 < signed_distance <= width``.

        The band includes the inside of holes near their boundary.  Any two
        points are at least ``spacing`` apart and every point of the band lies
        within about ``2 * spacing`` of one (a maximal sample).  With ``avoid``
        (an (N, 2) array, e.g. the interior particles) the ghosts also keep
        ``spacing`` away from those points.  Deterministic for a given seed."""
        return sampling.sample_ghosts(self, spacing, width, seed, avoid)

    def sample_ghosts_mirror(self, points, width: float):
        """``(ghosts, source)``: mirror images of interior points near the boundary.

        Every point of ``points`` (which must lie in the domain) within
        ``width`` of the boundary is reflected across the line of its closest
        boundary segment; images that do not land strictly outside the domain
        (e.g. near concave corners, or from points on the boundary) are dropped.
        ``source`` (G,) holds the index of each image's source point.
        :class:`~taichi_hh.geometry.box.Box` reflects across every side within
        ``width`` and adds the corner images."""
        return sampling.mirror_across_segments(self, points, width)

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
        return sampling.sample_interior(self, n_or_spacing, kind, seed,
                                        jitter=jitter, margin=margin)
