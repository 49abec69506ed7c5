"""Grid values at scattered points: the natural decomposition's way back
from its cell grid to the data (:mod:`.natural`).  The cubic B-spline
through the grid values (:func:`at_points`, its prefilter in a Taichi
kernel), the tensor cubic Lagrange interpolant (:func:`lagrange_at`), and
near the boundary a one-sided quadratic fit to the nodes inside
(:func:`one_sided_gradient`), where the potentials' kink at the boundary
spoils central differences and the spline.
"""
import math

import numpy as np
import taichi as ti

from .. import runtime
from .free_space import Grid
from .node_fits import FitWeights, cholesky_solve

#: the cubic B-spline's interpolation pole (Unser et al. 1991): the
#: prefilter that makes the spline pass through the grid values
SPLINE_POLE = math.sqrt(3.0) - 2.0
#: edge values repeated on each side of the grid before the prefilter, whose
#: starts are exact for the edge values repeated forever: the extension's own
#: coefficients for the knots of points up to a cell beyond the grid
SPLINE_PAD = 2
#: adjacent grid lines one thread of :func:`_spline_filter` filters together
#: (their values share cache lines)
SPLINE_LANES = 3


@ti.kernel
def _spline_filter(c: ti.types.ndarray(), A: ti.i32, n: ti.i32, B: ti.i32, z: ti.f64,
                   lanes: ti.template(), linear: ti.template()):
    """The cubic B-spline prefilter in place along the middle axis of ``c``
    (A, n, B, flat), the lines (a, :, b) in parallel, ``lanes`` adjacent ones
    per thread (their values share cache lines): the causal and anticausal
    filters with the gain, each started exactly for the line's edge values
    repeated forever (:func:`spline_coefficients_numpy`); the running value
    of each recursion kept in a register, the offsets stepped (no 3-d index
    arithmetic)."""
    gain = (1.0 - z) * (1.0 - 1.0 / z)
    blocks = (B + lanes - 1) // lanes
    for t in range(A * blocks):
        a = t // blocks
        b0 = (t - a * blocks) * lanes
        # a lane past the last line reads it again and writes nothing
        base = ti.Vector.zero(ti.i64, lanes)
        for w in ti.static(range(lanes)):
            base[w] = ti.cast(a, ti.i64) * n * B + ti.min(b0 + w, B - 1)
        last = ti.cast(n - 1, ti.i64) * B
        prev = ti.Vector.zero(ti.f64, lanes)
        # the far end's edge value, read before the causal pass overwrites it
        far = ti.Vector.zero(ti.f64, lanes)
        steady = ti.Vector.zero(ti.f64, lanes)
        for w in ti.static(range(lanes)):
            far[w] = gain * c[base[w] + last] / (1.0 - z)
            steady[w] = far[w]
            # causal start: the sum of z^i gain c_0 over the repeated edge
            prev[w] = gain * c[base[w]] / (1.0 - z)
            if ti.static(linear):
                # ... or over the line continued with its edge's slope: less
                # gain z / (1 - z)^2 times that slope; the causal values
                # beyond the far end tend to a line whose start is ``steady``
                slope0 = c[base[w] + B] - c[base[w]]
                slope1 = c[base[w] + last] - c[base[w] + last - B]
                prev[w] -= gain * z / ((1.0 - z) * (1.0 - z)) * slope0
                steady[w] = far[w] - gain * z / ((1.0 - z) * (1.0 - z)) * slope1
            if b0 + w < B:
                c[base[w]] = prev[w]
        off = ti.cast(0, ti.i64)
        for i in range(1, n):
            off += B
            for w in ti.static(range(lanes)):
                prev[w] = gain * c[base[w] + off] + z * prev[w]
                if b0 + w < B:
                    c[base[w] + off] = prev[w]
        # anticausal start: -z sum_j z^j c+_{n-1+j}, the causal values beyond
        # the end tending to ``far`` as z^j
        for w in ti.static(range(lanes)):
            prev[w] = -z * (far[w] / (1.0 - z) + (prev[w] - steady[w]) / (1.0 - z * z))
            if b0 + w < B:
                c[base[w] + off] = prev[w]
        for q in range(1, n):
            off -= B
            for w in ti.static(range(lanes)):
                prev[w] = z * (prev[w] - c[base[w] + off])
                if b0 + w < B:
                    c[base[w] + off] = prev[w]


def spline_coefficients(u: np.ndarray) -> np.ndarray:
    """The cubic B-spline coefficients interpolating ``u`` (nx, ny[, m]) on
    its grid, the grid's edge values repeated forever beyond it, on the grid
    padded by SPLINE_PAD nodes a side (a contiguous array):
    :func:`spline_coefficients_numpy`'s recursive filters in a Taichi
    kernel, every grid line in parallel."""
    runtime.ensure_init()
    pad = [(SPLINE_PAD, SPLINE_PAD)] * 2 + [(0, 0)] * (u.ndim - 2)
    c = np.pad(np.asarray(u, dtype=np.float64), pad, mode="edge")
    prefilter(c)
    return c


def prefilter(c: np.ndarray, linear: bool = False) -> None:
    """:func:`spline_coefficients`' filters in place on the padded grid
    values ``c`` (NX, NY[, m], C-contiguous float64, or a
    :class:`~taichi_hh.runtime.Device` array); ``linear``: each line
    continued beyond its ends with its edge's slope instead of its edge value."""
    if not (isinstance(c, runtime.Device) or c.flags.c_contiguous) or c.dtype != np.float64:
        raise ValueError("the spline prefilter takes a C-contiguous float64 array")
    if c.size:
        runtime.ensure_init()
        nx, ny = c.shape[0], c.shape[1]
        m = c.size // (nx * ny)
        flat = runtime.flat(c)
        _spline_filter(flat, 1, nx, ny * m, SPLINE_POLE, SPLINE_LANES, bool(linear))
        _spline_filter(flat, nx, ny, m, SPLINE_POLE, SPLINE_LANES, bool(linear))


def spline_coefficients_numpy(u: np.ndarray) -> np.ndarray:
    """The cubic B-spline coefficients interpolating ``u`` (nx, ny[, m]), the
    grid's edge values repeated forever beyond it (``nearest``): along each
    axis the causal and anticausal recursive filters with the pole z (Unser
    et al. 1991), each started exactly for that extension (the causal
    filter's start the geometric sum of the first value, the anticausal
    one's the causal values beyond the end, which tend to the last value's
    as z^j), on the grid padded by SPLINE_PAD edge values (the extension's
    coefficients there).  scipy.ndimage.spline_filter(mode="nearest") pads 12
    edge values and starts for a mirror instead: the same coefficients to
    z^12 (1.4e-7 of the edge's variation at the first node)."""
    pad = [(SPLINE_PAD, SPLINE_PAD)] * 2 + [(0, 0)] * (u.ndim - 2)
    c = np.pad(np.asarray(u, dtype=np.float64), pad, mode="edge")
    z = SPLINE_POLE
    gain = (1.0 - z) * (1.0 - 1.0 / z)
    for axis in (0, 1):
        c = np.moveaxis(c, axis, 0).copy()
        n = c.shape[0]
        c *= gain
        far = c[-1] / (1.0 - z)
        c[0] = c[0] / (1.0 - z)
        for i in range(1, n):
            c[i] += z * c[i - 1]
        c[-1] = -z * (far / (1.0 - z) + (c[-1] - far) / (1.0 - z * z))
        for i in range(n - 2, -1, -1):
            c[i] = z * (c[i + 1] - c[i])
        c = np.moveaxis(c, 0, axis)
    return c


@ti.func
def _cubic_weights(t):
    """The cubic B-spline's weights of the knots floor(x) - 1 .. floor(x) + 2
    at fractional position t = x - floor(x)."""
    s = 1.0 - t
    w0 = s * s * s / 6.0
    w1 = (3.0 * t * t * (t - 2.0) + 4.0) / 6.0
    w2 = (3.0 * s * s * (s - 2.0) + 4.0) / 6.0
    return ti.Vector([w0, w1, w2, 1.0 - w0 - w1 - w2], dt=ti.f64)


@ti.kernel
def _tensor_gather(coef: ti.types.ndarray(), NX: ti.i32, NY: ti.i32, M: ti.i32,
                   n: ti.i32, pts: ti.types.ndarray(), x0: ti.f64, y0: ti.f64,
                   hx: ti.f64, hy: ti.f64, pad: ti.template(), weights: ti.template(),
                   m: ti.template(), blocks: ti.i32, scatter: ti.template(),
                   dest: ti.types.ndarray(), out: ti.types.ndarray()):
    """out[p, :blocks * m] (with ``scatter``: row dest[p]) = the
    tensor-product 4 x 4 interpolant of the first blocks * m columns of
    ``coef`` (NX, NY, M, flat) at point p (``pts`` (N, 2) flat; ``out``
    (N, M) flat): ``weights(t)`` of the fractional
    position along each axis, the knots offset by ``pad`` cells (indices
    clamped: the edge knots again beyond them); the ``m`` columns of a
    block read together, the blocks one after another (the point's weights
    and knots found once for them all).  The cubic B-spline
    (:func:`_cubic_weights`, SPLINE_PAD) and the cubic Lagrange interpolant
    (:func:`_lagrange_weights`, 0)."""
    for p in range(n):          # (a bound computed from a shape: not on SPIR-V)
        x = (pts[2 * p] - x0) / hx + pad
        y = (pts[2 * p + 1] - y0) / hy + pad
        fx = ti.floor(x)
        fy = ti.floor(y)
        wx = weights(x - fx)
        wy = weights(y - fy)
        # clamp in floating point: far-away points would overflow i32
        ix = ti.cast(ti.math.clamp(fx, -2.0, ti.cast(NX, ti.f64)), ti.i32)
        iy = ti.cast(ti.math.clamp(fy, -2.0, ti.cast(NY, ti.f64)), ti.i32)
        row_out = p
        if ti.static(scatter):
            row_out = ti.cast(dest[p], ti.i32)
        for blk in range(blocks):
            col0 = blk * m
            acc = ti.Vector.zero(ti.f64, m)
            for a in ti.static(range(4)):
                i = ti.math.clamp(ix + a - 1, 0, NX - 1)
                row = ti.Vector.zero(ti.f64, m)
                for b in ti.static(range(4)):
                    j = ti.math.clamp(iy + b - 1, 0, NY - 1)
                    for col in ti.static(range(m)):
                        row[col] += wy[b] * coef[(i * NY + j) * M + col0 + col]
                acc += wx[a] * row
            for col in ti.static(range(m)):
                out[row_out * M + col0 + col] = acc[col]



#: columns of the spline's evaluation kernel at most (a potential and its
#: gradient for two fields)
SPLINE_COLUMNS = 6


def at_points(grid: Grid, u: np.ndarray, points, *, dest=None) -> np.ndarray:
    """Grid values ``u`` (nx, ny[, m]) interpolated at ``points`` by the cubic
    B-spline through them (:func:`spline_coefficients`, :func:`spline_values`).
    ``dest``: the row of the result each point's values go to (a permutation)."""
    return spline_values(grid, spline_coefficients(u), points, dest=dest)


def spline_values(grid: Grid, coef: np.ndarray, points, *, dest=None, out=None) -> np.ndarray:
    """The cubic B-spline of the coefficients ``coef`` (the grid padded by
    SPLINE_PAD nodes a side, (NX, NY[, m]): :func:`spline_coefficients` or
    :func:`prefilter`) at ``points``: the tensor product of the 4 x 4 knots
    around each point, one gather per point (exact up to a cell beyond the
    grid; further out the edge knots again).  ``dest``: the row of the
    result each point's values go to (a permutation); ``out``: an (N, m)
    array to write them to (a series' batches reuse one)."""
    c3 = coef if coef.ndim == 3 else coef.reshape(coef.shape + (1,))
    out = _tensor_at(grid, c3, points, SPLINE_PAD, _cubic_weights, dest, out)
    return out if coef.ndim == 3 else out.reshape(-1)


def _tensor_at(grid: Grid, c3, points, pad, weights, dest, out=None):
    """(N, m) :func:`_tensor_gather` of the columns of ``c3`` (NX, NY, m),
    in one launch: blocks of SPLINE_COLUMNS, 2 or 1 of them (the widest that
    divides m: the kernel compiles once per width; a series' many columns go
    through in blocks, read in place).  ``c3``, ``points`` (N, 2), ``dest``
    and ``out`` numpy arrays or :class:`~taichi_hh.runtime.Device` ones (the
    answer then too: ``out``, or one from :func:`taichi_hh.runtime.work`)."""
    runtime.ensure_init()
    NX, NY, m = c3.shape
    n = len(points)
    on_device = any(isinstance(a, runtime.Device) for a in (c3, points, out))
    if not runtime.writable(out, (n, m)):
        out = runtime.work((n, m)) if on_device else np.empty((n, m))
    if n:
        scatter = dest is not None
        rows = runtime.flat(dest, np.int64) if scatter else np.zeros(1, np.int64)
        width = next(w for w in (SPLINE_COLUMNS, 2, 1) if m % w == 0)
        _tensor_gather(runtime.flat(c3), NX, NY, m, n, runtime.flat(points),
                       float(grid.origin[0]), float(grid.origin[1]), grid.hx,
                       grid.hy, pad, weights, width, m // width, scatter, rows, runtime.flat(out))
    return out


#: points within this many cells of the boundary take their gradient from a
#: one-sided fit (:func:`one_sided_gradient`)
ONE_SIDED_CELLS = 6.0
#: the fit's stencil: the nodes of the square block this many cells around the
#: nearest node, weighted within ONE_SIDED_REACH - 1/2 cells of the point
ONE_SIDED_REACH = 4
#: fewer inside nodes than this in the stencil: no fit (the spline's gradient)
ONE_SIDED_MIN_NODES = 16


@ti.func
def _stencil_node(P, ci, cj, a, b, nx, ny, x0, y0, hx, hy, inside: ti.template()):
    """Node (ci + a, cj + b) of the one-sided fit's stencil around ``P``
    (indices clamped into the grid): ``(in the fit, its weight, the quadratic
    basis at it in cells from P, i, j)``."""
    R = ONE_SIDED_REACH
    ii = ti.math.clamp(ci + a, 0, nx - 1)
    jj = ti.math.clamp(cj + b, 0, ny - 1)
    dx = (x0 + ii * hx - P[0]) / hx                      # in cells
    dy = (y0 + jj * hy - P[1]) / hy
    q = ti.sqrt(dx * dx + dy * dy) / (R - 0.5)
    use = inside[ii, jj] != 0 and q < 1.0
    w = 0.0
    if use:
        w = (1.0 - q) ** 4 * (1.0 + 4.0 * q)
    B = ti.Vector([1.0, dx, dy, dx * dx, dx * dy, dy * dy], dt=ti.f64)
    return use, w, B, ii, jj


@ti.func
def _one_sided_system(P, x0, y0, hx, hy, nx, ny, inside: ti.template(), u: ti.template(), col,
                      with_values: ti.template()):
    """The weighted quadratic fit's normal equations at point ``P`` over the
    stencil around its nearest node: ``(ci, cj, M, rhs, count)``, the
    nearest node, the 6 x 6 moment matrix, with ``with_values`` the
    right-hand sides of the columns ``col`` and ``col + 1`` of ``u`` (nx,
    ny, m), and the nodes carrying weight."""
    R = ONE_SIDED_REACH
    ci = ti.cast(ti.math.clamp(ti.floor((P[0] - x0) / hx + 0.5), -1e9, 1e9), ti.i32)
    cj = ti.cast(ti.math.clamp(ti.floor((P[1] - y0) / hy + 0.5), -1e9, 1e9), ti.i32)
    M = ti.Matrix.zero(ti.f64, 6, 6)
    rhs = ti.Matrix.zero(ti.f64, 6, 2)
    ref = ti.Vector.zero(ti.f64, 2)
    if ti.static(with_values):
        # the values less the nearest node's (the constant term takes it):
        # sums of the differences do not carry the potential's level, and the
        # fit's constant is as small as its gradient term (the solver's ridge,
        # 1e-12 of the trace, biased the gradient by 1e-12 cond(M) |u| /
        # (h |grad u|): 1e-8 at 64k points)
        ri = ti.math.clamp(ci, 0, nx - 1)
        rj = ti.math.clamp(cj, 0, ny - 1)
        ref = ti.Vector([u[ri, rj, col], u[ri, rj, col + 1]], dt=ti.f64)
    count = 0
    for a in range(-R, R + 1):
        for b in range(-R, R + 1):
            use, w, B, ii, jj = _stencil_node(P, ci, cj, a, b, nx, ny, x0, y0, hx, hy, inside)
            if use:
                if w > 0.0:
                    count += 1
                M += w * B.outer_product(B)
                if ti.static(with_values):
                    v = ti.Vector([u[ii, jj, col], u[ii, jj, col + 1]], dt=ti.f64) - ref
                    rhs += w * B.outer_product(v)
    return ci, cj, M, rhs, count


@ti.kernel
def _one_sided(u: ti.types.ndarray(), inside: ti.types.ndarray(), pts: ti.types.ndarray(),
               x0: ti.f64, y0: ti.f64, hx: ti.f64, hy: ti.f64, col: ti.i32,
               out: ti.types.ndarray()):
    """:func:`one_sided_gradient` of the columns ``col`` and ``col + 1`` of
    ``u`` (nx, ny, m) at each point: out[p, 0:2] and out[p, 2:4] (NaN where
    fewer than ONE_SIDED_MIN_NODES nodes carry weight)."""
    nx, ny = u.shape[0], u.shape[1]
    for p in range(pts.shape[0]):
        P = ti.Vector([pts[p, 0], pts[p, 1]], dt=ti.f64)
        _, _, M, rhs, count = _one_sided_system(P, x0, y0, hx, hy, nx, ny, inside, u, col,
                                                True)
        for c in ti.static(range(4)):
            out[p, c] = ti.math.nan
        if count >= ONE_SIDED_MIN_NODES:
            x = cholesky_solve(M, rhs, 6, ti.f64, 0.0)
            out[p, 0] = x[1, 0] / hx
            out[p, 1] = x[2, 0] / hy
            out[p, 2] = x[1, 1] / hx
            out[p, 3] = x[2, 1] / hy


def one_sided_gradient(grid: Grid, u: np.ndarray, inside: np.ndarray, points) -> np.ndarray:
    """(len(points), 2) the gradient of the grid potential ``u`` (nx, ny) at
    ``points`` from a weighted quadratic least-squares fit to the nodes
    ``inside`` (nx, ny booleans: the cell centres inside the domain) within
    :data:`ONE_SIDED_REACH` cells.

    Why: the potential of a density that stops at the boundary is smooth on
    each side but only C^{1,1} across it (its second derivatives jump).
    Central differences and the cubic spline straddle that kink within a few
    cells of the boundary and err there by O(h) (measured: the rigid
    rotation on the unit square, 3.3e-3 -> 1.7e-3 -> 8.6e-4 near the boundary
    at 4k -> 16k -> 64k points, against 1.8e-5 -> 1.2e-6 inside); nodes on
    the inside alone see a smooth function, and a quadratic fit's gradient is
    second order.

    ``u`` (nx, ny, m) gives (len(points), m, 2): one fit's weights for every
    column.  A Taichi kernel (:func:`_one_sided`), one gather per point; NaN
    where fewer than :data:`ONE_SIDED_MIN_NODES` nodes are inside the stencil."""
    runtime.ensure_init()
    pts = np.ascontiguousarray(points, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    one = u.ndim == 2
    u3 = u[..., None] if one else u
    m = u3.shape[2]
    if m % 2:
        u3 = np.concatenate([u3, np.zeros(u3.shape[:2] + (1,))], axis=2)
    u3 = np.ascontiguousarray(u3)
    out = np.zeros((len(pts), m, 2))
    if len(pts):
        ins = np.ascontiguousarray(inside, dtype=np.int32)
        pair = np.empty((len(pts), 4))
        for c in range(0, m, 2):
            _one_sided(u3, ins, pts, float(grid.origin[0]), float(grid.origin[1]),
                       grid.hx, grid.hy, c, pair)
            out[:, c] = pair[:, :2]
            if c + 1 < m:
                out[:, c + 1] = pair[:, 2:]
    return out[:, 0] if one else out


@ti.kernel
def _one_sided_slots(inside: ti.types.ndarray(), pts: ti.types.ndarray(), x0: ti.f64,
                     y0: ti.f64, hx: ti.f64, hy: ti.f64, index: ti.types.ndarray(),
                     weights: ti.types.ndarray(), ok: ti.types.ndarray()):
    """:func:`one_sided_weights`' fits: point p's weight in each derivative
    on stencil node s at ``weights[p, s, :]`` (node ``index[p, s]``, -1
    where the node is not in the fit), ``ok[p]`` where the fit exists: the
    moment matrix of :func:`_one_sided`, solved once against the two
    derivatives' unit vectors."""
    nx, ny = inside.shape[0], inside.shape[1]
    R = ONE_SIDED_REACH
    for p in range(pts.shape[0]):
        P = ti.Vector([pts[p, 0], pts[p, 1]], dt=ti.f64)
        ci, cj, M, _, count = _one_sided_system(P, x0, y0, hx, hy, nx, ny, inside, inside, 0,
                                                False)
        fit = count >= ONE_SIDED_MIN_NODES
        ok[p] = 1 if fit else 0
        unit = ti.Matrix.zero(ti.f64, 6, 2)
        unit[1, 0] = 1.0
        unit[2, 1] = 1.0
        X = cholesky_solve(M, unit, 6, ti.f64, 0.0)
        s = 0
        for a in range(-R, R + 1):
            for b in range(-R, R + 1):
                use, w, B, ii, jj = _stencil_node(P, ci, cj, a, b, nx, ny, x0, y0, hx, hy,
                                                  inside)
                index[p, s] = -1
                if use and fit:
                    index[p, s] = ii * ny + jj
                    weights[p, s, 0] = w * (X[:, 0].dot(B)) / hx
                    weights[p, s, 1] = w * (X[:, 1].dot(B)) / hy
                s += 1


def one_sided_weights(grid: Grid, inside: np.ndarray, points) -> tuple:
    """:func:`one_sided_gradient` at fixed ``points`` as weights, for grids
    that carry many potentials (a series): ``(weights, ok)``, ``weights`` a
    :class:`~.node_fits.FitWeights` over the grid's nodes (flat index
    i * ny + j) whose :meth:`~.node_fits.FitWeights.gradients` of
    ``u.reshape(m, -1).T`` gives the fits' gradients of the m potentials,
    equal to :func:`one_sided_gradient` to rounding; ``ok`` (len(points),)
    where the fit exists (elsewhere that function's NaN).  The same weighted
    quadratic fit as :func:`_one_sided`, its matrix solved once per point
    for the two derivatives' weights (a Taichi kernel,
    :func:`_one_sided_slots`; numpy's batched solves took 20x as long)."""
    runtime.ensure_init()
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    stencil = (2 * ONE_SIDED_REACH + 1) ** 2
    index = np.empty((len(pts), stencil), dtype=np.int32)
    weights = np.empty((len(pts), stencil, 2))
    ok = np.zeros(len(pts), dtype=np.int32)
    if len(pts):
        _one_sided_slots(np.ascontiguousarray(inside, dtype=np.int32), pts,
                         float(grid.origin[0]), float(grid.origin[1]), grid.hx, grid.hy,
                         index, weights, ok)
    keep = index >= 0
    start = np.zeros(len(pts) + 1, dtype=np.int64)
    np.cumsum(keep.sum(axis=1), out=start[1:])
    index, weights = index[keep], weights[keep]
    # the reference each gather subtracts (the weights sum to zero): the
    # first node of the point's fit
    first = np.minimum(start[:-1], max(len(index) - 1, 0))
    reference = np.where(np.diff(start) > 0, index[first] if len(index) else 0, 0)
    return FitWeights.of_slots(start, index, weights, reference), ok.astype(bool)


@ti.func
def _lagrange_weights(t):
    """The cubic Lagrange weights of the nodes -1, 0, 1, 2 at t in [0, 1)."""
    return ti.Vector([-t * (t - 1.0) * (t - 2.0) / 6.0, (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0,
                      -(t + 1.0) * t * (t - 2.0) / 2.0, (t + 1.0) * t * (t - 1.0) / 6.0],
                     dt=ti.f64)


def lagrange_at(grid: Grid, u: np.ndarray, points, dest, out=None) -> np.ndarray:
    """(N, m): the tensor cubic Lagrange interpolant of the columns of ``u``
    (nx, ny, m) at ``points`` from the 4 x 4 nodes around each (indices
    clamped; :func:`_tensor_gather`), point p's values in row ``dest[p]``
    (of ``out`` when given)."""
    return _tensor_at(grid, u, points, 0, _lagrange_weights, dest, out)
