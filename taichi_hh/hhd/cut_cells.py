"""The cells of the natural decomposition's grid that a polygon's boundary
cuts, exactly (:mod:`.natural`).

Each cut cell's inside part ``C ∩ Omega`` is described by its boundary: the
pieces of the domain's boundary segments inside the cell (split where they
cross the grid lines) and the parts of the cell's four sides that lie in the
domain, all oriented with the inside part on the left.  From that boundary
follow, exactly: the part's area and centroid (the shoelace sums), and the
integral of the free-space Green's function G = ln|x| / (2 pi) over the part
at any point, edge by edge in closed form (:func:`log_integral`).

Why: seen from the nodes next to it, a cut part's charge as a charge at its
cell's centre errs by the charge's higher moments, which at one cell's
distance are as large as the charge's own potential: the potential's
gradient then erred by O(h) within a few cells of a curved boundary (a disk:
4.2e-4, 2.2e-4, 9.2e-5 of |grad u| at 4k, 16k, 64k points).
:func:`near_field_correction` replaces, at the nodes within ``NEAR_CELLS``
of each cut cell, the grid's representation of that cell's charge by its
exact potential; beyond, the grid carries each part's moments up to
``MULTIPOLE_ORDER`` (:func:`multipole_patches`): what is left falls as the
distance's power MULTIPOLE_ORDER + 1 (a fourth-order dipole stencil alone
left the fifth moments, first order within a few cells: docs/notes/hhd.md).
"""
import math

import numpy as np

#: nodes within this many cells (each axis) of a cut cell see its exact
#: potential instead of the grid's charge and moments (beyond, their error
#: falls as the distance's power MULTIPOLE_ORDER + 1)
NEAR_CELLS = 4
#: each cut part's charge is put on the grid (:func:`multipole_patches`) with
#: its moments Q_0 .. Q_MULTIPOLE_ORDER: the part's potential beyond
#: NEAR_CELLS to that order
MULTIPOLE_ORDER = 7
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


def _touching(a, b, owner, on_entry, on_exit, h) -> tuple:
    """``(entries, exits)`` (boolean per piece): the pieces' ends on their
    cell's perimeter where the boundary only touches it, an exit and an
    entry of one cell at one point (within 1e-9 of a cell; e.g. a vertex on a
    grid corner, rounded to either side of the grid lines): no crossing, the
    perimeter's arcs keep their side.  Counted as crossings they made the
    walk leave out the arc after them (a disk's part 0.25 of its cell where
    0.997 is inside)."""
    entries, exits = np.flatnonzero(on_entry), np.flatnonzero(on_exit)
    by_owner = entries[np.argsort(owner[entries], kind="stable")]
    lo = np.searchsorted(owner[by_owner], owner[exits], "left")
    hi = np.searchsorted(owner[by_owner], owner[exits], "right")
    pairs = []
    for k in range(int((hi - lo).max(initial=0))):
        has = lo + k < hi
        j = by_owner[np.minimum(lo + k, len(by_owner) - 1)]
        close = has & (np.abs((b[exits] - a[j]) / h).max(axis=1) <= 1e-9)
        pairs += zip(exits[close].tolist(), j[close].tolist())
    # each end once; first the pieces that follow each other (the exit's
    # piece then the entry's), then any (a piece shorter than the tolerance)
    pairs.sort(key=lambda p: p[1] != p[0] + 1)
    touch_entry = np.zeros(len(a), dtype=bool)
    touch_exit = np.zeros(len(a), dtype=bool)
    for i, j in pairs:
        if not (touch_exit[i] or touch_entry[j]):
            touch_exit[i] = touch_entry[j] = True
    return touch_entry, touch_exit


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
    touch_entry, touch_exit = _touching(a, b, owner, on_entry, on_exit, h)
    on_entry &= ~touch_entry
    on_exit &= ~touch_exit
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
    # a cell no piece enters or leaves (a hole inside one cell, the boundary
    # touching a corner): inside when 3 of its 4 corners are (one may be
    # the touching point, on the boundary)
    no_events = src < 0
    if no_events.any():
        quiet = np.unique(o[no_events])
        votes = sum(domain.contains(corner[quiet] + np.array(c) * h).astype(int)
                    for c in ((0, 0), (1, 0), (0, 1), (1, 1)))
        inside_quiet = np.zeros(K, dtype=bool)
        inside_quiet[quiet] = votes >= 3
        status[no_events] = inside_quiet[o[no_events]]
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


def part_moments(grid, cut: CutCells, order: int) -> np.ndarray:
    """(K, order + 1) complex: each cut part's moments Q_n = int over the part
    of w^n dA, n = 0 .. ``order``, about its cell's centre in cell units: w =
    ((x - cx) + i (y - cy)) / hx, dA over the cell's area (Q_0 is the inside
    fraction).  By Green's theorem, int w^n dA = closed int conj(w) w^n dw /
    (2 i rho) along the part's boundary (inside on the left; rho = hy / hx,
    dA in cell units), each edge by Gauss-Legendre exact for the integrand's
    degree n + 1 along it.  They fix the part's potential outside a disc
    around it (Re sum_n Q_n G^(n) (-1)^n / n!, G's n-th complex derivative):
    what :func:`multipole_patches` matches on the grid."""
    h = np.array([grid.hx, grid.hy])
    ci, cj = np.divmod(cut.cells, grid.ny)
    centre = grid.origin + np.c_[ci, cj] * h
    wa = cut.starts - centre[cut.owner]
    wb = cut.ends - centre[cut.owner]
    wa = (wa[:, 0] + 1j * wa[:, 1]) / grid.hx
    wb = (wb[:, 0] + 1j * wb[:, 1]) / grid.hx
    t, wt = np.polynomial.legendre.leggauss(order // 2 + 2)
    t, wt = 0.5 * (t + 1.0), 0.5 * wt
    w = wa[:, None] + t[None, :] * (wb - wa)[:, None]                    # (E, G)
    base = np.conj(w) * wt[None, :] * (wb - wa)[:, None]
    rho = grid.hy / grid.hx
    out = np.empty((len(cut.cells), order + 1), dtype=np.complex128)
    power = np.ones_like(w)
    for n in range(order + 1):
        line = (base * power).sum(axis=1) / (2j * rho)
        out[:, n] = np.bincount(cut.owner, weights=line.real, minlength=len(cut.cells)) \
            + 1j * np.bincount(cut.owner, weights=line.imag, minlength=len(cut.cells))
        power = power * w
    return out


def cell_moments(hx: float, hy: float, order: int) -> np.ndarray:
    """(order + 1,) the moments mean of w^n over a cell about its centre, w as
    in :func:`part_moments` (the cell is 1 x hy / hx there): real, zero for
    odd n."""
    def mean_power(h, k):                        # mean of t^k over [-h/2, h/2]
        return 0.0 if k % 2 else (h / 2) ** k / (k + 1)

    rho = hy / hx
    return np.array([sum(math.comb(n, k) * mean_power(1.0, n - k) * mean_power(rho, k)
                         * (-1) ** (k // 2) for k in range(0, n + 1, 2))
                     for n in range(order + 1)])


def patch_solver(hx: float, hy: float, order: int) -> np.ndarray:
    """(25, 2 order + 1): the charges on the 5 x 5 nodes around a cell (index
    (i + 2) * 5 + j + 2 for the offset (i, j)) of least sum of squares whose
    moments Q_0 .. Q_order (real parts, then imaginary parts from n = 1) are
    given: the pseudo-inverse of the moments' matrix.  A grid charge q at a
    node z_k is spread uniformly over its cell (the kernel is the cell's
    average of G): its moments q sum_j C(n, j) z_k^(n - j) M_j, M the cell's
    (:func:`cell_moments`)."""
    k = np.arange(-2, 3)
    z = (k[:, None] + 1j * (hy / hx) * k[None, :]).ravel()
    M = cell_moments(hx, hy, order)
    rows = [sum(math.comb(n, j) * z ** (n - j) * M[j] for j in range(n + 1))
            for n in range(order + 1)]
    A = np.array([r.real for r in rows] + [r.imag for r in rows[1:]])
    return np.linalg.pinv(A)


def multipole_patches(grid, moments: np.ndarray) -> np.ndarray:
    """(K, 5, 5) each cut part's charge distribution on the 5 x 5 nodes around
    its cell, per unit density, beyond what the grid carries already (its
    charge Q_0 spread over the whole cell at its centre): the charges of
    least squares (:func:`patch_solver`) whose moments with that cell's are
    the part's, Q_0 .. Q_order of ``moments`` (:func:`part_moments`).  Seen
    from a node D cells away, the part's potential and the grid's then differ
    by their moments beyond ``order`` over D^(order + 1): at 5 cells 2e-5 of
    a charge's (order 7); the fourth-order dipole stencil alone left the
    fifth moment, 1e-3 (docs/notes/hhd.md)."""
    order = moments.shape[1] - 1
    rhs = moments - moments[:, :1] * cell_moments(grid.hx, grid.hy, order)[None, :]
    rhs = np.concatenate([rhs.real, rhs.imag[:, 1:]], axis=1)
    # einsum, not @: no BLAS call (its threads spin beside Taichi's workers)
    return np.einsum("kc,pc->kp", rhs, patch_solver(grid.hx, grid.hy, order)).reshape(-1, 5, 5)


def multipole_density(grid, cut: CutCells, patches: np.ndarray, density) -> np.ndarray:
    """(m, nx * ny) the cut parts' moments beyond the charge as charges on the
    grid: each cut cell's patch (:func:`multipole_patches`) times its value
    of ``density`` (m, nx * ny) scattered to the 5 x 5 nodes around it (the
    cut cells lie at least MARGIN = 3 cells inside the grid)."""
    ci, cj = np.divmod(cut.cells, grid.ny)
    k = np.arange(-2, 3)
    node = ((ci[:, None, None] + k[None, :, None]) * grid.ny
            + cj[:, None, None] + k[None, None, :]).ravel()
    rho = density[:, cut.cells]
    return np.stack([np.bincount(node, weights=(r[:, None, None] * patches).ravel(),
                                 minlength=grid.nx * grid.ny) for r in rho])


def near_field_correction(grid, cut: CutCells, patches, density) -> np.ndarray:
    """(m, nx * ny) what to add to the grid potentials of ``density`` (m, nx *
    ny: each cell's value, before its inside fraction) so that at the nodes
    within :data:`NEAR_CELLS` of each cut cell that cell's charge is seen
    exactly: its density times the integral of G over its inside part
    (:func:`log_integral`), less what the grid gives (the cell's charge
    ``cut.area`` at its centre and its moments' ``patches``
    (:func:`multipole_patches`) on the nodes around it, through the grid's
    kernel, :meth:`~.free_space.Grid.kernel_at`)."""
    m = density.shape[0]
    cells, owner = cut.cells, cut.owner
    K = len(cells)
    ci, cj = np.divmod(cells, grid.ny)
    centre = grid.origin + np.c_[ci * grid.hx, cj * grid.hy]
    R = NEAR_CELLS
    # the grid kernel at every offset a patch node reaches from a target
    reach = np.arange(-R - 2, R + 3)
    kern = np.array([[grid.kernel_at(int(i), int(j)) for j in reach] for i in reach])
    # at each target offset (di, dj): the charge's and each patch node's kernel
    n_off = 2 * R + 1
    windows = np.lib.stride_tricks.sliding_window_view(kern, (5, 5))     # [di, dj, i', j']
    # a patch node at +(i, j) is seen from the offset (di, dj) at (di - i, dj - j)
    windows = windows[:, :, ::-1, ::-1].reshape(n_off * n_off, 25)
    charge = cut.area / (grid.hx * grid.hy)
    grid_rep = charge[:, None] * kern[2:-2, 2:-2].reshape(1, -1) \
        + np.einsum("kc,oc->ko", patches.reshape(K, 25), windows)       # (K, n_off^2)
    # the exact integrals: the segments about their cell's centre, every target
    a = cut.starts - centre[owner]
    b = cut.ends - centre[owner]
    d = np.arange(-R, R + 1)
    exact = np.empty((K, n_off * n_off))
    for row, di in enumerate(d):                 # a row of targets at a time: in cache
        target = np.c_[np.full(n_off, di * grid.hx), d * grid.hy]
        ints = log_integral(target[:, None, :], a, b)                    # (n_off, E)
        for col, w in enumerate(ints):
            exact[:, row * n_off + col] = np.bincount(owner, weights=w, minlength=K)
    diff = exact / (2.0 * math.pi) - grid_rep                            # (K, n_off^2)
    di = np.repeat(d, n_off)
    dj = np.tile(d, n_off)
    i_node, j_node = ci[:, None] + di[None], cj[:, None] + dj[None]
    ok = (i_node >= 0) & (i_node < grid.nx) & (j_node >= 0) & (j_node < grid.ny)
    node = (i_node * grid.ny + j_node)[ok]
    rho = density[:, cells]
    return np.stack([np.bincount(node, weights=(r[:, None] * diff)[ok], minlength=grid.nx * grid.ny)
                     for r in rho]) if m else np.zeros((0, grid.nx * grid.ny))
