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
centres of a regular grid of cells about one data spacing wide, weighted by
the fraction of each cell inside Omega.  The default
(:func:`natural_decomposition`) takes them from the gradient of a cubic
moving-least-squares fit of v itself at each cell centre (no operator at
the points, no neighbour search); with other operator options the SPH
operators' div v and curl v at the points are reconstructed at the centres
by quadratic moving least squares (:func:`natural_potentials`).  Then the
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
import os
import time

import numpy as np
import taichi as ti

from .. import runtime
from ..geometry.box import Box
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

    def cell_index(self, points) -> np.ndarray:
        """(N,) flat index ``i * ny + j`` of the cell holding each point (points
        beyond the grid in its edge cells)."""
        lower = self.origin - 0.5 * np.array([self.hx, self.hy])
        ij = np.floor((points - lower) / [self.hx, self.hy]).astype(np.int64)
        np.clip(ij[:, 0], 0, self.nx - 1, out=ij[:, 0])
        np.clip(ij[:, 1], 0, self.ny - 1, out=ij[:, 1])
        return ij[:, 0] * self.ny + ij[:, 1]

    def coverage(self, domain, sub: int = 4, *, centroids: bool = False, inside: bool = False):
        """(nx, ny) fraction of each cell inside ``domain``, by ``sub`` x ``sub``
        subsamples for the cells the boundary may cross; with ``centroids``
        also (nx, ny, 2) the offset of the inside part's centroid from the
        cell centre (0 for whole and empty cells), from the same subsamples;
        with ``inside`` also (nx, ny) whether each cell centre is in the
        domain (``domain.contains``).

        An axis-aligned rectangle (a :class:`~taichi_hh.geometry.box.Box`)
        in closed form: its inside subsamples are a product of the inside
        columns and rows.  Other polygons: the cells the locator decides whole
        (inside or out) without a distance, the rest by the exact signed
        distance of the centre and, where the boundary may cross, the
        subsamples."""
        rect = _rectangle(domain)
        if rect is not None:
            frac, offset, centre_in = self._rectangle_coverage(rect, domain.boundary_tolerance,
                                                               sub)
        else:
            frac, offset, centre_in = self._polygon_coverage(domain, sub)
        out = (frac.reshape(self.shape),)
        if centroids:
            out += (offset.reshape(self.shape + (2,)),)
        if inside:
            out += (centre_in.reshape(self.shape),)
        return out[0] if len(out) == 1 else out

    def _subsample_offsets(self, sub: int):
        s = (np.arange(sub) + 0.5) / sub - 0.5
        return s * self.hx, s * self.hy

    def _rectangle_coverage(self, rect, eps: float, sub: int):
        """Rectangle ``((x0, y0), (x1, y1))``: a subsample is inside when its x
        and its y are (within ``eps``, the domain's boundary tolerance), so a
        cell's inside subsamples are the product of its inside columns and rows:
        the fraction is the product of the two counts, the centroid the pair of
        the two means."""
        (x0, y0), (x1, y1) = rect
        sx, sy = self._subsample_offsets(sub)
        parts = []
        for n, o, h, lo, hi, s in ((self.nx, self.origin[0], self.hx, x0, x1, sx),
                                   (self.ny, self.origin[1], self.hy, y0, y1, sy)):
            c = o + np.arange(n) * h                           # as centres() makes them
            coords = c[:, None] + s[None, :]
            ins = (coords >= lo - eps) & (coords <= hi + eps)
            count = ins.sum(axis=1)
            mean = np.where(count > 0, (ins * s).sum(axis=1) / np.maximum(count, 1), 0.0)
            mean[count == sub] = 0.0                       # whole columns: the centre
            centre_in = (c >= lo - eps) & (c <= hi + eps)
            parts.append((count, mean, centre_in))
        (cx, mx, ix), (cy, my, iy) = parts
        frac = (cx[:, None] * cy[None, :]).astype(np.float64) / (sub * sub)
        offset = np.zeros(self.shape + (2,))
        offset[..., 0] = np.where(frac > 0, mx[:, None], 0.0)
        offset[..., 1] = np.where(frac > 0, my[None, :], 0.0)
        offset[frac == 1.0] = 0.0
        return frac.ravel(), offset.reshape(-1, 2), (ix[:, None] & iy[None, :]).ravel()

    def _polygon_coverage(self, domain, sub: int):
        c = self.centres()
        half_diag = 0.5 * math.hypot(self.hx, self.hy)
        # 1: the disc of the half diagonal inside (a whole cell), 0: outside
        # (an empty cell), 2: the boundary may cross it
        status = domain.classify_discs(c, half_diag, -np.inf, 0.0)
        frac = (status == 1).astype(np.float64)
        centre_in = status == 1
        offset = np.zeros((len(c), 2))
        cut = np.flatnonzero(status == 2)
        if cut.size:
            centre_in[cut] = domain.contains(c[cut])
            sx, sy = self._subsample_offsets(sub)
            ox, oy = np.meshgrid(sx, sy, indexing="ij")
            offs = np.c_[ox.ravel(), oy.ravel()]
            sp = (c[cut][:, None, :] + offs[None, :, :]).reshape(-1, 2)
            inside = domain.contains(sp).reshape(len(cut), -1)
            frac[cut] = inside.mean(axis=1)
            count = inside.sum(axis=1)
            offset[cut] = (inside @ offs) / np.maximum(count, 1)[:, None]
        return frac, offset, centre_in

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

    def kernel(self, shape=None) -> np.ndarray:
        """(2 nx, 2 ny) the Green's function times the cell area at every offset
        of the zero-padded grid (wrapped: offset -k at index 2n - k), the cell's
        own integral at offset 0 (Hockney and Eastwood's free-space convolution).
        ``shape``: a larger padded grid (each side at least 2 n - 2; the offsets
        wrap at half of it)."""
        L1, L2 = (2 * self.nx, 2 * self.ny) if shape is None else shape
        ix = np.arange(L1)
        iy = np.arange(L2)
        ix = np.where(ix <= L1 // 2, ix, ix - L1) * self.hx
        iy = np.where(iy <= L2 // 2, iy, iy - L2) * self.hy
        r2 = ix[:, None] ** 2 + iy[None, :] ** 2
        r2[0, 0] = 1.0
        K = np.log(r2) / (4.0 * math.pi) * (self.hx * self.hy)
        K[0, 0] = self.self_integral()
        return K


def _rectangle(domain):
    """``((x0, y0), (x1, y1))`` when ``domain`` is an axis-aligned rectangle
    without holes (a Box, or a Polygon of those four corners), else None."""
    if isinstance(domain, Box):
        return domain.lo, domain.hi
    rings = getattr(domain, "rings", ())
    if len(rings) != 1 or len(rings[0]) != 4:
        return None
    (x0, y0), (x1, y1) = domain.bounds
    corners = {(x0, y0), (x1, y0), (x1, y1), (x0, y1)}
    if {(float(x), float(y)) for x, y in rings[0]} != corners:
        return None
    return (x0, y0), (x1, y1)


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


@ti.func
def _mls_reach(R, hx, hy):
    """The cells (i and j offsets from a node's own) that can hold points
    closer than ``R`` to the node at their centre: offset a holds none closer
    than (|a| - 1/2) cells (a radius of 2.5 cells: 5 x 5 cells, not 7 x 7)."""
    return (ti.cast(ti.ceil(R / hx + 0.5), ti.i32) - 1,
            ti.cast(ti.ceil(R / hy + 0.5), ti.i32) - 1)


@ti.func
def _mls_add(M, rhs, d, v):
    """One data point's terms of the normal equations: ``d`` its offset from the
    node over the radius, ``v`` its two values."""
    w = _mls_weight(d.norm())
    if w > 0.0:
        b = ti.Vector([1.0, d[0], d[1], d[0] * d[0], d[0] * d[1], d[1] * d[1]])
        M += w * b.outer_product(b)
        rhs += w * b.outer_product(v)
    return M, rhs


@ti.func
def _cholesky_solve(M, rhs, n: ti.template(), dt: ti.template(), floor: ti.template()):
    """x with M x = rhs for the symmetric positive n x n ``M`` and n x 2 ``rhs``
    in precision ``dt`` (Cholesky, the diagonal raised by 1e-12 of the trace
    and ``floor``)."""
    tr = ti.cast(0.0, dt)
    for a in ti.static(range(n)):
        tr += M[a, a]
    for a in ti.static(range(n)):
        M[a, a] += 1e-12 * tr + floor
    # Cholesky M = L L^T, then L y = rhs, L^T x = y
    L = ti.Matrix.zero(dt, n, n)
    for jj in ti.static(range(n)):
        s = M[jj, jj]
        for kk in ti.static(range(jj)):
            s -= L[jj, kk] * L[jj, kk]
        L[jj, jj] = ti.sqrt(ti.max(s, 1e-30))
        for ii in ti.static(range(jj + 1, n)):
            s2 = M[ii, jj]
            for kk in ti.static(range(jj)):
                s2 -= L[ii, kk] * L[jj, kk]
            L[ii, jj] = s2 / L[jj, jj]
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


@ti.kernel
def _mls_nodes(targets: ti.types.ndarray(), nx: ti.i32, ny: ti.i32, x0: float, y0: float,
               hx: float, hy: float, start: ti.types.ndarray(), pos: ti.types.ndarray(),
               vals: ti.types.ndarray(), out: ti.types.ndarray()):
    """Quadratic moving least squares of the two columns of ``vals`` at the
    centres of the ``targets`` cells, from the points (sorted by cell, ``start``
    the offsets) within the first radius of MLS_RADII holding MLS_MIN_POINTS;
    one gather per node, the 6 x 6 normal equations by Cholesky.  Each
    radius is counted and summed in one pass (the sums kept when the count
    suffices); the cells of one grid row are consecutive, their points one
    slot range."""
    h = ti.max(hx, hy)
    for t in range(targets.shape[0]):
        c = targets[t]
        ci = c // ny
        cj = c - ci * ny
        X = ti.Vector([x0 + ci * hx, y0 + cj * hy])
        M = ti.Matrix.zero(float, 6, 6)
        rhs = ti.Matrix.zero(float, 6, 2)
        done = False
        for a in ti.static(range(_N_RADII)):
            if not done:
                R = MLS_RADII[a] * h
                ri, rj = _mls_reach(R, hx, hy)
                M = ti.Matrix.zero(float, 6, 6)
                rhs = ti.Matrix.zero(float, 6, 2)
                count = 0
                for i in range(ti.max(ci - ri, 0), ti.min(ci + ri + 1, nx)):
                    row = i * ny
                    for k in range(start[row + ti.max(cj - rj, 0)],
                                   start[row + ti.min(cj + rj + 1, ny)]):
                        d = ti.Vector([pos[k, 0], pos[k, 1]]) - X
                        if d.dot(d) < R * R:
                            count += 1
                            M, rhs = _mls_add(M, rhs, d / R,
                                              ti.Vector([vals[k, 0], vals[k, 1]]))
                if count >= MLS_MIN_POINTS or a == _N_RADII - 1:
                    done = True
        x = _cholesky_solve(M, rhs, 6, float, 1e-30)
        out[t, 0] = x[0, 0]
        out[t, 1] = x[0, 1]


@ti.kernel
def _cell_counts(pts: ti.types.ndarray(), lx: ti.f64, ly: ti.f64, hx: ti.f64, hy: ti.f64,
                 nx: ti.i32, ny: ti.i32, cell: ti.types.ndarray(), count: ti.types.ndarray()):
    """cell[p]: the flat index of the grid cell holding point p (as
    :meth:`Grid.cell_index`); count[c + 1] += 1 for each."""
    for p in range(pts.shape[0]):
        fx = ti.math.clamp(ti.floor((pts[p, 0] - lx) / hx), 0.0, ti.cast(nx - 1, ti.f64))
        fy = ti.math.clamp(ti.floor((pts[p, 1] - ly) / hy), 0.0, ti.cast(ny - 1, ti.f64))
        c = ti.cast(fx, ti.i32) * ny + ti.cast(fy, ti.i32)
        cell[p] = c
        ti.atomic_add(count[c + 1], 1)


@ti.kernel
def _sort_by_cell(pts: ti.types.ndarray(), cell: ti.types.ndarray(), cursor: ti.types.ndarray(),
                  order: ti.types.ndarray(), out: ti.types.ndarray()):
    """The counting sort's stable scatter: point p to the next free slot of its
    cell (``cursor``: the cells' starts, advanced), in input order."""
    ti.loop_config(serialize=True)
    for p in range(pts.shape[0]):
        c = cell[p]
        k = cursor[c]
        cursor[c] = k + 1
        order[k] = p
        out[k, 0] = pts[p, 0]
        out[k, 1] = pts[p, 1]


class _Binned:
    """Points sorted by the grid's cells (a counting sort, stable):
    ``order`` (sorted -> input index), ``start`` (nx * ny + 1 offsets into the
    sorted points), ``points`` sorted."""

    def __init__(self, grid: "Grid", points):
        runtime.ensure_init()
        pts = np.ascontiguousarray(points, dtype=np.float64)
        n = len(pts)
        lower = grid.origin - 0.5 * np.array([grid.hx, grid.hy])
        count = np.zeros(grid.nx * grid.ny + 1, dtype=np.int32)
        self.order = np.empty(n, dtype=np.int64)
        self.points = np.empty((n, 2))
        if n:
            cell = np.empty(n, dtype=np.int32)
            _cell_counts(pts, float(lower[0]), float(lower[1]), grid.hx, grid.hy, grid.nx,
                         grid.ny, cell, count)
            np.cumsum(count, out=count)
            _sort_by_cell(pts, cell, count[:-1].copy(), self.order, self.points)
        self.start = count


def reconstruct_on_grid(grid: "Grid", points, values, live, *, binned=None) -> np.ndarray:
    """(len(live), m) the columns of ``values`` (N, m) reconstructed at the centres
    of the cells ``live`` (flat indices) by quadratic moving least squares
    (:func:`_mls_nodes`, two columns per pass, on numpy arrays in the
    runtime's precision).  ``binned``: the points already sorted by cell
    (:class:`_Binned`)."""
    runtime.ensure_init()
    npr = runtime.np_real()
    values = np.asarray(values, dtype=np.float64)
    values = values[:, None] if values.ndim == 1 else values
    if binned is None:
        binned = _Binned(grid, points)
    order = binned.order
    live = np.asarray(live, dtype=np.int32)
    out = np.zeros((len(live), values.shape[1]))
    if len(live) == 0 or len(order) == 0:
        return out
    pos = np.ascontiguousarray(binned.points, dtype=npr)
    res = np.empty((len(live), 2), dtype=npr)
    for m in range(0, values.shape[1], 2):
        pair = np.zeros((len(order), 2), dtype=npr)
        cols = values[order, m:m + 2]
        pair[:, :cols.shape[1]] = cols
        _mls_nodes(live, grid.nx, grid.ny, float(grid.origin[0]), float(grid.origin[1]),
                   grid.hx, grid.hy, binned.start, pos, pair, res)
        out[:, m:m + cols.shape[1]] = res[:, : cols.shape[1]]
    return out


# --------------------------------------------------------------------------- v fitted at nodes
#: the polynomial degree of the moving-least-squares fit of v at the grid
#: nodes whose gradient gives div v and curl v there
#: (:func:`natural_decomposition`): cubic, its gradient third order (a
#: quadratic's errs 4-8x more: windows at 15k random points d 0.039% against
#: 0.011%)
FIT_DEGREE = 3
#: the fit's radius in local spacings (:func:`_local_spacing`; cells on
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


def _monomials(p: int) -> list:
    """(a, b) of the monomials x^a y^b of degree <= p: 1, x, y, x^2, xy, y^2, ..."""
    return [(a, s - a) for s in range(p + 1) for a in range(s, -1, -1)]


_MONO = {p: _monomials(p) for p in (1, 2, 3)}
_MOMENTS = {p: _monomials(2 * p) for p in (1, 2, 3)}
#: the normal matrix's entry (i, j) is the moment of monomial i times monomial j
_GRAM = {p: [[_MOMENTS[p].index((a + c, b + d)) for (c, d) in _MONO[p]] for (a, b) in _MONO[p]]
         for p in (1, 2, 3)}
_RHS = {p: [_MOMENTS[p].index(m) for m in _MONO[p]] for p in (1, 2, 3)}


@ti.kernel
def _fit_gradients(targets: ti.types.ndarray(), nx: ti.i32, ny: ti.i32, lx: ti.f64,
                   ly: ti.f64, hx: ti.f64, hy: ti.f64, start: ti.types.ndarray(),
                   pos: ti.types.ndarray(), vals: ti.types.ndarray(), p: ti.template(),
                   radii: ti.types.vector(3, ti.f64), min_points: ti.i32, edge_degree: ti.i32,
                   scale: ti.types.ndarray(), edge: ti.types.ndarray(),
                   out: ti.types.ndarray()):
    """The gradients of the two columns of ``vals`` at each target (T, 2) from
    their weighted least-squares polynomial of degree ``p`` over the points
    (sorted by cell, ``start`` the offsets; ``lx``, ``ly`` the grid's lower
    corner) within the first of ``radii`` (times the target's ``scale``)
    holding ``min_points``: out[t] = (d0/dx, d0/dy, d1/dx, d1/dy, the points
    in the fit); a radius beyond the first at a target flagged ``edge``: at
    most ``edge_degree``; fewer points than a degree's monomials and two:
    the next lower degree.  One gather per
    target; the normal equations from the weighted moments of the offsets (a
    monomial pair's entry is one moment), solved by Cholesky."""
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
        kref = ti.min(start[ci * ny + cj], pos.shape[0] - 1)
        ref0 = vals[kref, 0]
        ref1 = vals[kref, 1]
        mom = ti.Vector.zero(ti.f64, NM)
        r0 = ti.Vector.zero(ti.f64, NB)
        r1 = ti.Vector.zero(ti.f64, NB)
        done = False
        count = 0
        R = ti.cast(1.0, ti.f64)
        a = 0
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
                    dx = (pos[k, 0] - X[0]) * inv
                    dy = (pos[k, 1] - X[1]) * inv
                    q2 = dx * dx + dy * dy
                    if q2 < 1.0:
                        count += 1
                        q = ti.sqrt(q2)
                        w = (1.0 - q) ** 4 * (1.0 + 4.0 * q)
                        px = ti.Vector.zero(ti.f64, 2 * p + 1)
                        py = ti.Vector.zero(ti.f64, 2 * p + 1)
                        px[0] = w
                        py[0] = 1.0
                        for e in ti.static(range(1, 2 * p + 1)):
                            px[e] = px[e - 1] * dx
                            py[e] = py[e - 1] * dy
                        inc = ti.Vector.zero(ti.f64, NM)
                        for m in ti.static(range(NM)):
                            inc[m] = px[ti.static(_MOMENTS[p][m][0])] \
                                * py[ti.static(_MOMENTS[p][m][1])]
                        mom += inc
                        v0 = vals[k, 0] - ref0
                        v1 = vals[k, 1] - ref1
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
        for q in ti.static(range(p, 0, -1)):
            nq = ti.static(len(_MONO[q]))
            if not solved and ((q <= top and count >= nq + 2) or q == 1):
                M = ti.Matrix.zero(ti.f64, nq, nq)
                rhs = ti.Matrix.zero(ti.f64, nq, 2)
                for m in ti.static(range(nq)):
                    rhs[m, 0] = r0[m]
                    rhs[m, 1] = r1[m]
                    for l in ti.static(range(nq)):
                        M[m, l] = mom[ti.static(_GRAM[p][m][l])]
                x = _cholesky_solve(M, rhs, nq, ti.f64, 1e-30)
                g = ti.Vector([x[1, 0], x[2, 0], x[1, 1], x[2, 1]]) / R
                solved = True
        for c in ti.static(range(4)):
            out[t, c] = g[c]
        out[t, 4] = count


def fit_gradients(grid: Grid, binned: "_Binned", values, targets, degree: int | None = None,
                  radii=None, min_points: int | None = None, *, counts: bool = False,
                  edge_degree: int | None = None, scale=None, edge=None):
    """(T, 2, 2) the gradients of the two columns of ``values`` (N, 2, in the
    order of ``binned.points``) at ``targets`` (T, 2): out[t, c] = grad of
    column c, from the moving-least-squares polynomial of ``degree`` (a
    Taichi kernel, :func:`_fit_gradients`; None: :data:`FIT_DEGREE`,
    :data:`FIT_RADII`, :data:`FIT_MIN_POINTS`, :data:`EDGE_DEGREE`); the
    radii in units of ``scale`` (T,) (None: the grid's cell) and ``edge``
    (T,) the targets next to the boundary (None: all); with ``counts`` also
    (T,) the points in each fit."""
    runtime.ensure_init()
    degree = FIT_DEGREE if degree is None else degree
    radii = FIT_RADII if radii is None else radii
    min_points = FIT_MIN_POINTS if min_points is None else min_points
    tg = np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 2)
    out = np.zeros((len(tg), 5))
    if len(tg) and len(binned.points):
        lower = grid.origin - 0.5 * np.array([grid.hx, grid.hy])
        _fit_gradients(tg, grid.nx, grid.ny, float(lower[0]), float(lower[1]), grid.hx,
                       grid.hy, binned.start, binned.points,
                       np.ascontiguousarray(values, dtype=np.float64), int(degree),
                       ti.Vector([float(r) for r in radii], dt=ti.f64), int(min_points),
                       int(EDGE_DEGREE if edge_degree is None else edge_degree),
                       np.ascontiguousarray(np.broadcast_to(max(grid.hx, grid.hy) if scale is None
                                                            else scale, len(tg)),
                                            dtype=np.float64),
                       np.ascontiguousarray(np.broadcast_to(True if edge is None else edge,
                                                            len(tg)), dtype=np.int32), out)
    grads = out[:, :4].reshape(-1, 2, 2)
    return (grads, out[:, 4]) if counts else grads


def fast_length(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n (a length the FFTs factor well)."""
    best = 1 << max(int(n) - 1, 0).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            q = p35
            while q < n:
                q *= 2
            best = min(best, q)
            p35 *= 3
        p5 *= 5
    return best


def _fft():
    """``(module, keywords)``: scipy.fft on every core where scipy is installed
    (a test and benchmark dependency, not a core one), numpy.fft otherwise."""
    try:
        import scipy.fft as sfft
    except ImportError:
        return np.fft, {}
    return sfft, {"workers": os.cpu_count() or 1}


#: the last grid's kernel spectrum (a decomposition at one size repeated, or a
#: series of fields on the same points, reuses it)
_SPECTRA: dict = {}


def _kernel_spectrum(grid: Grid, shape, fft, kw) -> np.ndarray:
    """The transform of :meth:`Grid.kernel` on the padded ``shape``: real (the
    kernel is even in both offsets), (L1, L2 // 2 + 1)."""
    key = (grid.nx, grid.ny, grid.hx, grid.hy, tuple(shape), fft.__name__)
    K = _SPECTRA.get(key)
    if K is None:
        K = np.ascontiguousarray(fft.rfft2(grid.kernel(shape), **kw).real)
        _SPECTRA.clear()
        _SPECTRA[key] = K
    return K


def convolve_fft(grid: Grid, density: np.ndarray) -> np.ndarray:
    """(nx, ny) sum over cells of G(x_a - x_b) density_b (times the cell area),
    by zero-padded FFT (the padding makes the circular convolution free-space);
    ``density`` (k, nx, ny) gives (k, nx, ny).  The padded sides are lengths
    the FFT factors well (:func:`fast_length`, at least 2 n - 1), the
    transforms skip the padding's zero rows on the way in and the unused rows
    on the way out."""
    nx, ny = grid.shape
    d = np.asarray(density, dtype=np.float64)
    one = d.ndim == 2
    d = d[None] if one else d
    fft, kw = _fft()
    L1, L2 = fast_length(2 * nx - 1), fast_length(2 * ny - 1)
    K = _kernel_spectrum(grid, (L1, L2), fft, kw)
    A = fft.rfft(d, n=L2, axis=2, **kw)
    A = fft.fft(A, n=L1, axis=1, **kw)
    A *= K
    A = fft.ifft(A, axis=1, **kw)[:, :nx]
    out = fft.irfft(A, n=L2, axis=2, **kw)[:, :, :ny]
    return out[0] if one else out


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
    g = np.empty(u.shape + (2,))
    for axis, h in ((0, grid.hx), (1, grid.hy)):
        d = np.gradient(u, h, axis=axis, edge_order=2)
        v = np.moveaxis(u, axis, 0)
        inner = np.moveaxis(d, axis, 0)
        inner[2:-2] = (-v[4:] + 8 * v[3:-1] - 8 * v[1:-3] + v[:-4]) / (12 * h)
        g[..., axis] = d
    return g


#: the cubic B-spline's interpolation pole (Unser et al. 1991): the
#: prefilter that makes the spline pass through the grid values
SPLINE_POLE = math.sqrt(3.0) - 2.0
#: edge cells replicated on each side before the prefilter (as
#: scipy.ndimage.map_coordinates(mode="nearest") pads): the filter's boundary
#: start decays as SPLINE_POLE ** distance, below round-off at the points
SPLINE_PAD = 12


@ti.kernel
def _spline_filter(c: ti.types.ndarray(), z: ti.f64):
    """The cubic B-spline prefilter in place along the middle axis of ``c``
    (A, n, B), every line (a, :, b) in parallel: the gain, the causal filter
    started exactly for the half-sample symmetric extension, the anticausal
    filter (as :func:`spline_coefficients_numpy`)."""
    A, n, B = c.shape[0], c.shape[1], c.shape[2]
    gain = (1.0 - z) * (1.0 - 1.0 / z)
    zn = ti.pow(z, ti.cast(n, ti.f64))
    for t in range(A * B):
        a = t // B
        b = t - a * B
        for i in range(n):
            c[a, i, b] *= gain
        # causal start: sum_i z^i c_i over the mirrored sequence, in closed form
        mirror = ti.f64(0.0)
        zi = ti.f64(1.0)
        for i in range(1, n):
            zi *= z
            mirror += zi * (c[a, i, b] + zn * c[a, n - 1 - i, b])
        c0 = c[a, 0, b]
        c[a, 0, b] = c0 + z / (1.0 - zn * zn) * (c0 + zn * c[a, n - 1, b] + mirror)
        for i in range(1, n):
            c[a, i, b] += z * c[a, i - 1, b]
        c[a, n - 1, b] *= z / (z - 1.0)                  # anticausal start
        for q in range(1, n):
            i = n - 1 - q
            c[a, i, b] = z * (c[a, i + 1, b] - c[a, i, b])


def spline_coefficients(u: np.ndarray) -> np.ndarray:
    """The cubic B-spline coefficients interpolating ``u`` (nx, ny[, m]) on
    its grid padded by ``SPLINE_PAD`` replicated edge values (a contiguous
    array): :func:`spline_coefficients_numpy`'s recursive filters in a
    Taichi kernel, every grid line in parallel."""
    runtime.ensure_init()
    pad = [(SPLINE_PAD, SPLINE_PAD)] * 2 + [(0, 0)] * (u.ndim - 2)
    c = np.pad(np.asarray(u, dtype=np.float64), pad, mode="edge")
    c3 = c.reshape(c.shape[0], c.shape[1], -1)
    if c3.size:
        _spline_filter(c3.reshape(1, c3.shape[0], -1), SPLINE_POLE)        # along x
        _spline_filter(c3, SPLINE_POLE)                                    # along y
    return c


def spline_coefficients_numpy(u: np.ndarray) -> np.ndarray:
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
               hx: ti.f64, hy: ti.f64, m: ti.template(), scatter: ti.template(),
               dest: ti.types.ndarray(), out: ti.types.ndarray()):
    """out[p, :] (with ``scatter``: out[dest[p], :]) = the tensor-product cubic
    B-spline of ``coef`` (NX, NY, m) at point p: the 4 x 4 knots around it
    (indices clamped: ``nearest``); the ``m`` columns of a knot read together."""
    NX, NY = coef.shape[0], coef.shape[1]
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
        acc = ti.Vector.zero(ti.f64, m)
        for a in ti.static(range(4)):
            i = ti.math.clamp(ix + a - 1, 0, NX - 1)
            row = ti.Vector.zero(ti.f64, m)
            for b in ti.static(range(4)):
                j = ti.math.clamp(iy + b - 1, 0, NY - 1)
                for col in ti.static(range(m)):
                    row[col] += wy[b] * coef[i, j, col]
            acc += wx[a] * row
        row_out = p
        if ti.static(scatter):
            row_out = ti.cast(dest[p], ti.i32)
        for col in ti.static(range(m)):
            out[row_out, col] = acc[col]


def at_points(grid: Grid, u: np.ndarray, points, *, dest=None) -> np.ndarray:
    """Grid values ``u`` (nx, ny[, m]) interpolated at ``points`` by the cubic
    B-spline through them (:func:`spline_coefficients`; the tensor product
    of the 4 x 4 knots around each point, one gather per point).  ``dest``:
    the row of the result each point's values go to (a permutation)."""
    runtime.ensure_init()
    c = spline_coefficients(u)
    c3 = c if c.ndim == 3 else c[..., None]
    pts = np.ascontiguousarray(points, dtype=np.float64)
    out = np.zeros((len(pts), c3.shape[2]))
    if len(pts):
        scatter = dest is not None
        rows = np.ascontiguousarray(dest, dtype=np.int64) if scatter else np.zeros(1, np.int64)
        _spline_at(c3, pts, float(grid.origin[0]), float(grid.origin[1]), grid.hx, grid.hy,
                   c3.shape[2], scatter, rows, out)
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


@ti.kernel
def _one_sided(u: ti.types.ndarray(), inside: ti.types.ndarray(), pts: ti.types.ndarray(),
               x0: ti.f64, y0: ti.f64, hx: ti.f64, hy: ti.f64, col: ti.i32,
               out: ti.types.ndarray()):
    """:func:`one_sided_gradient` of the columns ``col`` and ``col + 1`` of
    ``u`` (nx, ny, m) at each point: out[p, 0:2] and out[p, 2:4] (NaN where
    fewer than ONE_SIDED_MIN_NODES nodes carry weight)."""
    nx, ny = u.shape[0], u.shape[1]
    R = ONE_SIDED_REACH
    for p in range(pts.shape[0]):
        P = ti.Vector([pts[p, 0], pts[p, 1]], dt=ti.f64)
        # the nearest node
        ci = ti.cast(ti.math.clamp(ti.floor((P[0] - x0) / hx + 0.5), -1e9, 1e9), ti.i32)
        cj = ti.cast(ti.math.clamp(ti.floor((P[1] - y0) / hy + 0.5), -1e9, 1e9), ti.i32)
        M = ti.Matrix.zero(ti.f64, 6, 6)
        rhs = ti.Matrix.zero(ti.f64, 6, 2)
        count = 0
        for a in range(-R, R + 1):
            ii = ti.math.clamp(ci + a, 0, nx - 1)
            for b in range(-R, R + 1):
                jj = ti.math.clamp(cj + b, 0, ny - 1)
                dx = (x0 + ii * hx - P[0]) / hx                      # in cells
                dy = (y0 + jj * hy - P[1]) / hy
                q = ti.sqrt(dx * dx + dy * dy) / (R - 0.5)
                if inside[ii, jj] != 0 and q < 1.0:
                    w = (1.0 - q) ** 4 * (1.0 + 4.0 * q)
                    if w > 0.0:
                        count += 1
                    B = ti.Vector([1.0, dx, dy, dx * dx, dx * dy, dy * dy], dt=ti.f64)
                    v = ti.Vector([u[ii, jj, col], u[ii, jj, col + 1]], dt=ti.f64)
                    M += w * B.outer_product(B)
                    rhs += w * B.outer_product(v)
        for c in ti.static(range(4)):
            out[p, c] = ti.math.nan
        if count >= ONE_SIDED_MIN_NODES:
            x = _cholesky_solve(M, rhs, 6, ti.f64, 0.0)
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


class _Stopwatch:
    """Seconds per stage, each lap charged to the stage it names."""

    def __init__(self):
        self.seconds = {}
        self._t = time.perf_counter()

    def __call__(self, stage: str) -> None:
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._t
        self._t = now


def _check_evaluation(evaluation: str) -> None:
    if evaluation not in NATURAL_EVALUATIONS:
        raise ValueError(f"natural evaluation must be one of {NATURAL_EVALUATIONS}, "
                         f"got {evaluation!r}")


class _Cells:
    """The grid of a natural decomposition and its cells' coverage of the
    domain: ``frac`` (nx * ny,) inside fractions, ``offset`` the inside
    parts' centroids, ``inside`` (nx, ny) the centres inside, ``live`` the
    cells with a part inside (flat indices)."""

    def __init__(self, domain, cell: float):
        self.grid = grid = Grid(domain, cell)
        frac, self.offset, self.inside = grid.coverage(domain, CUT_SUBSAMPLES, centroids=True,
                                                       inside=True)
        self.frac = frac.ravel()
        self.live = np.flatnonzero(self.frac > 0)


def _grid_potentials(cells: _Cells, at_cells: np.ndarray, evaluation: str,
                     lap) -> np.ndarray:
    """(m, nx, ny) the free-space potentials of the densities ``at_cells``
    (len(live), m) at the live cells' centres: each cell's charge its value
    times its inside area, placed at its inside part's centroid (a dipole
    about the centre), summed against G by ``evaluation``."""
    grid, live = cells.grid, cells.live
    m = at_cells.shape[1]
    dens = np.zeros((m, grid.nx * grid.ny))
    dens[:, live] = (at_cells * cells.frac[live, None]).T
    dens = dens.reshape((m,) + grid.shape)
    # a cut cell's charge sits at its inside part's centroid, not at its
    # centre: the difference is a dipole p = q (centroid - centre), whose
    # potential is that of the density -div P (central differences)
    for k in range(m):
        dens[k] += _dipole_density(grid, dens[k], cells.offset)
    lap("density")
    if evaluation == "fft":
        u = convolve_fft(grid, dens)
    else:
        u = np.stack([convolve_direct(grid, d) for d in dens])
    lap("convolve")
    return u


def _at_points(cells: _Cells, u: np.ndarray, binned: "_Binned", domain, lap) -> tuple:
    """``(values, near)``: ``values`` (N, m, 3) each potential of ``u`` (m, nx,
    ny) and its gradient at the points (input order): the cubic spline of the
    potentials and their fourth-order grid gradients, the gradient within
    ONE_SIDED_CELLS of the boundary from the one-sided fit
    (:func:`one_sided_gradient`); ``near``: those points (sorted order)."""
    grid = cells.grid
    m = len(u)
    # every potential and its grid gradient, one spline through them all
    cols = np.empty(grid.shape + (3 * m,))
    for k in range(m):
        cols[..., 3 * k] = u[k]
        cols[..., 3 * k + 1:3 * k + 3] = grid_gradient(grid, u[k])
    sp = binned.points
    at = at_points(grid, cols, sp, dest=binned.order)           # in the input order
    lap("interpolate")
    # the gradient within ONE_SIDED_CELLS of the boundary from the fit
    cell = math.hypot(grid.hx, grid.hy) / math.sqrt(2.0)
    near = _near_boundary(domain, sp, ONE_SIDED_CELLS * cell)
    fitted = one_sided_gradient(grid, np.moveaxis(u, 0, -1), cells.inside, sp[near])
    ok = np.isfinite(fitted).all(axis=(1, 2))
    rows = binned.order[near[ok]]
    at = at.reshape(len(sp), m, 3)
    at[rows, :, 1:] = fitted[ok]
    lap("boundary_fit")
    return at, near


def natural_potentials(points, domain, sources: dict, spacing: float, *,
                       evaluation: str = "fft", cell_ratio: float = 1.0) -> dict:
    """Free-space potentials of ``sources`` (name -> values at ``points``, e.g.
    ``{"phi": div v, "psi": -curl v}``) over ``domain``: name -> ``(potential
    at the points, its gradient at the points)``.  ``evaluation``: ``fft`` or
    ``direct`` (module doc); ``cell_ratio``: grid cell size / data spacing.

    The points are sorted by grid cell once (the reconstruction's bins; the
    interpolation and the boundary fit then read the grid in order) and every
    potential goes through each stage at once: one FFT pass, one spline of
    all the potentials and their grid gradients, one boundary fit."""
    _check_evaluation(evaluation)
    lap = _Stopwatch()
    cells = _Cells(domain, cell_ratio * spacing)
    grid = cells.grid
    lap("coverage")
    names = list(sources)
    vals = np.stack([np.asarray(sources[k], dtype=np.float64) for k in names], axis=1)
    binned = _Binned(grid, points)
    lap("bins")
    at_cells = reconstruct_on_grid(grid, points, vals, cells.live, binned=binned)
    lap("reconstruct")
    u = _grid_potentials(cells, at_cells, evaluation, lap)
    at, _ = _at_points(cells, u, binned, domain, lap)
    out = {name: (at[:, m, 0].copy(), at[:, m, 1:].copy()) for m, name in enumerate(names)}
    lap("gather")
    out["grid"] = grid
    out["seconds"] = lap.seconds
    return out


#: the harmonic check fits h at about this many nodes at most (a regular
#: subgrid of the nodes inside: its means estimate the full grid's to a
#: fraction of a percent)
CHECK_NODES = 65536


class NaturalSplit:
    """The natural decomposition of a field at scattered points
    (:func:`natural_decomposition`), in the points' input order: ``phi``,
    ``psi`` (N,), ``d`` = grad phi, ``grad_psi`` (N, 2); ``divergence``,
    ``curl`` (N,) div v and curl v at the points; ``volume`` (N,) each point's
    share of the domain's area; ``grid``; ``mean_fit_points``: the mean
    number of data points in a node's fit; ``seconds`` by stage."""

    def __init__(self, **kw):
        self.__dict__.update(kw)

    def harmonic_ratios(self, h) -> tuple:
        """``(div, curl)``: mean |div h| and mean |curl h| over the mean of
        sqrt(div v^2 + curl v^2), the same fit (of h, at the same nodes) as
        div v's: the nodes with centres inside the domain, every k-th along
        each axis for at most about :data:`CHECK_NODES` of them."""
        t = time.perf_counter()
        b = self._binned
        hs = np.asarray(h, dtype=np.float64)[b.order]
        g = fit_gradients(self.grid, b, hs, self._check_nodes, scale=self._check_scale_of,
                          edge=self._check_edge)
        div_h = np.abs(g[:, 0, 0] + g[:, 1, 1]).mean()
        curl_h = np.abs(g[:, 1, 0] - g[:, 0, 1]).mean()
        self.seconds["harmonic"] = time.perf_counter() - t
        scale = self._check_scale
        return tuple(x / scale if scale > 0 else (0.0 if x == 0 else math.inf)
                     for x in (div_h, curl_h))


def natural_decomposition(points, vectors, domain, spacing: float, *,
                          evaluation: str = "fft", cell_ratio: float = 1.0) -> NaturalSplit:
    """The natural HHD of ``vectors`` (N, 2) at ``points`` over ``domain``
    (module doc) with div v and curl v taken at the grid nodes: the cubic
    moving-least-squares fit of v at each live cell's centre
    (:func:`fit_gradients`) gives its gradient there, so the densities
    need no operator at the points (and no neighbour search); the rest as
    :func:`natural_potentials`.  div v and curl v at the points (the
    result's, and the harmonic check's scale): the nodes' values by
    tensor cubic Lagrange interpolation, and within ONE_SIDED_CELLS of the
    boundary the fit of v at the point itself.  Returns a
    :class:`NaturalSplit`."""
    _check_evaluation(evaluation)
    lap = _Stopwatch()
    cells = _Cells(domain, cell_ratio * spacing)
    grid, live = cells.grid, cells.live
    lap("coverage")
    binned = _Binned(grid, points)
    vs = np.ascontiguousarray(np.asarray(vectors, dtype=np.float64)[binned.order])
    lap("bins")
    nodes = grid.centres()[live]
    spacing, edge = _local_spacing(cells, binned)
    g, count = fit_gradients(grid, binned, vs, nodes, counts=True, scale=spacing[live],
                             edge=edge[live])
    div = g[:, 0, 0] + g[:, 1, 1]
    curl = g[:, 1, 0] - g[:, 0, 1]
    lap("fit")
    u = _grid_potentials(cells, np.c_[div, -curl], evaluation, lap)
    at, near = _at_points(cells, u, binned, domain, lap)
    # div v and curl v at the points: the nodes' values inside, the fit at
    # the point near the boundary (the nodes around it partly outside)
    dc_grid = np.zeros((grid.nx * grid.ny, 2))
    dc_grid[live, 0], dc_grid[live, 1] = div, curl
    dc = _lagrange_at(grid, dc_grid.reshape(grid.shape + (2,)), binned.points, binned.order)
    if near.size:
        cell_of = np.repeat(np.arange(grid.nx * grid.ny), np.diff(binned.start))[near]
        gn = fit_gradients(grid, binned, vs, binned.points[near], scale=spacing[cell_of],
                           edge=edge[cell_of])
        dc[binned.order[near]] = np.c_[gn[:, 0, 0] + gn[:, 1, 1], gn[:, 1, 0] - gn[:, 0, 1]]
    lap("divergence")
    check = cells.inside.ravel()[live]
    if not check.any():
        check = np.ones(len(live), dtype=bool)
    # at most about CHECK_NODES of them: every k-th node along each axis
    k = max(1, math.ceil(math.sqrt(check.sum() / CHECK_NODES)))
    if k > 1:
        i, j = np.divmod(live, grid.ny)
        check &= (i % k == 0) & (j % k == 0)
    volume = _volumes(cells, binned)
    split = NaturalSplit(phi=at[:, 0, 0].copy(), d=at[:, 0, 1:].copy(),
                         psi=at[:, 1, 0].copy(), grad_psi=at[:, 1, 1:].copy(),
                         divergence=dc[:, 0].copy(), curl=dc[:, 1].copy(), volume=volume,
                         grid=grid, mean_fit_points=float(count.mean()) if count.size else 0.0,
                         _binned=binned, _check_nodes=nodes[check],
                         _check_scale_of=spacing[live][check], _check_edge=edge[live][check],
                         _check_scale=float(np.hypot(div[check], curl[check]).mean()))
    lap("gather")
    split.seconds = lap.seconds
    return split


def _box_sum(a: np.ndarray, k: int) -> np.ndarray:
    """(nx, ny) the sums of ``a`` over the (2k + 1) x (2k + 1) cells around each
    (zero beyond the grid), from the summed-area table."""
    nx, ny = a.shape
    c = np.pad(np.asarray(a, dtype=np.float64), ((k + 1, k), (k + 1, k))).cumsum(0).cumsum(1)
    w = 2 * k + 1
    return c[w:, w:] - c[:nx, w:] - c[w:, :ny] + c[:nx, :ny]


#: the local spacing of the fits: sqrt(inside area / points) over the
#: (2 LOCAL_CELLS + 1)^2 cells around a cell, where it exceeds SPARSE_RATIO
#: cells (sparse data), else the cell (the block counts' fluctuations on
#: uniform data would only add noise)
LOCAL_CELLS = 3
SPARSE_RATIO = 1.3


def _local_spacing(cells: _Cells, binned: "_Binned") -> tuple:
    """``(spacing, edge)``, (nx * ny,) each: the data's local spacing at each
    cell where the points are sparse, else the cell (the fits' radii are in
    these units: about 38 points in 3.5 of them where the data are uniform
    or sparse, as the SPH operators' adaptive supports); ``edge``: the cells within
    LOCAL_CELLS + 2 of a cell not wholly inside the domain."""
    grid = cells.grid
    count = _shared_counts(grid, binned.points)
    frac = cells.frac.reshape(grid.shape)
    area = _box_sum(frac, LOCAL_CELLS) * (grid.hx * grid.hy)
    spacing = np.sqrt(area / np.maximum(_box_sum(count, LOCAL_CELLS), 1.0))
    cell = max(grid.hx, grid.hy)
    spacing = np.where(spacing > SPARSE_RATIO * cell, spacing, cell)
    edge = _box_sum((frac < 1.0).astype(np.float64), LOCAL_CELLS + 2) > 0.5
    return spacing.ravel(), edge.ravel()


def _shared_counts(grid: "Grid", points) -> np.ndarray:
    """(nx, ny) the points per cell, each point shared between the four cell
    centres around it bilinearly (cloud in cell): a count that moves
    continuously with the points.  Binned whole, a point on a cell's edge (the
    extreme points of data whose bounding box is the domain lie on the
    outermost cells' edges) moved the local spacing by 4% under a move of
    1e-16, and the fits' radii with it (the fuzz suite's units property)."""
    t = (np.asarray(points, dtype=np.float64) - grid.origin) / np.array([grid.hx, grid.hy])
    low = np.floor(t)
    f = t - low
    low = low.astype(np.int64)
    out = np.zeros(grid.nx * grid.ny)
    for di in (0, 1):
        ii = np.clip(low[:, 0] + di, 0, grid.nx - 1)
        wx = f[:, 0] if di else 1.0 - f[:, 0]
        for dj in (0, 1):
            jj = np.clip(low[:, 1] + dj, 0, grid.ny - 1)
            wy = f[:, 1] if dj else 1.0 - f[:, 1]
            out += np.bincount(ii * grid.ny + jj, weights=wx * wy, minlength=out.size)
    return out.reshape(grid.shape)


def _volumes(cells: _Cells, binned: "_Binned") -> np.ndarray:
    """(N,) each point's area (input order): the inside area of the 3 x 3 cells
    around its own over the points in them."""
    grid = cells.grid
    count = np.diff(binned.start).reshape(grid.shape).astype(np.float64)
    area = (cells.frac * (grid.hx * grid.hy)).reshape(grid.shape)

    def box3(a):
        p = np.pad(a, 1)
        s = p[:-2] + p[1:-1] + p[2:]
        return s[:, :-2] + s[:, 1:-1] + s[:, 2:]

    per = box3(area) / np.maximum(box3(count), 1.0)
    cell_of = np.repeat(np.arange(grid.nx * grid.ny), np.diff(binned.start))
    out = np.empty(len(binned.order))
    out[binned.order] = per.ravel()[cell_of]
    return out


@ti.kernel
def _lagrange_kernel(u: ti.types.ndarray(), pts: ti.types.ndarray(), x0: ti.f64, y0: ti.f64,
                     hx: ti.f64, hy: ti.f64, dest: ti.types.ndarray(),
                     out: ti.types.ndarray()):
    """out[dest[p], :2] = the tensor cubic Lagrange interpolant of the two
    columns of ``u`` (nx, ny, 2) at point p from the 4 x 4 nodes around it
    (indices clamped)."""
    NX, NY = u.shape[0], u.shape[1]
    for p in range(pts.shape[0]):
        x = (pts[p, 0] - x0) / hx
        y = (pts[p, 1] - y0) / hy
        fx = ti.floor(x)
        fy = ti.floor(y)
        wx = _lagrange_weights(x - fx)
        wy = _lagrange_weights(y - fy)
        ix = ti.cast(ti.math.clamp(fx, -2.0, ti.cast(NX, ti.f64)), ti.i32)
        iy = ti.cast(ti.math.clamp(fy, -2.0, ti.cast(NY, ti.f64)), ti.i32)
        acc = ti.Vector.zero(ti.f64, 2)
        for a in ti.static(range(4)):
            i = ti.math.clamp(ix + a - 1, 0, NX - 1)
            row = ti.Vector.zero(ti.f64, 2)
            for b in ti.static(range(4)):
                j = ti.math.clamp(iy + b - 1, 0, NY - 1)
                row += wy[b] * ti.Vector([u[i, j, 0], u[i, j, 1]], dt=ti.f64)
            acc += wx[a] * row
        q = ti.cast(dest[p], ti.i32)
        out[q, 0] = acc[0]
        out[q, 1] = acc[1]


@ti.func
def _lagrange_weights(t):
    """The cubic Lagrange weights of the nodes -1, 0, 1, 2 at t in [0, 1)."""
    return ti.Vector([-t * (t - 1.0) * (t - 2.0) / 6.0, (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0,
                      -(t + 1.0) * t * (t - 2.0) / 2.0, (t + 1.0) * t * (t - 1.0) / 6.0],
                     dt=ti.f64)


def _lagrange_at(grid: Grid, u: np.ndarray, points, dest) -> np.ndarray:
    """(N, 2): :func:`_lagrange_kernel` of ``u`` (nx, ny, 2) at ``points``,
    point p's values in row ``dest[p]``."""
    runtime.ensure_init()
    pts = np.ascontiguousarray(points, dtype=np.float64)
    out = np.zeros((len(pts), 2))
    if len(pts):
        _lagrange_kernel(np.ascontiguousarray(u, dtype=np.float64), pts,
                         float(grid.origin[0]), float(grid.origin[1]), grid.hx, grid.hy,
                         np.ascontiguousarray(dest, dtype=np.int64), out)
    return out


def _dipole_density(grid: Grid, dens: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(nx, ny) -div P of the dipoles P = dens * offset by central differences:
    each cut cell's dipole scattered to its four neighbours (the cut cells lie
    at least MARGIN cells inside the grid, where numpy.gradient's differences
    are these), zero elsewhere."""
    out = np.zeros(grid.nx * grid.ny)
    k = np.flatnonzero((offset[..., 0] != 0) | (offset[..., 1] != 0))
    if k.size == 0:
        return out.reshape(grid.shape)
    q = dens.ravel()[k]
    for axis, step, h in ((0, grid.ny, grid.hx), (1, 1, grid.hy)):
        p = q * offset.reshape(-1, 2)[k, axis] / (2.0 * h)
        np.add.at(out, k - step, -p)          # -(P[i+1] - P[i-1]) / 2h at i = cell - 1
        np.add.at(out, k + step, p)
    return out.reshape(grid.shape)


def _near_boundary(domain, points, width: float) -> np.ndarray:
    """Indices of ``points`` whose signed distance exceeds ``-width`` (within
    ``width`` of the boundary, or outside): a rectangle in closed form, other
    polygons through the locator (exact distances only near the boundary)."""
    rect = _rectangle(domain)
    if rect is None:
        return np.flatnonzero(domain.classify_discs(points, 0.0, -np.inf, -width) != 1)
    (x0, y0), (x1, y1) = rect
    x, y = points[:, 0], points[:, 1]
    gap = np.minimum(np.minimum(x - x0, x1 - x), np.minimum(y - y0, y1 - y))
    return np.flatnonzero(gap < width)
