"""Exact k-nearest-neighbour search: for every query point, the indices of
(and distances to) its ``k`` nearest source points, nearest first.

The sources are sorted into square cells holding about ``POINTS_PER_CELL``
points each (a :class:`~taichi_hh.sph.neighbors.GridSpec`); a query scans the rings of
cells around its own, ring by ring, keeping its ``k`` best in registers,
until the k-th best distance is within the distance to the nearest side of
the block of cells scanned: every point not yet scanned lies beyond that
side, so the result is exact (ties in any order).  Distances and the
binning are float64 whatever the runtime's precision.
One gather per query, no atomics; the queries go in cell order (locality).
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import InputError
from .cell_sort import counting_sort
from .neighbors import GridSpec, cell_coords

#: the largest k (the k best are kept in registers per query)
MAX_K = 64
#: mean source points per cell: about two keeps the rings scanned for k ~ 20
#: to two (25 cells, ~50 points)
POINTS_PER_CELL = 2.0
#: the stopping radius is shrunk by this relative slack: a point placed a
#: rounding error into the wrong cell can never be missed
_SLACK = 1.0 - 1e-9
#: :meth:`KNearest.nearest_weights`: a neighbour's weight falls from 1 to 0
#: over this fraction of the distance to the first neighbour left out
NEAREST_TAPER = 0.05


@ti.kernel
def _k_nearest(k: ti.template(), nq: ti.i32, qpos: ti.types.ndarray(), qorder: ti.types.ndarray(),
               spos: ti.types.ndarray(),
               order: ti.types.ndarray(), start: ti.types.ndarray(), lo_x: ti.f64, lo_y: ti.f64,
               inv_cell: ti.f64, cell: ti.f64, nx: ti.i32, ny: ti.i32,
               dist: ti.types.ndarray(), idx: ti.types.ndarray(), last_only: ti.template()):
    """dist[q, :], idx[q, :]: the k nearest of the sources ``spos`` (sorted by
    cell, ``order`` their input indices, ``start`` the cell offsets) to
    ``qpos[q]``, nearest first; the queries are visited in the order
    ``qorder`` (by cell: neighbouring queries read the same sources).
    last_only: dist[q, 0] is the k-th distance alone (``idx`` not written)."""
    for slot in range(nq):
        q = qorder[slot]
        p = qpos[q]
        cx, cy = cell_coords(p, lo_x, lo_y, inv_cell, nx, ny)
        best = ti.Vector([ti.math.inf] * k, dt=ti.f64)
        bid = ti.Vector([-1] * k, dt=ti.i32)
        ring = 0
        more = True
        while more:
            for j in range(ti.max(cy - ring, 0), ti.min(cy + ring, ny - 1) + 1):
                edge = j == cy - ring or j == cy + ring
                row = j * nx
                # an edge row of the ring is one contiguous run of cells; a
                # middle row contributes its two end cells
                for side in ti.static(range(2)):
                    a = 0
                    b = 0
                    if edge:
                        if side == 0:
                            a = start[row + ti.max(cx - ring, 0)]
                            b = start[row + ti.min(cx + ring, nx - 1) + 1]
                    else:
                        i = cx - ring if side == 0 else cx + ring
                        if 0 <= i < nx:
                            a = start[row + i]
                            b = start[row + i + 1]
                    for m in range(a, b):
                        d = spos[m] - p
                        r2 = d.dot(d)
                        if r2 < best[k - 1]:
                            s = order[m]
                            # branch-free insertion: carry the larger pair on
                            for t in ti.static(range(k)):
                                closer = r2 < best[t]
                                r_keep = ti.select(closer, r2, best[t])
                                s_keep = ti.select(closer, s, bid[t])
                                r2 = ti.select(closer, best[t], r2)
                                s = ti.select(closer, bid[t], s)
                                best[t] = r_keep
                                bid[t] = s_keep
            # every unscanned point lies beyond the scanned block's nearest side
            # (sides at the grid's border have nothing beyond them)
            reach = ti.cast(ti.math.inf, ti.f64)
            if cx - ring > 0:
                reach = ti.min(reach, p[0] - (lo_x + (cx - ring) * cell))
            if cx + ring < nx - 1:
                reach = ti.min(reach, lo_x + (cx + ring + 1) * cell - p[0])
            if cy - ring > 0:
                reach = ti.min(reach, p[1] - (lo_y + (cy - ring) * cell))
            if cy + ring < ny - 1:
                reach = ti.min(reach, lo_y + (cy + ring + 1) * cell - p[1])
            if reach == ti.math.inf or best[k - 1] <= (reach * _SLACK) ** 2:
                more = False
            ring += 1
        if ti.static(last_only):
            dist[q, 0] = ti.sqrt(best[k - 1])
        else:
            for t in ti.static(range(k)):
                dist[q, t] = ti.sqrt(best[t])
                idx[q, t] = bid[t]


@ti.kernel
def _source_cells(pts: ti.types.ndarray(), lo_x: ti.f64, lo_y: ti.f64, inv_cell: ti.f64,
                  nx: ti.i32, ny: ti.i32, cell: ti.types.ndarray()):
    """cell[i]: the flat cell of source i (as :meth:`KNearest.cells`, float64)."""
    for i in range(pts.shape[0]):
        fx = ti.math.clamp(ti.floor((pts[i, 0] - lo_x) * inv_cell), 0.0, ti.cast(nx - 1, ti.f64))
        fy = ti.math.clamp(ti.floor((pts[i, 1] - lo_y) * inv_cell), 0.0, ti.cast(ny - 1, ti.f64))
        cell[i] = ti.cast(fy, ti.i32) * nx + ti.cast(fx, ti.i32)


class KNearest:
    """The sources binned once; :meth:`query` any number of query sets."""

    def __init__(self, points):
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or not len(pts):
            raise InputError(f"k-nearest search needs (N, 2) source points, got shape {pts.shape}")
        runtime.ensure_init()
        self.n = n = len(pts)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        wx, wy = hi - lo
        cell = math.sqrt(POINTS_PER_CELL * wx * wy / n)
        # degenerate extents (a line of points, one point): cells along the long side
        cell = max(cell, max(wx, wy) / n, 1e-300 + 1e-12 * float(np.abs(pts).max()))
        self.spec = GridSpec.covering(lo, hi, cell)
        # binned in float64 whatever the runtime's precision: the kernel's
        # stopping test relies on every source lying in its cell
        # a counting sort by cell (stable: the order of np.argsort(self.cells(pts),
        # kind="stable")), the sorted positions written straight to the kernel's array
        s = self.spec
        cell = np.empty(n, dtype=np.int32)
        _source_cells(pts, s.lo_x, s.lo_y, s.inv_cell, s.nx, s.ny, cell)
        order, start = counting_sort(cell, s.ncells)
        self._order = order
        self.pos = runtime.array(ti.f64, n, vector=2, zeroed=False)
        self.pos.from_numpy(pts[order])
        self.order = runtime.array(ti.i32, n, zeroed=False)
        self.order.from_numpy(order)
        self.start = runtime.array(ti.i32, len(start), zeroed=False)
        self.start.from_numpy(start)

    def cells(self, points) -> np.ndarray:
        """Flat cell index ``cy * nx + cx`` of every point (as ``cell_coords``
        bins them: clamped to the grid)."""
        s = self.spec
        c = np.floor((points - [s.lo_x, s.lo_y]) * s.inv_cell)
        cx = np.clip(c[:, 0], 0, s.nx - 1).astype(np.int64)
        cy = np.clip(c[:, 1], 0, s.ny - 1).astype(np.int64)
        return cy * s.nx + cx

    def query(self, targets, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices), each (len(targets), k): the k nearest sources
        of every target, nearest first."""
        tg = np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 2)
        if not 1 <= k <= min(self.n, MAX_K):
            raise InputError(f"k nearest neighbours: k must be 1..{min(self.n, MAX_K)} "
                             f"({self.n} source points), got {k}")
        nq = len(tg)
        if nq == 0:
            return np.zeros((0, k)), np.zeros((0, k), dtype=np.int64)
        qpos = runtime.array(ti.f64, nq, vector=2)
        qpos.from_numpy(tg)
        qorder = runtime.array(ti.i32, nq)
        qorder.from_numpy(np.argsort(self.cells(tg), kind="stable").astype(np.int32))
        dist = runtime.array(ti.f64, (nq, k))
        idx = runtime.array(ti.i32, (nq, k))
        s = self.spec
        _k_nearest(k, nq, qpos, qorder, self.pos, self.order, self.start, s.lo_x, s.lo_y, s.inv_cell,
                   s.cell_size, s.nx, s.ny, dist, idx, False)
        return dist.to_numpy(), idx.to_numpy().astype(np.int64)

    def nearest_weights(self, targets, m: int,
                        taper: float = NEAREST_TAPER) -> tuple[np.ndarray, np.ndarray]:
        """(indices, weights), each (len(targets), m): every target's ``m``
        nearest sources and weights summing to 1 that make ``(weights *
        values[indices]).sum(axis=1)`` a mean of per-source values over the m
        nearest which is continuous in the targets and the sources.

        The plain mean over the m nearest is not: where the m-th and the
        (m+1)-th nearest are equally far (a target midway between two points
        of a lattice), rounding picks which one enters the mean, and the mean
        jumps by the difference of their values / m under a move of one ulp.
        Here a neighbour's weight is 1 up to ``(1 - taper)`` times the
        distance ``R`` of the (m+1)-th nearest (the first left out) and falls
        linearly to 0 at ``R``: two neighbours tied at a rank have the same
        weight (whichever order the search returns them in), and the one that
        leaves the m nearest has weight 0 as it goes.  The taper is narrowed
        to ``R - d_1`` where the nearest is within it, so that it keeps weight
        1; only where all m + 1 nearest are equally far (the search then
        leaves out an arbitrary one of them) is the weight 1 for all m.  With
        ``m`` at least the number of sources: all of them, equal weights."""
        tg = np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 2)
        if not 1 <= m <= MAX_K - 1:
            raise InputError(f"nearest weights: m must be 1..{MAX_K - 1}, got {m}")
        if m >= self.n:
            idx = np.broadcast_to(np.arange(self.n), (len(tg), self.n)).copy()
            return idx, np.full(idx.shape, 1.0 / self.n)
        d, idx = self.query(tg, m + 1)
        far = d[:, m:]                                  # the first left out
        width = np.minimum(taper * far, far - d[:, :1])
        w = np.ones((len(tg), m))
        ok = width[:, 0] > 0
        w[ok] = np.clip((far[ok] - d[ok, :m]) / width[ok], 0.0, 1.0)
        return idx[:, :m], w / w.sum(axis=1, keepdims=True)

    def kth_distance_among(self, k: int) -> np.ndarray:
        """Distance from every source point to its k-th nearest other source
        point (input order): the (k+1)-th nearest source, the point itself
        (distance 0) being among them.  Only the distances leave the kernel."""
        if not 1 <= k + 1 <= min(self.n, MAX_K):
            raise InputError(f"k-th nearest other point: k must be 1..{min(self.n, MAX_K) - 1} "
                             f"({self.n} points), got {k}")
        # the sources are their own queries, already sorted by cell: slot order
        # is query order, and the sorted positions serve as the query positions
        dist = runtime.array(ti.f64, (self.n, 1))
        s = self.spec
        _k_nearest(k + 1, self.n, self.pos, self._slots(), self.pos, self.order, self.start,
                   s.lo_x, s.lo_y, s.inv_cell, s.cell_size, s.nx, s.ny, dist, self._no_idx(),
                   True)
        out = np.empty(self.n)
        out[self._order] = dist.to_numpy()[:, 0]
        return out

    def _slots(self):
        slots = runtime.array(ti.i32, self.n)
        slots.from_numpy(np.arange(self.n, dtype=np.int32))
        return slots

    @staticmethod
    def _no_idx():
        return runtime.array(ti.i32, (1, 1))


def k_nearest(points, targets, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(distances, indices), each (len(targets), k): the ``k`` nearest of
    ``points`` to every target, nearest first (exact; module doc)."""
    return KNearest(points).query(targets, k)
