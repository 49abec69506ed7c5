"""The noise and the white-noise spreads the grid's critical points weigh
their significance by (:func:`~.critical_grid.find_grid_critical_points`):
the data's noise from a fixed quadratic filter over each sampled node's 20
nearest nodes (:func:`grid_noise_sigma`), and the rows of the operator whose
values the significance averages over discs (:class:`GridRows`)."""
import numpy as np

from .critical import NOISE_SAMPLES, noise_sigma

__all__ = ["window", "grid_noise_sigma", "noise_rows", "median", "NOISE_REACH", "noise_filter",
           "GridRows"]


def window(j, i, Ry, Rx, ny, nx):
    """``(grid slice, window shape, slice of the full window)`` of the nodes
    within Ry rows and Rx columns of (j, i), clipped to the grid."""
    j0, j1 = max(j - Ry, 0), min(j + Ry + 1, ny)
    i0, i1 = max(i - Rx, 0), min(i + Rx + 1, nx)
    return ((slice(j0, j1), slice(i0, i1)), (j1 - j0, i1 - i0),
            (slice(j0 - (j - Ry), j1 - (j - Ry)), slice(i0 - (i - Rx), i1 - (i - Rx))))


def grid_noise_sigma(lat, samples: int = NOISE_SAMPLES, *, geometry=None) -> float:
    """:func:`noise_sigma` on a grid: the quadratic moving-least-squares fit
    to each sampled node's 20 nearest nodes (itself left out; Wendland
    weights on the distance over 1.5 times the 20th), a fixed filter at the
    nodes whose 20 neighbours are all used; where fewer than a tenth of the
    samples have them, :func:`noise_sigma` of the used nodes.  ``geometry``:
    the grid's :class:`~.critical_grid.CriticalGeometry` if made already."""
    filt, centre, rows = (geometry.noise_filter(samples) if geometry is not None
                          else noise_filter(lat.used, lat.hx, lat.hy, samples))
    if filt is None:
        flat = np.flatnonzero(lat.used.ravel())
        nx = lat.used.shape[1]
        vec = np.stack([lat.u, lat.v], axis=-1).reshape(-1, 2)
        return noise_sigma(np.c_[lat.x[np.divmod(flat, nx)[1]], lat.y[np.divmod(flat, nx)[0]]],
                           vec[flat], samples)
    # the samples' rows by flat indices into the grid itself (made once per
    # grid), gathered by np.take (a tenth of fancy indexing's time), their
    # fits by einsum (no BLAS call: its threads would spin beside Taichi's
    # pinned workers after it)
    index, weights = noise_rows(lat.used.shape, centre, rows, filt) if geometry is None \
        else geometry.noise_rows(samples)
    values = np.empty((2,) + index.shape)                                      # (2, S, 21)
    lat.u.take(index, out=values[0])
    lat.v.take(index, out=values[1])
    deviations = np.abs(np.einsum("csk,k->cs", values, weights))
    return 1.4826 * float(median(deviations.ravel()))


def noise_rows(shape, centre, rows, filt) -> tuple:
    """``(index, weights)``: :func:`noise_filter`'s samples as flat indices
    into the grid of ``shape`` (ny, nx) itself, each sample's row its node
    then the filter's 20 (every one a node of the grid: the samples have all
    their neighbours used), and the weights of a row's values in the
    deviation from the fit: 1, then minus the filter's."""
    width = shape[1] + 2 * NOISE_REACH
    j, i = np.divmod(np.concatenate([centre[:, None], rows], axis=1), width)
    index = (j - NOISE_REACH) * shape[1] + (i - NOISE_REACH)
    return np.ascontiguousarray(index, dtype=np.intp), np.concatenate([[1.0], -filt])


def median(values: np.ndarray) -> float:
    """``np.median(values)`` of a flat array without NaN (the same
    arithmetic: the middle value, or the mean of the two middle ones), by one
    partition without the general function's per-call cost."""
    m = len(values)
    lo, hi = (m - 1) // 2, m // 2
    part = np.partition(values, (lo, hi))
    # np.mean of the two: their sum over two (the same operations)
    return float(part[lo]) if lo == hi else (float(part[lo]) + float(part[hi])) / 2.0


#: the noise filter's reach in nodes: its 20 nearest within 3 steps each way
NOISE_REACH = 3


def noise_filter(used: np.ndarray, hx: float, hy: float, samples: int = NOISE_SAMPLES) -> tuple:
    """``(filter, centres, rows)`` of :func:`grid_noise_sigma`: the fixed
    filter's weights (20,), and the flat indices (into the grid padded by
    :data:`NOISE_REACH`) of the sampled nodes whose 20 neighbours are all
    used and of those neighbours ((S,), (S, 20)); ``(None, None, None)``
    where fewer than a tenth of the samples have them."""
    ny, nx = used.shape
    k = 20
    R = NOISE_REACH
    oy, ox = np.mgrid[-R:R + 1, -R:R + 1]
    oy, ox = oy.ravel(), ox.ravel()
    r = np.hypot(oy * hy, ox * hx)
    order = np.argsort(r, kind="stable")[1:k + 1]          # the 20 nearest, not the node
    oy, ox, r = oy[order], ox[order], r[order]
    scale = 1.5 * r.max()
    q = r / scale
    w = (1 - q) ** 4 * (1 + 4 * q)
    dx, dy = ox * hx / scale, oy * hy / scale
    B = np.c_[np.ones(k), dx, dy, dx * dx, dx * dy, dy * dy]
    M = (B * w[:, None]).T @ B
    M += 1e-12 * np.trace(M) * np.eye(6)
    filt = np.linalg.solve(M, (B * w[:, None]).T)[0]        # the constant coefficient's weights
    flat = np.flatnonzero(used.ravel())
    step = max(1, -(-len(flat) // samples))
    at = flat[::step]
    j, i = np.divmod(at, nx)
    # flat indices into the grids padded by R (unused, zero): no bounds tests
    width = nx + 2 * R
    centre = (j + R) * width + (i + R)
    near = centre[:, None] + (oy * width + ox)[None, :]
    full = np.pad(used, R).ravel()[near].all(axis=1)
    if full.sum() < max(8, 0.1 * len(at)):
        return None, None, None
    return filt, centre[full], near[full]


class GridRows:
    """The rows of the operator the critical points read on a grid: the
    difference stencils of the vectors (:mod:`taichi_hh.hhd.natural_grid`,
    along x on u, along y on v), smoothed by the binomial filter
    (:func:`~taichi_hh.hhd.natural_grid.smoothed`): the white-noise spread of
    a mean over a disc of nodes."""

    def __init__(self, geo):
        from .natural_grid import PAD, STENCILS
        self.cx, self.cy = geo.data_codes
        self.inside = geo.inside
        self.table, self.pad = STENCILS, PAD
        self.hx, self.hy = geo.hx, geo.hy
        self._interior = {}          # discs' shape -> the norms of an interior window

    def cached_mean_row_norms(self, discs, win, used) -> np.ndarray:
        """:meth:`mean_row_norms`, computed once for every window of the
        grid's interior: a window of used nodes, unclipped, whose nodes and
        the filter's reach around them are inside and take the central
        stencils has the same discs and the same rows wherever it lies."""
        gs = win[0]
        ny, nx = self.inside.shape
        j0, j1, i0, i1 = gs[0].start - 1, gs[0].stop + 1, gs[1].start - 1, gs[1].stop + 1
        interior = (win[1] == discs.shape[1:] and j0 >= 0 and i0 >= 0 and j1 <= ny
                    and i1 <= nx and used[gs].all())
        if interior:
            grown = (slice(j0, j1), slice(i0, i1))
            interior = (self.inside[grown].all() and not self.cx[grown].any()
                        and not self.cy[grown].any())
        if not interior:
            return self.mean_row_norms(discs, win)
        key = discs.shape
        if key not in self._interior:
            self._interior[key] = self.mean_row_norms(discs, win)
        return self._interior[key]

    def mean_row_norms(self, discs, win) -> np.ndarray:
        """2-norms of the means of the smoothed divergence rows of the nodes
        of each of ``discs`` (bool (k, wy, wx) over the window ``win``,
        :func:`window`): each disc's indicator smeared by the binomial
        filter weighs the rows of the nodes it reaches; the central stencils
        (nearly every node's) by shifted sums, the others node by node."""
        P = self.pad
        k = discs.shape[0]
        m = discs.reshape(k, -1).sum(axis=1)
        ny, nx = self.inside.shape
        # the window grown by the filter's reach (one node), clipped to the grid
        gs = win[0]
        j0, j1 = max(gs[0].start - 1, 0), min(gs[0].stop + 1, ny)
        i0, i1 = max(gs[1].start - 1, 0), min(gs[1].stop + 1, nx)
        wy, wx = j1 - j0, i1 - i0
        ind = np.zeros((k, wy + 2, wx + 2))
        oj, oi = gs[0].start - j0 + 1, gs[1].start - i0 + 1
        ind[:, oj:oj + discs.shape[1], oi:oi + discs.shape[2]] = discs
        ind = 0.25 * ind[:, :, :-2] + 0.5 * ind[:, :, 1:-1] + 0.25 * ind[:, :, 2:]
        sl = (slice(j0, j1), slice(i0, i1))
        weight = (0.25 * ind[:, :-2] + 0.5 * ind[:, 1:-1] + 0.25 * ind[:, 2:]) \
            * self.inside[sl]                                           # (k, wy, wx)
        total = np.zeros(k)
        for codes, h, axis in ((self.cx, self.hx, 1), (self.cy, self.hy, 0)):
            c = codes[sl]
            acc = np.zeros((k, wy + 2 * P, wx + 2 * P))
            central = weight * ((c == 0) / h)
            for o in (-2, -1, 1, 2):
                w = self.table[0, o + P]
                if axis == 1:
                    acc[:, P:P + wy, P + o:P + o + wx] += w * central
                else:
                    acc[:, P + o:P + o + wy, P:P + wx] += w * central
            other = (c != 0) & (weight > 0).any(axis=0)
            if other.any():
                gj, gi = np.nonzero(other)
                co = c[other].astype(np.intp)
                wo = weight[:, other] / h                              # (k, n)
                for o in range(-P, P + 1):
                    wgt = self.table[co, o + P][None, :] * wo
                    if axis == 1:
                        idx = (slice(None), gj + P, gi + P + o)
                    else:
                        idx = (slice(None), gj + P + o, gi + P)
                    np.add.at(acc, (np.arange(k)[:, None], idx[1][None, :], idx[2][None, :]),
                              wgt)
            total += np.einsum("kij,kij->k", acc, acc)
        return np.sqrt(total) / np.maximum(m, 1)
