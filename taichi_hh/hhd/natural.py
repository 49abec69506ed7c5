"""The natural Helmholtz-Hodge decomposition (Bhatia et al. 2014): potentials
from the free-space Green's function, no boundary condition imposed.

    phi(x) = int_Omega G(x - y) div v(y) dy,   psi(x) = -int_Omega G(x - y) curl v(y) dy,
    G(x) = ln|x| / (2 pi)   (lap G = delta in 2D),

so that lap phi = div v and lap psi = -curl v (the sign of psi keeps r = J grad
psi, J of :mod:`.rotation`), d = grad phi, r = J grad psi, h = v - d - r is
harmonic inside Omega.  d and r are the fields that the sources and vortices
inside Omega alone induce; whatever enters from outside (a constant, a
gradient of a harmonic function) is h.

Discretisation (particle-mesh, Hockney and Eastwood): div v and curl v at the
data points (the decomposition's SPH operators) are reconstructed at the
centres of a regular grid of cells about one data spacing wide by quadratic
moving least squares, weighted by the fraction of each cell inside Omega; the
convolution with G over the grid (midpoint rule, with the integral of G over
the cell itself on the diagonal) is done by zero-padded FFT in O(M log M) for
M cells, or by direct summation in a Taichi kernel (O(M^2), one gather per
target cell) as the exact reference of the same sum; the gradients of the
potentials by fourth-order central differences on the grid, interpolated to
the points.  Why a grid and not the points themselves as quadrature nodes:
the point sum sum_j grad G(x_i - y_j) div v_j V_j errs by the points'
irregularity within each cell, which does not average out near the target
(measured 4-5% mean error of d on the ``gaussian`` field at 1.5k-13k
blue-noise points, hardly falling); the midpoint rule on a uniform grid is
second order and its error is smooth, so differencing it keeps second order
(docs/notes/hhd.md).
"""
import math

import numpy as np
import taichi as ti

from .. import runtime
from ..sph.knn import KNearest
from .options import NATURAL_EVALUATIONS

#: data points in each quadratic moving-least-squares fit at a grid node
MLS_NEIGHBOURS = 20
#: cells beyond the domain's bounding box on each side: room for the
#: differences and the interpolation at points on the boundary
MARGIN = 3


class Grid:
    """Cell-centred grid covering ``domain``'s bounding box (whole cells of
    size ``hx`` x ``hy`` close to ``cell``) plus ``MARGIN`` cells on each side."""

    def __init__(self, domain, cell: float):
        (x0, y0), (x1, y1) = domain.bounds
        nx = max(int(math.ceil((x1 - x0) / cell - 1e-9)), 1)
        ny = max(int(math.ceil((y1 - y0) / cell - 1e-9)), 1)
        self.hx, self.hy = (x1 - x0) / nx, (y1 - y0) / ny
        self.nx, self.ny = nx + 2 * MARGIN, ny + 2 * MARGIN
        self.origin = np.array([x0 - (MARGIN - 0.5) * self.hx, y0 - (MARGIN - 0.5) * self.hy])

    @property
    def shape(self):
        return self.nx, self.ny

    def centres(self) -> np.ndarray:
        """(nx * ny, 2) cell centres, x fastest within each row of constant ... index
        order ``[i * ny + j]`` for cell (i, j)."""
        i, j = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="ij")
        return np.c_[self.origin[0] + i.ravel() * self.hx, self.origin[1] + j.ravel() * self.hy]

    def coverage(self, domain, sub: int = 4, *, centroids: bool = False):
        """(nx, ny) fraction of each cell inside ``domain``, by ``sub`` x ``sub``
        subsamples for the cells the boundary may cross; with ``centroids``
        also (nx, ny, 2) the offset of the inside part's centroid from the
        cell centre (0 for whole and empty cells), from the same subsamples."""
        c = self.centres()
        sd = domain.signed_distance(c)
        half_diag = 0.5 * math.hypot(self.hx, self.hy)
        frac = (sd < -half_diag).astype(np.float64)
        offset = np.zeros((len(c), 2))
        cut = np.flatnonzero(np.abs(sd) <= half_diag)
        if cut.size:
            s = (np.arange(sub) + 0.5) / sub - 0.5
            ox, oy = np.meshgrid(s * self.hx, s * self.hy, indexing="ij")
            offs = np.c_[ox.ravel(), oy.ravel()]
            sp = (c[cut][:, None, :] + offs[None, :, :]).reshape(-1, 2)
            inside = domain.contains(sp).reshape(len(cut), -1)
            frac[cut] = inside.mean(axis=1)
            count = inside.sum(axis=1)
            offset[cut] = (inside @ offs) / np.maximum(count, 1)[:, None]
        if centroids:
            return frac.reshape(self.shape), offset.reshape(self.shape + (2,))
        return frac.reshape(self.shape)

    def self_integral(self) -> float:
        """int over one cell (centred at 0) of G = ln|s| / (2 pi): Gauss-Legendre
        in polar-free form, the log singularity handled by splitting the cell
        into four triangles from the centre (each integrable in closed form in r)."""
        # integral of ln r over the triangle (0,0), (a, -b), (a, b) is, in polar form,
        # int_{-atan(b/a)}^{atan(b/a)} (R^2 ln R / 2 - R^2 / 4) dt with R = a / cos t
        total = 0.0
        x, w = np.polynomial.legendre.leggauss(64)
        for a, b in ((self.hx / 2, self.hy / 2), (self.hy / 2, self.hx / 2)):
            t_max = math.atan2(b, a)
            t = x * t_max
            R = a / np.cos(t)
            total += 2.0 * float((w * t_max * (R * R * np.log(R) / 2 - R * R / 4)).sum())
        return total / (2.0 * math.pi)

    def kernel(self) -> np.ndarray:
        """(2 nx, 2 ny) the Green's function times the cell area at every offset
        of the zero-padded grid (wrapped: offset -k at index 2n - k), the cell's
        own integral at offset 0 (Hockney and Eastwood's free-space convolution)."""
        ix = np.arange(2 * self.nx)
        iy = np.arange(2 * self.ny)
        ix = np.where(ix <= self.nx, ix, ix - 2 * self.nx) * self.hx
        iy = np.where(iy <= self.ny, iy, iy - 2 * self.ny) * self.hy
        r2 = ix[:, None] ** 2 + iy[None, :] ** 2
        r2[0, 0] = 1.0
        K = np.log(r2) / (4.0 * math.pi) * (self.hx * self.hy)
        K[0, 0] = self.self_integral()
        return K


def mls_at(points, values, targets, k: int = MLS_NEIGHBOURS,
           exclude_self: bool = False) -> np.ndarray:
    """Quadratic moving least squares: each of ``values`` (N, m) reconstructed at
    ``targets`` from its ``k`` nearest data points (Wendland weights on the
    distance over 1.5 times the k-th distance; exact on quadratics).
    exclude_self: the targets are the points themselves, each left out of its fit."""
    points = np.asarray(points, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    values = values[:, None] if values.ndim == 1 else values
    # leaving the target itself out takes one neighbour more: at most all points
    k = min(k, len(points) - int(exclude_self))
    out = np.zeros((len(targets), values.shape[1]))
    if len(targets) == 0:
        return out
    search = KNearest(points)
    for s in range(0, len(targets), 65536):
        tg = targets[s:s + 65536]
        dist, idx = search.query(tg, k + 1 if exclude_self else k)
        if exclude_self:
            dist, idx = dist[:, 1:], idx[:, 1:]
        scale = 1.5 * dist[:, -1:] + 1e-300
        q = dist / scale
        w = (1 - q) ** 4 * (1 + 4 * q)
        dx = (points[idx] - tg[:, None, :]) / scale[..., None]
        B = np.stack([np.ones_like(q), dx[..., 0], dx[..., 1], dx[..., 0] ** 2,
                      dx[..., 0] * dx[..., 1], dx[..., 1] ** 2], axis=-1)     # (t, k, 6)
        BWt = (B * w[..., None]).transpose(0, 2, 1)                          # (t, 6, k)
        M = BWt @ B
        M += 1e-12 * np.trace(M, axis1=1, axis2=2)[:, None, None] * np.eye(6)
        # only the constant coefficient is wanted: row 0 of M^-1 times BW^T values
        e0 = np.linalg.solve(M, np.broadcast_to(np.eye(6)[:, :1], (len(tg), 6, 1)))[..., 0]
        weights = np.einsum("ti,tik->tk", e0, BWt)                           # (t, k)
        out[s:s + 65536] = np.einsum("tk,tkm->tm", weights, values[idx])
    return out


#: the reconstruction radius at a grid node, in cells: the first of these that
#: holds ``MLS_MIN_POINTS`` data points (more near the boundary and corners)
MLS_RADII = (2.5, 4.0, 6.0)
MLS_MIN_POINTS = 15
_N_RADII = len(MLS_RADII)


@ti.func
def _mls_weight(q):
    return (1.0 - q) ** 4 * (1.0 + 4.0 * q) if q < 1.0 else 0.0


@ti.kernel
def _mls_nodes(targets: ti.types.ndarray(), nx: ti.i32, ny: ti.i32, x0: float, y0: float,
               hx: float, hy: float, start: ti.types.ndarray(), pos: ti.types.ndarray(),
               vals: ti.types.ndarray(), out: ti.types.ndarray()):
    """Quadratic moving least squares of the two columns of ``vals`` at the
    centres of the ``targets`` cells, from the points (sorted by cell, ``start``
    the offsets) within the first radius of MLS_RADII holding MLS_MIN_POINTS;
    one gather per node, the 6 x 6 normal equations by Cholesky."""
    h = ti.max(hx, hy)
    for t in range(targets.shape[0]):
        c = targets[t]
        ci = c // ny
        cj = c - ci * ny
        X = ti.Vector([x0 + ci * hx, y0 + cj * hy])
        R = 0.0
        for a in ti.static(range(_N_RADII)):
            if R == 0.0:
                r_try = MLS_RADII[a] * h
                reach = ti.cast(ti.ceil(r_try / ti.min(hx, hy)), ti.i32)
                count = 0
                for i in range(ti.max(ci - reach, 0), ti.min(ci + reach + 1, nx)):
                    for j in range(ti.max(cj - reach, 0), ti.min(cj + reach + 1, ny)):
                        cell = i * ny + j
                        for k in range(start[cell], start[cell + 1]):
                            d = pos[k] - X
                            if d.dot(d) < r_try * r_try:
                                count += 1
                if count >= MLS_MIN_POINTS or a == _N_RADII - 1:
                    R = r_try
        reach = ti.cast(ti.ceil(R / ti.min(hx, hy)), ti.i32)
        M = ti.Matrix.zero(float, 6, 6)
        rhs = ti.Matrix.zero(float, 6, 2)
        for i in range(ti.max(ci - reach, 0), ti.min(ci + reach + 1, nx)):
            for j in range(ti.max(cj - reach, 0), ti.min(cj + reach + 1, ny)):
                cell = i * ny + j
                for k in range(start[cell], start[cell + 1]):
                    d = (pos[k] - X) / R
                    w = _mls_weight(d.norm())
                    if w > 0.0:
                        b = ti.Vector([1.0, d[0], d[1], d[0] * d[0], d[0] * d[1], d[1] * d[1]])
                        M += w * b.outer_product(b)
                        rhs += w * b.outer_product(vals[k])
        tr = 0.0
        for a in ti.static(range(6)):
            tr += M[a, a]
        for a in ti.static(range(6)):
            M[a, a] += 1e-12 * tr + 1e-30
        # Cholesky M = L L^T, then L y = rhs, L^T x = y; only x[0, :] is wanted
        L = ti.Matrix.zero(float, 6, 6)
        for jj in ti.static(range(6)):
            s = M[jj, jj]
            for kk in ti.static(range(jj)):
                s -= L[jj, kk] * L[jj, kk]
            L[jj, jj] = ti.sqrt(ti.max(s, 1e-30))
            for ii in ti.static(range(jj + 1, 6)):
                s2 = M[ii, jj]
                for kk in ti.static(range(jj)):
                    s2 -= L[ii, kk] * L[jj, kk]
                L[ii, jj] = s2 / L[jj, jj]
        y = ti.Matrix.zero(float, 6, 2)
        for ii in ti.static(range(6)):
            r0 = rhs[ii, 0]
            r1 = rhs[ii, 1]
            for kk in ti.static(range(ii)):
                r0 -= L[ii, kk] * y[kk, 0]
                r1 -= L[ii, kk] * y[kk, 1]
            y[ii, 0] = r0 / L[ii, ii]
            y[ii, 1] = r1 / L[ii, ii]
        x = ti.Matrix.zero(float, 6, 2)
        for q in ti.static(range(6)):
            ii = ti.static(5 - q)
            r0 = y[ii, 0]
            r1 = y[ii, 1]
            for kk in ti.static(range(ii + 1, 6)):
                r0 -= L[kk, ii] * x[kk, 0]
                r1 -= L[kk, ii] * x[kk, 1]
            x[ii, 0] = r0 / L[ii, ii]
            x[ii, 1] = r1 / L[ii, ii]
        out[t] = ti.Vector([x[0, 0], x[0, 1]])


def reconstruct_on_grid(grid: "Grid", points, values, live) -> np.ndarray:
    """(len(live), m) the columns of ``values`` (N, m) reconstructed at the centres
    of the cells ``live`` (flat indices) by quadratic moving least squares
    (:func:`_mls_nodes`, two columns per pass)."""
    runtime.ensure_init()
    real, npr = runtime.real_dtype(), runtime.np_real()
    values = np.asarray(values, dtype=np.float64)
    values = values[:, None] if values.ndim == 1 else values
    lower = grid.origin - 0.5 * np.array([grid.hx, grid.hy])
    ij = np.floor((points - lower) / [grid.hx, grid.hy]).astype(np.int64)
    ij[:, 0] = np.clip(ij[:, 0], 0, grid.nx - 1)
    ij[:, 1] = np.clip(ij[:, 1], 0, grid.ny - 1)
    cell = ij[:, 0] * grid.ny + ij[:, 1]
    order = np.argsort(cell, kind="stable")
    start = np.zeros(grid.nx * grid.ny + 1, dtype=np.int32)
    np.cumsum(np.bincount(cell, minlength=grid.nx * grid.ny), out=start[1:])
    pos = runtime.array(real, len(points), vector=2)
    pos.from_numpy(points[order].astype(npr))
    start_nd = runtime.array(ti.i32, len(start))
    start_nd.from_numpy(start)
    live = np.asarray(live, dtype=np.int32)
    tg = runtime.array(ti.i32, max(len(live), 1))
    tg.from_numpy(np.resize(live, max(len(live), 1)))
    out = np.zeros((len(live), values.shape[1]))
    res = runtime.array(real, max(len(live), 1), vector=2)
    vals = runtime.array(real, len(points), vector=2)
    for m in range(0, values.shape[1], 2):
        pair = np.zeros((len(points), 2))
        cols = values[order, m:m + 2]
        pair[:, :cols.shape[1]] = cols
        vals.from_numpy(pair.astype(npr))
        if len(live):
            _mls_nodes(tg, grid.nx, grid.ny, float(grid.origin[0]), float(grid.origin[1]),
                       grid.hx, grid.hy, start_nd, pos, vals, res)
        out[:, m:m + cols.shape[1]] = res.to_numpy()[: len(live), : cols.shape[1]]
    return out


def convolve_fft(grid: Grid, density: np.ndarray) -> np.ndarray:
    """(nx, ny) sum over cells of G(x_a - x_b) density_b (times the cell area),
    by zero-padded FFT (the padding makes the circular convolution free-space)."""
    nx, ny = grid.shape
    K = np.fft.rfft2(grid.kernel())
    rho = np.zeros((2 * nx, 2 * ny))
    rho[:nx, :ny] = density
    return np.fft.irfft2(np.fft.rfft2(rho) * K, s=rho.shape)[:nx, :ny]


@ti.kernel
def _direct_sum(n: ti.i32, pos: ti.types.ndarray(), q: ti.types.ndarray(), self_term: float,
                out: ti.types.ndarray()):
    # one gather per target: no atomics; the own cell contributes its integral
    for a in range(n):
        acc = q[a] * self_term
        for b in range(n):
            if b != a:
                d = pos[a] - pos[b]
                acc += q[b] * ti.log(d.dot(d)) * (0.25 / math.pi)
        out[a] = acc


def convolve_direct(grid: Grid, density: np.ndarray) -> np.ndarray:
    """The same sum as :func:`convolve_fft` by direct summation over the cells
    with nonzero density (a Taichi kernel, O(M^2)): its exact reference."""
    runtime.ensure_init()
    dens = np.asarray(density, dtype=np.float64).ravel()
    c = grid.centres()
    area = grid.hx * grid.hy
    # targets: every cell; sources: the cells with density (the others add zero)
    n = len(c)
    real = runtime.real_dtype()
    pos = runtime.array(real, n, vector=2)
    pos.from_numpy(c.astype(runtime.np_real()))
    q = runtime.array(real, n)
    q.from_numpy((dens * area).astype(runtime.np_real()))
    out = runtime.array(real, n)
    _direct_sum(n, pos, q, grid.self_integral() / area, out)
    return out.to_numpy().astype(np.float64).reshape(grid.shape)


def grid_gradient(grid: Grid, u: np.ndarray) -> np.ndarray:
    """(nx, ny, 2) fourth-order central differences (second order on the two
    outermost cells)."""
    g = np.zeros(u.shape + (2,))
    for axis, h in ((0, grid.hx), (1, grid.hy)):
        d = np.gradient(u, h, axis=axis, edge_order=2)
        sl = [slice(None)] * 2
        sl[axis] = slice(2, -2)
        p2 = np.roll(u, -2, axis=axis)
        p1 = np.roll(u, -1, axis=axis)
        m1 = np.roll(u, 1, axis=axis)
        m2 = np.roll(u, 2, axis=axis)
        d4 = (-p2 + 8 * p1 - 8 * m1 + m2) / (12 * h)
        d[tuple(sl)] = d4[tuple(sl)]
        g[..., axis] = d
    return g


#: the cubic B-spline's interpolation pole (Unser et al. 1991): the
#: prefilter that makes the spline pass through the grid values
SPLINE_POLE = math.sqrt(3.0) - 2.0
#: edge cells replicated on each side before the prefilter (as
#: scipy.ndimage.map_coordinates(mode="nearest") pads): the filter's boundary
#: start decays as SPLINE_POLE ** distance, below round-off at the points
SPLINE_PAD = 12


def spline_coefficients(u: np.ndarray) -> np.ndarray:
    """The cubic B-spline coefficients interpolating ``u`` (nx, ny[, m]) on
    its grid padded by ``SPLINE_PAD`` replicated edge values: along each axis
    the causal and anticausal recursive filters with the pole z (Unser et al.
    1991), each started exactly for the half-sample symmetric extension.
    The same maths as scipy.ndimage.spline_filter(mode="nearest") on the
    edge-padded grid (map_coordinates' prefilter)."""
    pad = [(SPLINE_PAD, SPLINE_PAD)] * 2 + [(0, 0)] * (u.ndim - 2)
    c = np.pad(np.asarray(u, dtype=np.float64), pad, mode="edge")
    z = SPLINE_POLE
    for axis in (0, 1):
        c = np.moveaxis(c, axis, 0).copy()
        n = c.shape[0]
        c *= (1.0 - z) * (1.0 - 1.0 / z)                 # the filter's gain
        # causal start: sum_i z^i c_i over the mirrored sequence, in closed form
        zi = z ** np.arange(n)
        zn = z ** n
        mirror = np.tensordot(zi[1:], c[1:] + zn * c[-2::-1], axes=(0, 0))
        c0 = c[0].copy()
        c[0] = c0 + z / (1.0 - zn * zn) * (c0 + zn * c[-1] + mirror)
        for i in range(1, n):
            c[i] += z * c[i - 1]
        c[-1] *= z / (z - 1.0)                           # anticausal start
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
def _spline_at(coef: ti.types.ndarray(), pts: ti.types.ndarray(), x0: ti.f64, y0: ti.f64,
               hx: ti.f64, hy: ti.f64, out: ti.types.ndarray()):
    """out[p, :] = the tensor-product cubic B-spline of ``coef`` (NX, NY, m) at
    point p: the 4 x 4 knots around it (indices clamped: ``nearest``)."""
    NX, NY, m = coef.shape[0], coef.shape[1], coef.shape[2]
    for p in range(pts.shape[0]):
        x = (pts[p, 0] - x0) / hx + SPLINE_PAD
        y = (pts[p, 1] - y0) / hy + SPLINE_PAD
        fx = ti.floor(x)
        fy = ti.floor(y)
        wx = _cubic_weights(x - fx)
        wy = _cubic_weights(y - fy)
        # clamp in floating point: far-away points would overflow i32
        ix = ti.cast(ti.math.clamp(fx, -2.0, ti.cast(NX, ti.f64)), ti.i32)
        iy = ti.cast(ti.math.clamp(fy, -2.0, ti.cast(NY, ti.f64)), ti.i32)
        for col in range(m):
            acc = ti.f64(0.0)
            for a in ti.static(range(4)):
                i = ti.math.clamp(ix + a - 1, 0, NX - 1)
                row = ti.f64(0.0)
                for b in ti.static(range(4)):
                    row += wy[b] * coef[i, ti.math.clamp(iy + b - 1, 0, NY - 1), col]
                acc += wx[a] * row
            out[p, col] = acc


def at_points(grid: Grid, u: np.ndarray, points) -> np.ndarray:
    """Grid values ``u`` (nx, ny[, m]) interpolated at ``points`` by the cubic
    B-spline through them (:func:`spline_coefficients`; the tensor product
    of the 4 x 4 knots around each point, one gather per point)."""
    runtime.ensure_init()
    c = spline_coefficients(u)
    c3 = np.ascontiguousarray(c if c.ndim == 3 else c[..., None])
    pts = np.ascontiguousarray(points, dtype=np.float64)
    out = np.zeros((len(pts), c3.shape[2]))
    if len(pts):
        _spline_at(c3, pts, float(grid.origin[0]), float(grid.origin[1]), grid.hx, grid.hy, out)
    return out if c.ndim == 3 else out[:, 0]


#: subsamples per side of a cut cell for its inside fraction and centroid
CUT_SUBSAMPLES = 16
#: points within this many cells of the boundary take their gradient from a
#: one-sided fit (:func:`one_sided_gradient`)
ONE_SIDED_CELLS = 3.0
#: the fit's stencil: the nodes of the square block this many cells around the
#: nearest node, weighted within ONE_SIDED_REACH - 1/2 cells of the point
ONE_SIDED_REACH = 4
#: fewer inside nodes than this in the stencil: no fit (the spline's gradient)
ONE_SIDED_MIN_NODES = 16


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
    second order."""
    pts = np.asarray(points, dtype=np.float64)
    out = np.zeros((len(pts), 2))
    if len(pts) == 0:
        return out
    R = ONE_SIDED_REACH
    offs = np.arange(-R, R + 1)
    oi, oj = np.meshgrid(offs, offs, indexing="ij")
    oi, oj = oi.ravel(), oj.ravel()
    h = np.array([grid.hx, grid.hy])
    for s in range(0, len(pts), 8192):
        p = pts[s:s + 8192]
        c = np.rint((p - grid.origin) / h).astype(np.int64)              # nearest node
        ii = np.clip(c[:, :1] + oi[None], 0, grid.nx - 1)                  # (m, K)
        jj = np.clip(c[:, 1:] + oj[None], 0, grid.ny - 1)
        node = np.stack([grid.origin[0] + ii * grid.hx, grid.origin[1] + jj * grid.hy], -1)
        d = (node - p[:, None, :]) / h                                     # in cells
        # the weights vanish within R - 1/2 cells: the block around the nearest
        # node always holds that disc, so the fit moves continuously with p
        q = np.hypot(d[..., 0], d[..., 1]) / (R - 0.5)
        w = np.where(inside[ii, jj] & (q < 1.0), (1 - q) ** 4 * (1 + 4 * q), 0.0)
        B = np.stack([np.ones_like(q), d[..., 0], d[..., 1], d[..., 0] ** 2,
                      d[..., 0] * d[..., 1], d[..., 1] ** 2], axis=-1)     # (m, K, 6)
        BW = B * w[..., None]
        M = np.einsum("mki,mkj->mij", BW, B)
        M += 1e-12 * np.trace(M, axis1=1, axis2=2)[:, None, None] * np.eye(6)
        rhs = np.einsum("mki,mk->mi", BW, u[ii, jj])
        coef = np.linalg.solve(M, rhs[..., None])[..., 0]
        out[s:s + 8192] = coef[:, 1:3] / h
        # too few nodes inside (a corner, a thin strip, a ragged outline): the
        # fit extrapolates; such points keep the spline's gradient (NaN here)
        out[s:s + 8192][(w > 0).sum(axis=1) < ONE_SIDED_MIN_NODES] = np.nan
    return out


def natural_potentials(points, domain, sources: dict, spacing: float, *,
                       evaluation: str = "fft", cell_ratio: float = 1.0) -> dict:
    """Free-space potentials of ``sources`` (name -> values at ``points``, e.g.
    ``{"phi": div v, "psi": -curl v}``) over ``domain``: name -> ``(potential
    at the points, its gradient at the points)``.  ``evaluation``: ``fft`` or
    ``direct`` (module doc); ``cell_ratio``: grid cell size / data spacing."""
    if evaluation not in NATURAL_EVALUATIONS:
        raise ValueError(f"natural evaluation must be one of {NATURAL_EVALUATIONS}, "
                         f"got {evaluation!r}")
    grid = Grid(domain, cell_ratio * spacing)
    frac, offset = grid.coverage(domain, CUT_SUBSAMPLES, centroids=True)
    frac = frac.ravel()
    live = np.flatnonzero(frac > 0)
    names = list(sources)
    vals = np.stack([np.asarray(sources[k], dtype=np.float64) for k in names], axis=1)
    at_cells = reconstruct_on_grid(grid, points, vals, live)
    convolve = convolve_fft if evaluation == "fft" else convolve_direct
    cell = math.hypot(grid.hx, grid.hy) / math.sqrt(2.0)
    near = np.flatnonzero(domain.signed_distance(points) > -ONE_SIDED_CELLS * cell)
    inside = domain.contains(grid.centres()).reshape(grid.shape)
    out = {}
    for m, name in enumerate(names):
        dens = np.zeros(grid.nx * grid.ny)
        dens[live] = at_cells[:, m] * frac[live]
        dens = dens.reshape(grid.shape)
        # a cut cell's charge sits at its inside part's centroid, not at its
        # centre: the difference is a dipole p = q (centroid - centre), whose
        # potential is that of the density -div P (central differences)
        P = dens[..., None] * offset
        dipole = -(np.gradient(P[..., 0], grid.hx, axis=0)
                   + np.gradient(P[..., 1], grid.hy, axis=1))
        u = convolve(grid, dens + dipole)
        gradient = at_points(grid, grid_gradient(grid, u), points)
        fitted = one_sided_gradient(grid, u, inside, points[near])
        ok = np.isfinite(fitted).all(axis=1)
        gradient[near[ok]] = fitted[ok]
        out[name] = (at_points(grid, u, points), gradient)
    out["grid"] = grid
    return out
