"""A domain from the data themselves, for data that do not fill the domain a
user has (issue 13): the points' bounding box, their convex hull, or their
alpha shape (a concave hull that also leaves out the gaps inside the data)."""
from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

#: the names :func:`domain_from_points` knows (also accepted as ``domain=`` by
#: :func:`taichi_hh.decompose`)
DOMAINS_FROM_POINTS = ("bbox", "hull", "alpha")

#: the alpha shape's default: a Delaunay triangle stays in the domain while its
#: circumradius (the radius of the empty circle it spans) is below this many
#: local spacings; a support is 3.5 spacings, so every gap a kernel support
#: cannot bridge is left out, and no triangle inside uniformly random,
#: clustered or 1:10 graded points (their largest ratio is 1.8-2.1 at 1M points)
ALPHA = 3.0
#: the margin, in local spacings, by which a shape drawn through the outermost
#: points is moved out.  Data points on the boundary itself (the hull's and the
#: alpha shape's vertices) once cost the solves 2.5x the iterations (34/30
#: against 9/8 with a margin of 0.5 at 13k random points); since the positive
#: rows' wall term they take 10/10.  A margin of 0.5 then left data in the
#: filled notches up to about 2 spacings from the wall, and iterations grew with
#: N (1M random points in [0.05, 0.95]^2: 17/19, against 12/12 with 0.25;
#: 13k 11/11, 200k 14/13; d and r errors 1-4% higher than with 0.5;
#: docs/notes/scattered.md)
MARGIN = 0.25
#: notches of the alpha shape's boundary shallower than this many local spacings
#: are filled (the boundary zigzags between the outermost data points otherwise)
NOTCH_DEPTH = 1.0
#: the alpha shape's tolerance for degenerate geometry, relative: lattices (PIV
#: grids) are degenerate everywhere, each square's four corners on one circle
#: and each side's points on one line, and there rounding alone (moves of
#: 1e-16, or the 1.5e-6 spacings of a 1/3 spacing written with 6 decimals)
#: decided which diagonal each square got, which sliver triangles lay along the
#: rim, which rim points turned in, and with them the local spacings, the
#: margin (0.25 or 0.37 spacings), the vertices (36 or 8) and the area (+-4%).
#: Within it two triangles across an edge count as cocircular (their far
#: angles sum to pi, radians), a triangle as flat (twice its area against its
#: longest edge squared), a boundary vertex as straight (its depth below its
#: neighbours' chord, in local spacings), and a circumradius or a hole's area
#: as on its threshold (relative; such ties are decided the same way always)
DEGENERATE_TOL = 1e-4
#: a Delaunay edge longer than this many times the scale of both its ends (the
#: largest lower quartile of edge lengths around each) spans a gap (a bay, a
#: hole, the rim of the data) and is left out of the local spacing
GAP_EDGE = 3.0
# the refusal of point sets that span no area lives with the other input
# checks (every layer runs it); re-exported here, where it was first written
from ..checks import LINE_ROWS, NEEDS_AREA as _NEEDS_AREA, check_spread  # noqa: E402,F401


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull of ``points``, counter-clockwise (Andrew's
    monotone chain, O(N log N)); collinear points on an edge are left out."""
    pts = unique_points(points)
    if len(pts) < 3:
        raise InputError(f"the points are {len(pts)} distinct point(s) and span no area, so "
                         f"they have no convex hull: {_NEEDS_AREA}")

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
        raise InputError(f"the points lie on a line and span no area, so they have no convex "
                         f"hull: {_NEEDS_AREA}")
    return hull


def unique_points(points) -> np.ndarray:
    """The distinct rows of an (N, 2) array, sorted by x then y (what
    ``np.unique(points, axis=0)`` gives, in a third of its time)."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return pts.reshape(0, 2)
    ordered = pts[np.lexsort((pts[:, 1], pts[:, 0]))]
    new = np.ones(len(ordered), dtype=bool)
    new[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    return ordered[new]


def delaunay_triangles(points: np.ndarray) -> np.ndarray:
    """(T, 3) vertex indices of the Delaunay triangulation of distinct
    ``points``, counter-clockwise (:func:`delaunay_triangulation`)."""
    return delaunay_triangulation(points)[0]


def delaunay_triangulation(points: np.ndarray):
    """The Delaunay triangulation of distinct ``points``: ``(triangles, across)``,
    the (T, 3) vertex indices counter-clockwise and, for edge k (the vertices
    k, k + 1) of triangle t, the triangle across it at ``across[k * T + t]``
    (-1 on the hull).  By the sweep-hull of :mod:`~taichi_hh.geometry.delaunay`
    (a Taichi kernel: 9 ms at 13k points, 1.6 s at 1M), checked; where it fails
    (all points on a line, or floating-point trouble on degenerate input), and
    on a GPU (:func:`taichi_hh.runtime.on_gpu`: the sweep is serial, one GPU
    thread), by Qhull as matplotlib (a dependency) ships it (30 ms, 6.7 s):
    scipy is not a run-time dependency."""
    from .. import runtime
    from . import delaunay
    pts = np.asarray(points, dtype=np.float64)
    if not runtime.on_gpu():
        made = delaunay.sweep_hull(pts)
        if made is not None:
            return made
    from matplotlib.tri import Triangulation
    try:
        qhull = Triangulation(pts[:, 0], pts[:, 1])
        tri = np.asarray(qhull.triangles, dtype=np.int64)
        # neighbors[t, j]: across the edge of the vertices j, j + 1
        nbr = np.asarray(qhull.neighbors, dtype=np.int64)
    except (ValueError, RuntimeError) as exc:
        raise InputError(f"the points cannot be triangulated ({exc}): they span no area, or "
                         f"nearly none; {_NEEDS_AREA}") from None
    # Qhull orients its triangles alike, by their facets' topology: turned as
    # one, by the sign of their total area.  Turned one by one, by the sign of
    # each one's area, the flat triangles that Qhull fans a rim moved by an
    # ulp into (a lattice's) came out turned by rounding, against their
    # neighbours: a rim point's edge was then one direction's twice and
    # neither once, and its spacing, the margin and the area changed (1.1e-3
    # of the area of a 16 x 12 lattice of 0.1 x 0.05)
    a, b, c = (pts[tri[:, k]] for k in range(3))
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    if area2.sum() < 0:
        # (a, c, b): its edges (a, c), (c, b), (b, a) are the old edges 2, 1, 0
        tri, nbr = tri[:, [0, 2, 1]], nbr[:, [2, 1, 0]]
    return tri, nbr.T.ravel()


def _flat(pts: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Per triangle, whether it is flat within :data:`DEGENERATE_TOL` (twice
    its area against its longest edge squared)."""
    a, b, c = (pts[tri[:, k]] for k in range(3))
    ab, bc, ca = b - a, c - b, a - c
    area2 = np.abs(ab[:, 0] * bc[:, 1] - ab[:, 1] * bc[:, 0])
    longest2 = np.maximum.reduce([(ab ** 2).sum(axis=1), (bc ** 2).sum(axis=1),
                                  (ca ** 2).sum(axis=1)])
    return area2 <= DEGENERATE_TOL * longest2


def _circumradii(pts: np.ndarray, tri: np.ndarray) -> np.ndarray:
    a, b, c = (pts[tri[:, k]] for k in range(3))
    la = np.hypot(*(b - c).T)
    lb = np.hypot(*(c - a).T)
    lc = np.hypot(*(a - b).T)
    area2 = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                   - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    with np.errstate(divide="ignore"):
        return np.where(area2 > 0, la * lb * lc / (2.0 * np.maximum(area2, 1e-300)), np.inf)


def _firm_edges(pts: np.ndarray, tri: np.ndarray, edges: np.ndarray, across: np.ndarray):
    """``(firm, cocircular)``, two (3T,) bool arrays over the directed ``edges``
    (edge e of triangle e % T).  ``cocircular``: the two triangles across the
    edge have one circumcircle (within :data:`DEGENERATE_TOL`; a lattice
    square's diagonal: which of the two the triangulation takes is a rounding
    decision, its far angles sum to pi).  ``firm``: an edge every Delaunay
    triangulation of the points, moved by rounding, has, and that a triangle
    with area has: neither cocircular nor an edge of flat triangles only (the
    slivers that rounding lays along a row of collinear rim points, whose long
    edges span several spacings).  Both directions of an edge agree."""
    t = len(tri)
    a, b, c = (pts[tri[:, k]] for k in range(3))
    ab, bc, ca = b - a, c - b, a - c
    area2 = np.abs(ab[:, 0] * bc[:, 1] - ab[:, 1] * bc[:, 0])
    # the angle at each edge's far vertex (edge k of a triangle: vertices k, k + 1)
    angle = np.concatenate([np.arctan2(area2, -(ca * bc).sum(axis=1)),      # at c
                            np.arctan2(area2, -(ab * ca).sum(axis=1)),      # at a
                            np.arctan2(area2, -(bc * ab).sum(axis=1))])     # at b
    flat = _flat(pts, tri)
    owner = np.arange(3 * t) % t
    inner = across >= 0
    other = np.where(inner, across, 0)
    # the same edge seen from the triangle across, where the edge's end is its start
    end = edges[:, 1]
    k_other = np.where(tri[other, 0] == end, 0, np.where(tri[other, 1] == end, 1, 2))
    twin = k_other * t + other
    cocircular = inner & (np.abs(angle + angle[twin] - np.pi) <= DEGENERATE_TOL)
    with_area = ~flat[owner] | (inner & ~flat[other])
    return ~cocircular & with_area, cocircular


def _cocircular_groups(t: int, across: np.ndarray, cocircular: np.ndarray):
    """``(group, count)``: the (T,) group id (0 .. count - 1) of every triangle,
    triangles joined across ``cocircular`` edges sharing one: the Delaunay
    triangles of points on one empty circle (a lattice square's two, or a
    polygon of lattice points around a gap).  Their union is the same
    whichever way the triangulation splits it, so the alpha shape keeps or
    leaves out a group as a whole."""
    label = np.arange(t)
    e = np.flatnonzero(cocircular)
    a, b = e % t, across[e]
    while e.size:
        before = label
        label = label.copy()
        np.minimum.at(label, a, label[b])
        label = label[label]                  # a smaller id of the same group
        if np.array_equal(label, before):
            break
    # each group labelled by its smallest triangle, which labels itself
    root = label == np.arange(t)
    return (np.cumsum(root) - 1)[label], int(root.sum())


def _local_spacing(n: int, pts: np.ndarray, edges: np.ndarray, across: np.ndarray,
                   firm: np.ndarray) -> np.ndarray:
    """Per point, the median length of its firm Delaunay edges that span no
    gap, averaged with its neighbours' along those edges.  ``firm`` (from
    :func:`_firm_edges`): the edges no rounding makes or unmakes.  An edge
    spans a gap when it is longer than :data:`GAP_EDGE` times the scale of
    both its ends, a point's scale the largest lower quartile of edge lengths
    over it and its neighbours.  A point on the coast of a bay has about as
    many long edges across it as short ones into the data: with all of them
    its median read 1.4-2.5 spacings (1.15 inside), and triangles across a bay
    12 spacings wide passed a radius of 3 spacings.  A quartile, not the
    median: the coast point's own median counts the long edges.  Over the
    neighbours too: a point of a cluster's or a dense region's rim has short
    edges into it and long ones out, but its neighbours outside have long
    edges only (with the point's own quartile the largest interior ratio of
    the 1:10 gradient went from 1.58 to 2.44).  A point left without firm
    edges (none on lattices and in general position) takes all its edges."""
    once = (across < 0) | (edges[:, 0] < edges[:, 1])
    pick = edges[once & firm]
    length = np.hypot(*(pts[pick[:, 0]] - pts[pick[:, 1]]).T)
    vertex = pick.T.ravel()
    both = np.concatenate([length, length])
    # the scale of a point's neighbourhood: the largest lower quartile of its
    # edges' lengths over it and its neighbours (a sparser neighbour's: an
    # edge from a cluster or a denser region into a sparser one is no gap)
    near, median = _quantile_by(n, both, vertex, (0.25, 0.5))
    scale = near.copy()
    np.maximum.at(scale, vertex, near[np.roll(vertex, len(pick))])
    short = length <= GAP_EDGE * np.maximum(scale[pick[:, 0]], scale[pick[:, 1]])
    if not short.all():
        # the medians again, of the points that lost edges
        lost = np.zeros(n, dtype=bool)
        lost[pick[~short].ravel()] = True
        pick, length = pick[short], length[short]
        near_lost = lost[pick].any(axis=1)
        again = _quantile_by(n, np.tile(length[near_lost], 2), pick[near_lost].T.ravel())
        median[lost] = again[lost]
        vertex = pick.T.ravel()
    count = np.bincount(vertex, minlength=n)
    bare = count == 0
    if bare.any():
        every = edges[once]
        every = every[bare[every].any(axis=1)]
        owner = every.T.ravel()
        length = np.hypot(*(pts[every[:, 0]] - pts[every[:, 1]]).T)
        median[bare] = _quantile_by(n, np.concatenate([length, length]), owner)[bare]
    # averaged over the point and its neighbours: a few close pairs in
    # random data would otherwise read as a small spacing
    total = median + np.bincount(vertex, weights=median[np.roll(vertex, len(pick))], minlength=n)
    return total / (1 + count)


def _quantile_by(n: int, values: np.ndarray, owner: np.ndarray, fraction=0.5):
    """Per point, the ``fraction`` quantile (0.5: the median, the upper of two
    middle values) of the ``values`` whose ``owner`` it is; a tuple of
    fractions gives a list, one array each (one sort for all)."""
    # sorted by owner, then value: one integer key (owner, rank of the value),
    # a quarter of lexsort's time
    m = len(values)
    rank = np.empty(m, dtype=np.int64)
    rank[np.argsort(values)] = np.arange(m)
    ordered = values[np.argsort(owner.astype(np.int64) * m + rank)]
    count = np.bincount(owner, minlength=n)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    picked = [ordered[np.minimum(start + np.floor(count * f).astype(np.int64), m - 1)]
              for f in np.atleast_1d(fraction)]
    return picked if isinstance(fraction, tuple) else picked[0]


def _rings(edges: np.ndarray):
    """The closed loops of directed boundary edges (each vertex has one edge
    out), as vertex-index arrays."""
    nxt = dict(zip(edges[:, 0].tolist(), edges[:, 1].tolist()))
    rings = []
    while nxt:
        start, v = next(iter(nxt.items()))
        ring = [start]
        del nxt[start]
        while v != start:
            ring.append(v)
            v = nxt.pop(v)
        rings.append(np.array(ring))
    return rings


def _fill_notches(ring: np.ndarray, pts: np.ndarray, spacing: np.ndarray,
                  depth: float) -> np.ndarray:
    """``ring`` (vertex indices, region on the left) without its shallow
    notches: a vertex where the boundary turns right, between which and its
    neighbours at least one neighbour turns left (a zigzag, not a curve: a
    hole's rim turns right all along and stays), is dropped while every vertex
    of ``ring`` its neighbours' chord passes over lies less than ``depth``
    local spacings below it.  Passes repeat while vertices drop, but the
    depth is measured from the given ring, not from the last pass's chords:
    measured from those the filling crept into the corners of land (50k
    random points over a sea with land: 152 squared spacings of land covered
    against 53, the boundary up to 4.5 spacings from a point against 3.0).
    Dropping a vertex only adds to the region, so every point stays inside;
    along an edge of the data the boundary becomes as straight as the hull,
    whose normals the boundary rows use."""
    m = len(ring)
    at = np.arange(m)                      # the current ring's places in the given one
    p0 = pts[ring]
    limit = depth * spacing[ring]
    for _ in range(m):
        if len(at) <= 4:
            break
        p = p0[at]
        prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        cross = (p[:, 0] - prev[:, 0]) * (nxt[:, 1] - prev[:, 1]) \
            - (p[:, 1] - prev[:, 1]) * (nxt[:, 0] - prev[:, 0])
        chord = np.hypot(*(nxt - prev).T)
        below = -cross / np.maximum(chord, 1e-300)      # > 0: v is right of prev -> next
        # a straight vertex (a lattice's rim point: on its neighbours' chord but
        # for rounding) is no notch, nor part of a zigzag
        reflex = below > DEGENERATE_TOL * spacing[ring[at]]
        zigzag = ~np.roll(reflex, 1) | ~np.roll(reflex, -1)
        candidate = np.flatnonzero(reflex & zigzag & (below < limit[at]))
        if candidate.size:
            # every given vertex from the candidate's previous to its next one
            # (dropped earlier, or the candidate) against the chord that would
            # replace them
            k = len(at)
            first = at[(candidate - 1) % k] + 1
            count = (at[(candidate + 1) % k] - first) % m
            group = np.repeat(np.arange(candidate.size), count)
            offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
            under = (first[group] + offset) % m
            a_, b_ = prev[candidate][group], nxt[candidate][group]
            d = b_ - a_
            deep = -((p0[under, 0] - a_[:, 0]) * d[:, 1] - (p0[under, 1] - a_[:, 1]) * d[:, 0]) \
                / np.maximum(np.hypot(*d.T), 1e-300)
            too_deep = np.zeros(candidate.size, dtype=bool)
            np.logical_or.at(too_deep, group, deep >= limit[under])
            candidate = candidate[~too_deep]
        drop = np.zeros(len(at), dtype=bool)
        drop[candidate] = True
        drop &= ~np.roll(drop, 1)                         # no two neighbours in one pass
        if not drop.any():
            break
        at = at[~drop]
    return ring[at]


def offset_ring(ring: np.ndarray, distance) -> np.ndarray:
    """``ring`` (counter-clockwise for an outer boundary, clockwise for a hole:
    the region on the left) with every edge moved ``distance`` (a number or one
    per vertex) away from the region; the corners mitred, a mitre at most twice
    the distance long."""
    ring = np.asarray(ring, dtype=np.float64)
    edge = np.roll(ring, -1, axis=0) - ring
    normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1)       # right of each edge: outside
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    before, after = np.roll(normal, 1, axis=0), normal          # the edges into and out of a vertex
    cos = np.clip((before * after).sum(axis=1), -1.0, 1.0)
    mitre = (before + after) / np.maximum(1.0 + cos, 0.5)[:, None]
    return ring + mitre * np.broadcast_to(np.asarray(distance, dtype=np.float64),
                                          (len(ring),))[:, None]


def _moved_out(rings, distances, make):
    """``make(rings moved out by distances)``, or with half the margin, or none,
    whichever first gives a valid polygon (a margin can make a narrow gap's
    two sides cross)."""
    for scale in (1.0, 0.5, 0.0):
        try:
            return make([offset_ring(r, scale * d) for r, d in zip(rings, distances)])
        except InputError:
            if scale == 0.0:
                raise
    raise AssertionError("unreachable")


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def alpha_shape(points, alpha: float = ALPHA, margin: float = MARGIN):
    """The alpha shape of ``points`` as a :class:`Polygon` with holes: the
    union of the Delaunay triangles whose circumradius is below ``alpha``
    times the local spacing (the median over its vertices of their median
    Delaunay edge lengths),
    after Edelsbrunner, Kirkpatrick & Seidel (1983) with a spacing that follows
    the data's density.  Degenerate input (a lattice: cocircular squares,
    collinear rows) gives the same shape whichever way rounding breaks its
    ties (:data:`DEGENERATE_TOL`): the spacing leaves out the edges a
    triangulation may or may not have (cocircular diagonals, slivers along
    collinear rims), cocircular triangles are kept or left out together, and
    straight boundary vertices are no notches.  A triangle's circumcircle holds no point (the
    Delaunay property), so a large circumradius is a gap in the data: the
    shape follows concave outlines and leaves out interior gaps (as holes).

    Where the boundary would touch itself at a vertex, the smallest left-out
    triangle there is put back; holes smaller than a square of ``alpha`` local
    spacings are filled (no kernel support misses them).  Then the boundary is
    moved ``margin`` local spacings out, so that no data point lies on it.  Raises
    :class:`~taichi_hh.errors.InputError` when points lie apart from the rest
    (the shape falls into pieces: ``alpha`` too small for the data's gaps),
    naming the radius from which they form one piece.
    The Delaunay triangulation costs about 0.3 s at 200k points."""
    return _alpha_shape(points, alpha, margin, lambda a: f"alpha={a}")


def _alpha_shape(points, alpha: float, margin: float, radius_advice, to_caller=None):
    """:func:`alpha_shape`; for the messages ``radius_advice(text)``: how the
    caller sets the radius ``text`` (its syntax: ``alpha=6``,
    ``domain=('alpha', 6)``), ``to_caller``: the caller's coordinates of
    points (None: as given)."""
    where = to_caller or (lambda p: p)
    from .polygon import Polygon
    alpha = check_alpha(alpha)
    pts = unique_points(points)
    if len(pts) < 3:
        raise InputError(f"the points are {len(pts)} distinct point(s) and span no area, so "
                         f"they have no alpha shape: {_NEEDS_AREA}")
    n = len(pts)
    tri, across = delaunay_triangulation(pts)
    t = len(tri)
    # the directed edges of every triangle (edge e of triangle e % T)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    radius = _circumradii(pts, tri)
    firm, cocircular = _firm_edges(pts, tri, edges, across)
    spacing = _local_spacing(n, pts, edges, across, firm)
    # each group of cocircular triangles decided as one (for points in general
    # position a group is one triangle): its radius against the median spacing
    # of its vertices
    group, n_groups = _cocircular_groups(t, across, cocircular)
    group_radius = np.zeros(n_groups)
    np.maximum.at(group_radius, group, radius)
    # (group, vertex) pairs: a lone triangle's three vertices, a larger group's
    # distinct ones
    alone = np.bincount(group, minlength=n_groups)[group] == 1
    shared = np.unique(np.repeat(group[~alone], 3) * n + tri[~alone].ravel())
    member_group = np.concatenate([np.repeat(group[alone], 3), shared // n])
    member_vertex = np.concatenate([tri[alone].ravel(), shared % n])
    group_spacing = np.empty(n_groups)
    group_spacing[group[alone]] = np.median(spacing[tri[alone]], axis=1)
    if shared.size:
        larger = np.unique(shared // n)
        group_spacing[larger] = _quantile_by(n_groups, spacing[shared % n], shared // n)[larger]
    # a circumradius on the threshold (a lattice's triangles have radii like
    # 3 spacings exactly) is kept, however rounding leaves it
    group_kept = group_radius < alpha * group_spacing * (1.0 + DEGENERATE_TOL)
    owner = np.arange(3 * t) % t
    by_vertex = first = None            # triangles around each vertex, when a pinch needs them

    def boundary():
        keep = group_kept[group]
        return keep[owner] & ((across < 0) | ~keep[np.maximum(across, 0)])

    for _ in range(t):
        out_degree = np.bincount(edges[boundary(), 0], minlength=n)
        pinches = np.flatnonzero(out_degree > 1)
        if pinches.size == 0:
            break
        if by_vertex is None:
            by_vertex = np.argsort(tri.ravel()) // 3
            first = np.concatenate([[0], np.cumsum(np.bincount(tri.ravel(), minlength=n))])
        for v in pinches:
            around = group[by_vertex[first[v]:first[v + 1]]]
            left_out = around[~group_kept[around]]
            if left_out.size:
                # the smallest, and any as small (of one radius on a lattice:
                # which comes first is the triangulation's order)
                small = group_radius[left_out]
                group_kept[left_out[small <= small.min() * (1.0 + DEGENERATE_TOL)]] = True
    keep = group_kept[group]
    covered = np.zeros(n, dtype=bool)
    covered[tri[keep].ravel()] = True
    ratio = group_radius[group] / group_spacing[group]
    if not covered.all():
        miss = np.flatnonzero(~covered)
        first = where(pts[miss[0]])
        raise InputError(
            f"{miss.size} point(s) (first at ({first[0]:.4g}, {first[1]:.4g})) lie "
            f"apart from the rest at an alpha-shape radius of {alpha:g} local spacings: "
            f"{_larger_radius(n, edges, across, ratio, radius_advice)}")
    rings = [_fill_notches(r, pts, spacing, NOTCH_DEPTH) for r in _rings(edges[boundary()])]
    areas = np.array([_signed_area(pts[r]) for r in rings])
    if np.count_nonzero(areas > 0) > 1:
        # the second piece's vertex least in x, then y (not the ring's first:
        # that is the triangulation's order)
        ring = pts[rings[int(np.argsort(areas)[-2])]]
        piece = where(ring[np.lexsort((ring[:, 1], ring[:, 0]))[0]])
        raise InputError(
            f"the data fall into {np.count_nonzero(areas > 0)} pieces at an alpha-shape radius "
            f"of {alpha:g} local spacings (one near ({piece[0]:.4g}, {piece[1]:.4g})): "
            f"{_larger_radius(n, edges, across, ratio, radius_advice)}")
    outer = int(np.argmax(areas))
    holes = [r for k, r in enumerate(rings)
             if k != outer
             and -areas[k] >= (alpha * spacing[r].mean()) ** 2 * (1.0 - DEGENERATE_TOL)]
    chosen = [rings[outer]] + holes
    # the margin by the spacing of the triangles kept around each vertex (the
    # spacing that decided them): a rim point's own edges run across the gap
    # (each group kept around a vertex counted once, however many of its
    # triangles the vertex has)
    kept = group_kept[member_group]
    inside = _quantile_by(n, group_spacing[member_group[kept]], member_vertex[kept])
    return _moved_out([pts[r] for r in chosen], [margin * inside[r] for r in chosen],
                      lambda rs: Polygon(rs[0], rs[1:]))


def check_alpha(alpha) -> float:
    """``alpha`` (the alpha shape's radius, in local spacings) as a float, or
    :class:`~taichi_hh.errors.InputError` unless it is a finite number > 0."""
    if isinstance(alpha, (bool, np.bool_)) or not isinstance(alpha, (int, float, np.integer,
                                                                     np.floating)):
        raise InputError(f"alpha (the alpha shape's radius) must be a positive number of local "
                         f"spacings, got {alpha!r}")
    if not np.isfinite(alpha) or alpha <= 0:
        raise InputError(f"alpha (the alpha shape's radius) must be a positive number of local "
                         f"spacings, got {alpha!r}")
    return float(alpha)


def _radius_text(largest: float) -> str:
    """The least radius of two significant digits (64, 7.3, 0.45) that keeps a
    triangle whose circumradius is ``largest`` local spacings."""
    step = 10.0 ** (math.floor(math.log10(largest)) - 1)
    digits = math.ceil(largest / (1.0 + DEGENERATE_TOL) / step - 1e-9)
    while digits * step * (1.0 + DEGENERATE_TOL) <= largest:
        digits += 1
    return f"{digits * step:.10g}"


def _larger_radius(n: int, edges: np.ndarray, across: np.ndarray, ratio: np.ndarray,
                   radius_advice) -> str:
    """The remedy for an alpha shape in pieces: the radius from which the data
    form one piece, in the caller's syntax (``radius_advice``), or the hull.

    ``edges``, ``across``: the triangulation's directed edges (edge e of
    triangle e % T) and the triangle across each; ``ratio``: each triangle's
    circumradius over its spacing (its group's).  A triangle is kept while its
    ratio is below alpha (to :data:`DEGENERATE_TOL`); the kept triangles form
    one piece once they join every point (pinches are filled), so the radius
    wanted is the largest edge of the minimum spanning tree of the points,
    each Delaunay edge weighted by the least ratio of its two triangles
    (Boruvka's rounds, vectorised: 0.3 s at 200k points)."""
    t = len(ratio)
    owner = np.arange(len(edges)) % t
    one = (across < 0) | (owner < across)               # each undirected edge once
    w = ratio[owner[one]]
    inner = across[one] >= 0
    w[inner] = np.minimum(w[inner], ratio[across[one][inner]])
    order = np.argsort(w, kind="stable")                # an edge's rank: its index here
    u, v, w = edges[one, 0][order], edges[one, 1][order], w[order]
    rank = np.arange(len(w))
    comp = np.arange(n)
    largest = 0.0
    while True:
        cu, cv = comp[u[rank]], comp[v[rank]]
        cross = cu != cv
        if not cross.any():
            break
        rank, cu, cv = rank[cross], cu[cross], cv[cross]
        best = np.full(n, len(w))
        np.minimum.at(best, cu, rank)
        np.minimum.at(best, cv, rank)
        src = np.flatnonzero(best < len(w))
        e = best[src]
        a, b = comp[u[e]], comp[v[e]]
        parent = np.arange(n)
        parent[src] = np.where(a == src, b, a)
        largest = max(largest, float(w[e].max()))
        # two components that chose one edge: the lower one the root
        mutual = (parent[parent[src]] == src) & (src < parent[src])
        parent[src[mutual]] = src[mutual]
        while True:
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                break
            parent = nxt
        comp = parent[comp]
    hull = "or domain='hull' (the points' convex hull)"
    if np.unique(comp).size > 1 or not math.isfinite(largest) or largest <= 0:
        return f"give a larger radius, {hull}"
    radius = _radius_text(largest)
    return (f"they form one from a radius of {radius} on: give {radius_advice(radius)} or more, "
            f"{hull}")


def domain_spec(domain):
    """``(kind, alpha)`` when ``domain`` asks for a domain made from the points:
    None (their bounding box), ``"bbox"``, ``"hull"``, ``"alpha"`` or
    ``("alpha", A)`` (their alpha shape at a radius of ``A`` local spacings,
    :data:`ALPHA` without); None for any other domain (a Box, a Polygon, a
    box's bounds, vertices).  An unknown name is left to
    :func:`domain_from_points` to refuse; a pair other than ``("alpha", A)``
    is refused here (:class:`~taichi_hh.errors.InputError`)."""
    if domain is None:
        return "bbox", ALPHA
    if isinstance(domain, str):
        return domain, ALPHA
    if isinstance(domain, (tuple, list)) and len(domain) == 2 and isinstance(domain[0], str):
        kind, alpha = domain
        if kind in DOMAINS_FROM_POINTS and kind != "alpha":
            raise InputError(f"cannot make a domain from {domain!r}: only the alpha shape takes "
                             f"a radius, ('alpha', A); give domain={kind!r} alone")
        if kind != "alpha":
            raise InputError(f"cannot make a domain from {domain!r}: give a Box, a Polygon, "
                             f"(x0, y0, x1, y1), an (M, 2) array of vertices, one of "
                             f"{DOMAINS_FROM_POINTS} (a domain from the points), or ('alpha', A) "
                             "(the alpha shape at a radius of A local spacings)")
        return "alpha", check_alpha(alpha)
    return None


def domain_from_points(points, kind: str, alpha: float = ALPHA, *, to_caller=None):
    """The Box (``"bbox"``), convex-hull Polygon (``"hull"``, moved
    :data:`MARGIN` mean spacings out) or alpha shape (``"alpha"``,
    :func:`alpha_shape` at a radius of ``alpha`` local spacings) of
    ``points``.  Points that span no
    area (:func:`check_spread`: one point, a line, a single row) are refused
    first, whatever the kind: their bounding box, hull or alpha shape has no
    area, or one so thin that sampling its boundary at their spacing would
    never end.  The messages name the remedy as ``domain=`` of
    :func:`taichi_hh.decompose` (``domain=('alpha', 6)``: a larger radius),
    and places in the caller's coordinates, ``to_caller(points)`` (None:
    those of ``points``)."""
    from .box import Box
    from .polygon import Polygon
    if kind not in DOMAINS_FROM_POINTS:
        raise InputError(f"cannot make a domain from {kind!r}: give a Box, a Polygon, "
                         f"(x0, y0, x1, y1), an (M, 2) array of vertices, or one of "
                         f"{DOMAINS_FROM_POINTS} (a domain from the points)")
    alpha = check_alpha(alpha)
    pts = np.asarray(points, dtype=np.float64)
    check_spread(pts)
    if kind == "bbox":
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if not np.all(hi > lo):
            raise InputError(f"the points' bounding box has no area: {_NEEDS_AREA}")
        return Box(lo, hi)
    if kind == "hull":
        hull = convex_hull(pts)
        spacing = math.sqrt(_signed_area(hull) / len(pts))
        return _moved_out([hull], [MARGIN * spacing], lambda rs: Polygon(rs[0]))
    return _alpha_shape(pts, alpha, MARGIN, lambda a: f"domain=('alpha', {a})", to_caller)
