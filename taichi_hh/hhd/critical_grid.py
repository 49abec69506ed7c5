"""Critical points of a decomposition on a uniform grid's nodes: the tests
of :func:`~.critical.find_critical_points` on the grid itself, without a
neighbour search (candidates by shifted views of the whole grid, the
significance sums and the refinements for all candidates at once)."""
from __future__ import annotations

import functools
import math
import threading
from types import SimpleNamespace

import numpy as np

from .critical import (COHERENCE, COHERENCE_RADIUS, EDGE, POT_PASSES, SCALE_EDGE, SIGNIFICANCE,
                       SIGNIFICANCE_RADII, THRESHOLD, CriticalPoint, scale_of, strength_scale)
# the noise and the spreads' rows
from .grid_noise import GridRows, grid_noise_sigma, noise_filter, noise_rows, window
from .recent import Recent


def find_grid_critical_points(lat, threshold: float = THRESHOLD, radius: float | None = None,
                              *, filter: bool = True, edge: float | None = EDGE,
                              significance: float | None = SIGNIFICANCE,
                              coherence: float | None = COHERENCE):
    """:func:`find_critical_points` of a decomposition on a uniform grid's
    nodes (``lat``: :class:`~taichi_hh.hhd.natural_grid.NodeFields`), the same
    tests on the grid without a neighbour search:

    - the support H (and the default ``radius``) is what the adaptive
      support gives a grid's node (``support_ratio`` times the local spacing
      of its 12 nearest nodes), the local spacing the mean spacing;
    - a candidate is a strict extremum among its 8 neighbours (a necessary
      condition, vectorised over the grid), then among the used nodes within
      ``radius`` (a window of the grid);
    - strengths from div d and curl r by the decomposition's differences;
    - distances to the outline from the grid
      (:func:`~taichi_hh.hhd.natural_grid.outline_distance`: exact along
      straight edges, at most the exact one at the outline's corners);
    - the noise from the quadratic fit to each sampled node's 20 nearest
      nodes (a fixed filter on the grid where all of them are used), the
      white-noise spread of a disc mean from the difference stencils' rows;
    - what those take from the nodes alone (:class:`CriticalGeometry`) kept
      for the last few grids, as the decomposition keeps its layouts.
    """
    # one errstate for all (NaN off the used nodes compares and sums
    # quietly; a context costs a few microseconds each)
    with np.errstate(invalid="ignore", divide="ignore"):
        return _grid_points(lat, threshold, radius, filter, edge, significance, coherence)


def _grid_points(lat, threshold, radius, filter, edge, significance, coherence) -> list:
    """:func:`find_grid_critical_points`'s work, under its errstate."""
    from .natural_grid import smoothed
    used = lat.used
    if np.count_nonzero(used) < 4:
        return []
    if not filter:
        edge = significance = coherence = None
    ell = float(lat.spacing)
    support = grid_support(lat.hx, lat.hy, lat.options.support_ratio)
    rad = support if radius is None else float(radius)
    # distances to the outline (in the points' units) up to what the tests need
    far = max(SCALE_EDGE, edge or 0.0) * ell
    geo = CriticalGeometry.of(lat, rad, far)
    # the derivatives smoothed as the scattered path's MLS operator smooths
    # them (natural_grid.smoothed): the strengths, signs, coherence and
    # significance read them
    ddr = lat.components_div_curl
    sm = smoothed([lat.divergence, lat.curl, ddr[..., 0], ddr[..., 1], lat.phi, lat.psi],
                  lat.inside, (1, 1, 1, 1, POT_PASSES, POT_PASSES), steps=geo.smoothing,
                  outside=None)                 # only the used nodes are read
    scale = grid_strength_scale(lat, geo, sm[0:2], ell)
    if scale == 0.0 or not math.isfinite(scale):
        return []
    Ry, Rx = geo.Ry, geo.Rx
    ny, nx = used.shape
    found = []              # (refined place, node, kind, strength, significance, coherence)
    # both components at once, stacked: d's sources and sinks (phi's minima
    # and maxima), then r's clockwise and counter-clockwise vortices (psi's)
    kinds = (("source", "sink"), ("cw_vortex", "ccw_vortex"))
    # padded by the window (what the gathers over the windows read): div d
    # and curl r, 0 off the used nodes (the sums over discs); phi and psi,
    # NaN off them (the extrema: fmin and fmax skip NaN)
    inner = (slice(None), slice(Ry, Ry + ny), slice(Rx, Rx + nx))
    cpad = np.zeros((2, ny + 2 * Ry, nx + 2 * Rx))
    np.copyto(cpad[inner], sm[2:4], where=used)
    padded = np.full((2, ny + 2 * Ry, nx + 2 * Rx), np.nan)
    np.copyto(padded[inner], sm[4:6], where=used)
    pot = padded[inner]                                          # (2, ny, nx)
    # a strict extremum of the potential among the 8 neighbours first (a
    # necessary condition, by shifted views of the whole grid: few nodes
    # pass it), then the node's own tests on those (the same arithmetic as
    # over the whole grid, on fewer nodes), then a strict extremum among the
    # used nodes within the radius (gathers).  fmin/fmax skip NaN (off the
    # used nodes) as nanmin/nanmax do; none but NaN: no extremum
    lo8 = hi8 = None
    if Ry >= 1 and Rx >= 1:
        # separably: the two row neighbours, the three nodes of the rows
        # above and below (min and max are exact: the same values as eight
        # shifted views, half the calls)
        rows = padded[:, Ry - 1:Ry + ny + 1]
        left, right = rows[:, :, Rx - 1:Rx - 1 + nx], rows[:, :, Rx + 1:Rx + 1 + nx]
        lo_side, hi_side = np.fmin(left, right), np.fmax(left, right)
        lo3 = np.fmin(lo_side, rows[:, :, Rx:Rx + nx])
        hi3 = np.fmax(hi_side, rows[:, :, Rx:Rx + nx])
        lo8 = np.fmin(np.fmin(lo3[:, :-2], lo3[:, 2:]), lo_side[:, 1:-1])
        hi8 = np.fmax(np.fmax(hi3[:, :-2], hi3[:, 2:]), hi_side[:, 1:-1])
    else:
        for dy in range(-min(Ry, 1), min(Ry, 1) + 1):
            for dx in range(-min(Rx, 1), min(Rx, 1) + 1):
                if dy or dx:
                    view = padded[:, Ry + dy:Ry + dy + ny, Rx + dx:Rx + dx + nx]
                    lo8 = view if lo8 is None else np.fmin(lo8, view)
                    hi8 = view if hi8 is None else np.fmax(hi8, view)
    if lo8 is not None:
        low8 = pot < lo8                           # False off the used nodes (NaN)
        flat = ((low8 | (pot > hi8)) & geo.two_of_eight).ravel().nonzero()[0]
        low = low8.take(flat)                  # else a strict maximum (one of the two)
        cc, node = np.divmod(flat, ny * nx)
        jj, ii = np.divmod(node, nx)
        at = (cc * padded[0].shape[0] + jj + Ry) * padded[0].shape[1] + ii + Rx   # flat
        c_here = cpad.take(at)
        # d's speed for phi, r's for psi, by the squares (np.hypot's guard
        # costs five times as much); the component's sign, tested below,
        # makes it nonzero
        fld = np.where((cc == 0)[:, None], lat.curl_free.reshape(-1, 2).take(node, axis=0),
                       lat.div_free.reshape(-1, 2).take(node, axis=0))
        speed = np.sqrt(fld[:, 0] * fld[:, 0] + fld[:, 1] * fld[:, 1])
        size = np.abs(c_here)
        keep = (size / scale >= threshold) & (speed <= size * rad)
        if edge is not None and edge > 0:
            keep &= geo.dist.take(node) >= edge * ell
        # the candidates' grid, row, column, flat index, minimum (1) or
        # maximum (0), filtered together from here on
        nodes = np.array((cc, jj, ii, at, low))[:, keep]
        cc, jj, ii, at, low = nodes
        c_here = c_here[keep]
        nb = padded.take(at[:, None] + geo.in_radius_flat)
        here = padded.take(at)
        # div d or curl r positive at phi's or psi's minimum (times -1 at a
        # maximum, and for psi: exact)
        sign = np.where((low == 1) == (cc == 0), 1.0, -1.0)
        keep = np.where(low, here < np.fmin.reduce(nb, axis=1), here > np.fmax.reduce(nb, axis=1))
        keep &= (c_here * sign > 0) & (np.isfinite(nb).sum(axis=1) >= 2)
        nodes, c_here = nodes[:, keep], c_here[keep]
        c_all = np.full(len(c_here), math.nan)
        if coherence is not None and len(c_here):       # one sign over the disc
            # the used nodes' values, 0 off them (nansum's sums of the same
            # values, NaN for 0), one flat gather
            disc_c = cpad.take(nodes[3][:, None] + geo.coherence_offsets(ell))
            sign = np.sign(c_here)
            total = np.abs(disc_c).sum(axis=1)
            c_all = np.where(total > 0, sign * disc_c.sum(axis=1) /
                             np.maximum(total, 1e-300), 1.0)
            keep = c_all >= coherence
            nodes, c_all, c_here = nodes[:, keep], c_all[keep], c_here[keep]
        # by component, then by strength (stable: ties in the grid's order)
        strength = np.abs(c_here) / scale
        order = np.lexsort((-strength, nodes[0]))
        nodes, c_all, c_here, strength = (nodes[:, order], c_all[order], c_here[order],
                                          strength[order])
        z_all = np.full(len(c_here), math.nan)
        if significance is not None and len(c_here):
            sigma = grid_noise_sigma(lat, geometry=geo)
            z_all = _grid_significance(geo, c_here, cpad, nodes, sigma)
            keep = z_all >= significance
            nodes, c_all, z_all, strength = (nodes[:, keep], c_all[keep], z_all[keep],
                                             strength[keep])
        cc, jj, ii, at, low = nodes
        places = _grid_refine(lat, geo, padded, nodes, rad)
        for k in range(jj.size):
            c, j, i = int(cc[k]), int(jj[k]), int(ii[k])
            found.append((places[k], (float(lat.x[i]), float(lat.y[j])),
                          kinds[c][0] if low[k] else kinds[c][1], strength[k],
                          float(z_all[k]), float(c_all[k])))
    if found and lat.domain is not None:
        # a refined place outside the outline falls back to its node (one
        # vectorised test for those not deep inside: a place at most the
        # radius from a node whose block of nodes reaching a cell past the
        # radius is inside is inside)
        inside = geo.deep[jj, ii]
        if not inside.all():
            moved = np.array([f[0] for f, ok in zip(found, inside) if not ok], dtype=np.float64)
            inside[~inside] = _inside_outline(lat.domain, moved, geo.segments)
        found = [(f[0] if ok else f[1],) + f[1:] for f, ok in zip(found, inside)]
    out = [CriticalPoint(float(p[0][0]), float(p[0][1]), p[2], p[3], p[4], p[5])
           for p in found]
    out.sort(key=lambda p: -p.strength)
    return out


def grid_strength_scale(lat, geo, div_curl, ell: float) -> float:
    """:func:`~.critical.strength_scale` of the smoothed div v and curl v
    ``div_curl`` (2, ny, nx) on the used nodes: where they are all finite (as
    the decomposition leaves them) the nodes far enough from the outline are
    the geometry's (:attr:`CriticalGeometry.scale_nodes`), one gather; else
    the general function."""
    if geo.every_node_used:                 # views: no gathers
        both = div_curl.reshape(2, -1)
        u, v = lat.u.reshape(-1), lat.v.reshape(-1)
    else:                                   # np.take: a tenth of fancy indexing's time
        both = div_curl.reshape(2, -1).take(geo.used_flat, axis=1)
        u, v = lat.u.take(geo.used_flat), lat.v.take(geo.used_flat)
    if not np.isfinite(both).all():
        return strength_scale(SimpleNamespace(divergence=both[0], curl=both[1],
                                              vectors=np.stack([u, v], axis=1),
                                              stats={"spacing": ell}), geo.edge_distance)
    sel = both if geo.scale_nodes is None else both.take(geo.scale_nodes, axis=1)
    return scale_of(np.abs(sel), u, v, ell)


def _inside_outline(domain, points, segments=None) -> np.ndarray:
    """``domain.contains(points)`` for a few points: the even-odd crossing
    test over every boundary segment (outer ring and holes), O(points x
    segments) without the point locator :meth:`Polygon.contains` builds on
    its first query (0.15 s for the staircase outline of a masked 64 x 64
    grid, four times the decomposition).  ``segments``: ``domain.segments()``
    if made already, or :func:`segment_columns` of it.  Points on the
    boundary itself (a set of measure zero) may go either way."""
    if segments is None:
        segments = getattr(domain, "segments", None)
        segments = None if segments is None else segments()
    if segments is None or len(points) > 256:
        return domain.contains(points)
    ax, ay, by, dx, dy = segments if len(segments) == 5 else segment_columns(segments)
    px, py = points[:, 0:1], points[:, 1:2]                     # (k, 1) against (S,)
    crosses = (ay > py) != (by > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = ax + (py - ay) * dx / dy
    return ((crosses & (px < at)).sum(axis=1) % 2) == 1


def segment_columns(segments) -> tuple:
    """``(ax, ay, by, bx - ax, by - ay)``, contiguous, of the segments
    ``(a, b)`` ((S, 2) each): what :func:`_inside_outline` reads."""
    a, b = segments
    return tuple(np.ascontiguousarray(c) for c in (a[:, 0], a[:, 1], b[:, 1], b[:, 0] - a[:, 0],
                                                   b[:, 1] - a[:, 1]))


@functools.lru_cache(maxsize=16)
def grid_support(hx: float, hy: float, support_ratio: float) -> float:
    """The adaptive support of a grid's node (:mod:`taichi_hh.sph.support`):
    ``support_ratio`` times its local spacing, the distance to its 12th
    nearest node times sqrt(pi / 12)."""
    from ..sph.support import DEFAULT_NEIGHBOURS
    k = DEFAULT_NEIGHBOURS
    R = int(math.ceil(math.sqrt(k))) + 1
    oy, ox = np.mgrid[-R:R + 1, -R:R + 1]
    r = np.sort(np.hypot(oy * hy, ox * hx).ravel())
    return support_ratio * float(r[k]) * math.sqrt(math.pi / k)     # r[0]: the node itself


def _padded(values, Ry, Rx, fill):
    """``values`` (..., ny, nx) with Ry rows and Rx columns of ``fill``
    around (np.pad's work without its per-call overhead, a tenth of a
    millisecond)."""
    *lead, ny, nx = values.shape
    out = np.full(tuple(lead) + (ny + 2 * Ry, nx + 2 * Rx), fill, dtype=values.dtype)
    out[..., Ry:Ry + ny, Rx:Rx + nx] = values
    return out


def _grid_significance(geo, c_here, padded_comp, nodes, sigma) -> np.ndarray:
    """Per candidate node (jj, ii) (K,), the significance of
    :func:`find_grid_critical_points`: the best over ``SIGNIFICANCE_RADII`` of
    the mean of ``comp`` over the used nodes of the disc (also within the
    radius), signed by the candidate's, over ``sigma`` times the disc mean's
    white-noise spread (:meth:`CriticalGeometry.spreads`).  The sums for all
    candidates at once (``c_here``: (K,) the candidates' components;
    ``padded_comp``: ``comp`` padded by the window, 0 off the used
    nodes; ``nodes``: the candidates' grid, row, column and flat index in
    ``padded_comp`` (4+, K); the discs' counts of used nodes kept per
    node)."""
    cc, jj, ii, at = nodes[:4]
    g_comp = padded_comp.take(at[:, None] + geo.window_flat_offsets)
    counts, spreads = geo.disc_rows(jj, ii)                             # (K, 4) each
    sums = g_comp @ geo.disc_weights.T
    sign = np.where(c_here > 0, 1.0, -1.0)
    means = sign[:, None] * sums / counts
    spread = sigma * spreads
    z = np.where(spread > 0, means / np.where(spread > 0, spread, 1.0),
                 np.where(means > 0, math.inf, -math.inf))
    return z.max(axis=1) if z.size else np.full(len(jj), -math.inf)


def _grid_refine(lat, geo, padded_pot, nodes, rad) -> list:
    """Per candidate node (jj, ii), the stationary point of the quadratic
    least-squares fit of its potential (``padded_pot``: the two potentials,
    (2, ny, nx) padded by the window, NaN off the used nodes; the
    candidates' at cc) over the used nodes within ``rad`` of it (the
    node kept where the fit has fewer than 6 nodes, is singular, or its
    stationary point falls farther than ``rad``; the caller keeps it where
    it falls outside the domain's outline): all fits at once."""
    cc, jj, ii, at = nodes[:4]
    if len(jj) == 0:
        return []
    here_x, here_y = lat.x[ii], lat.y[jj]
    # the fits' matrices (the nodes alone: kept per node by the geometry)
    m, A, normal, fit = geo.fit_rows(jj, ii)
    P = np.where(m, padded_pot.take(at[:, None] + geo.near_flat_offsets), 0.0)
    rhs = np.einsum("koa,ko->ka", A, P)
    try:                                  # the normal equations: no LAPACK least squares
        if fit.all():
            coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
        else:
            coef = np.full((len(jj), 6), np.nan)
            coef[fit] = np.linalg.solve(normal[fit], rhs[fit][..., None])[..., 0]
    except np.linalg.LinAlgError:         # one singular: each on its own
        coef = np.full((len(jj), 6), np.nan)
        for k in np.flatnonzero(fit):
            try:
                coef[k] = np.linalg.solve(normal[k], rhs[k])
            except np.linalg.LinAlgError:
                pass
    a, b, c = 2 * coef[:, 3], coef[:, 4], 2 * coef[:, 5]
    det = a * c - b * b                   # (the caller's errstate: quiet)
    step_x = -(c * coef[:, 1] - b * coef[:, 2]) / det
    step_y = -(a * coef[:, 2] - b * coef[:, 1]) / det
    # a step within the radius is finite (so det is not 0); an infinite det
    # would make a finite step of 0
    ok = np.isfinite(det) & (np.hypot(step_x, step_y) <= rad)
    out = []
    for k, good in enumerate(ok.tolist()):
        x, y = float(here_x[k]), float(here_y[k])
        out.append((x + float(step_x[k]), y + float(step_y[k])) if good else (x, y))
    return out


class KeptRows:
    """Rows made per grid node once and kept, in one array per part: ``make(nj,
    ni)`` gives a tuple of arrays with a row per node asked; :meth:`rows`
    makes the nodes not kept yet and gathers every node's rows.  At most
    :data:`KEPT_FITS` nodes (then it begins again); safe across threads."""

    def __init__(self, make, nx: int):
        self._make, self._nx = make, nx
        self._slot = {}                  # node (flat index) -> its row in the parts
        self._parts = None
        self._lock = threading.Lock()    # the slots and the parts agree

    def rows(self, jj, ii) -> tuple:
        with self._lock:
            keys = (jj * self._nx + ii).tolist()
            slot = self._slot
            new = list(dict.fromkeys(key for key in keys if key not in slot))
            if new:
                if len(slot) + len(new) > KEPT_FITS:
                    slot.clear()
                    self._parts = None
                parts = self._make(*np.divmod(np.array(new), self._nx))
                start = len(slot)
                self._parts = parts if self._parts is None else \
                    tuple(np.concatenate(pair) for pair in zip(self._parts, parts))
                slot.update((key, start + k) for k, key in enumerate(new))
            at = [slot[key] for key in keys]
            return tuple(part.take(at, axis=0) for part in self._parts)


class CriticalGeometry:
    """What :func:`find_grid_critical_points` takes from a grid's nodes
    alone (the nodes used and inside, the steps, the spacing, the radius and
    the outline distances' reach): the distances to the outline, the
    smoothing's weights, the window of offsets within the radius and the
    significance discs over it, the noise filter, and the disc means'
    white-noise spreads per window.  :meth:`of` keeps those of the last
    :data:`KEPT_GEOMETRIES` grids (a run's frames on a fixed mask pay for
    them once)."""

    def __init__(self, lat, rad: float, far: float):
        from .natural_grid import eroded, outline_distance, smoothing_steps
        self.used, self.inside = lat.used, lat.inside
        self.data_codes = lat.data_codes
        self.hx, self.hy = lat.hx, lat.hy
        ell = float(lat.spacing)
        jj, ii, best, _ = outline_distance(self.used, self.inside, self.hx, self.hy, far)
        dist = np.full(self.used.shape, np.inf)
        dist[jj, ii] = best
        self.dist = dist
        self.edge_distance = dist[self.used] / ell
        self.used_flat = np.flatnonzero(self.used.ravel())
        self.every_node_used = len(self.used_flat) == self.used.size
        # the used nodes the strength scale reads where its derivatives are
        # all finite (strength_scale's rule: those SCALE_EDGE spacings from
        # the outline where they are a quarter or more, else all)
        far_nodes = self.edge_distance >= SCALE_EDGE
        self.scale_nodes = None if far_nodes.sum() < 0.25 * len(far_nodes) else \
            np.flatnonzero(far_nodes)
        self.smoothing = smoothing_steps(self.inside)
        # the nodes whose block of nodes a cell past the radius is inside: a
        # place within the radius of one is inside the outline
        self.deep = eroded(self.inside, int(math.ceil(rad / self.hy)) + 1,
                           int(math.ceil(rad / self.hx)) + 1)
        self.Ry, self.Rx = int(rad // self.hy), int(rad // self.hx)
        self.oy, self.ox = np.mgrid[-self.Ry:self.Ry + 1, -self.Rx:self.Rx + 1]
        self.r_off = np.hypot(self.oy * self.hy, self.ox * self.hx)
        self.window_offsets = (self.oy.ravel(), self.ox.ravel())
        self.window_flat_offsets = (self.oy.ravel() * (lat.used.shape[1] + 2 * self.Rx)
                                    + self.ox.ravel())
        self.discs = np.stack([(self.r_off < rad) & (self.r_off <= radius_i * ell)
                               for radius_i in SIGNIFICANCE_RADII])      # (4, wy, wx)
        self.disc_weights = self.discs.reshape(len(self.discs), -1).astype(np.float64)
        near = self.r_off < rad
        self.near_offsets = (self.oy[near], self.ox[near])
        self.near_flat_offsets = self.oy[near] * (lat.used.shape[1] + 2 * self.Rx) + \
            self.ox[near]
        # the others within the radius (the extremum's test): flat offsets
        # in the grid padded by the window
        others = near & (self.r_off > 0)
        self.in_radius_flat = self.oy[others] * (lat.used.shape[1] + 2 * self.Rx) + \
            self.ox[others]
        self.padded_used = _padded(self.used, self.Ry, self.Rx, False)
        # the axes padded by the window (clamped: the padding is never used)
        ny, nx = self.used.shape
        self.padded_x = lat.x[np.clip(np.arange(-self.Rx, nx + self.Rx), 0, nx - 1)]
        self.padded_y = lat.y[np.clip(np.arange(-self.Ry, ny + self.Ry), 0, ny - 1)]
        self.x, self.y = lat.x, lat.y
        # the used nodes with two used nodes or more among their 8 neighbours
        count8 = np.zeros(self.used.shape, dtype=np.int64)
        ry, rx = min(self.Ry, 1), min(self.Rx, 1)
        for dy in range(-ry, ry + 1):
            for dx in range(-rx, rx + 1):
                if dy or dx:
                    count8 += self.padded_used[self.Ry + dy:self.Ry + dy + ny,
                                               self.Rx + dx:self.Rx + dx + nx]
        self.two_of_eight = count8 >= 2
        segments = getattr(lat.domain, "segments", None)
        self.segments = None if segments is None else segment_columns(segments())
        self._rows = None
        self._off_centre_area = None
        self._noise = {}
        self._spreads = {}                    # node -> its windows' spreads
        self._clear = None
        nx = self.used.shape[1]
        self._discs = KeptRows(self._make_disc_rows, nx)     # disc_rows
        self._fits = KeptRows(self._make_fit_rows, nx)       # fit_rows
        self._coherence = None

    @classmethod
    def of(cls, lat, rad: float, far: float) -> "CriticalGeometry":
        """The geometry of ``lat``'s grid: one of the last few made where the
        nodes, steps, spacing, radius and reach are the same, else a new one
        (kept up to :data:`KEPT_GEOMETRY_NODES` nodes)."""
        used, inside = lat.used, lat.inside
        if used.size > KEPT_GEOMETRY_NODES:
            return cls(lat, rad, far)
        key = (used.shape, used.tobytes(), inside.tobytes(), lat.x.tobytes(), lat.y.tobytes(),
               float(lat.spacing), float(rad), float(far), lat.options.support_ratio)
        geo = _GEOMETRIES.get(key)
        if geo is None:
            geo = cls(lat, rad, far)
        _GEOMETRIES.put(key, geo)
        return geo

    def coherence_offsets(self, ell: float) -> np.ndarray:
        """The flat offsets, in the grid padded by the window, of the nodes
        within :data:`COHERENCE_RADIUS` spacings ``ell`` of a node."""
        if self._coherence is None:
            sel = (self.r_off <= COHERENCE_RADIUS * ell).ravel()
            self._coherence = self.window_flat_offsets[sel]
        return self._coherence

    def fit_rows(self, jj, ii) -> tuple:
        """``(m, A, normal, fits)`` of :func:`_grid_refine`'s fits at the
        nodes (jj, ii) (K,): the used nodes among those within the radius
        (:attr:`near_offsets`), the quadratic's rows (K, O, 6: 1, X, Y, X^2,
        XY, Y^2 from the node; 0 off the used nodes), the normal matrices
        A^T A (K, 6, 6) and whether 6 nodes or more are used; each node's
        made once and kept (:class:`KeptRows`; einsum's sums per node: the
        same in any batch)."""
        return self._fits.rows(jj, ii)

    def _make_fit_rows(self, nj, ni) -> tuple:
        oy, ox = self.near_offsets
        rows = nj[:, None] + self.Ry + oy[None, :]
        cols = ni[:, None] + self.Rx + ox[None, :]
        m = np.take(self.padded_used, rows * self.padded_used.shape[1] + cols)  # (k, O)
        A = np.empty(m.shape + (6,))                                   # (k, O, 6)
        A[..., 0] = m
        A[..., 1] = X = np.where(m, self.padded_x[cols] - self.x[ni][:, None], 0.0)
        A[..., 2] = Y = np.where(m, self.padded_y[rows] - self.y[nj][:, None], 0.0)
        np.multiply(X, X, out=A[..., 3])
        np.multiply(X, Y, out=A[..., 4])
        np.multiply(Y, Y, out=A[..., 5])
        return m, A, np.einsum("koa,kob->kab", A, A), m.sum(axis=1) >= 6

    def disc_rows(self, jj, ii) -> tuple:
        """``(counts, spreads)`` (K, 4) each: per node (jj, ii) the used nodes
        of its significance discs (1 where none) and their means'
        white-noise spreads (:meth:`spreads`); each node's made once and kept
        (:class:`KeptRows`)."""
        return self._discs.rows(jj, ii)

    def _make_disc_rows(self, nj, ni) -> tuple:
        nx = self.used.shape[1]
        centre = (nj + self.Ry) * (nx + 2 * self.Rx) + ni + self.Rx
        used = np.take(self.padded_used, centre[:, None] + self.window_flat_offsets)
        return (np.maximum(used.astype(np.float64) @ self.disc_weights.T, 1),  # exact
                self.spreads(nj, ni))

    def noise_filter(self, samples: int) -> tuple:
        """:func:`noise_filter` of these nodes (made once per ``samples``)."""
        if samples not in self._noise:
            self._noise[samples] = noise_filter(self.used, self.hx, self.hy, samples)
        return self._noise[samples]

    def noise_rows(self, samples: int) -> tuple:
        """:func:`noise_rows` of :meth:`noise_filter` (made once per ``samples``)."""
        key = ("rows", samples)
        if key not in self._noise:
            filt, centre, rows = self.noise_filter(samples)
            self._noise[key] = noise_rows(self.used.shape, centre, rows, filt)
        return self._noise[key]

    def spreads(self, jj, ii) -> np.ndarray:
        """(K, 4): per candidate node (jj, ii) the white-noise spread of its
        discs' means in units of the noise (:class:`GridRows`).  A window of
        used nodes whose filter reach (one node more) is inside, takes the central
        stencils and is clear of the grid's edges has the same discs and
        rows wherever it lies: computed once; the others once per node."""
        rows, Ry, Rx = self.rows(), self.Ry, self.Rx
        ny, nx = self.used.shape
        clear = self.clear_windows()[jj, ii]
        norms = np.empty((len(jj), len(self.discs)))
        for k in range(len(jj)):
            key = "clear" if clear[k] else (int(jj[k]), int(ii[k]))
            found = self._spreads.get(key)
            if found is None:
                j, i = int(jj[k]), int(ii[k])
                win = window(j, i, Ry, Rx, ny, nx)
                mine = self.discs[:, win[2][0], win[2][1]] & self.used[win[0]][None]
                found = self._spreads[key] = rows.cached_mean_row_norms(mine, win, self.used)
            norms[k] = found
        return norms


    def rows(self) -> "GridRows":
        """The rows of the operator the spreads read (made once)."""
        if self._rows is None:
            self._rows = GridRows(self)
        return self._rows

    def clear_windows(self) -> np.ndarray:
        """(ny, nx) bool: the nodes whose window (its nodes all used) and the
        filter's reach around it (one node more: inside, the central
        stencils) lie clear of the grid's edges and the outline (made once)."""
        if self._clear is not None:
            return self._clear
        rows, Ry, Rx = self.rows(), self.Ry, self.Rx
        ny, nx = self.used.shape
        jj, ii = np.mgrid[0:ny, 0:nx]

        def box_sum(flags, j0, j1, i0, i1):      # of flags over rows j0:j1, columns i0:i1
            area = np.zeros((ny + 1, nx + 1), dtype=np.int64)
            area[1:, 1:] = flags.cumsum(0).cumsum(1)
            a0, a1, b0, b1 = (np.clip(t, 0, s) for t, s in ((j0, ny), (j1, ny), (i0, nx),
                                                             (i1, nx)))
            return area[a1, b1] - area[a0, b1] - area[a1, b0] + area[a0, b0]
        j0, j1, i0, i1 = jj - Ry - 1, jj + Ry + 2, ii - Rx - 1, ii + Rx + 2
        clear = (j0 >= 0) & (i0 >= 0) & (j1 <= ny) & (i1 <= nx)
        window_nodes = (2 * Ry + 1) * (2 * Rx + 1)
        clear &= box_sum(self.used, j0 + 1, j1 - 1, i0 + 1, i1 - 1) == window_nodes
        off_centre = ~rows.inside | (rows.cx != 0) | (rows.cy != 0)
        clear &= box_sum(off_centre, j0, j1, i0, i1) == 0
        self._clear = clear
        return clear


#: the geometries :meth:`CriticalGeometry.of` keeps (as the layouts,
#: :data:`~taichi_hh.hhd.grid.KEPT_LAYOUTS`)
KEPT_GEOMETRIES = 4
#: the nodes whose fit rows (:meth:`CriticalGeometry.fit_rows`, 2 kB each
#: at the default radius) and disc rows a geometry keeps: all dropped past
#: this count (a frame's points are tens of nodes)
KEPT_FITS = 1024
#: grids of more nodes keep none (their windows' spreads are a small part of
#: their critical points' time)
KEPT_GEOMETRY_NODES = 1_000_000
_GEOMETRIES = Recent(KEPT_GEOMETRIES)


def forget_geometries() -> None:
    """Drop the kept :class:`CriticalGeometry` (their memory, or to time a
    grid seen for the first time)."""
    _GEOMETRIES.clear()
