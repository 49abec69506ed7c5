"""Delaunay triangulation of points in the plane, by sweep-hull (Sinclair 2010,
as Agafonkin's Delaunator implements it): the points are taken in order of
their distance from a seed triangle's circumcentre, each joins the convex
hull of those before it through the hull edges it sees, and edges are
flipped until every pair of triangles is Delaunay.  The sweep is one serial
Taichi kernel: at 13k points it takes a few milliseconds where matplotlib's
qhull takes 31-35 (docs/notes/scattered.md, "Alpha shape").

The arithmetic is plain floating point (no exact predicates), so the result
is checked (:func:`valid_triangulation`: every point used, one orientation,
Euler's count of triangles); a caller falls back to another triangulation
when the check fails (:func:`taichi_hh.geometry.from_points.delaunay_triangles`
does, to matplotlib's).
"""

import math

import numpy as np
import taichi as ti

from .. import runtime

__all__ = ["sweep_hull", "valid_triangulation", "convex_loop"]

#: the legalisation's stack of edges still to check (Delaunator's size: only
#: extremely degenerate input reaches it, and then flips are left undone)
EDGE_STACK = 512
#: the sweep gives up (and the caller falls back) after this many edge flips a point
FLIPS_PER_POINT = 64


@ti.func
def _ccw(ax, ay, bx, by, cx, cy):
    """(b - a) x (c - a) > 0: a, b, c counter-clockwise."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax) > 0.0


@ti.func
def _in_circle(ax, ay, bx, by, cx, cy, px, py):
    """p inside the circumcircle of the clockwise triangle a, b, c."""
    dx = ax - px
    dy = ay - py
    ex = bx - px
    ey = by - py
    fx = cx - px
    fy = cy - py
    ap = dx * dx + dy * dy
    bp = ex * ex + ey * ey
    cp = fx * fx + fy * fy
    return dx * (ey * cp - bp * fy) - dy * (ex * cp - bp * fx) + ap * (ex * fy - ey * fx) < 0.0


@ti.func
def _hash_key(x, y, cx, cy, hash_size):
    dx = x - cx
    dy = y - cy
    p = 0.0
    if ti.abs(dx) + ti.abs(dy) > 0.0:       # (a point at the centre: angle 1/4)
        p = dx / (ti.abs(dx) + ti.abs(dy))
    angle = (3.0 - p) / 4.0 if dy > 0.0 else (1.0 + p) / 4.0      # monotone in the angle
    return ti.cast(ti.floor(angle * hash_size), ti.i32) % hash_size


@ti.func
def _link(halfedges: ti.template(), a, b):
    halfedges[a] = b
    if b != -1:
        halfedges[b] = a


@ti.func
def _full(triangles: ti.template(), state: ti.template()):
    """Whether another triangle would overflow the arrays (a valid sweep makes
    at most 2 N - 5): then the sweep is marked failed."""
    full = state[1] + 3 > triangles.shape[0]
    if full:
        state[2] = 1
    return full


@ti.func
def _add_triangle(triangles: ti.template(), halfedges: ti.template(), state: ti.template(),
                  i0, i1, i2, a, b, c):
    t = state[1]
    triangles[t] = i0
    triangles[t + 1] = i1
    triangles[t + 2] = i2
    _link(halfedges, t, a)
    _link(halfedges, t + 1, b)
    _link(halfedges, t + 2, c)
    state[1] = t + 3
    return t


@ti.func
def _legalize(a0_edge, xy: ti.template(), triangles: ti.template(), halfedges: ti.template(),
              hull_prev: ti.template(), hull_tri: ti.template(), stack: ti.template(),
              state: ti.template()):
    """Flip edges from ``a0_edge`` on until the triangles around them are
    Delaunay; returns the edge the new point's last triangle ends with."""
    a = a0_edge
    i = 0
    ar = 0
    while True:
        b = halfedges[a]
        t0 = a - a % 3
        ar = t0 + (a + 2) % 3
        if b == -1:                             # a hull edge: nothing to flip
            if i == 0:
                break
            i -= 1
            a = stack[i]
            continue
        b0 = b - b % 3
        al = t0 + (a + 1) % 3
        bl = b0 + (b + 2) % 3
        p0 = triangles[ar]
        pr = triangles[a]
        pl = triangles[al]
        p1 = triangles[bl]
        if state[3] <= 0:              # the flip budget is spent: give up (checked after)
            state[2] = 1
            break
        if _in_circle(xy[p0, 0], xy[p0, 1], xy[pr, 0], xy[pr, 1], xy[pl, 0], xy[pl, 1],
                      xy[p1, 0], xy[p1, 1]):
            state[3] -= 1
            triangles[a] = p1
            triangles[b] = p0
            hbl = halfedges[bl]
            if hbl == -1:       # the flipped edge is on the hull: repoint its triangle
                e = state[0]
                for _step in range(hull_prev.shape[0]):
                    if hull_tri[e] == bl:
                        hull_tri[e] = a
                        break
                    e = hull_prev[e]
                    if e == state[0]:
                        break
            _link(halfedges, a, hbl)
            _link(halfedges, b, halfedges[ar])
            _link(halfedges, ar, bl)
            br = b0 + (b + 1) % 3
            if i < EDGE_STACK:
                stack[i] = br
                i += 1
        else:
            if i == 0:
                break
            i -= 1
            a = stack[i]
    return ar


@ti.func
def _walk_hull(forward: ti.template(), start, i, x, y, n, xy: ti.template(),
               triangles: ti.template(), halfedges: ti.template(), hull_prev: ti.template(),
               hull_next: ti.template(), hull_tri: ti.template(), stack: ti.template(),
               state: ti.template()):
    """From hull vertex ``start``, forward (along ``hull_next``) or backward,
    fan new point ``i`` at (x, y) to every hull edge it sees, taking the edge's
    inner vertex off the hull; returns the vertex where the walk stopped.  A
    walk that does not stop within ``n`` edges (the hull no longer a cycle)
    or a flip budget spent on the way set ``state[2]`` (failed)."""
    v = start
    ended = 0
    for _step in range(n):
        q = hull_next[v] if ti.static(forward) else hull_prev[v]
        a, b = (v, q) if ti.static(forward) else (q, v)     # the edge, counter-clockwise
        if not _ccw(x, y, xy[a, 0], xy[a, 1], xy[b, 0], xy[b, 1]):
            ended = 1
            break
        if _full(triangles, state):
            ended = 1
            break
        if ti.static(forward):
            t = _add_triangle(triangles, halfedges, state, v, i, q, hull_tri[i], -1,
                              hull_tri[v])
            hull_tri[i] = _legalize(t + 2, xy, triangles, halfedges, hull_prev, hull_tri,
                                    stack, state)
        else:
            t = _add_triangle(triangles, halfedges, state, q, i, v, -1, hull_tri[v],
                              hull_tri[q])
            _legalize(t + 2, xy, triangles, halfedges, hull_prev, hull_tri, stack, state)
            hull_tri[q] = t
        hull_next[v] = v                # removed from the hull
        v = q
    if ended == 0:
        state[2] = 1
    return v


@ti.kernel
def _sweep(n: ti.i32, xy: ti.types.ndarray(), ids: ti.types.ndarray(), seed: ti.types.ndarray(),
           cx: ti.f64, cy: ti.f64, hash_size: ti.i32, eps: ti.f64,
           triangles: ti.types.ndarray(), halfedges: ti.types.ndarray(),
           hull_prev: ti.types.ndarray(), hull_next: ti.types.ndarray(),
           hull_tri: ti.types.ndarray(), hull_hash: ti.types.ndarray(),
           stack: ti.types.ndarray(), state: ti.types.ndarray()) -> ti.i32:
    """The sweep (serial).  ``seed``: the first triangle, clockwise; ``ids``: the
    points by distance from its circumcentre (cx, cy).  ``state``: [hull start,
    3 x triangles made, failed, flips left] (the flips' budget set by the
    caller; every walk is bounded too, so degenerate input cannot hang it).
    Returns how many points were skipped (no hull edge found from them, or
    within ``eps`` of the point before)."""
    skipped = 0
    ti.loop_config(serialize=True)
    for _ in range(1):
        i0 = seed[0]
        i1 = seed[1]
        i2 = seed[2]
        for h in range(hash_size):
            hull_hash[h] = -1
        state[0] = i0
        hull_next[i0] = i1
        hull_prev[i2] = i1
        hull_next[i1] = i2
        hull_prev[i0] = i2
        hull_next[i2] = i0
        hull_prev[i1] = i0
        hull_tri[i0] = 0
        hull_tri[i1] = 1
        hull_tri[i2] = 2
        hull_hash[_hash_key(xy[i0, 0], xy[i0, 1], cx, cy, hash_size)] = i0
        hull_hash[_hash_key(xy[i1, 0], xy[i1, 1], cx, cy, hash_size)] = i1
        hull_hash[_hash_key(xy[i2, 0], xy[i2, 1], cx, cy, hash_size)] = i2
        state[1] = 0
        _add_triangle(triangles, halfedges, state, i0, i1, i2, -1, -1, -1)
        xp = 0.0
        yp = 0.0
        for k in range(n):
            if state[2] != 0:
                break
            i = ids[k]
            x = xy[i, 0]
            y = xy[i, 1]
            near = k > 0 and ti.abs(x - xp) <= eps and ti.abs(y - yp) <= eps
            xp = x
            yp = y
            if near:
                skipped += 1
                continue
            if i == i0 or i == i1 or i == i2:
                continue
            # a visible hull edge, found through the angular hash
            start = 0
            key = _hash_key(x, y, cx, cy, hash_size)
            for j in range(hash_size):
                start = hull_hash[(key + j) % hash_size]
                if start != -1 and start != hull_next[start]:
                    break
            start = hull_prev[start]
            e = start
            ended = 0
            for _step in range(n + 1):
                q = hull_next[e]
                if _ccw(x, y, xy[e, 0], xy[e, 1], xy[q, 0], xy[q, 1]):
                    ended = 1
                    break
                e = q
                if e == start:
                    e = -1
                    ended = 1
                    break
            if ended == 0:              # the hull is no longer a cycle
                state[2] = 1
                break
            if e == -1:                 # no edge sees it: a near-duplicate
                skipped += 1
                continue
            if _full(triangles, state):
                break
            t = _add_triangle(triangles, halfedges, state, e, i, hull_next[e], -1, -1,
                              hull_tri[e])
            hull_tri[i] = _legalize(t + 2, xy, triangles, halfedges, hull_prev, hull_tri,
                                    stack, state)
            hull_tri[e] = t
            m = _walk_hull(True, hull_next[e], i, x, y, n, xy, triangles, halfedges,
                           hull_prev, hull_next, hull_tri, stack, state)
            if state[2] != 0:
                break
            if e == start:
                e = _walk_hull(False, e, i, x, y, n, xy, triangles, halfedges, hull_prev,
                               hull_next, hull_tri, stack, state)
                if state[2] != 0:
                    break
            state[0] = e
            hull_prev[i] = e
            hull_next[e] = i
            hull_prev[m] = i
            hull_next[i] = m
            hull_hash[_hash_key(x, y, cx, cy, hash_size)] = i
            hull_hash[_hash_key(xy[e, 0], xy[e, 1], cx, cy, hash_size)] = e
    return skipped


def _circumcentre(a, b, c):
    d = b - a
    e = c - a
    bl = d @ d
    cl = e @ e
    den = 2.0 * (d[0] * e[1] - d[1] * e[0])
    return a + np.array([e[1] * bl - d[1] * cl, d[0] * cl - e[0] * bl]) / den


def sweep_hull(points: np.ndarray):
    """The Delaunay triangulation of distinct ``points`` ((N, 2), N >= 3):
    ``(triangles, across)``, the (T, 3) vertex indices counter-clockwise and,
    for edge k (the vertices k, k + 1) of triangle t, the triangle across it
    at ``across[k * T + t]`` (-1 on the hull); None where the sweep cannot
    start (all points on a line), skipped a point or made an invalid
    triangulation (:func:`valid_triangulation`)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    if n < 3:
        return None
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    i0 = int(np.argmin(((pts - centre) ** 2).sum(axis=1)))
    d0 = ((pts - pts[i0]) ** 2).sum(axis=1)
    d0[i0] = np.inf
    d0[d0 == 0] = np.inf
    i1 = int(np.argmin(d0))
    if not np.isfinite(d0[i1]):
        return None
    a, b = pts[i0], pts[i1]
    d = b - a
    e = pts - a
    bl = d @ d
    cl = (e ** 2).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = 0.5 / (d[0] * e[:, 1] - d[1] * e[:, 0])
        ox = (e[:, 1] * bl - d[1] * cl) * den
        oy = (d[0] * cl - e[:, 0] * bl) * den
        radius = ox * ox + oy * oy
    radius[[i0, i1]] = np.inf
    radius[~np.isfinite(radius)] = np.inf
    i2 = int(np.argmin(radius))
    if not np.isfinite(radius[i2]):
        return None                     # collinear
    c = pts[i2]
    if (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) > 0:
        i1, i2 = i2, i1                 # the sweep's triangles are clockwise
    cc = _circumcentre(pts[i0], pts[i1], pts[i2])
    ids = np.argsort(((pts - cc) ** 2).sum(axis=1), kind="stable").astype(np.int32)
    max_t = max(2 * n - 5, 1)
    hash_size = max(int(math.ceil(math.sqrt(n))), 1)

    def arr(dtype, size):
        return runtime.array(dtype, size, zeroed=False)

    xy = runtime.array(ti.f64, (n, 2), zeroed=False)
    xy.from_numpy(pts)
    ids_nd = arr(ti.i32, n)
    ids_nd.from_numpy(ids)
    seed = arr(ti.i32, 3)
    seed.from_numpy(np.array([i0, i1, i2], dtype=np.int32))
    triangles, halfedges = arr(ti.i32, 3 * max_t), arr(ti.i32, 3 * max_t)
    hull_prev, hull_next, hull_tri = arr(ti.i32, n), arr(ti.i32, n), arr(ti.i32, n)
    hull_hash, stack, state = arr(ti.i32, hash_size), arr(ti.i32, EDGE_STACK), arr(ti.i32, 4)
    # a sweep flips a few edges a point (about 2 on random points): far more
    # means the predicates are going round in circles
    state.from_numpy(np.array([0, 0, 0, min(FLIPS_PER_POINT * n, 2**31 - 1)], dtype=np.int32))
    skipped = _sweep(n, xy, ids_nd, seed, float(cc[0]), float(cc[1]), hash_size,
                     float(np.finfo(np.float64).eps), triangles, halfedges, hull_prev,
                     hull_next, hull_tri, hull_hash, stack, state)
    _, count, failed, _ = (int(v) for v in state.to_numpy())
    if skipped or failed:
        return None
    tri = triangles.to_numpy()[:count].reshape(-1, 3).astype(np.int64)
    half = halfedges.to_numpy()[:count].reshape(-1, 3).astype(np.int64)
    hull = int(np.count_nonzero(half == -1))
    # counter-clockwise (w0, w1, w2) = (v0, v2, v1): its edges (w0, w1), (w1, w2),
    # (w2, w0) are the sweep's halfedges 2, 1, 0 of the triangle, reversed
    tri = tri[:, [0, 2, 1]]
    twin = half[:, [2, 1, 0]]
    on_hull = twin == -1
    boundary = np.stack([tri[on_hull], tri[:, [1, 2, 0]][on_hull]], axis=1)
    if not valid_triangulation(pts, tri, hull, boundary):
        return None
    across = np.where(twin >= 0, twin // 3, -1).T.ravel()
    return tri, across


def valid_triangulation(points: np.ndarray, tri: np.ndarray, hull: int, boundary=None) -> bool:
    """Whether ``tri`` with ``hull`` edges on the convex hull is a triangulation
    of all of ``points``: every point a vertex, every triangle counter-clockwise
    with positive area, and Euler's count of triangles, 2 N - 2 - hull (a fold
    or an overlap, which floating-point predicates can make on degenerate
    input, breaks one of them).  ``boundary``: optionally the (H, 2) directed
    hull edges (interior on their left), which must then go once around a
    convex loop (:func:`convex_loop`): on an L-shaped lattice, whose hull edges
    run through collinear points, the sweep once folded its hull in two and
    kept Euler's count."""
    n = len(points)
    if len(tri) == 0 or np.bincount(tri.ravel(), minlength=n).min() == 0:
        return False
    a, b, c = (points[tri[:, k]] for k in range(3))
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    if not (bool(np.all(cross > 0)) and len(tri) == 2 * n - 2 - hull):
        return False
    return boundary is None or convex_loop(points, np.asarray(boundary))


#: a hull vertex may turn right by this much (radians: rounding on nearly
#: collinear hull points), and the hull's turns must add up to 2 pi within
#: HULL_TURN_TOL * 1e3
HULL_TURN_TOL = 1e-9


def convex_loop(points: np.ndarray, edges: np.ndarray) -> bool:
    """Whether the directed ``edges`` ((H, 2) vertex indices) form one loop
    that turns left or goes straight at every vertex (to within
    :data:`HULL_TURN_TOL`) and goes once around: a convex polygon, which
    positively oriented triangles bounded by it cover exactly once (a folded
    hull turns twice around, or right somewhere)."""
    n = len(points)
    if len(edges) < 3 or np.bincount(edges[:, 0], minlength=n).max() > 1:
        return False
    out = np.full(n, -1)
    out[edges[:, 0]] = np.arange(len(edges))
    nxt = out[edges[:, 1]]
    if (nxt < 0).any():
        return False
    d = points[edges[:, 1]] - points[edges[:, 0]]
    e = d[nxt]
    turn = np.arctan2(d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0], (d * e).sum(axis=1))
    return bool(turn.min() >= -HULL_TURN_TOL
                and abs(turn.sum() - 2.0 * math.pi) <= 1e3 * HULL_TURN_TOL)
