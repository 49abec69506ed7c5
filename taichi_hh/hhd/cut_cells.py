"""The cells of the natural decomposition's grid that a polygon's boundary
cuts, exactly (:mod:`.natural`).

Each cut cell's inside part ``C ∩ Omega`` is described by its boundary: the
pieces of the domain's boundary segments inside the cell (split where they
cross the grid lines) and the parts of the cell's four sides that lie in the
domain, all oriented with the inside part on the left.  From that boundary
follow, exactly: the part's area and centroid (the shoelace sums), and the
integral of the free-space Green's function G = ln|x| / (2 pi) over the part
at any point, edge by edge in closed form (:func:`log_integral`).

Why: the grid carries a cut cell's charge as a charge at the cell's centre
plus a dipole to its centroid (:func:`~.free_space.dipole_density`).  Seen
from the nodes next to the cell that representation errs by the charge's
higher moments, which at one cell's distance are as large as the charge's
own potential: the potential's gradient then errs by O(h) within a few cells
of a curved boundary (a disk: 4.2e-4, 2.2e-4, 9.2e-5 of |grad u| at 4k, 16k,
64k points, first order).  :func:`near_field_correction` replaces, at the
nodes within ``NEAR_CELLS`` of each cut cell, the grid's representation of
that cell's charge by its exact potential (docs/notes/hhd.md).
"""
import math

import numpy as np

from .free_space import DIPOLE_STENCIL

#: nodes within this many cells (each axis) of a cut cell see its exact
#: potential instead of the grid's charge-and-dipole (beyond, the dipole's
#: error falls as the cube of the distance)
NEAR_CELLS = 4
#: a segment's piece shorter than this fraction of a cell is dropped (a vertex
#: on a grid line splits a segment there)
_TINY = 1e-12


class CutCells:
    """The cut cells of a grid (``cells``: flat indices ``i * ny + j``) and
    the boundary of each one's inside part: segments ``starts`` to ``ends``
    (E, 2) with ``owner`` (E,) the position in ``cells`` of each; ``area``
    (K,) and ``centroid`` (K, 2) of the inside parts."""

    def __init__(self, cells, owner, starts, ends, area, centroid):
        self.cells, self.owner, self.starts, self.ends = cells, owner, starts, ends
        self.area, self.centroid = area, centroid


def _segment_pieces(grid, starts, ends, lower):
    """The domain's segments split where they cross the grid lines: ``(cell,
    a, b)``, each piece's cell (flat index) and its two ends, in the
    segment's direction.  A segment along a grid line (a polygon aligned with
    the grid) cuts no cell: it is left out."""
    h = np.array([grid.hx, grid.hy])
    p0 = (starts - lower) / h                      # in cell units
    p1 = (ends - lower) / h
    ts = [np.zeros((len(p0), 1)), np.ones((len(p0), 1))]
    seg_of = [np.arange(len(p0))] * 2
    for axis in (0, 1):
        a, b = p0[:, axis], p1[:, axis]
        first = np.floor(np.minimum(a, b)) + 1.0
        last = np.ceil(np.maximum(a, b)) - 1.0
        count = np.maximum(last - first + 1.0, 0.0).astype(np.int64)
        seg = np.repeat(np.arange(len(p0)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        line = first[seg] + k
        ts.append(((line - a[seg]) / (b[seg] - a[seg]))[:, None])
        seg_of.append(seg)
    seg = np.concatenate(seg_of)
    t = np.concatenate(ts)[:, 0]
    order = np.lexsort((t, seg))
    seg, t = seg[order], t[order]
    same = seg[1:] == seg[:-1]
    s, t0, t1 = seg[:-1][same], t[:-1][same], t[1:][same]
    d = p1[s] - p0[s]
    keep = (t1 - t0) * np.hypot(d[:, 0], d[:, 1]) > _TINY
    s, t0, t1 = s[keep], t0[keep], t1[keep]
    d = d[keep]
    mid = p0[s] + 0.5 * (t0 + t1)[:, None] * d
    # along a grid line: the segment is parallel to an axis and lies on a line
    on_line = np.zeros(len(s), dtype=bool)
    for axis in (0, 1):
        c = mid[:, axis]
        on_line |= (np.abs(d[:, axis]) <= _TINY * np.abs(d).max(axis=1)) & \
            (np.abs(c - np.round(c)) <= 1e-9)
    s, t0, t1, mid = s[~on_line], t0[~on_line], t1[~on_line], mid[~on_line]
    ij = np.floor(mid).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < grid.nx) & (ij[:, 1] >= 0) & (ij[:, 1] < grid.ny)
    s, t0, t1, ij = s[inside], t0[inside], t1[inside], ij[inside]
    cell = ij[:, 0] * grid.ny + ij[:, 1]
    seg_d = ends[s] - starts[s]
    return cell, starts[s] + t0[:, None] * seg_d, starts[s] + t1[:, None] * seg_d


def cut_cells(grid, domain) -> CutCells | None:
    """The cells of ``grid`` that the boundary of the polygon ``domain`` cuts,
    with the boundary of each one's inside part (module doc); None when it
    cuts none."""
    starts, ends = domain.segments()
    h = np.array([grid.hx, grid.hy])
    lower = grid.origin - 0.5 * h
    cell, a, b = _segment_pieces(grid, starts, ends, lower)
    if len(cell) == 0:
        return None
    cells, owner = np.unique(cell, return_inverse=True)
    ci, cj = np.divmod(cells, grid.ny)
    corner = lower + np.c_[ci, cj] * h                       # each cut cell's lower left
    K = len(cells)
    # Walking each cell's perimeter counter-clockwise, the inside part's
    # boundary runs along it from where a piece leaves the cell to where the
    # next one enters (the inside on the left of both): the perimeter's
    # parts from an exit to the next entry belong to it.  Positions on the
    # perimeter as P in [0, 4): bottom, right, top, left side.
    tol = 1e-9

    def perimeter(p, own):
        u, v = ((p - corner[own]) / h).T
        P = np.full(len(p), np.nan)
        for on, at in ((u <= tol, 3.0 + (1.0 - v)), (v >= 1 - tol, 2.0 + (1.0 - u)),
                       (u >= 1 - tol, 1.0 + v), (v <= tol, u)):
            P = np.where(on, at, P)
        return P

    P_entry, P_exit = perimeter(a, owner), perimeter(b, owner)
    on_entry, on_exit = ~np.isnan(P_entry), ~np.isnan(P_exit)
    corners = np.arange(5.0)
    o = np.concatenate([owner[on_exit], owner[on_entry], np.repeat(np.arange(K), 5)])
    P = np.concatenate([P_exit[on_exit], P_entry[on_entry], np.tile(corners, K)]) % 4.0
    P[len(P) - 5 * K:] = np.tile(corners, K)                 # the closing corner stays at 4
    kind = np.concatenate([np.ones(on_exit.sum()), -np.ones(on_entry.sum()), np.zeros(5 * K)])
    order = np.lexsort((-kind, P, o))
    o, P, kind = o[order], P[order], kind[order]
    n = len(o)
    idx = np.arange(n)
    group_start = np.r_[0, np.flatnonzero(o[1:] != o[:-1]) + 1]
    first_of = np.repeat(group_start, np.diff(np.r_[group_start, n]))
    last_event = np.maximum.accumulate(np.where(kind != 0, idx, -1))
    # before a cell's first event: its last one (the walk is a loop)
    cell_last = np.maximum.reduceat(np.where(kind != 0, idx, -1), group_start)
    src = np.where(last_event >= first_of, last_event, np.repeat(cell_last, np.diff(np.r_[group_start, n])))
    status = np.where(src >= 0, kind[np.maximum(src, 0)] > 0, False)
    # a cell no piece enters or leaves (a hole inside one cell): its corner
    no_events = src < 0
    if no_events.any():
        status[no_events] = domain.contains(corner[o[no_events]])
    same = (o[1:] == o[:-1]) & (P[1:] - P[:-1] > _TINY) & status[:-1]
    o, P0, P1 = o[:-1][same], P[:-1][same], P[1:][same]
    side = np.minimum(np.floor(P0), 3).astype(np.int64)
    start = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    direc = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    s0 = corner[o] + (start[side] + (P0 - side)[:, None] * direc[side]) * h
    s1 = corner[o] + (start[side] + (P1 - side)[:, None] * direc[side]) * h
    owner = np.concatenate([owner, o])
    a = np.concatenate([a, s0])
    b = np.concatenate([b, s1])
    # area and centroid by the shoelace sums, about each cell's centre
    centre = corner + 0.5 * h
    ra, rb = a - centre[owner], b - centre[owner]
    cross = ra[:, 0] * rb[:, 1] - ra[:, 1] * rb[:, 0]
    # a sliver's area rounds to about -1e-12 of the cell's: none is negative
    area = np.maximum(np.bincount(owner, weights=cross, minlength=K) / 2.0, 0.0)
    mom = np.stack([np.bincount(owner, weights=cross * (ra[:, c] + rb[:, c]), minlength=K)
                    for c in (0, 1)], axis=1) / 6.0
    centroid = centre + mom / np.where(area > 0, area, 1.0)[:, None]
    return CutCells(cells, owner, a, b, area, centroid)


def log_integral(x, a, b) -> np.ndarray:
    """The signed integral of ln|y - x| over the triangle (x, a, b), for targets
    ``x`` (..., E, 2) and edges ``a`` -> ``b`` (E, 2): in polar coordinates
    about x, with d the edge's signed distance (positive when x is on its
    left) and s the position along it from the foot of the perpendicular,
    (1/2) [d s (ln r - 3/2) + d^2 atan(s / d)] from a to b.  Summed over a
    closed boundary (inside on the left) it is the integral of ln|y - x| over
    the region, for x anywhere."""
    e = b - a
    length = np.hypot(e[:, 0], e[:, 1])
    e = e / np.where(length > 0, length, 1.0)[:, None]
    ra, rb = a - x, b - x
    d = ra[..., 0] * e[:, 1] - ra[..., 1] * e[:, 0]
    safe_d = np.where(d != 0, d, 1.0)

    def primitive(r):
        s = (r * e).sum(axis=-1)
        dist = np.hypot(r[..., 0], r[..., 1])
        lnr = np.log(np.where(dist > 0, dist, 1.0))
        return d * s * (lnr - 1.5) + d * d * np.where(d != 0, np.arctan(s / safe_d), 0.0)

    return 0.5 * (primitive(rb) - primitive(ra))


def near_field_correction(grid, cut: CutCells, frac, offset, density) -> np.ndarray:
    """(m, nx * ny) what to add to the grid potentials of ``density`` (m, nx *
    ny: each cell's value, before its inside fraction ``frac``) so that at
    the nodes within :data:`NEAR_CELLS` of each cut cell that cell's charge
    is seen exactly: its density times the integral of G over its inside part
    (:func:`log_integral`), less what the grid gives (the cell's charge at its
    centre through the grid's kernel, :meth:`~.free_space.Grid.kernel_at`,
    and the dipole to its centroid ``offset``, as
    :func:`~.free_space.dipole_density` spreads it)."""
    m = density.shape[0]
    out = np.zeros((m, grid.nx * grid.ny))
    cells, owner = cut.cells, cut.owner
    ci, cj = np.divmod(cells, grid.ny)
    centre = grid.origin + np.c_[ci * grid.hx, cj * grid.hy]
    kernel = grid.kernel_at
    q = frac[cells]
    px = q * offset[cells, 0] / grid.hx
    py = q * offset[cells, 1] / grid.hy
    rho = density[:, cells]
    # the segments about their cell's centre, the offsets' targets about it too
    a = cut.starts - centre[owner]
    b = cut.ends - centre[owner]
    R = NEAR_CELLS
    K = len(cells)
    for di in range(-R, R + 1):
        dj = np.arange(-R, R + 1)
        target = np.stack([np.full(len(dj), di * grid.hx), dj * grid.hy], axis=1)
        ints = log_integral(target[:, None, :], a, b)                    # (2R + 1, E)
        exact = np.stack([np.bincount(owner, weights=w, minlength=K) for w in ints])
        exact /= 2.0 * math.pi
        for row, j in enumerate(dj):
            j = int(j)
            grid_rep = q * kernel(di, j)
            # the dipole: -w p at the cells before, +w p at the cells after, each axis
            for step, w in DIPOLE_STENCIL:
                grid_rep = grid_rep + w * (px * (kernel(di - step, j) - kernel(di + step, j))
                                           + py * (kernel(di, j - step) - kernel(di, j + step)))
            i_node, j_node = ci + di, cj + j
            ok = (i_node >= 0) & (i_node < grid.nx) & (j_node >= 0) & (j_node < grid.ny)
            node = (i_node * grid.ny + j_node)[ok]
            diff = (exact[row] - grid_rep)[ok]
            # one offset sends each cut cell to its own node: no repeated index
            out[:, node] += rho[:, ok] * diff
    return out
