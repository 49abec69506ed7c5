"""Scattered points with SPH operators, numpy in and numpy out.

:class:`PointSet` is the assembly step of the pipeline: validate the points,
make particles (mass = area / N, Petronetto Sec. 5a), bin and reorder them by
cell, build the pair list, compute densities by summation, and expose every
operator variant on numpy arrays given in the caller's point order.
"""
from __future__ import annotations

import math

import numpy as np

from .. import runtime
from ..arrays import bounds
from ..checks import check_points, check_values
from ..errors import InputError, NeighbourError
from .kernels import KERNELS
from .neighbors import GridSpec, PairList, bin_particles
from .operators import Operators
from .particles import BOUNDARY, FLUID, GHOST, Particles, from_slots, to_slots

#: default kernel support radius in units of the mean particle spacing
#: sqrt(area / N): 24 neighbours on a regular lattice, about 26 on disordered
#: points (pi * 3^2 - 1 on average), enough for the corrected operators to stay
#: well conditioned on strongly disordered points.
DEFAULT_SUPPORT_RATIO = 3.0
DEFAULT_KERNEL = "wendland"
#: points closer than this fraction of the mean spacing count as duplicates
DUPLICATE_FRACTION = 1e-6
#: the direction along which :func:`close_pair` sorts the points: of slope the
#: golden ratio, so that no row, column or diagonal of a lattice projects onto
#: one value (every pair of a 1000 x 1000 lattice stays ~1e-3 steps apart)
_GOLDEN = (1.0 + 5.0 ** 0.5) / 2.0
_SORT_DIRECTION = np.array([1.0, _GOLDEN]) / math.hypot(1.0, _GOLDEN)


#: from this many points on, :func:`close_pair` screens them in O(N) first
#: (:func:`~.close_screen.screen`) and sorts only where the screen finds a pair
SCREEN_MIN_POINTS = 50_000


def close_pair(points, tolerance: float = 0.0):
    """``(i, j)``, ``i < j``: a pair of ``points`` at most ``tolerance`` apart
    (0: exact copies), the one with the lowest first index among those found
    first, or None when there is none.  Float64 and numpy whatever the Taichi
    precision: two points distinct in float64 are never taken for copies
    because single precision rounds them together.

    The points are sorted by their projection on :data:`_SORT_DIRECTION`; a
    pair within ``tolerance`` lies in one run of that order whose consecutive
    projections are within ``tolerance``.  The points of such runs (none or a
    few, but for copies) are sorted by run, then across the direction, and
    the pairs k apart in that order tested for k = 1, 2, ... while any is in
    one run and that close across (O(N log N); a lattice whose rows lie
    across the direction costs one more sort).  From
    :data:`SCREEN_MIN_POINTS` points on, an O(N) screen on a grid of cells
    answers None first where no pair is that close."""
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n < 2:
        return None
    if n >= SCREEN_MIN_POINTS:
        from .close_screen import screen
        lo, hi = bounds(pts)
        if screen(pts, lo, hi, tolerance) is False:
            return None
    # elementwise, not pts @ direction: a BLAS call this long wakes
    # OpenBLAS's threads, which spin beside Taichi's pinned workers after it
    proj = pts[:, 0] * _SORT_DIRECTION[0] + pts[:, 1] * _SORT_DIRECTION[1]
    order = np.argsort(proj)                  # (a third of a stable sort's time)
    sp = proj[order]
    # the projections' rounding: a pair tolerance apart may differ a little more
    reach = float(tolerance) + 4e-16 * float(np.abs(pts).max())
    close = sp[1:] - sp[:-1] <= reach
    if not close.any():
        return None
    in_run = np.zeros(n, dtype=bool)
    in_run[:-1] |= close
    in_run[1:] |= close
    run = np.concatenate([[0], np.cumsum(~close)])[in_run]
    idx = order[in_run]
    across = pts[idx, 1] * _SORT_DIRECTION[0] - pts[idx, 0] * _SORT_DIRECTION[1]
    by = np.lexsort((across, run))
    idx, run, across = idx[by], run[by], across[by]
    tol2 = float(tolerance) ** 2
    m = len(idx)
    cand = np.arange(m - 1)
    k = 1
    while True:
        cand = cand[cand + k < m]
        cand = cand[(run[cand + k] == run[cand]) & (across[cand + k] - across[cand] <= reach)]
        if not cand.size:
            return None
        a, b = idx[cand], idx[cand + k]
        d = pts[a] - pts[b]
        hit = np.flatnonzero(np.einsum("ij,ij->i", d, d) <= tol2)
        if hit.size:
            lo, hi = np.minimum(a[hit], b[hit]), np.maximum(a[hit], b[hit])
            first = int(np.argmin(lo))
            return int(lo[first]), int(hi[first])
        k += 1


def _listed(idx) -> str:
    """'points 3 and 7', 'points 3, 7, 9, 12, 15, 20 and 44 more'."""
    idx = [int(i) for i in idx]
    if len(idx) == 2:
        return f"points {idx[0]} and {idx[1]}"
    if len(idx) <= 6:
        return "points " + ", ".join(map(str, idx[:-1])) + f" and {idx[-1]}"
    return "points " + ", ".join(map(str, idx[:6])) + f" and {len(idx) - 6} more"


def check_distinct(points, tolerance: float | None = None, *, rows=None,
                   n_data: int | None = None) -> None:
    """Refuse (:class:`~taichi_hh.errors.InputError`) points given more than once:
    any two at most ``tolerance`` apart (default :data:`DUPLICATE_FRACTION` of
    the mean spacing sqrt(bounding-box area / N); exact copies only where the
    box has no area).  The message names the point's coordinates, how many
    copies of it there are and their indices (``rows[i]`` for index i when
    ``rows`` is given: the caller's row numbers).  Points from ``n_data`` on
    are boundary or fake particles (named as such).  Float64 (:func:`close_pair`).

    Any number of copies counts: every SPH operator is singular on them (and
    a local spacing from the k nearest neighbours is zero from k + 1 copies)."""
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n < 2:
        return
    if tolerance is None:
        lo, hi = bounds(pts)
        box = float(np.prod(hi - lo))
        tolerance = DUPLICATE_FRACTION * math.sqrt(box / n) if box > 0 else 0.0
    pair = close_pair(pts, tolerance)
    if pair is None:
        return
    i, j = pair
    d2 = ((pts - pts[i]) ** 2).sum(axis=1)
    members = np.flatnonzero(d2 <= float(tolerance) ** 2)
    count = members.size
    n_data = n if n_data is None else int(n_data)
    name = (lambda k: int(k)) if rows is None else (lambda k: int(np.asarray(rows)[k]))
    x, y = pts[i]
    at = f"({x:.9g}, {y:.9g})"
    if members[-1] >= n_data:
        # boundary or fake particles (made by the package, never the caller's)
        if members[0] < n_data:
            raise InputError(
                f"point {name(members[0])} at {at} lies on a boundary or fake particle "
                f"({count} within {tolerance:.3g}): a point sits where the domain's boundary "
                "is sampled; move it inside the domain")
        raise InputError(
            f"{count} boundary or fake particles lie within {tolerance:.3g} of {at}: the "
            "domain's boundary has vertices or pieces closer than 1e-6 of the points' "
            "spacing; remove the repeated vertex")
    listed = _listed([name(k) for k in members])
    if (pts[members] == pts[i]).all():
        raise InputError(
            f"duplicate points: {listed} are {count} copies of the point {at}: give every "
            "point once (drop the copies, or merge them into one point with the mean of "
            "their vectors)")
    raise InputError(
        f"duplicate points: {listed} are {count} points within {tolerance:.3g} of {at} "
        f"({math.sqrt(d2[members].max()):.3g} apart at most), closer than "
        f"{DUPLICATE_FRACTION:g} of the points' mean spacing: the SPH operators cannot tell "
        "them apart, as if one point were given several times; drop or merge them")


class PointSet:
    """SPH operators on scattered 2D points.

    Parameters
    ----------
    points: (N, 2) array: the data points (fluid particles).
    kernel: one of ``quartic``, ``poly6``, ``wendland``, ``cubic``.
    support_ratio: kernel support radius / mean spacing ``sqrt(area / N)``.
    support: the support radius itself (overrides ``support_ratio``).
    area: the domain's area (default: the points' bounding box).
    mass: particle mass (default ``area / N``, Petronetto Sec. 5a).
    boundary: optional ``(points, outward normals)`` of boundary particles.
    ghosts: optional (G, 2) fake particles outside the domain.
    support_neighbours: k for an adaptive support (:mod:`taichi_hh.sph.support`):
    every particle's support is ``support_ratio`` local spacings, estimated
    from its k nearest neighbours, and pairs use the larger of their two
    supports; None (default) for the fixed support.  ``support`` (explicit)
    always means a fixed support.

    Boundary and ghost particles get the data points' mass, join the neighbour
    search and the density summation, and are what the Poisson rows of
    :mod:`taichi_hh.poisson.matrix` use; the numpy operator methods below take values
    at the data points only and sum over data-point neighbours only.
    """

    def __init__(self, points, *, kernel: str = DEFAULT_KERNEL,
                 support_ratio: float = DEFAULT_SUPPORT_RATIO, support: float | None = None,
                 area: float | None = None, mass=None, boundary=None, ghosts=None,
                 support_neighbours: int | None = None):
        pts = check_points(points)
        if kernel not in KERNELS:
            raise ValueError(f"unknown kernel {kernel!r}; choose one of {KERNELS}")
        runtime.ensure_init()
        n = pts.shape[0]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if area is None or boundary is not None or ghosts is not None:
            # one point, a line or a single row: no area for the mass and spacing,
            # nor a 2D domain for boundary or fake particles to close (alone,
            # with an area given, a line is left to the operators, which refuse
            # their corrected variants on it)
            from ..checks import check_spread
            check_spread(pts)
        if area is None:
            area = float(np.prod(hi - lo))
        if not (area > 0 and math.isfinite(area)):
            raise InputError(f"area must be a positive finite number (the domain's area), got "
                             f"{area!r}")
        self.n = n
        self.area = float(area)
        self.spacing = math.sqrt(self.area / n)
        self.support = float(support) if support is not None else support_ratio * self.spacing
        self.kernel = kernel
        mass = self.area / n if mass is None else mass
        # data points, boundary samples, ghosts: one append (each append rewrites
        # every quantity's whole array)
        parts, normals, kinds = [pts], [np.zeros_like(pts)], [np.full(n, FLUID, np.int32)]
        if boundary is not None:
            if len(boundary[0]) == 0:
                raise InputError("boundary=(points, normals) holds no boundary particle: pass "
                                 "boundary=None for none")
            bpts = check_points(boundary[0], "boundary points")
            parts.append(bpts)
            normals.append(check_values(boundary[1], len(bpts), 2, "boundary normals"))
            kinds.append(np.full(len(bpts), BOUNDARY, np.int32))
        if ghosts is not None and len(ghosts):
            gpts = check_points(ghosts, "ghost points")
            parts.append(gpts)
            normals.append(np.zeros_like(gpts))
            kinds.append(np.full(len(gpts), GHOST, np.int32))
        allpts = np.concatenate(parts) if len(parts) > 1 else pts
        # copies (any number: k + 1 of them would make the adaptive supports
        # zero), in float64 here rather than by the pair search in the runtime's
        # precision, where float32 would merge points distinct in float64
        tolerance = DUPLICATE_FRACTION * self.spacing
        check_distinct(allpts, tolerance, n_data=n)
        p = self.particles = Particles(len(allpts))
        p.append(allpts, mass=mass, kind=np.concatenate(kinds), normal=np.concatenate(normals))
        self.n_total = p.n
        supports = None           # per particle, input order (data, boundary, ghosts)
        if support_neighbours is not None and support is None:
            from .support import adaptive_supports
            nb = 0 if boundary is None else len(boundary[0])
            supports = adaptive_supports(allpts, support_ratio, int(support_neighbours),
                                         self.area, boundary=slice(n, n + nb))
            self.support = float(supports.max())
        if supports is None:
            spec = GridSpec.covering(allpts.min(axis=0), allpts.max(axis=0), self.support)
        else:       # cells narrower than the largest support (sph.support)
            from .support import adaptive_grid_spec
            spec = adaptive_grid_spec(allpts, supports)
        self.grid = bin_particles(p, spec)
        self.pairs = PairList()
        hs = None
        if supports is not None:
            hs = runtime.array(runtime.real_dtype(), max(p.n, 1))
            hs.from_numpy(np.resize(supports[p.get("original_index")],
                                    max(p.n, 1)).astype(runtime.np_real()))
        self.supports = supports[:n] if supports is not None else np.full(n, self.support)
        if hs is None:
            self.pairs.build(p.position, p.n, p.position, self.grid, self.support)
        else:
            from .support import adaptive_pairs
            adaptive_pairs(self.pairs, p, self.grid, hs)
        # slot -> input index over all particles (data points first, then boundary, ghosts)
        self.order = p.get("original_index").astype(np.int64)
        self.slot_of_all = np.empty(p.n, dtype=np.int64)
        self.slot_of_all[self.order] = np.arange(p.n)
        self.slot_of = self.slot_of_all[:n]                    # data point -> slot
        counts = self.pairs.counts()
        lonely = np.flatnonzero(counts[self.slot_of] == 0)
        if lonely.size:
            i = int(lonely[0])
            raise NeighbourError(
                f"point {i} at {pts[i].tolist()} has no neighbour within the kernel support "
                f"{self.supports[i]:.6g}; {lonely.size} point(s) are isolated. "
                "Increase support_ratio.")
        self.neighbour_counts = counts[self.slot_of]
        self.ops = Operators(p, self.pairs, self.support, kernel, supports=hs)
        self.ops.compute_density()
        self._stencils: dict = {}

    # ---- slot <-> caller order ---------------------------------------------------
    def new_array(self, ncomp: int = 1, *, zeroed: bool = True):
        """A Taichi array with one entry per particle slot, zeroed (Taichi's fill
        on allocation: no fill pass, which for vectors is a kernel launch of its
        own) unless ``zeroed=False``, for an array written in full before it is
        read (no serial fill: the writing kernel's loop touches its pages first)."""
        real = runtime.real_dtype()
        size = max(self.n_total, 1)
        if ncomp == 1:
            return runtime.array(real, size, zeroed=zeroed)
        return runtime.array(real, size, vector=ncomp, zeroed=zeroed)

    def upload(self, values):
        """Data-point values (caller order) -> Taichi array in slot order
        (zero at boundary and ghost slots): one scatter kernel."""
        values = np.ascontiguousarray(values, dtype=np.float64)
        ncomp = 1 if values.ndim == 1 else values.shape[1]
        nd = self.new_array(ncomp, zeroed=self.n_total > self.n or self.n == 0)
        if self.n:
            to_slots(values.reshape(self.n, ncomp), self._slots(), ncomp, ncomp > 1, nd)
        return nd

    def download(self, nd) -> np.ndarray:
        """Taichi array in slot order -> data-point values in caller order
        (float64): one gather kernel."""
        shape = tuple(getattr(nd, "element_shape", ()))
        ncomp = shape[0] if shape else 1
        out = np.empty((self.n, ncomp))
        if self.n:
            from_slots(nd, self._slots(), ncomp, bool(shape), out)
        return out if shape else out[:, 0]

    def _slots(self) -> np.ndarray:
        """slot_of as int32 (the kernels' index), made once."""
        if getattr(self, "_slot32", None) is None:
            self._slot32 = np.ascontiguousarray(self.slot_of, dtype=np.int32)
        return self._slot32

    def gradient_stencil(self, variant: str, source_kinds=(FLUID,)):
        key = ("gradient", variant, tuple(source_kinds))
        if key not in self._stencils:
            self._stencils[key] = self.ops.gradient_coefficients(
                variant, row_kinds=(FLUID,), source_kinds=source_kinds)
        return self._stencils[key]

    def laplacian_stencil(self, variant: str, source_kinds=(FLUID,)):
        key = ("laplacian", variant, tuple(source_kinds))
        if key not in self._stencils:
            self._stencils[key] = self.ops.laplacian_coefficients(
                variant, row_kinds=(FLUID,), source_kinds=source_kinds)
        return self._stencils[key]

    # ---- operators on numpy arrays -------------------------------------------------
    def density(self) -> np.ndarray:
        return self.particles.get("density")[self.slot_of]

    def volume(self) -> np.ndarray:
        return self.particles.get("volume")[self.slot_of]

    def gradient(self, f, variant: str = "corrected") -> np.ndarray:
        """(N, 2) gradient of the scalar samples ``f``."""
        f = check_values(f, self.n, 1, "f")
        out = self.new_array(2)
        self.ops.gradient(self.gradient_stencil(variant), self.upload(f), out)
        return self.download(out)

    def divergence(self, v, variant: str = "corrected") -> np.ndarray:
        v = check_values(v, self.n, 2, "v")
        out = self.new_array(1)
        self.ops.divergence(self.gradient_stencil(variant), self.upload(v), out)
        return self.download(out)

    def curl(self, v, variant: str = "corrected") -> np.ndarray:
        """Scalar 2D curl dv_y/dx - dv_x/dy, as div(J v) (Petronetto Eq. 4)."""
        v = check_values(v, self.n, 2, "v")
        out = self.new_array(1)
        self.ops.curl(self.gradient_stencil(variant), self.upload(v), out)
        return self.download(out)

    def laplacian(self, f, variant: str = "corrected") -> np.ndarray:
        f = check_values(f, self.n, 1, "f")
        out = self.new_array(1)
        self.ops.laplacian(self.laplacian_stencil(variant), self.upload(f), out)
        return self.download(out)

    def interpolate(self, f) -> np.ndarray:
        """Shepard-normalised SPH smoothing of ``f`` at the points (Petronetto Eq. 14)."""
        f = check_values(f, self.n, 1, "f")
        out = self.new_array(1)
        self.ops.shepard(self.upload(f), out, source_kinds=(FLUID,))
        return self.download(out)
