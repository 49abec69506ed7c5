"""The natural Helmholtz-Hodge decomposition on a uniform grid's own nodes:
the fast path of :func:`~taichi_hh.hhd.grid.decompose_grid`.

The scattered path (:mod:`taichi_hh.hhd.natural`) reconstructs div v and
curl v from the data points onto a grid of cells by moving least squares,
weighs the cells by their coverage of the domain, and interpolates the
potentials' gradients back to the points.  A uniform grid of measurements
needs none of that: each node is the centre of its cell, and the domain of
:func:`~taichi_hh.hhd.grid.decompose_grid` is the union of the cells of the
nodes kept (the raster outline of :mod:`taichi_hh.geometry.raster`, but for
the 45-degree cuts at its corners: an eighth of a cell each).  So

* div v and curl v at the nodes by finite differences: fourth order where
  two nodes on each side are inside the domain, one-sided fourth order next
  to the outline and holes, lower order only where a line of inside nodes is
  shorter than five (:func:`axis_derivative`); the bridged gaps (dropouts,
  isolated nodes left out: inside the domain, no vector) get v from a
  weighted quadratic least-squares fit to the valid nodes around them
  (:func:`fill_gaps`) so the differences across them stay fourth order;
* phi = G * div v and psi = -G * curl v over the cells by zero-padded FFT
  (:func:`~taichi_hh.hhd.natural.convolve_fft`, the free-space kernel of
  :meth:`~taichi_hh.hhd.natural.Grid.kernel` with each cell's own integral),
  the midpoint rule: second order;
* d = grad phi, r = J grad psi by the same differences over the inside
  nodes: the potentials are only C^{1,1} across the outline (their
  density stops there), so differences straddling it would err by O(h);
  one-sided ones see a smooth function.

No neighbour search, no interpolation: at 161 x 81 nodes the numerics take a
few milliseconds (benchmarks/grid_peer.py).
"""

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import AccuracyWarning
from .decompose import ENERGY_LIMIT, HHDResult, flag_harmonic
from .free_space import Grid, convolve_direct, convolve_fft
# the differences' names as the grid's critical points and the tests read them here
from .grid_differences import (PAD, STENCILS, axis_derivative, codes_div_curl,
                               components_checks, div_curl, stencil_codes)

__all__ = ["NodeGrid", "uniform_steps", "div_curl", "axis_derivative", "stencil_codes",
           "smoothed", "smoothing_steps", "mls_gradient_stencil", "eroded", "outline_distance",
           "fill_gaps", "natural_on_nodes", "decompose_nodes", "NodeResult", "NodeFields", "STENCILS", "PAD",
           "UNIFORM_RTOL"]

#: an axis is uniform when every step is within this fraction of the mean step:
#: DaVis's text export writes 4 decimals (a 0.62 mm step off by 8.7e-5 of
#: itself); a node that far off a uniform grid moves the differences by as
#: much, below any measurement's noise and 0.02% on exact fields
UNIFORM_RTOL = 2e-4


def uniform_steps(x: np.ndarray, y: np.ndarray, rtol: float = UNIFORM_RTOL):
    """``(hx, hy)`` when the increasing axes ``x``, ``y`` have equal steps (to
    ``rtol`` of the step), else None."""
    steps = []
    for axis in (x, y):
        d = np.diff(axis)
        if len(d) == 0:
            return None
        h = (axis[-1] - axis[0]) / len(d)
        if not (h > 0) or np.max(np.abs(d - h)) > rtol * h:
            return None
        steps.append(float(h))
    return tuple(steps)


class NodeGrid(Grid):
    """The cells of a uniform grid's nodes as a :class:`~taichi_hh.hhd.natural.Grid`
    (no margin: the potentials are wanted at the nodes only): ``nx`` x ``ny``
    cells of ``hx`` x ``hy``, the first centred at ``origin``."""

    def __init__(self, origin, hx: float, hy: float, nx: int, ny: int):
        self.hx, self.hy = float(hx), float(hy)
        self.nx, self.ny = int(nx), int(ny)
        self.origin = np.asarray(origin, dtype=np.float64)


def smoothing_steps(avail: np.ndarray) -> list:
    """What :func:`smoothed` takes from the nodes ``avail`` alone: per axis
    (x, then y) the shift between a node and its neighbour along it in the
    grid grown by one row and one column (flat indices) and the
    renormalisation there (one over the weight of the available nodes the
    filter reaches; 0 off ``avail`` and on the added row and column)."""
    ny, nx = avail.shape
    w = avail.astype(np.float64)
    steps = []                          # (shift, the renormalisation (ny + 1) * (nx + 1))
    for axis, shift in ((1, 1), (0, nx + 1)):
        n = avail.shape[axis]
        if n < 2:
            continue
        lo = (slice(None),) * axis + (slice(0, n - 1),)
        hi = (slice(None),) * axis + (slice(1, n),)
        den = 2.0 * w
        den[hi] += w[lo]
        den[lo] += w[hi]
        scale = np.zeros((ny + 1, nx + 1))
        scale[:ny, :nx] = np.where(avail, 1.0 / np.maximum(den, 1e-300), 0.0)
        steps.append((shift, scale.ravel()))
    return steps


def smoothed(F, avail: np.ndarray, passes=1, steps: list | None = None,
             outside=np.nan) -> np.ndarray:
    """``F`` (ny, nx), or a stack of fields (k, ny, nx) (or a list of k
    (ny, nx) arrays), smoothed over the nodes ``avail`` by the binomial
    filter [1, 2, 1] / 4 along x, then along y (each pass renormalised by the
    weight of the available nodes; NaN off ``avail``), ``passes`` times (or
    per field: k counts); ``steps``: :func:`smoothing_steps` of ``avail`` if
    made already; ``outside``: the value off ``avail`` (None: left as the
    passes leave it, 0, for a caller that reads the available nodes only).
    One pass is what the scattered path's cubic moving-least-squares
    divergence does to a field's differences: on pivpy's noisy samples the
    differences smoothed so differ from it by 16-22% (wing tip, soap film;
    31-54% unsmoothed).

    Each step is (2 p + lower) + upper times the renormalisation, node by
    node, as sums of shifted flat arrays: each field grown by a row and a
    column of zeros (a node's neighbour off the grid, or in the next row or
    field, adds 0), one contiguous sum per shift over all the fields at
    once rather than one short row at a time, and one work array for every
    pass.  Returns views (ny, nx) of the grown fields."""
    ny, nx = avail.shape
    if isinstance(F, (list, tuple)):          # no stack: the fields copied in once
        one, k = False, len(F)
        Z = np.zeros((k, ny + 1, nx + 1))
        for z, values in zip(Z, F):
            np.copyto(z[:ny, :nx], values, where=avail)
    else:
        F = np.asarray(F, dtype=np.float64)
        one = F.ndim == 2
        k = 1 if one else len(F)
        Z = np.zeros((k, ny + 1, nx + 1))
        np.copyto(Z[:, :ny, :nx], F[None] if one else F, where=avail)
    if steps is None:
        steps = smoothing_steps(avail)
    # per field, in plain ints (a handful of fields: numpy's per-call cost
    # would outweigh the work on a small grid)
    counts = [int(passes)] * k if np.ndim(passes) == 0 else [int(c) for c in passes]
    if len(counts) != k:
        raise ValueError(f"passes: one count per field ({k}), got {len(counts)}")
    flat = Z.reshape(k, -1)
    work = np.empty_like(flat)
    for done in range(max(counts, default=0)):
        sel = [f for f, c in enumerate(counts) if c > done]
        run = sel[-1] - sel[0] + 1 == len(sel)          # a range of fields: a view
        part = flat[sel[0]:sel[-1] + 1] if run else flat[sel]
        num = work[:len(sel)]
        line, total = part.reshape(-1), num.reshape(-1)
        for shift, scale in steps:
            np.multiply(line, 2.0, out=total)
            total[shift:] += line[:-shift]
            total[:-shift] += line[shift:]
            np.multiply(num, scale, out=part)
        if not run:
            flat[sel] = part
    out = Z[:, :ny, :nx]
    if outside is not None:
        out[:, ~avail] = outside
    return out[0] if one else out


def mls_gradient_stencil(hx: float, hy: float, support: float) -> tuple:
    """The scattered path's ``cubic`` gradient (:mod:`taichi_hh.sph.operators`:
    the weighted least-squares cubic fit of f_j - f_i, weights the Wendland C2
    kernel of support ``support``) at a grid node whose neighbours within the
    support are all there: ``(oy, ox, wx, wy)``, the offsets in steps and the
    weights of d/dx and d/dy (a fixed stencil on a uniform grid)."""
    Ry, Rx = int(support // hy), int(support // hx)
    oy, ox = np.mgrid[-Ry:Ry + 1, -Rx:Rx + 1]
    oy, ox = oy.ravel(), ox.ravel()
    X, Y = ox * hx, oy * hy
    r = np.hypot(X, Y)
    keep = (r < support) & (r > 0)
    oy, ox, X, Y, r = oy[keep], ox[keep], X[keep], Y[keep], r[keep]
    q = 2.0 * r / support                                   # h = support / 2
    w = (1.0 - q / 2.0) ** 4 * (2.0 * q + 1.0)
    x, y = X / support, Y / support
    P = np.stack([x, y, x * x, x * y, y * y, x ** 3, x * x * y, x * y * y, y ** 3], axis=1)
    M = (P * w[:, None]).T @ P
    coef = np.linalg.solve(M, (P * w[:, None]).T)           # (9, n): fit of f_j - f_i
    return oy, ox, coef[0] / support, coef[1] / support


def eroded(mask: np.ndarray, ky: int, kx: int) -> np.ndarray:
    """The nodes of ``mask`` whose (2 ky + 1) x (2 kx + 1) block is all in
    ``mask`` (the grid's outside counted out)."""
    ny, nx = mask.shape
    pad = np.zeros((ny + 2 * ky, nx + 2 * kx), dtype=bool)
    pad[ky:ky + ny, kx:kx + nx] = mask
    rows = pad[:, 0:nx].copy()
    for o in range(1, 2 * kx + 1):
        rows &= pad[:, o:o + nx]
    out = rows[0:ny].copy()
    for o in range(1, 2 * ky + 1):
        out &= rows[o:o + ny]
    return out


def outline_distance(nodes: np.ndarray, inside: np.ndarray, hx: float, hy: float,
                     reach: float) -> tuple:
    """The distance from the grid's ``nodes`` (bool (ny, nx), a subset of
    ``inside``) to the outline of the cells ``inside``, and the outward normal
    there, for the nodes closer than ``reach``: ``(rows, cols, distance,
    normal)``, the nodes (rows, cols) those within the reach's block of a node
    not inside (the others are farther), ``distance`` (inf beyond the reach).

    The outline (:mod:`taichi_hh.geometry.raster`) runs half way between a
    node inside and one not (or the grid's edge): a node's distance to it is
    that to the nearest node not inside less the part of the segment between
    them that lies in that node's cell; the normal points to that node (the
    mean direction where several are as near, one of them where those cancel).
    Exact along straight edges; at the 45-degree cuts of the outline's corners
    within a cell of the exact distance, from below but for nodes less than a
    step from the outline."""
    kx, ky = int(math.ceil(reach / hx)) + 1, int(math.ceil(reach / hy)) + 1
    jj, ii = np.nonzero(nodes & ~eroded(inside, ky, kx))
    out = np.pad(~inside, ((ky, ky), (kx, kx)), constant_values=True)
    oy, ox = np.mgrid[-ky:ky + 1, -kx:kx + 1]
    oy, ox = oy.ravel(), ox.ravel()
    step = np.maximum(np.abs(ox), np.abs(oy))
    r = np.hypot(ox * hx, oy * hy)
    dist = r - 0.5 * r / np.maximum(step, 1)
    near = (step > 0) & (dist < reach)     # a node whose nearest is farther: out of reach
    oy, ox, r, dist = oy[near], ox[near], r[near], dist[near]
    hit = out[jj[:, None] + ky + oy[None, :], ii[:, None] + kx + ox[None, :]]      # (C, K)
    d_all = np.where(hit, dist[None, :], np.inf)
    best = d_all.min(axis=1) if d_all.shape[1] else np.full(jj.size, np.inf)
    nearest = hit & (d_all <= best[:, None] + 1e-12 * r[None, :])
    unit = np.c_[ox * hx / r, oy * hy / r]
    normal = nearest.astype(np.float64) @ unit
    length = np.linalg.norm(normal, axis=1)
    flat = np.isfinite(best) & (length < 1e-9)   # opposite nearest nodes (a strip): either
    if flat.any():
        normal[flat] = unit[np.argmax(nearest[flat], axis=1)]
        length[flat] = 1.0
    normal /= np.maximum(length, 1e-300)[:, None]
    return jj, ii, best, normal


#: the gap fill's window: nodes within this many steps each way
FILL_REACH = 3


def fill_gaps(u: np.ndarray, valid: np.ndarray, gaps: np.ndarray, hx: float,
              hy: float) -> np.ndarray:
    """``u`` (ny, nx, k) with the nodes ``gaps`` set from a weighted quadratic
    least-squares fit to the ``valid`` nodes within :data:`FILL_REACH` steps
    (Wendland weights on the distance in steps over FILL_REACH + 1; exact on
    quadratics); the mean of the valid nodes there where fewer than 6 are (or
    their layout cannot carry a quadratic), 0 where none is."""
    out = np.array(u, dtype=np.float64)
    jj, ii = np.nonzero(gaps)
    if jj.size == 0:
        return out
    ny, nx = valid.shape
    R = FILL_REACH
    oy, ox = np.mgrid[-R:R + 1, -R:R + 1]
    oy, ox = oy.ravel(), ox.ravel()
    q = np.hypot(oy, ox) / (R + 1.0)
    w0 = np.where(q < 1.0, (1.0 - q) ** 4 * (1.0 + 4.0 * q), 0.0)
    B = np.stack([np.ones_like(q), ox, oy, ox * ox, ox * oy, oy * oy], axis=1)   # (s, 6)
    J_ = jj[:, None] + oy[None, :]
    I_ = ii[:, None] + ox[None, :]
    inb = (J_ >= 0) & (J_ < ny) & (I_ >= 0) & (I_ < nx)
    Jc, Ic = np.clip(J_, 0, ny - 1), np.clip(I_, 0, nx - 1)
    ok = inb & valid[Jc, Ic]
    W = ok * w0[None, :]                                            # (g, s)
    vals = np.where(ok[..., None], out[Jc, Ic], 0.0)                # (g, s, k)
    M = np.einsum("gs,si,sj->gij", W, B, B)
    M += 1e-12 * np.trace(M, axis1=1, axis2=2)[:, None, None] * np.eye(6)
    rhs = np.einsum("gs,si,gsk->gik", W, B, vals)
    count = ok.sum(axis=1)
    wsum = W.sum(axis=1)
    mean = (W[..., None] * vals).sum(axis=1) / np.maximum(wsum, 1e-300)[:, None]
    fit = mean.copy()
    enough = count >= 6
    if enough.any():
        Me = M[enough]
        # a layout that cannot carry a quadratic (a line of nodes) keeps the mean
        cond = np.linalg.cond(Me)
        good = np.isfinite(cond) & (cond < 1e10)
        idx = np.flatnonzero(enough)[good]
        if idx.size:
            fit[idx] = np.linalg.solve(M[idx], rhs[idx])[:, 0, :]
    fit[wsum == 0] = 0.0
    out[jj, ii] = fit
    return out


def natural_on_nodes(hx: float, hy: float, u: np.ndarray, v: np.ndarray, inside: np.ndarray,
                     used: np.ndarray, length: float = 1.0, origin=(0.0, 0.0),
                     evaluation: str = "fft") -> dict:
    """The natural decomposition of the field ``u``, ``v`` (ny, nx; finite on
    ``used``) over the cells of the nodes ``inside`` (bool (ny, nx); ``used``
    a subset: the nodes with vectors, the others inside are gaps filled by
    :func:`fill_gaps`), on the uniform grid of steps ``hx``, ``hy``.

    ``length``: the unit of length of the Green's function ln(|x| / length) /
    (2 pi) (the scattered path's unit frame: the potentials then agree with
    its; the gradients do not depend on it).  ``evaluation``: ``fft``, or
    ``direct`` (:func:`~taichi_hh.hhd.natural.convolve_direct`, O(M^2): the
    same sum's exact reference).

    Returns a dict of (ny, nx) arrays (NaN off ``inside``; ``divergence``,
    ``curl``: div v, curl v on the inside nodes, the gaps' from their fill):
    ``phi``, ``psi``, ``curl_free`` and ``div_free`` ((ny, nx, 2)),
    ``harmonic`` (v - d - r on ``used``, NaN elsewhere), ``h_divergence``,
    ``h_curl`` (div h and curl h), ``components_div_curl`` ((ny, nx, 2):
    div d and curl r, 0 off ``inside``), ``codes`` (the stencils along x and y
    of the potentials, :func:`stencil_codes`), ``data_codes`` (those of the
    vectors: second order next to the outline), ``grid`` (:class:`NodeGrid`) and ``seconds`` per stage."""
    seconds = {}
    clock = [time.perf_counter()]

    def lap(stage):
        now = time.perf_counter()
        seconds[stage] = now - clock[0]
        clock[0] = now

    ny, nx = inside.shape
    vec = np.stack([u, v], axis=-1, dtype=np.float64)
    if not used.all():
        vec[~used] = 0.0
        gaps = inside & ~used
        if gaps.any():
            vec = fill_gaps(vec, used, gaps, hx, hy)
    lap("fill")
    codes, dc = codes_div_curl(inside, vec, hx, hy)      # the data's differences
    div, curl = dc[..., 0], dc[..., 1]
    lap("divergence")
    grid = NodeGrid(origin, hx, hy, nx, ny)
    dens = np.stack([div.T, -curl.T])                   # the Grid's (nx, ny) layout
    if evaluation == "fft":
        pot = convolve_fft(grid, dens)
    else:
        pot = np.stack([convolve_direct(grid, q) for q in dens])
    # ln(|x| / length): minus ln(length) / (2 pi) times each density's integral
    shift = math.log(length) / (2.0 * math.pi) * hx * hy
    P = np.empty((ny, nx, 2))
    P[..., 0] = pot[0].T
    P[..., 1] = pot[1].T
    P[..., 0] -= shift * float(div.sum())
    P[..., 1] += shift * float(curl.sum())
    lap("convolve")
    # d, r, h, then div h and curl h over the data's stencils (how harmonic h
    # is; h at the gaps from their fill): one launch
    drh = components_checks(P, vec, codes, hx, hy)
    d, r, h, hdc = drh[0], drh[1], drh[2], drh[3]
    ddr = drh[4]
    lap("gradient")
    out = {"phi": P[..., 0], "psi": P[..., 1], "divergence": dc[..., 0], "curl": dc[..., 1],
           "curl_free": d, "div_free": r, "codes": (codes[0], codes[1]),
           "data_codes": (codes[2], codes[3])}
    if not inside.all():
        out_mask = ~inside
        P[out_mask] = np.nan
        dc[out_mask] = np.nan
    if not used.all():
        h[~used] = np.nan
    out["harmonic"] = h
    out["h_divergence"], out["h_curl"] = hdc[..., 0], hdc[..., 1]
    out["components_div_curl"] = ddr
    out["grid"] = grid
    lap("gather")
    out["seconds"] = seconds
    return out


# --------------------------------------------------------------------------- the grid's result
@dataclass
class NodeFields:
    """A decomposition on a uniform grid's nodes, on the grid: the increasing
    axes ``x``, ``y``, steps ``hx``, ``hy``, the nodes ``inside`` the domain
    and ``used`` (decomposed), the input ``u``, ``v`` (ny, nx), and on every
    node (ny, nx[, 2], NaN off ``inside``) ``phi``, ``psi``, ``curl_free``,
    ``div_free``, ``divergence``, ``curl``, and ``harmonic`` (NaN off
    ``used``); ``codes``: the difference stencils along x and y
    (:func:`stencil_codes`); ``components_div_curl``: (ny, nx, 2) div d and
    curl r by them (0 off ``inside``); ``spacing``: sqrt(area / nodes used);
    ``domain``: the outline; ``stats`` and ``options``: the decomposition's;
    ``frame``: the unit frame its potentials' logarithm took its length from.
    What its critical points are found from
    (:func:`~taichi_hh.hhd.critical_grid.find_grid_critical_points`)."""
    x: np.ndarray
    y: np.ndarray
    hx: float
    hy: float
    inside: np.ndarray
    used: np.ndarray
    u: np.ndarray
    v: np.ndarray
    phi: np.ndarray
    psi: np.ndarray
    curl_free: np.ndarray
    div_free: np.ndarray
    harmonic: np.ndarray
    divergence: np.ndarray
    curl: np.ndarray
    codes: tuple
    data_codes: tuple
    components_div_curl: np.ndarray
    spacing: float
    domain: object
    stats: dict
    options: object
    frame: object

    @property
    def vectors(self) -> np.ndarray:
        """(ny, nx, 2) the input's vectors, NaN off ``used``."""
        out = np.stack([self.u, self.v], axis=-1)
        out[~self.used] = np.nan
        return out

    def div_curl(self, w: np.ndarray) -> np.ndarray:
        """(ny, nx, 2): div w and curl w of a field ``w`` (ny, nx, 2) finite on
        the inside nodes, by the decomposition's differences (NaN off them)."""
        out = div_curl(w, self.inside, self.hx, self.hy, self.codes)
        out[~self.inside] = np.nan
        return out

    def result(self) -> "NodeResult":
        """The decomposition of the used nodes (in the grid's row order) as an
        :class:`NodeResult`."""
        idx = np.flatnonzero(self.used.ravel())
        X, Y = np.meshgrid(self.x, self.y)
        n_all = self.used.size

        def take(a):
            a = np.asarray(a)
            return a.reshape((n_all,) + a.shape[2:])[idx]
        return NodeResult(points=np.c_[take(X), take(Y)], vectors=np.c_[take(self.u),
                                                                        take(self.v)],
                          curl_free=take(self.curl_free), div_free=take(self.div_free),
                          harmonic=take(self.harmonic), phi=take(self.phi), psi=take(self.psi),
                          divergence=take(self.divergence), curl=take(self.curl),
                          stats=self.stats, options=self.options,
                          valid=np.ones(idx.size, dtype=bool), frame=self.frame,
                          domain=self.domain, lattice=self)


@dataclass
class NodeResult(HHDResult):
    """An :class:`~taichi_hh.hhd.decompose.HHDResult` of the nodes a uniform
    grid's natural decomposition used (``points`` in row order of the grid),
    with ``lattice`` (:class:`NodeFields`): its critical points are found on
    the grid (no neighbour search)."""
    lattice: NodeFields = field(repr=False, default=None)


def decompose_nodes(xs: np.ndarray, ys: np.ndarray, steps: tuple, u: np.ndarray,
                    v: np.ndarray, inside: np.ndarray, used: np.ndarray, domain, opts,
                    chosen: dict, progress=None) -> NodeFields:
    """The natural decomposition (:func:`natural_on_nodes`) of the grid with
    increasing axes ``xs``, ``ys`` and steps ``steps`` = (hx, hy) over the
    nodes ``inside`` (the cells that make ``domain``), the vectors on
    ``used``, as a :class:`NodeFields` whose ``stats`` are those
    :func:`~taichi_hh.hhd.decompose.decompose` gives (``chosen``: the
    condition chosen and the boundary flux), the energy and the harmonicity
    flagged alike."""
    from .inputs import check_point_count
    from .units import Frame
    t_start = time.perf_counter()
    say = progress or (lambda stage: None)
    hx, hy = steps
    full = bool(used.all())
    n = used.size if full else int(used.sum())
    stats = {}
    check_point_count(n, stats, stacklevel=4)
    idx = None if full else np.flatnonzero(used.ravel())

    def take(a):                          # the used nodes' rows of a grid array
        a = a.reshape((used.size,) + a.shape[2:])
        return a if idx is None else a[idx]
    vec = np.stack([take(u), take(v)], axis=1)
    frame = Frame.of(domain.bounds, vec)
    flags = []
    if (vec == 0.0).any():               # blocks of exact zeros named (PIV's invalid mark)
        X, Y = np.meshgrid(xs, ys)
        _flag_zero_vectors(vec, np.c_[take(X), take(Y)], np.flatnonzero(used.ravel()), flags)
    say("natural potentials")
    nat = natural_on_nodes(hx, hy, u, v, inside, used, frame.length, (xs[0], ys[0]),
                           opts.natural_evaluation)
    spacing = math.sqrt(domain.area / n)
    seconds = {f"natural_{k}": s for k, s in nat["seconds"].items()}
    seconds["natural"] = sum(nat["seconds"].values())
    stats.update(n_points=n, n_boundary=0, n_ghosts=0, support=opts.support_ratio * spacing,
                 spacing=spacing, natural_grid=nat["grid"].shape, grid_native=True)
    stats["flags"] = flags + stats.get("flags", [])
    d, r, h = take(nat["curl_free"]), take(nat["div_free"]), take(nat["harmonic"])
    _energy_check(stats, vec, d, r, h, opts)
    div_v, curl_v = take(nat["divergence"]), take(nat["curl"])
    scale = _mean_norm(div_v, curl_v)
    ratios = {}
    for name in ("divergence", "curl"):
        mean = float(np.abs(take(nat[f"h_{name}"])).mean())
        ratios[name] = mean / scale if scale > 0 else (0.0 if mean == 0 else math.inf)
    flag_harmonic(stats, ratios, opts)
    stats.update(chosen)
    stats["n_invalid"] = 0
    stats["frame"] = frame.as_dict()
    seconds["total"] = time.perf_counter() - t_start
    stats["seconds"] = seconds
    return NodeFields(x=xs, y=ys, hx=hx, hy=hy, inside=inside, used=used, u=u, v=v,
                      phi=nat["phi"], psi=nat["psi"], curl_free=nat["curl_free"],
                      div_free=nat["div_free"], harmonic=nat["harmonic"],
                      divergence=nat["divergence"], curl=nat["curl"], codes=nat["codes"],
                      data_codes=nat["data_codes"],
                      components_div_curl=nat["components_div_curl"], spacing=spacing, domain=domain, stats=stats, options=opts, frame=frame)


def _mean_norm(a: np.ndarray, b: np.ndarray) -> float:
    """mean sqrt(a^2 + b^2), by the squares where the mean is far from
    overflow and underflow (np.hypot, whose guard costs five times as much:
    0.25 ms at 161 x 81 nodes, elsewhere)."""
    mean = float(np.sqrt(a * a + b * b).mean())
    if not 1e-100 < mean < 1e100:
        mean = float(np.hypot(a, b).mean())
    return mean


def _energy_check(stats: dict, v, d, r, h, opts) -> None:
    """``stats["energy_ratio"]`` (|d|^2 + |r|^2 + |h|^2 over |v|^2, the nodes'
    volumes equal) as :func:`~taichi_hh.hhd.decompose.decompose` measures it,
    flagged above :data:`~taichi_hh.hhd.decompose.ENERGY_LIMIT` in its words
    (the default method's operators: the grid-native path runs with them)."""
    def energy(x):
        return float(np.einsum("ij,ij->", x, x))
    total = energy(v)
    ratio = (energy(d) + energy(r) + energy(h)) / total if total > 0 else 1.0
    stats["energy_ratio"] = ratio
    stats.setdefault("flags", [])
    if not np.isfinite(ratio) or ratio > ENERGY_LIMIT:
        msg = (f"decomposition components carry {ratio:.3g} times the field's energy "
               "(|d|^2 + |r|^2 + |h|^2 over |v|^2; 1 for an exact decomposition): the "
               "components cancel each other: the data are too few or too noisy for the "
               "operators at this resolution, or the boundary condition "
               f"({opts.boundary_condition!r}) forces large opposite parts near the boundary "
               "(boundary_condition='natural' imposes none); the components are unreliable")
        stats["flags"].append(msg)
        warnings.warn(msg, AccuracyWarning, stacklevel=4)


def _flag_zero_vectors(vec, points, rows, flags: list) -> None:
    """Name exactly zero vectors when there are enough of them to be an
    instrument's mark for invalid ones rather than still fluid (as
    :func:`~taichi_hh.hhd.decompose.decompose` does; ``rows``: the nodes'
    flat indices on the grid)."""
    from .inputs import ZERO_FRACTION, ZERO_ROWS
    zero = (vec == 0.0).all(axis=1)
    count = int(zero.sum())
    if count < max(ZERO_ROWS, ZERO_FRACTION * zero.size) or count == zero.size:
        return
    where = rows[zero]
    lo, hi = points[zero].min(axis=0), points[zero].max(axis=0)
    msg = (f"{count} of {zero.size} vectors are exactly zero (rows {where[0]}"
           f"{', ' + str(where[1]) if count > 1 else ''}, ...; within x {lo[0]:.6g}..{hi[0]:.6g},"
           f" y {lo[1]:.6g}..{hi[1]:.6g}): they are decomposed as still fluid. PIV software "
           "(DaVis text, Insight .vec) writes invalid vectors as zeros; if these are invalid, "
           "mark them missing (NaN, or False in valid)")
    flags.append(msg)
    warnings.warn(msg, AccuracyWarning, stacklevel=4)
