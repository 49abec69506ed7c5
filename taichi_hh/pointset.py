"""Scattered points with SPH operators, numpy in and numpy out.

:class:`PointSet` is the assembly step of the pipeline: validate the points,
make particles (mass = area / N, Petronetto Sec. 5a), bin and reorder them by
cell, build the pair list, compute densities by summation, and expose every
operator variant on numpy arrays given in the caller's point order.
"""
from __future__ import annotations

import math

import numpy as np
import taichi as ti

from . import runtime
from .errors import InputError, NeighbourError
from .kernels import KERNELS
from .neighbors import GridSpec, PairList, bin_particles
from .operators import Operators
from .particles import FLUID, Particles

#: default kernel support radius in units of the mean particle spacing
#: sqrt(area / N): 24 neighbours on a regular lattice, about 26 on disordered
#: points (pi * 3^2 - 1 on average), enough for the corrected operators to stay
#: well conditioned on strongly disordered points.
DEFAULT_SUPPORT_RATIO = 3.0
DEFAULT_KERNEL = "wendland"
#: points closer than this fraction of the mean spacing count as duplicates
DUPLICATE_FRACTION = 1e-6


def check_points(points, name: str = "points") -> np.ndarray:
    """Validate an (N, 2) array of finite coordinates; returns it as float64."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric (N, 2) array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must have shape (N, 2), got {arr.shape}")
    if arr.shape[0] == 0:
        raise InputError(f"{name} is empty: at least one point is needed")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise InputError(f"{name} contains {idx.size} non-finite (NaN or inf) entries, "
                         f"first at index {idx[0]}: {arr[idx[0]].tolist()}")
    return arr


def check_values(values, n: int, ncomp: int, name: str = "values") -> np.ndarray:
    """Validate per-point values: shape (n,) for ncomp = 1 or (n, ncomp); finite."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric: {exc}") from None
    want = (n,) if ncomp == 1 else (n, ncomp)
    if arr.shape != want:
        raise InputError(f"{name} must have shape {want} (one per point), got {arr.shape}")
    bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise InputError(f"{name} contains {idx.size} non-finite (NaN or inf) entries, "
                         f"first at point {idx[0]}")
    return arr


class PointSet:
    """SPH operators on scattered 2D points.

    Parameters
    ----------
    points: (N, 2) array.
    kernel: one of ``quartic``, ``poly6``, ``wendland``, ``cubic``.
    support_ratio: kernel support radius / mean spacing ``sqrt(area / N)``.
    support: the support radius itself (overrides ``support_ratio``).
    area: the domain's area (default: the points' bounding box).
    mass: particle mass (default ``area / N``).
    """

    def __init__(self, points, *, kernel: str = DEFAULT_KERNEL,
                 support_ratio: float = DEFAULT_SUPPORT_RATIO, support: float | None = None,
                 area: float | None = None, mass=None):
        pts = check_points(points)
        if kernel not in KERNELS:
            raise ValueError(f"unknown kernel {kernel!r}; choose one of {KERNELS}")
        runtime.ensure_init()
        n = pts.shape[0]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if area is None:
            area = float(np.prod(hi - lo))
        if not (area > 0 and math.isfinite(area)):
            raise InputError("the points span no area (all on one line or one point); "
                             "give the domain's area explicitly")
        self.n = n
        self.area = float(area)
        self.spacing = math.sqrt(self.area / n)
        self.support = float(support) if support is not None else support_ratio * self.spacing
        self.kernel = kernel
        mass = self.area / n if mass is None else mass
        self.particles = Particles.from_numpy(pts, mass=mass, kind=FLUID)
        self.grid = bin_particles(self.particles, GridSpec.covering(lo, hi, self.support))
        p = self.particles
        self.pairs = PairList()
        try:
            self.pairs.build(p.position, n, p.position, self.grid, self.support,
                             duplicate_tolerance=DUPLICATE_FRACTION * self.spacing)
        except InputError as exc:
            if getattr(self.pairs, "duplicate_query", None) is None:
                raise
            raise self._duplicate_error() from exc
        self.slot_of = np.empty(n, dtype=np.int64)      # input index -> slot
        self.order = p.get("original_index").astype(np.int64)   # slot -> input index
        self.slot_of[self.order] = np.arange(n)
        counts = self.pairs.counts()
        if (counts == 0).any():
            slot = int(np.flatnonzero(counts == 0)[0])
            raise NeighbourError(
                f"point {self.order[slot]} at {pts[self.order[slot]].tolist()} has no neighbour "
                f"within the kernel support {self.support:.6g}; "
                f"{int((counts == 0).sum())} point(s) are isolated. Increase support_ratio.")
        self.neighbour_counts = counts[self.slot_of]
        self.ops = Operators(p, self.pairs, self.support, kernel)
        self.ops.compute_density()
        self._gradients: dict = {}
        self._laplacians: dict = {}

    def _duplicate_error(self) -> InputError:
        pts = self.particles.get("position")
        orig = self.particles.get("original_index")
        q = self.pairs.duplicate_query
        d = np.linalg.norm(pts - pts[q], axis=1)
        d[q] = np.inf
        j = int(np.argmin(d))
        return InputError(f"duplicate points: points {int(orig[q])} and {int(orig[j])} are "
                          f"{d[j]:.3g} apart (at {pts[q].tolist()}); remove duplicates")

    # ---- slot <-> caller order ---------------------------------------------------
    def _upload(self, values, ncomp: int):
        arr = values[self.order]
        real = runtime.real_dtype()
        if ncomp == 1:
            nd = ti.ndarray(real, shape=(self.n,))
        else:
            nd = ti.Vector.ndarray(ncomp, real, shape=(self.n,))
        nd.from_numpy(arr.astype(runtime.np_real()))
        return nd

    def _new(self, ncomp: int):
        real = runtime.real_dtype()
        if ncomp == 1:
            return ti.ndarray(real, shape=(self.n,))
        return ti.Vector.ndarray(ncomp, real, shape=(self.n,))

    def _download(self, nd) -> np.ndarray:
        arr = nd.to_numpy()[: self.n]
        out = np.empty_like(arr, dtype=np.float64)
        out[self.order] = arr
        return out

    def gradient_stencil(self, variant: str):
        if variant not in self._gradients:
            self._gradients[variant] = self.ops.gradient_coefficients(variant)
        return self._gradients[variant]

    def laplacian_stencil(self, variant: str):
        if variant not in self._laplacians:
            self._laplacians[variant] = self.ops.laplacian_coefficients(variant)
        return self._laplacians[variant]

    # ---- operators on numpy arrays -------------------------------------------------
    def density(self) -> np.ndarray:
        return self.particles.get("density")[self.slot_of]

    def volume(self) -> np.ndarray:
        return self.particles.get("volume")[self.slot_of]

    def gradient(self, f, variant: str = "corrected") -> np.ndarray:
        """(N, 2) gradient of the scalar samples ``f``."""
        f = check_values(f, self.n, 1, "f")
        st = self.gradient_stencil(variant)
        out = self._new(2)
        self.ops.gradient(st, self._upload(f, 1), out)
        return self._download(out)

    def divergence(self, v, variant: str = "corrected") -> np.ndarray:
        v = check_values(v, self.n, 2, "v")
        st = self.gradient_stencil(variant)
        out = self._new(1)
        self.ops.divergence(st, self._upload(v, 2), out)
        return self._download(out)

    def curl(self, v, variant: str = "corrected") -> np.ndarray:
        """Scalar 2D curl dv_y/dx - dv_x/dy, as div(J v) (Petronetto Eq. 4)."""
        v = check_values(v, self.n, 2, "v")
        st = self.gradient_stencil(variant)
        out = self._new(1)
        self.ops.curl(st, self._upload(v, 2), out)
        return self._download(out)

    def laplacian(self, f, variant: str = "corrected") -> np.ndarray:
        f = check_values(f, self.n, 1, "f")
        st = self.laplacian_stencil(variant)
        out = self._new(1)
        self.ops.laplacian(st, self._upload(f, 1), out)
        return self._download(out)

    def interpolate(self, f) -> np.ndarray:
        """Shepard-normalised SPH smoothing of ``f`` at the points (Petronetto Eq. 14)."""
        f = check_values(f, self.n, 1, "f")
        out = self._new(1)
        self.ops.shepard(self._upload(f, 1), out)
        return self._download(out)
