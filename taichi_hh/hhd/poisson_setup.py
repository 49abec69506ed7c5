"""Steps (a)-(d) of the decomposition through the SPH operators (Petronetto
et al. 2010, Sec. 5), split by what they depend on:

* :func:`unit_setup`: everything that depends only on the points and the
  options: particles, boundary or fake particles, the neighbour pairs, the
  stencils of div v and curl v, the assembled Poisson matrix of Eq. 5 with
  the boundary rows of Eq. 6 (its preconditioner is built on first solve and
  kept by the matrix);
* :func:`right_hand_sides`: what depends on the field: div v and curl v on
  the particle slots.

One decomposition runs both once; a series of fields on the same points
(:class:`~taichi_hh.hhd.decomposer.Decomposer`) runs the first once and the
second per field.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .. import runtime
from ..sph.particles import BOUNDARY, FLUID, GHOST
from ..sph.pointset import PointSet
from ..sph.positive import make_rows_positive
from ..poisson.matrix import PoissonMatrix
from .boundary import collocation_particles
from .inputs import Data, check_data_near_boundary, check_data_reach_boundary, refuse_too_few
from .options import HHDOptions

__all__ = ["PoissonSetup", "unit_setup", "right_hand_sides"]


@dataclass
class PoissonSetup:
    """What a decomposition through the SPH operators needs of the points
    and the options alone (module doc), in the unit frame.  ``A`` is None
    under the natural condition (no linear system)."""
    opts: HHDOptions
    points: np.ndarray
    ps: PointSet
    A: PoissonMatrix
    kind: np.ndarray
    seconds: dict
    stats: dict
    domain: object
    divergence_stencil: object       # of div v and curl v, over the data points
    div_sources: tuple               # the particle kinds div v reads
    factor: object = None            # (scipy matrix, its SuperLU) where a series factorised A

    def gradient_stencil(self):
        """The stencil of step (e), d = grad phi and r = J grad psi at the data
        points: the Neumann rows' gradient where it is the same fit, else the
        options' gradient (built once, kept)."""
        st = getattr(self, "_gradient", None)
        if st is None:
            from ..sph.operators import ALL_KINDS
            A, opts = self.A, self.opts
            if A is not None and A.grad.variant == opts.gradient \
                    and A.grad.source_kinds == ALL_KINDS:
                st = A.grad
            else:
                st = self.ps.ops.gradient_coefficients(opts.gradient, row_kinds=(FLUID,))
            self._gradient = st
        return st


def _extra_particles(domain, pts, opts: HHDOptions, spacing: float, support: float):
    """Boundary particles (points, normals) and ghosts for the boundary method."""
    if opts.boundary == "none":
        return None, None
    if opts.boundary == "collocation":
        return collocation_particles(domain, pts, spacing, local=opts.adaptive_support), None
    band = domain.sample_ghosts(spacing, support, seed=opts.seed, avoid=pts)
    if opts.boundary == "colin":
        _, _, nrm, _ = domain.closest_boundary(band)
        return (band, nrm), None
    return None, band                                   # petronetto: fake particles


def default_stencils(opts: HHDOptions) -> bool:
    """Whether the operators are the default's (cubic divergence over the data
    points, quadratic Neumann gradient, corrected Laplacian), which
    :meth:`~taichi_hh.sph.operators.Operators.decomposition_coefficients`
    computes in one kernel."""
    return (opts.divergence == "cubic" and opts.neumann_gradient == "quadratic"
            and opts.laplacian == "corrected" and opts.boundary != "petronetto")


def unit_setup(pts, domain, opts: HHDOptions, progress=None,
               data: Data | None = None) -> PoissonSetup:
    """Steps (a)-(d) that depend on the points alone (module doc), on checked
    points in the unit frame; ``data``: the caller's input (its frame and
    domain for the messages)."""
    say = progress or (lambda stage: None)
    seconds = {}
    n = len(pts)
    refuse_too_few(n)
    spacing = math.sqrt(domain.area / n)
    support = opts.support_ratio * spacing

    natural = opts.boundary_condition == "natural"
    say("setup")
    t = time.perf_counter()
    # the natural decomposition has no boundary rows: the boundary samples of
    # collocation would only be read by stencils it does not build
    rows_on_boundary = not (natural and opts.boundary == "collocation")
    boundary, ghosts = (_extra_particles(domain, pts, opts, spacing, support)
                        if rows_on_boundary else (None, None))
    ps = PointSet(pts, kernel=opts.kernel, support_ratio=opts.support_ratio,
                  support=None if opts.adaptive_support else support, area=domain.area,
                  boundary=boundary, ghosts=ghosts,
                  support_neighbours=opts.support_neighbours if opts.adaptive_support else None)
    if opts.boundary == "collocation" and rows_on_boundary:
        check_data_reach_boundary(ps, BOUNDARY, FLUID, data)
    elif opts.boundary == "collocation":
        check_data_near_boundary(pts, domain, spacing, ps.support, data)
    ops = ps.ops
    p = ps.particles
    kind = p.get("kind")
    near = None
    if opts.boundary == "petronetto":
        ghosts_ok = _ghosts_with_data(ps)
        if not ghosts_ok.all():   # rebuild without fake particles that see no data
            ghosts = p.get("position")[kind == GHOST][ghosts_ok[kind == GHOST]]
            ps = PointSet(pts, kernel=opts.kernel, support=support, area=domain.area,
                          ghosts=ghosts)
            ops, p = ps.ops, ps.particles
            kind = p.get("kind")
        near = _petronetto_band(ps, domain)
    # Eq. 14: petronetto extends v to the fake particles, whose div v then counts
    div_sources = (FLUID, GHOST) if opts.boundary == "petronetto" else (FLUID,)
    st_neumann = st_lap = None
    if default_stencils(opts) and not natural:
        # the three stencils of the default from one kernel (two passes over the pairs)
        st_div, st_neumann, st_lap = ops.decomposition_coefficients()
    else:
        st_div = ops.gradient_coefficients(opts.divergence, row_kinds=(FLUID,),
                                           source_kinds=div_sources)
    seconds["setup"] = time.perf_counter() - t

    A = None
    stats_positive = None
    if not natural:
        say("assemble")
        t = time.perf_counter()
        # normal-parallel: Dirichlet rows, a regular problem, nothing to border
        dirichlet = opts.boundary_condition == "normal-parallel"
        if opts.positive_rows is not None and opts.laplacian == "corrected":
            if st_lap is None:
                st_lap = ops.laplacian_coefficients("corrected", row_kinds=(FLUID,))
            wall = None
            if opts.boundary == "collocation":
                # the boundary rows' homogeneous condition holds all along the wall
                wall = (domain.closest_wall, "dirichlet" if dirichlet else "neumann")
            stats_positive = make_rows_positive(ops, st_lap, opts.positive_rows, FLUID, wall)
        A = PoissonMatrix(ops, laplacian=opts.laplacian if st_lap is None else st_lap,
                          gradient=opts.neumann_gradient if st_neumann is None else st_neumann,
                          kappa=opts.kappa, near=near, bordered=opts.bordered and not dirichlet,
                          dirichlet=dirichlet, overwrite_laplacian=True)
        seconds["assemble"] = time.perf_counter() - t

    stats = {"n_points": n, "n_boundary": int((kind == BOUNDARY).sum()),
             "n_ghosts": int((kind == GHOST).sum()), "support": support, "spacing": spacing,
             "mean_neighbours": float(ps.neighbour_counts.mean())}
    if stats_positive is not None:
        stats["positive_rows"] = stats_positive
    return PoissonSetup(opts, pts, ps, A, kind, seconds, stats, domain, st_div, div_sources)


def right_hand_sides(setup: PoissonSetup, vec) -> dict:
    """Step (b)-(c) for one field ``vec`` (the valid rows, unit frame): the
    right-hand sides of Eq. 5 on the particle slots, ``{"phi": div v, "psi":
    -curl v}`` (zero on boundary and fake particles)."""
    ps, opts, kind = setup.ps, setup.opts, setup.kind
    ops, p = ps.ops, ps.particles
    v_nd = ps.upload(vec)
    if opts.boundary == "petronetto":      # Eq. 14: extend v to the fake particles
        ext = ps.new_array(2)
        ops.shepard(v_nd, ext, source_kinds=(FLUID,))
        full = ext.to_numpy()
        full[kind == FLUID] = v_nd.to_numpy()[: ps.n_total][kind == FLUID]
        v_nd.from_numpy(full)
    dc_nd = ps.new_array(2, zeroed=False)
    ops.divergence_and_curl(setup.divergence_stencil, v_nd, dc_nd)
    dc = dc_nd.to_numpy()[: ps.n_total].astype(np.float64)
    div_slots, curl_slots = dc[:, 0].copy(), dc[:, 1].copy()
    fluid = kind == FLUID
    div_slots[~fluid] = 0.0
    curl_slots[~fluid] = 0.0
    if opts.remove_mean:
        # the compatibility option for pure Neumann problems: the right-hand
        # sides' discrete integrals over the domain made zero
        vol = p.get("volume")[fluid]
        for slots in (div_slots, curl_slots):
            slots[fluid] -= np.average(slots[fluid], weights=vol)
    return {"phi": div_slots, "psi": -curl_slots}


def _ghosts_with_data(ps, reach: float = 0.8) -> np.ndarray:
    """Per slot: False for fake particles without a data point within ``reach`` x
    support.  0.8: the published quartic is negative beyond 0.848 of its support, so
    a Shepard sum over only such far neighbours would have no positive weight."""
    off, nb = ps.pairs.to_numpy()
    kind = ps.particles.get("kind")
    pos = ps.particles.get("position")
    rows = np.repeat(np.arange(ps.n_total), np.diff(off))
    close = np.linalg.norm(pos[nb] - pos[rows], axis=1) < reach * ps.support
    has = np.zeros(ps.n_total, dtype=bool)
    np.logical_or.at(has, rows, (kind[nb] == FLUID) & close)
    return has | (kind != GHOST)


def _petronetto_band(ps, domain):
    """Petronetto Sec. 4: fluid particles within sqrt(m/rho)/pi of the boundary get
    the Neumann term, with the outward normal of the closest boundary point; their
    weights (-1) go to the Poisson rows, the normals to the particles."""
    p = ps.particles
    kind = p.get("kind")
    pos = p.get("position")
    vol = p.get("volume")
    dist, _, nrm, _ = domain.closest_boundary(pos)
    band = (kind == FLUID) & (dist < np.sqrt(vol) / math.pi)
    normals = p.get("normal")
    normals[band] = nrm[band]
    p.set("normal", normals)
    w = np.where(band, -1.0, 0.0).astype(runtime.np_real())
    near = runtime.array(runtime.real_dtype(), max(ps.n_total, 1))
    near.from_numpy(np.resize(w, max(ps.n_total, 1)))
    return near
