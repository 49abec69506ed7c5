"""Helmholtz-Hodge decomposition of a 2D vector field sampled at scattered
points with SPH operators (SPH-HH, Petronetto et al. 2010, Sec. 5 (a)-(e)).

    v = d + r + h,  d = grad phi (curl-free),  r = J grad psi (divergence-free),
    h harmonic,  lap phi = div v,  lap psi = -curl v  (Eq. 5),
    d phi/dn = d psi/dn = 0 on the boundary  (Eq. 6).

Eq. 6 is the option ``boundary_condition="neumann"``; the others (Bhatia et
al., The Helmholtz-Hodge decomposition: a survey, IEEE TVCG 2013), and the
default ``auto``, which chooses from the data (:mod:`taichi_hh.hhd.auto`):
``natural`` for a window of a larger flow (the flow crosses the boundary),
``no-flux`` for a closed container (v.n = 0 next to the boundary);
``stats["boundary_condition"]`` and ``result.options`` say which was used,
``stats["boundary_flux"]`` the measure:

``neumann``          Eq. 6: d tangent to the boundary (no flux through it) and
                     r normal to it, with the bordered system absorbing what
                     is incompatible with that (a net divergence or a net
                     curl: a rigid rotation goes wholly into h, which then
                     has curl: not harmonic; flagged).
``normal-parallel``  phi = psi = 0 on the boundary (Dirichlet rows on the
                     boundary particles): d normal and r tangent to the
                     boundary, d, r, h L2-orthogonal and unique, h harmonic and
                     free on the boundary.  On a domain with holes psi = 0 on
                     every boundary component (not a constant per component):
                     the decomposition stays orthogonal and the flow circulating
                     around a hole is harmonic, so it stays in h.
``no-flux``          d phi/dn = 0 and psi = 0 on the boundary (phi's Neumann
                     rows, psi's Dirichlet rows: two systems): d and r both
                     tangent to the boundary, no flux through it, h carries
                     all of v.n.  The split of a flow in a closed container
                     (v.n = 0 on the walls): its sources in d, its
                     circulation in r however close to a wall, h = 0.
``natural``          Bhatia et al. 2014: phi = G * div v and psi = -G * curl v
                     over the domain with the free-space Green's function, no
                     condition imposed (:mod:`taichi_hh.hhd.natural`); d and r
                     are what the sources and vortices inside induce, h the
                     influence of everything outside.  With the default
                     method's operator options div v and curl v come from
                     fits of v at the grid's nodes (no particles, no
                     neighbour search: :func:`_natural_unit`).

Steps (a)-(e): particles and boundary or fake particles, div v and curl v,
the two Poisson problems of Eq. 5 with the boundary rows of Eq. 6, their
solutions phi and psi, and d, r, h.  Every numerical choice is an option of
:class:`~taichi_hh.hhd.options.HHDOptions`; :data:`~taichi_hh.hhd.options.METHODS`
bundles them (``default``, ``petronetto2010``, ``colin2006``).  Accuracy of
each bundle: docs/notes/hhd.md.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .. import runtime
from ..errors import InputError
from ..sph.operators import ALL_KINDS
from ..sph.particles import BOUNDARY, FLUID, GHOST
from ..sph.pointset import PointSet
from ..sph.positive import make_rows_positive
from ..poisson.matrix import PoissonMatrix
from .boundary import collocation_particles, far_from
from .inputs import (INVALID_MODES, Data, check_data_near_boundary, check_data_reach_boundary,
                     check_point_count, prepare_data, refuse_too_few, validate_input)
from .auto import (ORTHOGONAL_CONDITION, choose_boundary_condition, energy_closer,
                   natural_cancels)
from .corners import check_corners
from .natural import natural_decomposition, natural_potentials
from .options import (BOUNDARY_CONDITIONS, BOUNDARY_METHODS, METHODS, PRECONDITIONERS,
                      HHDOptions, options_for)
from .rotation import J
from .units import Frame

# re-exported: importers of the options, the input checks and J from here
__all__ = ["decompose", "poisson_problems", "PoissonProblems", "HHDResult", "ENERGY_LIMIT",
           "HHDOptions", "METHODS", "BOUNDARY_METHODS", "BOUNDARY_CONDITIONS", "PRECONDITIONERS",
           "options_for",
           "validate_input", "far_from", "J"]


@dataclass
class HHDResult:
    """A decomposition, in the caller's units and row order.

    ``curl_free`` (d), ``div_free`` (r), ``harmonic`` (h): (N, 2); ``phi``,
    ``psi``, ``divergence``, ``curl``: (N,); NaN on the rows ``valid`` marks
    missing.  ``frame``: the unit frame the numerics ran in
    (:mod:`taichi_hh.hhd.units`); ``pointset`` and ``unit`` (the same
    decomposition of the valid rows in that frame) are there for diagnostics."""
    points: np.ndarray
    vectors: np.ndarray
    curl_free: np.ndarray      # d = grad phi
    div_free: np.ndarray       # r = J grad psi
    harmonic: np.ndarray       # h = v - d - r
    phi: np.ndarray
    psi: np.ndarray
    divergence: np.ndarray     # SPH div v at the points (the right-hand side of Eq. 5)
    curl: np.ndarray
    stats: dict
    options: HHDOptions
    pointset: PointSet = field(repr=False, default=None)
    valid: np.ndarray = field(repr=False, default=None)
    frame: Frame = field(repr=False, default=None)
    unit: "HHDResult" = field(repr=False, default=None)
    domain: object = field(repr=False, default=None)   # the Box or Polygon it ran on

    def valid_rows(self) -> "HHDResult":
        """The same result on the valid rows only (no NaN rows): for plots and
        statistics that do not take NaN."""
        if self.valid is None or self.valid.all():
            return self
        keep = self.valid
        return replace(self, points=self.points[keep], vectors=self.vectors[keep],
                       curl_free=self.curl_free[keep], div_free=self.div_free[keep],
                       harmonic=self.harmonic[keep], phi=self.phi[keep], psi=self.psi[keep],
                       divergence=self.divergence[keep], curl=self.curl[keep],
                       valid=np.ones(int(keep.sum()), dtype=bool))

    def critical_points(self, threshold: float = 0.1, radius: float | None = None,
                        **filters):
        """Sources, sinks and vortices (Petronetto Sec. 6c), strongest first:
        ``[CriticalPoint(x, y, kind, strength, significance, coherence)]``,
        which unpack as ``(x, y, kind)``.  ``radius`` in the points' units;
        ``filters`` (``filter=False``, ``edge``, ``significance``,
        ``coherence``): the measured-data filters.

        See :func:`taichi_hh.hhd.critical.find_critical_points`."""
        from .critical import critical_points
        return critical_points(self, threshold, radius, **filters)


# ---------------------------------------------------------------------------

def _extra_particles(domain, pts, opts: HHDOptions, spacing: float, support: float):
    """Boundary particles (points, normals) and ghosts for the boundary method."""
    if opts.boundary == "none":
        return None, None
    if opts.boundary == "collocation":
        return collocation_particles(domain, pts, spacing, local=opts.adaptive_support,
                                     clear_corners=opts.boundary_condition == "neumann"), None
    band = domain.sample_ghosts(spacing, support, seed=opts.seed, avoid=pts)
    if opts.boundary == "colin":
        _, _, nrm, _ = domain.closest_boundary(band)
        return (band, nrm), None
    return None, band                                   # petronetto: fake particles


@dataclass
class PoissonProblems:
    """The two Poisson problems of a decomposition (Eq. 5), assembled: the
    matrix ``A`` shared by both and the right-hand sides ``rhs["phi"]`` = div v
    and ``rhs["psi"]`` = -curl v on the particle slots (zero on boundary and
    fake particles).  From :func:`poisson_problems`; :func:`decompose` solves
    them.  Useful on its own to benchmark or compare solvers on the matrix.
    ``A`` is None for the natural decomposition (no linear system)."""
    opts: HHDOptions
    points: np.ndarray
    ps: PointSet
    A: PoissonMatrix
    rhs: dict
    vectors: np.ndarray
    kind: np.ndarray
    seconds: dict
    stats: dict
    domain: object = None
    divergence_stencil: object = None    # of div v and curl v, over the data points
    frame: Frame = None                  # the unit frame the problems are in
    data: Data = None                    # the caller's input (poisson_problems)


def poisson_problems(points, vectors, domain=None, *, method: str = "default", progress=None,
                     invalid: str = "missing", valid=None, **options) -> PoissonProblems:
    """Steps (a)-(d) of :func:`decompose` (arguments alike): particles, boundary
    or fake particles, div v and curl v, the assembled Poisson matrix, in the
    unit frame (``problems.frame``; :mod:`taichi_hh.hhd.units`) over the valid
    rows (``problems.data``)."""
    opts = options_for(method, **options)
    runtime.ensure_init()
    data = prepare_data(points, vectors, domain, invalid=invalid, valid=valid)
    opts, chosen = resolved_options(opts, data)
    if opts.boundary_condition == "no-flux":
        raise InputError("boundary_condition='no-flux' has two matrices (phi's Neumann rows, "
                         "psi's Dirichlet rows): ask for boundary_condition='neumann' or "
                         "'normal-parallel' to get the one")
    problems = _unit_problems(data.unit_points, data.unit_vectors, data.unit_domain, opts,
                              progress, data)
    problems.stats.update(chosen)
    problems.frame, problems.data = data.frame, data
    return problems


def resolved_options(opts: HHDOptions, data: Data) -> tuple:
    """``(opts, stats)``: ``boundary_condition="auto"`` replaced by the condition
    the data call for (:func:`~taichi_hh.hhd.auto.choose_boundary_condition`);
    ``stats``: ``boundary_condition`` (the one used) and, for ``auto``,
    ``boundary_flux``."""
    if opts.boundary_condition != "auto":
        return opts, {"boundary_condition": opts.boundary_condition}
    spacing = math.sqrt(data.unit_domain.area / max(len(data.unit_points), 1))
    condition, flux = choose_boundary_condition(data.unit_points, data.unit_vectors,
                                                data.unit_domain, spacing, opts.boundary)
    return replace(opts, boundary_condition=condition), {"boundary_condition": condition,
                                                         "boundary_flux": flux}


def _unit_problems(pts, vec, domain, opts: HHDOptions, progress,
                   data: Data | None = None) -> PoissonProblems:
    """:func:`poisson_problems` on checked input in the unit frame; ``data``:
    the caller's (its frame and domain for the messages)."""
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
    seconds["setup"] = time.perf_counter() - t

    say("divergence and curl")
    t = time.perf_counter()
    v_nd = ps.upload(vec)
    if opts.boundary == "petronetto":      # Eq. 14: extend v to the fake particles
        ext = ps.new_array(2)
        ops.shepard(v_nd, ext, source_kinds=(FLUID,))
        full = ext.to_numpy()
        full[kind == FLUID] = v_nd.to_numpy()[: ps.n_total][kind == FLUID]
        v_nd.from_numpy(full)
        div_sources = (FLUID, GHOST)
    else:
        div_sources = (FLUID,)
    st_neumann = st_lap = None
    if _default_stencils(opts) and not natural:
        # the three stencils of the default from one kernel (two passes over the pairs)
        st_div, st_neumann, st_lap = ops.decomposition_coefficients()
    else:
        st_div = ops.gradient_coefficients(opts.divergence, row_kinds=(FLUID,),
                                           source_kinds=div_sources)
    dc_nd = ps.new_array(2, zeroed=False)
    ops.divergence_and_curl(st_div, v_nd, dc_nd)
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
    seconds["divergence"] = time.perf_counter() - t

    A = None
    stats_positive = None
    if opts.boundary_condition != "natural":
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
    return PoissonProblems(opts, pts, ps, A, {"phi": div_slots, "psi": -curl_slots}, vec, kind,
                           seconds, stats, domain, st_div)


def _default_stencils(opts: HHDOptions) -> bool:
    """Whether the operators are the default's (cubic divergence over the data
    points, quadratic Neumann gradient, corrected Laplacian), which
    :meth:`~taichi_hh.sph.operators.Operators.decomposition_coefficients`
    computes in one kernel."""
    return (opts.divergence == "cubic" and opts.neumann_gradient == "quadratic"
            and opts.laplacian == "corrected" and opts.boundary != "petronetto")


def decompose(points, vectors, domain=None, *, method: str = "default", progress=None,
              invalid: str = "missing", valid=None, **options) -> HHDResult:
    """Helmholtz-Hodge decomposition of ``vectors`` sampled at ``points``.

    points, vectors: (N, 2) arrays.  domain: :class:`~taichi_hh.geometry.domain.Box` or
    :class:`~taichi_hh.geometry.domain.Polygon` (holes allowed), ``(x0, y0, x1,
    y1)``, or one made from the points: ``"bbox"`` (their bounding box, the
    default), ``"hull"`` (convex hull), ``"alpha"`` (alpha shape: concave
    outlines, and gaps in the data as holes; ``("alpha", A)``: at a radius of
    ``A`` local spacings, default 3,
    :func:`~taichi_hh.geometry.from_points.alpha_shape`).  method: a bundle of
    :data:`METHODS`; keyword ``options``
    override single fields of :class:`HHDOptions`, e.g.
    ``boundary_condition="normal-parallel"`` or ``"natural"`` (module doc).
    progress: optional ``callable(stage: str)`` told as each stage starts.

    Missing data: a row whose point or vector holds a NaN, that a numpy mask
    hides, or where ``valid`` (a boolean array, one per row) is False is left
    out of the operators; its rows of the result are NaN, and
    ``stats["n_invalid"]`` counts them.  ``invalid="error"`` refuses them
    instead.  Exactly zero vectors in many rows are named in a warning (PIV
    software writes invalid vectors as zeros).

    Units: the numerics run in a frame where the domain and the field are of
    order one (:mod:`taichi_hh.hhd.units`; ``result.frame``): the answer does
    not depend on the units or the origin of the coordinates, nor on the
    field's magnitude.

    ``stats["h_divergence"]`` and ``stats["h_curl"]``: mean |div h| and |curl h|
    over the mean of sqrt(div v^2 + curl v^2) (the decomposition's divergence
    operator); above :data:`HARMONIC_LIMIT` h is not harmonic and the result is
    flagged (``stats["flags"]`` and an AccuracyWarning): the Neumann condition
    with a field of net curl or divergence (docs/notes/hhd.md).
    ``stats["positive_rows"]``: the corrected-Laplacian rows flagged by the
    ``positive_rows`` option, how many were replaced by positive stencils and
    how many kept (:mod:`taichi_hh.sph.positive`).
    """
    t_start = time.perf_counter()
    opts = options_for(method, **options)
    runtime.ensure_init()
    data = prepare_data(points, vectors, domain, invalid=invalid, valid=valid)
    opts, chosen = resolved_options(opts, data)
    if "boundary_flux" in chosen and opts.boundary_condition == "natural":
        unit, opts, chosen = _auto_window(data, opts, chosen, progress)
    else:
        unit = _decompose_unit(data, opts, progress)
    unit.stats.update(chosen)
    unit.stats["seconds"]["total"] = time.perf_counter() - t_start
    return _in_caller_units(unit, data)


def _auto_window(data: Data, opts: HHDOptions, chosen: dict, progress) -> tuple:
    """``(unit result, options, chosen)`` of ``auto``'s window split: the
    natural one unless its parts cancel, then the orthogonal one
    (:func:`~taichi_hh.hhd.auto.natural_cancels`; the natural attempt's
    warnings are not the answer's and are dropped with it)."""
    import warnings

    def attempt(options):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            return _decompose_unit(data, options, progress), caught

    def answer(unit, caught):
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return unit

    natural, natural_warnings = attempt(opts)
    ratio = natural.stats["energy_ratio"]
    if not natural_cancels(ratio):
        return answer(natural, natural_warnings), opts, chosen
    orthogonal_opts = replace(opts, boundary_condition=ORTHOGONAL_CONDITION)
    orthogonal, orthogonal_warnings = attempt(orthogonal_opts)
    seconds = {"natural": natural.stats["seconds"]["total"],
               "orthogonal": orthogonal.stats["seconds"]["total"]}
    if not energy_closer(orthogonal.stats["energy_ratio"], ratio):
        # data the orthogonal condition serves worse (gaps at the boundary):
        # the natural split stands, with its own flags
        natural.stats["seconds"]["auto_attempts"] = seconds
        return answer(natural, natural_warnings), opts, {
            **chosen, "orthogonal_energy_ratio": orthogonal.stats["energy_ratio"]}
    orthogonal.stats["seconds"]["auto_attempts"] = seconds
    return answer(orthogonal, orthogonal_warnings), orthogonal_opts, {
        **chosen, "boundary_condition": ORTHOGONAL_CONDITION, "natural_energy_ratio": ratio}


def _in_caller_units(unit: HHDResult, data: Data) -> HHDResult:
    """The unit-frame decomposition of the valid rows mapped back to every row
    of the caller's input, in the caller's units."""
    f = data.frame
    stats = dict(unit.stats)
    stats["spacing"] = unit.stats["spacing"] * f.length
    stats["support"] = unit.stats["support"] * f.length
    for name in ("phi", "psi"):
        if stats.get(f"compatibility_{name}") is not None:
            stats[f"compatibility_{name}"] = stats[f"compatibility_{name}"] * f.derivative
    stats["n_invalid"] = data.n_invalid
    stats["frame"] = f.as_dict()
    stats["flags"] = data.flags + list(unit.stats.get("flags", []))
    stats["arch"], stats["precision"] = runtime.state().arch, runtime.state().precision
    return HHDResult(points=data.points, vectors=data.vectors,
                     curl_free=data.rows(unit.curl_free, f.speed),
                     div_free=data.rows(unit.div_free, f.speed),
                     harmonic=data.rows(unit.harmonic, f.speed),
                     phi=data.rows(unit.phi, f.potential), psi=data.rows(unit.psi, f.potential),
                     divergence=data.rows(unit.divergence, f.derivative),
                     curl=data.rows(unit.curl, f.derivative), stats=stats, options=unit.options,
                     pointset=unit.pointset, valid=data.valid, frame=f, unit=unit,
                     domain=data.domain if data.domain is not None
                     else f.domain_from_unit(unit.domain))


#: ``no-flux``: each potential under its own condition, one system each
#: (phi's Neumann rows, psi's Dirichlet rows)
NO_FLUX_PARTS = (("phi", "neumann"), ("psi", "normal-parallel"))


def _decompose_unit(data: Data, opts: HHDOptions, progress) -> HHDResult:
    """Steps (a)-(e) on the valid rows in the unit frame."""
    if _natural_at_nodes(opts):
        return _natural_unit(data, opts, progress)
    t_start = time.perf_counter()
    say = progress or (lambda stage: None)
    if opts.boundary_condition == "no-flux":
        # two systems built and solved one after the other (the first's arrays
        # freed before the second's are made); d from the first, r from the second
        solved, seconds = {}, {}
        for name, condition in NO_FLUX_PARTS:
            problems = _checked_problems(data, replace(opts, boundary_condition=condition),
                                         progress, check=name == "phi")
            rhs = problems.rhs
            problems.rhs = {name: rhs[name]}
            potentials, gradients = _potentials_and_gradients(problems, say)
            solved[name] = (potentials[name], gradients[name])
            for key, value in problems.seconds.items():
                seconds[key] = seconds.get(key, 0.0) + value
            if name == "phi":
                first = problems.stats
        problems.rhs = rhs
        stats = problems.stats
        for key in ("iterations_phi", "residual_phi", "compatibility_phi", "flags"):
            if key in first:
                stats[key] = first[key]
        (phi, d), (psi, grad_psi) = solved["phi"], solved["psi"]
        opts = problems.opts = replace(problems.opts, boundary_condition="no-flux")
    else:
        problems = _checked_problems(data, opts, progress)
        seconds, stats = problems.seconds, problems.stats
        if opts.boundary_condition == "natural":
            say("natural potentials")
            t = time.perf_counter()
            ps = problems.ps
            nat = natural_potentials(problems.points, problems.domain,
                                     {k: problems.rhs[k][ps.slot_of] for k in ("phi", "psi")},
                                     stats["spacing"], evaluation=opts.natural_evaluation)
            phi, d = nat["phi"]
            psi, grad_psi = nat["psi"]
            stats["natural_grid"] = nat["grid"].shape
            seconds["natural"] = time.perf_counter() - t
            seconds.update({f"natural_{k}": v for k, v in nat.get("seconds", {}).items()})
        else:
            potentials, gradients = _potentials_and_gradients(problems, say)
            phi, psi = potentials["phi"], potentials["psi"]
            d, grad_psi = gradients["phi"], gradients["psi"]
    ps, vec, pts = problems.ps, problems.vectors, problems.points
    div_slots, curl_slots = problems.rhs["phi"], -problems.rhs["psi"]
    r = J(grad_psi)
    h = vec - d - r
    seconds["total"] = time.perf_counter() - t_start
    stats["seconds"] = seconds
    _check_energy(stats, vec, d, r, h, ps.particles.get("volume")[ps.slot_of], opts)
    _check_harmonic(stats, problems, h)
    if opts.boundary_condition != "natural":
        check_corners(stats, pts, d, r, problems.domain, stats["spacing"],
                      opts.boundary_condition, data.frame.points_from_unit)
    runtime.release_launch_arguments(ps.n_total)
    return HHDResult(points=pts, vectors=vec, curl_free=d, div_free=r, harmonic=h,
                     phi=phi, psi=psi, divergence=div_slots[ps.slot_of],
                     curl=curl_slots[ps.slot_of], stats=stats, options=opts, pointset=ps,
                     domain=problems.domain)


#: the options of the SPH operator at the points: the natural decomposition
#: with all of them at the default's values takes div v and curl v from fits
#: of v at its grid nodes instead (:func:`_natural_at_nodes`)
POINT_OPERATOR_OPTIONS = ("kernel", "support_ratio", "adaptive_support", "support_neighbours",
                          "divergence", "boundary", "remove_mean")


def _natural_at_nodes(opts: HHDOptions) -> bool:
    """Whether the natural decomposition takes div v and curl v from fits of v
    at its grid nodes (:func:`~taichi_hh.hhd.natural.natural_decomposition`:
    no operator at the points, no neighbour search): with the default
    method's point operator (:data:`POINT_OPERATOR_OPTIONS` as
    ``METHODS["default"]`` has them).  Any other kernel, support or
    divergence variant, the ``petronetto`` fake particles or ``remove_mean``
    asks for the SPH operator at the points (its div v and curl v
    reconstructed at the nodes, :func:`~taichi_hh.hhd.natural.natural_potentials`)."""
    default = METHODS["default"]
    return opts.boundary_condition == "natural" and all(
        getattr(opts, name) == getattr(default, name) for name in POINT_OPERATOR_OPTIONS)


class _LazyPointSet:
    """The decomposition's :class:`~taichi_hh.sph.pointset.PointSet`, built on
    first use (the natural decomposition at the nodes needs none; the
    critical points and diagnostics read one)."""

    def __init__(self, make):
        self._make, self._ps = make, None

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        if self._ps is None:
            self._ps = self._make()
        return getattr(self._ps, name)


def _check_natural_reach(pts, domain, spacing: float, opts: HHDOptions, data: Data) -> None:
    """The data reach the boundary (:func:`~taichi_hh.hhd.inputs.check_data_near_boundary`)
    within the fixed support (``support_ratio`` mean spacings); failing that,
    with an adaptive support, within the largest of the points' supports
    (the reach the point set's operators would have had)."""
    try:
        check_data_near_boundary(pts, domain, spacing, opts.support_ratio * spacing, data)
    except InputError:
        if not opts.adaptive_support:
            raise
        from ..sph.support import adaptive_supports
        supports = adaptive_supports(pts, opts.support_ratio, opts.support_neighbours,
                                     domain.area)
        check_data_near_boundary(pts, domain, spacing, float(supports.max()), data)


def _natural_unit(data: Data, opts: HHDOptions, progress) -> HHDResult:
    """:func:`_decompose_unit` of the natural decomposition at the grid nodes
    (:func:`_natural_at_nodes`): no point set (one is built if the result's
    ``pointset`` is read), div v and curl v from the nodes' fits of v, the
    energy check with the points' cell areas
    (:class:`~taichi_hh.hhd.natural.NaturalSplit`), the harmonic check with
    the nodes' fits of h."""
    t_start = time.perf_counter()
    say = progress or (lambda stage: None)
    pts, vec, domain = data.unit_points, data.unit_vectors, data.unit_domain
    n = len(pts)
    refuse_too_few(n)
    spacing = math.sqrt(domain.area / n)
    support = opts.support_ratio * spacing
    seconds = {}
    say("setup")
    t = time.perf_counter()
    _check_natural_reach(pts, domain, spacing, opts, data)
    stats = {"n_points": n, "n_boundary": 0, "n_ghosts": 0, "support": support,
             "spacing": spacing}
    check_point_count(n, stats, stacklevel=5)
    seconds["setup"] = time.perf_counter() - t
    say("natural potentials")
    t = time.perf_counter()
    split = natural_decomposition(pts, vec, domain, spacing, evaluation=opts.natural_evaluation)
    # "divergence": div v and curl v (the nodes' fits and the points' values)
    seconds["divergence"] = sum(split.seconds.get(k, 0.0) for k in ("fit", "divergence"))
    seconds["natural"] = time.perf_counter() - t - seconds["divergence"]
    stats["natural_grid"] = split.grid.shape
    stats["mean_neighbours"] = split.mean_fit_points
    say("checks")
    t = time.perf_counter()
    d, r = split.d, J(split.grad_psi)
    h = vec - d - r
    _check_energy(stats, vec, d, r, h, split.volume, opts, stacklevel=5)
    flag_harmonic(stats, dict(zip(("divergence", "curl"), split.harmonic_ratios(h))), opts)
    seconds["checks"] = time.perf_counter() - t
    seconds.update({f"natural_{k}": v for k, v in split.seconds.items()})
    seconds["total"] = time.perf_counter() - t_start
    stats["seconds"] = seconds

    def pointset():
        return PointSet(pts, kernel=opts.kernel, support_ratio=opts.support_ratio,
                        support=None if opts.adaptive_support else support, area=domain.area,
                        support_neighbours=opts.support_neighbours if opts.adaptive_support
                        else None)

    runtime.release_launch_arguments(n)
    return HHDResult(points=pts, vectors=vec, curl_free=d, div_free=r, harmonic=h,
                     phi=split.phi, psi=split.psi, divergence=split.divergence,
                     curl=split.curl, stats=stats, options=opts,
                     pointset=_LazyPointSet(pointset), domain=domain)


def _checked_problems(data: Data, opts: HHDOptions, progress, *,
                      check: bool = True) -> PoissonProblems:
    """The problems of ``data`` under ``opts``; with ``check``, too few points
    refused or flagged."""
    problems = _unit_problems(data.unit_points, data.unit_vectors, data.unit_domain, opts,
                              progress, data)
    problems.frame, problems.data = data.frame, data
    if check:
        check_point_count(len(problems.points), problems.stats, stacklevel=5)
    return problems


def _potentials_and_gradients(problems: PoissonProblems, say) -> tuple:
    """Steps (d) and (e) for the potentials ``problems.rhs`` names: ``(potentials,
    gradients)``, each a dict by name, at the data points."""
    opts, ps = problems.opts, problems.ps
    slots = _solve_potentials(problems, say)
    say("components")
    t = time.perf_counter()
    A = problems.A
    if A.grad.variant == opts.gradient and A.grad.source_kinds == ALL_KINDS:
        st_grad = A.grad        # the Neumann rows' gradient: the same fit at the data points
    else:
        st_grad = ps.ops.gradient_coefficients(opts.gradient, row_kinds=(FLUID,))
    some = np.asarray(next(iter(slots.values())))
    a, b = (np.asarray(slots[k]) if k in slots else np.zeros_like(some) for k in ("phi", "psi"))
    ga, gb = _gradients(ps, st_grad, a, b)
    problems.seconds["components"] = time.perf_counter() - t
    potentials = {k: np.asarray(v)[ps.slot_of] for k, v in slots.items()}
    gradients = {k: g for k, g in (("phi", ga), ("psi", gb)) if k in slots}
    return potentials, gradients


def _solve_potentials(problems, say) -> dict:
    """Steps (d): phi and psi per particle slot from the assembled problems.
    With BiCGSTAB (the default) the two are solved together, the matrix and
    the preconditioner read once per iteration for both
    (:meth:`~taichi_hh.poisson.matrix.PoissonMatrix.solve_columns`).
    ``seconds["preconditioner"]``: the preconditioner's set-up;
    ``seconds["solve"]``: the iterations of both."""
    opts, A, stats, seconds = problems.opts, problems.A, problems.stats, problems.seconds
    say("preconditioner")
    t = time.perf_counter()
    preconditioner = A.preconditioner_for(opts.preconditioner, opts.solver,
                                          dict(opts.multilevel_options))
    seconds["preconditioner"] = time.perf_counter() - t
    say("solve phi and psi")
    t = time.perf_counter()
    names = list(problems.rhs)
    if opts.solver == "bicgstab":
        results = A.solve_columns(np.stack([problems.rhs[name] for name in names], axis=1),
                                  tol=opts.tol, max_iterations=opts.max_iterations,
                                  preconditioner=preconditioner)
    else:
        # Colin's stacked boundary system is overdetermined and inconsistent in
        # general: CGNR then seeks its least-squares solution (Colin Sec. 3.5)
        extra = {"least_squares": True} if opts.solver == "cgnr" else {}
        results = [A.solve(problems.rhs[name], method=opts.solver, tol=opts.tol,
                           max_iterations=opts.max_iterations, preconditioner=preconditioner,
                           **extra) for name in names]
    seconds["solve"] = time.perf_counter() - t
    potentials = {}
    for name, res in zip(names, results):
        potentials[name] = res.x
        stats[f"iterations_{name}"] = res.iterations
        stats[f"residual_{name}"] = res.relative_residual
        stats[f"compatibility_{name}"] = res.border
    return potentials


def _gradients(ps, st_grad, a, b) -> tuple:
    """Step (e): the gradients (stencil ``st_grad``) of two per-slot fields at the
    data points, one pass over the pairs."""
    f_nd = ps.new_array(2, zeroed=False)
    f_nd.from_numpy(np.stack([a, b], axis=1).astype(runtime.np_real()))
    ga, gb = ps.new_array(2, zeroed=False), ps.new_array(2, zeroed=False)
    ps.ops.gradients(st_grad, f_nd, ga, gb)
    return ps.download(ga), ps.download(gb)


#: h with mean |div h| or |curl h| above this fraction of the field's mean
#: sqrt(div v^2 + curl v^2) is not harmonic: flagged.  Measured (docs/notes/hhd.md):
#: 0.02-0.16 for the default method on the analytic fields at 13k-1k points,
#: up to 0.29 for petronetto2010, 0.47 for the natural HHD of pure 1% noise
#: (finer than its grid), 1.0 for a rigid rotation under Neumann
HARMONIC_LIMIT = 0.5


def _divergence_curl(ps, st, w):
    """div w and curl w at the data points by the stencil ``st``."""
    out = ps.new_array(2)
    ps.ops.divergence_and_curl(st, ps.upload(w), out)
    dc = ps.download(out)
    return dc[:, 0], dc[:, 1]


def _check_harmonic(stats, problems, h) -> None:
    """How harmonic h is: ``stats["h_divergence"]``, ``stats["h_curl"]`` (mean |div h|
    and |curl h| over the mean of sqrt(div v^2 + curl v^2), the divergence operator
    over the data points); above :data:`HARMONIC_LIMIT` flagged as _check_energy does."""
    ps, opts = problems.ps, problems.opts
    if opts.boundary == "petronetto" or opts.remove_mean:
        # the right-hand sides are not div v and curl v over the data alone there
        st = ps.gradient_stencil(opts.divergence)
        div_v, curl_v = _divergence_curl(ps, st, problems.vectors)
    else:                                   # the same operator as the right-hand sides'
        st = problems.divergence_stencil
        div_v = problems.rhs["phi"][ps.slot_of]
        curl_v = -problems.rhs["psi"][ps.slot_of]
    scale = float(np.hypot(div_v, curl_v).mean())
    ratios = {}
    for name, values in zip(("divergence", "curl"), _divergence_curl(ps, st, h)):
        mean = float(np.abs(values).mean())
        ratios[name] = mean / scale if scale > 0 else (0.0 if mean == 0 else math.inf)
    flag_harmonic(stats, ratios, opts)


def flag_harmonic(stats, ratios: dict, opts: HHDOptions) -> None:
    """``stats["h_divergence"]``, ``stats["h_curl"]`` from ``ratios`` (by
    ``divergence``, ``curl``); above :data:`HARMONIC_LIMIT` flagged (stats and
    an AccuracyWarning)."""
    import warnings
    from ..errors import AccuracyWarning
    for name in ("divergence", "curl"):
        stats[f"h_{name}"] = ratios[name]
    stats.setdefault("flags", [])
    worst = max(ratios, key=ratios.get)
    if not ratios[worst] <= HARMONIC_LIMIT:
        msg = (f"h is not harmonic: mean |{'div' if worst == 'divergence' else 'curl'} h| is "
               f"{ratios[worst]:.3g} of the field's mean derivative (limit {HARMONIC_LIMIT:g}); "
               f"with boundary_condition={opts.boundary_condition!r}")
        if not stats.get("energy_ratio", 1.0) <= ENERGY_LIMIT:
            msg += "; the operators are inconsistent on these points (see the energy flag)"
        elif opts.boundary_condition == "neumann":
            msg += ("; the usual cause: the field has net curl or divergence, which the "
                    "Neumann condition cannot put into d or r (boundary_condition="
                    "'normal-parallel' or 'natural' can)")
        stats["flags"].append(msg)
        warnings.warn(msg, AccuracyWarning, stacklevel=5)


#: components with more than this many times the field's energy are flagged
ENERGY_LIMIT = 4.0


def _check_energy(stats, v, d, r, h, vol, opts, *, stacklevel: int = 4) -> None:
    """The decomposition is L2-orthogonal (Petronetto Eq. 16), so
    |d|^2 + |r|^2 + |h|^2 = |v|^2 (volume-weighted sums) for an exact one; an
    accurate discrete one stays within a few percent (docs/notes/hhd.md).
    Components carrying several times the field's energy cancel each other: the
    operators are inconsistent on these points (e.g. the symmetric gradient on
    random points).  Flagged in ``stats["flags"]`` and by an
    :class:`~taichi_hh.errors.AccuracyWarning`."""
    import warnings
    from ..errors import AccuracyWarning

    def energy(x):
        return float((vol * (x * x).sum(axis=1)).sum())

    total = energy(v)
    ratio = (energy(d) + energy(r) + energy(h)) / total if total > 0 else 1.0
    stats["energy_ratio"] = ratio
    stats.setdefault("flags", [])
    if not np.isfinite(ratio) or ratio > ENERGY_LIMIT:
        default = METHODS["default"]
        if (opts.gradient, opts.divergence, opts.laplacian) != \
                (default.gradient, default.divergence, default.laplacian):
            why = (f"the operators (gradient {opts.gradient!r}, divergence "
                   f"{opts.divergence!r}, Laplacian {opts.laplacian!r}) are not consistent "
                   "on these points; the default method's are")
        else:
            why = ("the components cancel each other: the data are too few or too noisy "
                   "for the operators at this resolution, or the boundary condition "
                   f"({opts.boundary_condition!r}) forces large opposite parts near the "
                   "boundary (boundary_condition='natural' imposes none)")
        msg = (f"decomposition components carry {ratio:.3g} times the field's energy "
               f"(|d|^2 + |r|^2 + |h|^2 over |v|^2; 1 for an exact decomposition): {why}; "
               "the components are unreliable")
        stats["flags"].append(msg)
        warnings.warn(msg, AccuracyWarning, stacklevel=stacklevel)


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
