"""Moving least squares on a cell grid: the natural decomposition's fits of
scattered data (:mod:`.natural`).  The points are binned by the grid's
cells once (:class:`PointBins`, a stable counting sort); each target then
gathers the points of the cells within its fit's radius, growing the radius
where too few points answer (the boundary, sparse data).  Quadratic fits
reconstruct values at the nodes (:mod:`.mls_reconstruct`); fits of
degree 1-3 give gradients (:func:`fit_gradients`, div v and curl v at the
nodes), or their weights (:class:`FitWeights`).
"""
import numpy as np
import taichi as ti

from .. import runtime
from ..sph.cell_sort import cells_of, counting_sort
from .free_space import Grid

@ti.func
def cholesky_factor(M, n: ti.template(), dt: ti.template(), floor: ti.template()):
    """``(L, pivot)``: the Cholesky factor L L^T = M of the symmetric positive
    n x n ``M`` in precision ``dt`` (the diagonal raised by 1e-12 of the
    trace and ``floor``), and its smallest pivot relative to its diagonal
    entry, min_j L[j, j]^2 / M[j, j]: the squared sine of the angle between
    column j and the columns before it (1 for orthogonal columns, near 0
    where a column is nearly a combination of the earlier ones)."""
    tr = ti.cast(0.0, dt)
    for a in ti.static(range(n)):
        tr += M[a, a]
    for a in ti.static(range(n)):
        M[a, a] += 1e-12 * tr + floor
    L = ti.Matrix.zero(dt, n, n)
    pivot = ti.cast(1.0, dt)
    for jj in ti.static(range(n)):
        s = M[jj, jj]
        for kk in ti.static(range(jj)):
            s -= L[jj, kk] * L[jj, kk]
        L[jj, jj] = ti.sqrt(ti.max(s, 1e-30))
        pivot = ti.min(pivot, s / M[jj, jj])
        for ii in ti.static(range(jj + 1, n)):
            s2 = M[ii, jj]
            for kk in ti.static(range(jj)):
                s2 -= L[ii, kk] * L[jj, kk]
            L[ii, jj] = s2 / L[jj, jj]
    return L, pivot


@ti.func
def cholesky_substitute(L, rhs, n: ti.template(), dt: ti.template()):
    """x with L L^T x = rhs (n x 2), L from :func:`cholesky_factor`."""
    y = ti.Matrix.zero(dt, n, 2)
    for ii in ti.static(range(n)):
        r0 = rhs[ii, 0]
        r1 = rhs[ii, 1]
        for kk in ti.static(range(ii)):
            r0 -= L[ii, kk] * y[kk, 0]
            r1 -= L[ii, kk] * y[kk, 1]
        y[ii, 0] = r0 / L[ii, ii]
        y[ii, 1] = r1 / L[ii, ii]
    x = ti.Matrix.zero(dt, n, 2)
    for q in ti.static(range(n)):
        ii = ti.static(n - 1 - q)
        r0 = y[ii, 0]
        r1 = y[ii, 1]
        for kk in ti.static(range(ii + 1, n)):
            r0 -= L[kk, ii] * x[kk, 0]
            r1 -= L[kk, ii] * x[kk, 1]
        x[ii, 0] = r0 / L[ii, ii]
        x[ii, 1] = r1 / L[ii, ii]
    return x


@ti.func
def cholesky_solve(M, rhs, n: ti.template(), dt: ti.template(), floor: ti.template()):
    """x with M x = rhs for the symmetric positive n x n ``M`` and n x 2 ``rhs``
    in precision ``dt`` (Cholesky, the diagonal raised by 1e-12 of the trace
    and ``floor``)."""
    L, _ = cholesky_factor(M, n, dt, floor)
    return cholesky_substitute(L, rhs, n, dt)


class PointBins:
    """Points sorted by the grid's cells (a counting sort, stable):
    ``order`` (sorted -> input index), ``start`` (nx * ny + 1 offsets into the
    sorted points), ``points`` sorted."""

    def __init__(self, grid: "Grid", points):
        runtime.ensure_init()
        pts = np.ascontiguousarray(points, dtype=np.float64)
        lower = grid.origin - 0.5 * np.array([grid.hx, grid.hy])
        cell = cells_of(pts, lower, grid.hx, grid.hy, grid.nx, grid.ny)
        order, self.start = counting_sort(cell, grid.nx * grid.ny)
        self.order = order.astype(np.int64)
        self.points = np.take(pts, self.order, axis=0)      # 10x fancy indexing's speed
        self._kernel_arrays = None

    def __getstate__(self):
        # the device copies stay behind (Taichi's arrays do not pickle; made again)
        return {**self.__dict__, "_kernel_arrays": None}

    def kernel_arrays(self) -> tuple:
        """``(start, points, order)`` as the fit and gather kernels take them,
        on the device where :func:`taichi_hh.runtime.resident` (copied once,
        for every launch of the points' fits and interpolations; numpy
        arrays otherwise)."""
        kept = self._kernel_arrays
        key = (runtime.generation(), runtime.resident())
        if kept is None or kept[0] != key:
            kept = self._kernel_arrays = (key, runtime.to_device(self.start, np.int32),
                                          runtime.to_device(self.points),
                                          runtime.to_device(self.order, np.int64))
        return kept[1:]


# --------------------------------------------------------------------------- v fitted at nodes
#: the polynomial degree of the moving-least-squares fit of v at the grid
#: nodes whose gradient gives div v and curl v there
#: (:func:`natural_decomposition`): cubic, its gradient third order (a
#: quadratic's errs 4-8x more: windows at 15k random points d 0.039% against
#: 0.011%)
FIT_DEGREE = 3
#: the fit's radius in local spacings (:func:`~.cell_counts.spacing_edge_volume`; cells on
#: uniform data): the first of these that holds FIT_MIN_POINTS data points
#: (about 38 inside at 3.5; more radius near the boundary and corners).  3.5 cells: the noise of PIV-like data (2% noise: d 1.37%
#: at 3 cells, 1.27% at 3.5, 1.16% at 4.5) against the bias on smooth data
#: (15k random: d 0.008%, 0.011%, 0.019%) and the cost (pairs ~ radius^2)
FIT_RADII = (3.5, 4.5, 6.0)
FIT_MIN_POINTS = 22
#: the degree at most of a fit whose radius grew beyond the first (a node at
#: the boundary, sparse data): a one-sided cubic amplifies noise (pivpy's
#: cavity: energy ratio 1.36 with cubic, 1.10 with quadratic; 1.17 with the
#: SPH operator before)
EDGE_DEGREE = 2
#: the smallest relative Cholesky pivot (:func:`cholesky_factor`) of a fit's
#: normal equations taken as well posed; below it the fit drops to the next
#: lower degree.  Points nearly on fewer curves than the degree needs (three
#: rows of a lattice bent by a map, next to a straight land edge: a one-sided
#: cubic) give pivots of 1e-9-1e-6 and gradients off by 1e-2 of their size;
#: scattered points' fits stay above 3e-4, a straight lattice's above 3.6e-3
#: (issue 33, docs/notes/lonlat.md "The fits' conditioning guard")
FIT_MIN_PIVOT = 1e-5


def _monomials(p: int) -> list:
    """(a, b) of the monomials x^a y^b of degree <= p: 1, x, y, x^2, xy, y^2, ..."""
    return [(a, s - a) for s in range(p + 1) for a in range(s, -1, -1)]


_MONO = {p: _monomials(p) for p in (1, 2, 3)}
_MOMENTS = {p: _monomials(2 * p) for p in (1, 2, 3)}
#: the normal matrix's entry (i, j) is the moment of monomial i times monomial j
_GRAM = {p: [[_MOMENTS[p].index((a + c, b + d)) for (c, d) in _MONO[p]] for (a, b) in _MONO[p]]
         for p in (1, 2, 3)}
_RHS = {p: [_MOMENTS[p].index(m) for m in _MONO[p]] for p in (1, 2, 3)}


@ti.func
def _fit_powers(pos: ti.template(), k, X, inv, n: ti.template()):
    """``(near, px, py)``: whether point k lies within the fit's radius of X
    (``inv`` = 1 / radius), its Wendland weight w times the powers of its
    offset's x over the radius (px[e] = w dx^e) and the powers of its y
    (py[e] = dy^e), e = 0 .. n (a monomial's weighted value: px[a] py[b])."""
    dx = (pos[2 * k] - X[0]) * inv
    dy = (pos[2 * k + 1] - X[1]) * inv
    q2 = dx * dx + dy * dy
    w = 0.0
    if q2 < 1.0:
        q = ti.sqrt(q2)
        w = (1.0 - q) ** 4 * (1.0 + 4.0 * q)
    px = ti.Vector.zero(ti.f64, n + 1)
    py = ti.Vector.zero(ti.f64, n + 1)
    px[0] = w
    py[0] = 1.0
    for e in ti.static(range(1, n + 1)):
        px[e] = px[e - 1] * dx
        py[e] = py[e - 1] * dy
    return q2 < 1.0, px, py


@ti.kernel
def _fit_gradients(targets: ti.types.ndarray(), nx: ti.i32, ny: ti.i32, lx: ti.f64,
                   ly: ti.f64, hx: ti.f64, hy: ti.f64, start: ti.types.ndarray(),
                   pos: ti.types.ndarray(), vals: ti.types.ndarray(), stride: ti.i32,
                   col0: ti.i32, p: ti.template(),
                   radii: ti.types.vector(3, ti.f64), min_points: ti.i32, edge_degree: ti.i32,
                   min_pivot: ti.f64,
                   scale: ti.types.ndarray(), edge: ti.types.ndarray(),
                   grads: ti.types.ndarray(), counts: ti.types.ndarray(), emit: ti.template(),
                   count_only: ti.template(),
                   wstart: ti.types.ndarray(),
                   widx: ti.types.ndarray(), wval: ti.types.ndarray(),
                   wref: ti.types.ndarray()):
    """The gradients of the two columns ``col0``, ``col0 + 1`` of ``vals`` (the
    points' rows of ``stride`` values, flat; ``pos`` their coordinates, flat)
    at each target (T, 2) from
    their weighted least-squares polynomial of degree ``p`` over the points
    (sorted by cell, ``start`` the offsets; ``lx``, ``ly`` the grid's lower
    corner) within the first of ``radii`` (times the target's ``scale``)
    holding ``min_points``: ``grads`` (T, stride, 2, flat) rows t, columns
    col0 and col0 + 1 the two gradients, ``counts[t]`` the points in the
    fit; a radius beyond the first at a target flagged ``edge``: at
    most ``edge_degree``; fewer points than a degree's monomials and two,
    or normal equations whose smallest relative pivot is below ``min_pivot``
    (nearly singular: :data:`FIT_MIN_PIVOT`): the next lower degree.  One gather per
    target; the normal equations from the weighted moments of the offsets (a
    monomial pair's entry is one moment), solved by Cholesky.  With ``emit``
    also each point's weights in the target's gradient, written to the slots
    ``wstart[t]`` on (the counts of a pass without: :class:`FitWeights`):
    ``widx`` the point, ``wval`` its weights in d/dx and d/dy (the rows of
    the inverse normal matrix times the point's weighted monomials), and
    ``wref[t]`` the point whose value the fit subtracts first.  With
    ``count_only`` the points in each fit alone (the radius depends on the
    counts alone), ``grads`` not written: the slots' pass of :class:`FitWeights`."""
    NB = ti.static(len(_MONO[p]))
    NM = ti.static(len(_MOMENTS[p]))
    for t in range(targets.shape[0]):
        h = scale[t]
        X = ti.Vector([targets[t, 0], targets[t, 1]])
        ci = ti.cast(ti.math.clamp(ti.floor((X[0] - lx) / hx), 0.0, nx - 1.0), ti.i32)
        cj = ti.cast(ti.math.clamp(ti.floor((X[1] - ly) / hy), 0.0, ny - 1.0), ti.i32)
        # the target's offset within its cell: the cells reached are those
        # with a part closer than R
        fx = (X[0] - lx) / hx - ci
        fy = (X[1] - ly) / hy - cj
        # the values less those of a point at or after the target's cell in
        # the sorted order: the same gradients, smaller rounding (the
        # constant need not cancel in the normal equations)
        kref = ti.min(start[ci * ny + cj], pos.shape[0] // 2 - 1)
        ref0 = vals[kref * stride + col0]
        ref1 = vals[kref * stride + col0 + 1]
        mom = ti.Vector.zero(ti.f64, NM)
        r0 = ti.Vector.zero(ti.f64, NB)
        r1 = ti.Vector.zero(ti.f64, NB)
        done = False
        count = 0
        R = ti.cast(1.0, ti.f64)
        a = 0
        i0, i1, j0, j1 = 0, -1, 0, -1
        while not done:           # one copy of the loop for every radius
            R = radii[a] * h
            i0 = ti.max(ci - ti.cast(ti.ceil(R / hx - fx), ti.i32), 0)
            i1 = ti.min(ci + ti.cast(ti.ceil(R / hx - (1.0 - fx)), ti.i32), nx - 1)
            j0 = ti.max(cj - ti.cast(ti.ceil(R / hy - fy), ti.i32), 0)
            j1 = ti.min(cj + ti.cast(ti.ceil(R / hy - (1.0 - fy)), ti.i32), ny - 1)
            mom = ti.Vector.zero(ti.f64, NM)
            r0 = ti.Vector.zero(ti.f64, NB)
            r1 = ti.Vector.zero(ti.f64, NB)
            count = 0
            inv = 1.0 / R
            for i in range(i0, i1 + 1):
                row = i * ny
                for k in range(start[row + j0], start[row + j1 + 1]):
                    if ti.static(count_only):
                        near, _, _ = _fit_powers(pos, k, X, inv, 0)
                        if near:
                            count += 1
                    else:
                        near, px, py = _fit_powers(pos, k, X, inv, 2 * p)
                        if near:
                            count += 1
                            inc = ti.Vector.zero(ti.f64, NM)
                            for m in ti.static(range(NM)):
                                inc[m] = px[ti.static(_MOMENTS[p][m][0])] \
                                    * py[ti.static(_MOMENTS[p][m][1])]
                            mom += inc
                            v0 = vals[k * stride + col0] - ref0
                            v1 = vals[k * stride + col0 + 1] - ref1
                            for m in ti.static(range(NB)):
                                r0[m] += inc[ti.static(_RHS[p][m])] * v0
                                r1[m] += inc[ti.static(_RHS[p][m])] * v1
            done = count >= min_points or a == 2
            a += 1
        # a radius beyond the first next to the boundary: at most edge_degree
        top = p if (a == 1 or edge[t] == 0) else ti.min(p, edge_degree)
        # the degree p fit, or a lower one where the points are too few for it
        # (the monomials are ordered by degree: a lower degree's normal
        # equations are the leading block)
        g = ti.Vector.zero(ti.f64, 4)
        solved = False
        for q in ti.static(range(p, 0, -1) if not count_only else ()):
            nq = ti.static(len(_MONO[q]))
            if not solved and ((q <= top and count >= nq + 2) or q == 1):
                M = ti.Matrix.zero(ti.f64, nq, nq)
                rhs = ti.Matrix.zero(ti.f64, nq, 2)
                for m in ti.static(range(nq)):
                    rhs[m, 0] = r0[m]
                    rhs[m, 1] = r1[m]
                    for l in ti.static(range(nq)):
                        M[m, l] = mom[ti.static(_GRAM[p][m][l])]
                L, pivot = cholesky_factor(M, nq, ti.f64, 1e-30)
                # a nearly singular fit (the points nearly on fewer curves
                # than the degree needs): the next lower degree
                if pivot >= min_pivot or q == 1:
                    x = cholesky_substitute(L, rhs, nq, ti.f64)
                    g = ti.Vector([x[1, 0], x[2, 0], x[1, 1], x[2, 1]]) / R
                    solved = True
                    if ti.static(emit):
                        # the rows 1 and 2 of M^-1 (M symmetric: its columns)
                        unit = ti.Matrix.zero(ti.f64, nq, 2)
                        unit[1, 0] = 1.0
                        unit[2, 1] = 1.0
                        rows = cholesky_substitute(L, unit, nq, ti.f64)
                        slot = wstart[t]
                        wref[t] = kref
                        inv = 1.0 / R
                        for i in range(i0, i1 + 1):
                            row = i * ny
                            for k in range(start[row + j0], start[row + j1 + 1]):
                                near, px, py = _fit_powers(pos, k, X, inv, q)
                                if near:
                                    gx = 0.0
                                    gy = 0.0
                                    for m in ti.static(range(nq)):
                                        b = px[ti.static(_MONO[q][m][0])] \
                                            * py[ti.static(_MONO[q][m][1])]
                                        gx += rows[m, 0] * b
                                        gy += rows[m, 1] * b
                                    widx[slot] = k
                                    wval[slot, 0] = gx * inv
                                    wval[slot, 1] = gy * inv
                                    slot += 1
        if ti.static(not count_only):
            o = (t * stride + col0) * 2
            for c in ti.static(range(4)):
                grads[o + c] = g[c]
        counts[t] = count


def fit_gradients(grid: Grid, binned: "PointBins", values, targets, degree: int | None = None,
                  radii=None, min_points: int | None = None, *, counts: bool = False,
                  edge_degree: int | None = None, scale=None, edge=None, new=None):
    """(T, m, 2) the gradients of the columns of ``values`` (N, m, m even, in
    the order of ``binned.points``; a numpy array or a
    :class:`~taichi_hh.runtime.Device`) at ``targets`` (T, 2): out[t, c] =
    grad of column c, from the moving-least-squares polynomial of ``degree``
    (a Taichi kernel, :func:`_fit_gradients`, a launch per two columns;
    None: :data:`FIT_DEGREE`, :data:`FIT_RADII`, :data:`FIT_MIN_POINTS`,
    :data:`EDGE_DEGREE`); the radii in units of ``scale`` (T,) (None: the
    grid's cell) and ``edge`` (T,) the targets next to the boundary (None:
    all); with ``counts`` also (T,) the points in each fit.  ``new``: where
    the answers' arrays come from (``new(shape)``, e.g.
    :func:`taichi_hh.runtime.work`; None: new numpy arrays)."""
    runtime.ensure_init()
    tg = np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 2)
    if not isinstance(values, runtime.Device):
        values = np.asarray(values, dtype=np.float64)
    m = 1 if len(values.shape) == 1 else int(np.prod(values.shape[1:]))
    if m % 2:
        raise ValueError(f"the fits take pairs of columns, got {m}")
    if not (len(tg) and len(binned.points) and m):
        grads, count = np.zeros((len(tg), m, 2)), np.zeros(len(tg))
    else:
        new = new or np.empty
        grads, count = new((len(tg), m, 2)), new((len(tg),))
        head, tail = _fit_arguments(grid, binned, tg, degree, radii, min_points, edge_degree,
                                    scale, edge)
        vals = runtime.flat(values)
        for c in range(0, m, 2):
            _fit_gradients(*head, vals, m, c, *tail, runtime.flat(grads), runtime.flat(count),
                           False, False, _NO_SLOTS, _NO_INDEX, _NO_WEIGHTS, _NO_INDEX)
    return (grads, count) if counts else grads


def _fit_arguments(grid: Grid, binned: "PointBins", tg, degree=None, radii=None,
                   min_points=None, edge_degree=None, scale=None, edge=None) -> tuple:
    """:func:`_fit_gradients`' arguments before the values (``head``) and
    after their columns (``tail``), the defaults of :func:`fit_gradients`
    for the None ones."""
    lower = grid.origin - 0.5 * np.array([grid.hx, grid.hy])
    start, points, _ = binned.kernel_arrays()
    head = (tg, grid.nx, grid.ny, float(lower[0]), float(lower[1]), grid.hx, grid.hy,
            runtime.flat(start, np.int32), runtime.flat(points))
    tail = (int(FIT_DEGREE if degree is None else degree),
            ti.Vector([float(r) for r in (FIT_RADII if radii is None else radii)], dt=ti.f64),
            int(FIT_MIN_POINTS if min_points is None else min_points),
            int(EDGE_DEGREE if edge_degree is None else edge_degree), float(FIT_MIN_PIVOT),
            np.ascontiguousarray(np.broadcast_to(max(grid.hx, grid.hy) if scale is None
                                                 else scale, len(tg)), dtype=np.float64),
            np.ascontiguousarray(np.broadcast_to(True if edge is None else edge, len(tg)),
                                 dtype=np.int32))
    return head, tail


_NO_SLOTS = np.zeros(1, dtype=np.int32)
_NO_INDEX = np.zeros(1, dtype=np.int32)
_NO_WEIGHTS = np.zeros((1, 2))


#: the widest column block :func:`_apply_weights` sums at once, and the
#: columns one launch takes at most (more go through in launches of this many)
APPLY_WIDTH = 8
APPLY_COLUMNS = 16


def gather_stride(m: int) -> int:
    """The row length a gather of ``m`` columns reads its values in: ``m``
    up to 2, else ``m`` rounded up to a multiple of 4 (at most
    APPLY_COLUMNS).  A compile-time row length lets LLVM load a slot's
    columns as vectors; with the row length a runtime value (a 2-d ndarray's
    shape) the gather ran 3x slower, and a row of 6 or 12 doubles (rows
    straddling cache lines) 2-3x slower than the same columns in rows of 8
    or 16 (docs/notes/series.md)."""
    return m if m <= 2 else min(APPLY_COLUMNS, 4 * -(-m // 4))


def _column_blocks(stride: int) -> tuple:
    """(first column, width) of the blocks a row of ``stride`` values is
    summed in: APPLY_WIDTH wide, then 4."""
    blocks, c = [], 0
    for width in (APPLY_WIDTH, 4, 2, 1):
        while stride - c >= width:
            blocks.append((c, width))
            c += width
    return tuple(blocks)


@ti.kernel
def _apply_weights(wstart: ti.types.ndarray(), widx: ti.types.ndarray(),
                   wval: ti.types.ndarray(), wref: ti.types.ndarray(),
                   values: ti.types.ndarray(), out: ti.types.ndarray(), stride: ti.template(),
                   m: ti.i32, div_curl: ti.template()):
    """out[(t m + c) 2 + j] = the sum over target t's slots of the weights
    ``wval[2 s + j]`` times column c of ``values`` (rows of ``stride``,
    flat) less its value at the fit's reference point (as the fit subtracts
    it: the same rounding), for the first ``m`` columns: one gather per
    target, a slot's index and weights read once for a block's columns
    (adjacent in a row), each column summed in slot order (the loop's step
    written so that the vectorizer cannot split the sum).  With
    ``div_curl`` the columns are fields' components in pairs (2 f, 2 f + 1)
    and out[(t m / 2 + f) 2 + 0|1] = |div|, |curl| of field f from those
    gradients (:meth:`FitWeights.gradients`)."""
    for t in range(wstart.shape[0] - 1):
        for c0, width in ti.static(_column_blocks(stride)):
            gx = ti.Vector.zero(ti.f64, width)
            gy = ti.Vector.zero(ti.f64, width)
            ref = ti.Vector.zero(ti.f64, width)
            kref = wref[t] * stride + c0
            for w in ti.static(range(width)):
                ref[w] = values[kref + w]
            s = wstart[t]
            end = wstart[t + 1]
            while s < end:
                k = widx[s]
                row = k * stride + c0
                ax = wval[2 * s]
                ay = wval[2 * s + 1]
                for w in ti.static(range(width)):
                    v = values[row + w] - ref[w]
                    gx[w] += ax * v
                    gy[w] += ay * v
                # k >= 0: a step of 1 that the loop vectorizer cannot count
                s += 1 + (k >> 31)
            o = (t * m + c0) * 2
            if ti.static(div_curl):
                # a block's columns start even: its pairs are whole
                for w in ti.static(range(0, width - 1, 2)):
                    if c0 + w < m:
                        q = t * m + c0 + w          # (t m / 2 + f) 2
                        out[q] = ti.abs(gx[w] + gy[w + 1])
                        out[q + 1] = ti.abs(gx[w + 1] - gy[w])
            else:
                for w in ti.static(range(width)):
                    if c0 + w < m:
                        out[o + 2 * w] = gx[w]
                        out[o + 2 * w + 1] = gy[w]


def abs_div_curl(gradients) -> np.ndarray:
    """(T, k, 2) |div| and |curl| of k fields from the gradients (T, 2 k, 2)
    of their components (columns 2 f, 2 f + 1 the x and y components of
    field f): div = dx/dx + dy/dy, curl = dy/dx - dx/dy."""
    g = np.asarray(gradients).reshape(len(gradients), -1, 2, 2)
    out = np.empty(g.shape[:2] + (2,))
    np.abs(g[:, :, 0, 0] + g[:, :, 1, 1], out=out[..., 0])
    np.abs(g[:, :, 1, 0] - g[:, :, 0, 1], out=out[..., 1])
    return out


class FitWeights:
    """The fits of :func:`fit_gradients` at fixed targets as weights: each
    target's gradient a weighted sum of the values of the points in its fit
    (a sparse matrix in slots, built by the fit kernel itself).  Built once
    for points that carry many fields (a series of snapshots): each field's
    gradients are then one gather (:meth:`gradients`), the same as
    :func:`fit_gradients` to rounding, in any number of columns.
    ``counts`` (T,): the points in each fit."""

    def __init__(self, grid: Grid, binned: "PointBins", targets, *, scale=None, edge=None):
        runtime.ensure_init()
        tg = np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 2)
        zero = np.zeros((len(binned.points), 2))
        self.counts = np.zeros(len(tg))
        self.start = np.zeros(len(tg) + 1, dtype=np.int32)
        self.index = np.zeros(1, dtype=np.int32)
        self.weights = np.zeros((1, 2))
        self.reference = np.zeros(max(len(tg), 1), dtype=np.int32)
        self.n_targets = len(tg)
        if not (len(tg) and len(binned.points)):
            return
        head, tail = _fit_arguments(grid, binned, tg, scale=scale, edge=edge)
        head, tail = head + (zero.reshape(-1), 2, 0), tail
        grads = np.zeros(len(tg) * 4)
        # the first pass counts each fit's points (the slots: the radii's
        # search alone), the second writes their weights
        _fit_gradients(*head, *tail, grads, self.counts, False, True, _NO_SLOTS, _NO_INDEX,
                       _NO_WEIGHTS, _NO_INDEX)
        # 32-bit slots (the kernels' loop bounds): the weights stay far below
        # 2^31 of them (natural.FIT_WEIGHTS_BYTES)
        self.start[1:] = np.cumsum(self.counts.astype(np.int64))
        n = int(self.start[-1])
        self.index = np.zeros(max(n, 1), dtype=np.int32)
        self.weights = np.zeros((max(n, 1), 2))
        _fit_gradients(*head, *tail, grads, self.counts, True, False, self.start, self.index,
                       self.weights, self.reference)

    @classmethod
    def of_slots(cls, start, index, weights, reference) -> "FitWeights":
        """Gradient weights made elsewhere, in the same slots: ``start``
        (T + 1,) int32, ``index`` (S,) int32 and ``weights`` (S, 2) per slot,
        ``reference`` (T,) the value each target's gather subtracts (e.g.
        :func:`~.grid_sampling.one_sided_weights`)."""
        self = cls.__new__(cls)
        self.start = np.ascontiguousarray(start, dtype=np.int32)
        self.n_targets = len(self.start) - 1
        self.counts = np.diff(self.start).astype(np.float64)
        n = max(int(self.start[-1]), 1)
        self.index = np.zeros(n, dtype=np.int32)
        self.index[:len(index)] = index
        self.weights = np.zeros((n, 2))
        self.weights[:len(weights)] = weights
        self.reference = np.zeros(max(self.n_targets, 1), dtype=np.int32)
        self.reference[:self.n_targets] = reference
        return self

    def rows(self, rows) -> "FitWeights":
        """The weights of the targets ``rows`` (indices, increasing) alone:
        the same slots (a fit depends on its target alone, so a subset of
        targets fitted again would give these weights bit for bit)."""
        rows = np.asarray(rows, dtype=np.int64)
        if len(rows) == self.n_targets and np.array_equal(rows, np.arange(self.n_targets)):
            return self
        first, count = self.start[rows].astype(np.int64), np.diff(self.start)[rows]
        start = np.zeros(len(rows) + 1, dtype=np.int64)
        np.cumsum(count, out=start[1:])
        # each kept slot's place: its target's first slot plus its rank
        slots = np.repeat(first - start[:-1], count) + np.arange(start[-1])
        out = FitWeights.of_slots(start, self.index[slots], self.weights[slots],
                                  self.reference[rows])
        out.counts = self.counts[rows]
        return out

    @property
    def nbytes(self) -> int:
        return self.start.nbytes + self.index.nbytes + self.weights.nbytes + self.reference.nbytes

    def gradients(self, values, out=None, div_curl: bool = False) -> np.ndarray:
        """(T, m, 2) the gradient of each column of ``values`` (N, m, in the
        order of the bins' points) at the targets (written to ``out`` when
        it is such an array: a series' batches reuse one).  ``div_curl``:
        the columns are fields' (x, y) components in pairs, and the answer
        (T, m / 2, 2) |div| and |curl| of each field (those gradients'
        :func:`abs_div_curl`, in the gather: the harmonic check's terms)."""
        v = np.asarray(values, dtype=np.float64)
        v = v[:, None] if v.ndim == 1 else v
        m = v.shape[1]
        if div_curl and m % 2:
            raise ValueError(f"div_curl takes pairs of columns, got {m}")
        per = 1 if div_curl else 2                  # the answer's columns a value column
        shape = (self.n_targets, m // 2 if div_curl else m, 2)
        if out is None or out.shape != shape or not out.flags.c_contiguous:
            out = np.empty(shape)
        if not (self.n_targets and m):
            return out
        for c in range(0, m, APPLY_COLUMNS):
            part = v[:, c:c + APPLY_COLUMNS]
            width = part.shape[1]
            stride = gather_stride(width)
            if stride == width and part.flags.c_contiguous:
                rows = part
            else:
                rows = np.zeros((len(v), stride))
                rows[:, :width] = part
            dest = out if width == m else np.empty((self.n_targets, width * per // 2, 2))
            _apply_weights(self.start, self.index, self.weights.reshape(-1), self.reference,
                           rows.reshape(-1), dest.reshape(-1), stride, width, bool(div_curl))
            if dest is not out:
                out[:, c * per // 2:(c + width) * per // 2] = dest
        return out
