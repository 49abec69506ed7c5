"""Quadratic moving least squares of scattered values: reconstructed at the
centres of a grid's cells (:func:`reconstruct_on_grid`: the natural
decomposition's densities from the SPH operators' div v and curl v,
:func:`.natural.natural_potentials`) or, in the k-nearest-neighbour form
for few targets, anywhere (:func:`mls_at`).  The points binned by the
grid's cells as the fits of :mod:`.node_fits` bin them
(:class:`~.node_fits.PointBins`)."""
import numpy as np
import taichi as ti

from .. import runtime
from ..sph.knn import KNearest
from .free_space import Grid
from .node_fits import PointBins, cholesky_solve

#: data points in each quadratic moving-least-squares fit at a grid node
MLS_NEIGHBOURS = 20


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
        x = cholesky_solve(M, rhs, 6, float, 1e-30)
        out[t, 0] = x[0, 0]
        out[t, 1] = x[0, 1]



def reconstruct_on_grid(grid: "Grid", points, values, live, *, binned=None) -> np.ndarray:
    """(len(live), m) the columns of ``values`` (N, m) reconstructed at the centres
    of the cells ``live`` (flat indices) by quadratic moving least squares
    (:func:`_mls_nodes`, two columns per pass, on numpy arrays in the
    runtime's precision).  ``binned``: the points already sorted by cell
    (:class:`PointBins`)."""
    runtime.ensure_init()
    npr = runtime.np_real()
    values = np.asarray(values, dtype=np.float64)
    values = values[:, None] if values.ndim == 1 else values
    if binned is None:
        binned = PointBins(grid, points)
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
