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

import functools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .. import runtime
from ..errors import InputError
from ..sph.pointset import PointSet
from ..poisson.matrix import PoissonMatrix
from .boundary import far_from
from .inputs import (Data, check_data_near_boundary, check_point_count, prepare_data,
                     refuse_too_few, validate_input)
from .auto import choose_boundary_condition, window_split
from .component_checks import (ENERGY_LIMIT, HARMONIC_LIMIT, Components, check_energy,
                               check_harmonic, flag_harmonic)
from .natural import natural_decomposition
from .operator_split import OperatorSplit
from .options import (BOUNDARY_CONDITIONS, BOUNDARY_METHODS, METHODS, PRECONDITIONERS,
                      HHDOptions, options_for)
from .poisson_setup import right_hand_sides, unit_setup
from .rotation import J
from .units import Frame

# re-exported: importers of the options, the input checks and J from here
__all__ = ["decompose", "poisson_problems", "PoissonProblems", "Components", "HHDResult", "ENERGY_LIMIT",
           "HARMONIC_LIMIT", "flag_harmonic", "check_energy", "check_harmonic", "decompose_unit",
           "in_caller_units", "resolved_options",
           "HHDOptions", "METHODS", "BOUNDARY_METHODS", "BOUNDARY_CONDITIONS", "PRECONDITIONERS",
           "options_for",
           "validate_input", "far_from", "J"]


@dataclass
class HHDResult(Components):
    """A decomposition, in the caller's units and row order.

    ``curl_free`` (d), ``div_free`` (r), ``harmonic`` (h): (N, 2); ``phi``,
    ``psi``, ``divergence``, ``curl``: (N,); NaN on the rows ``valid`` marks
    missing.  ``frame``: the unit frame the numerics ran in
    (:mod:`taichi_hh.hhd.units`); ``pointset`` and :attr:`unit` (the same
    decomposition of the valid rows in that frame) are there for diagnostics."""
    points: np.ndarray
    vectors: np.ndarray
    stats: dict
    options: HHDOptions
    pointset: PointSet = field(repr=False, default=None)
    valid: np.ndarray = field(repr=False, default=None)
    frame: Frame = field(repr=False, default=None)
    domain: object = field(repr=False, default=None)   # the Box or Polygon it ran on

    @functools.cached_property
    def unit(self) -> "HHDResult | None":
        """The same decomposition of the valid rows in the unit frame
        (:attr:`frame`; None without one), made from this one on first read
        (to rounding the arrays and stats the numerics gave: a result keeps
        one copy of its arrays, and a natural split's are scaled to the
        caller's units in place, :func:`in_caller_units`)."""
        f = self.frame
        if f is None:
            return None
        keep = slice(None) if self.valid is None or self.valid.all() else self.valid

        def back(values, scale):
            return np.asarray(values, dtype=np.float64)[keep] / scale
        return HHDResult(
            points=f.points_to_unit(self.points[keep]), vectors=back(self.vectors, f.speed),
            curl_free=back(self.curl_free, f.speed), div_free=back(self.div_free, f.speed),
            harmonic=back(self.harmonic, f.speed), phi=back(self.phi, f.potential),
            psi=back(self.psi, f.potential), divergence=back(self.divergence, f.derivative),
            curl=back(self.curl, f.derivative), stats=scaled_stats(self.stats, f, inverse=True),
            options=self.options,
            pointset=self.pointset,
            domain=None if self.domain is None else f.domain_to_unit(self.domain))

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
    problems = _unit_problems(data, opts, progress)
    problems.stats.update(chosen)
    return problems


def resolved_options(opts: HHDOptions, data: Data, *, near=None, flow=None) -> tuple:
    """``(opts, stats)``: ``boundary_condition="auto"`` replaced by the condition
    the data call for (:func:`~taichi_hh.hhd.auto.choose_boundary_condition`;
    ``near``: its band of points, :func:`~taichi_hh.hhd.auto.flux_band`, if
    made already; ``flow``: its ``(flux, along)``, made already,
    :func:`~taichi_hh.hhd.auto.boundary_flows`); ``stats``:
    ``boundary_condition`` (the one used) and, for ``auto``,
    ``boundary_flux`` and ``boundary_along`` (the normal and the tangential
    flow next to the boundary)."""
    if opts.boundary_condition != "auto":
        return opts, {"boundary_condition": opts.boundary_condition}
    condition, flux, along = choose_boundary_condition(data.unit_points, data.unit_vectors,
                                                       data.unit_domain, unit_spacing(data),
                                                       opts.boundary, near=near, flow=flow)
    return with_condition(opts, condition), {
        "boundary_condition": condition, "boundary_flux": flux, "boundary_along": along}


@functools.lru_cache(maxsize=32)
def with_condition(opts: HHDOptions, condition: str) -> HHDOptions:
    """``opts`` with ``boundary_condition`` set (made once per pair: the
    options' checks cost a millisecond, paid per snapshot of a series
    otherwise)."""
    return replace(opts, boundary_condition=condition)


def unit_spacing(data: Data) -> float:
    """The mean spacing of the valid points in the unit frame."""
    return math.sqrt(data.unit_domain.area / max(len(data.unit_points), 1))


def _unit_problems(data: Data, opts: HHDOptions, progress) -> PoissonProblems:
    """:func:`poisson_problems` on checked input in the unit frame: the point
    set-up (:func:`~taichi_hh.hhd.poisson_setup.unit_setup`) and the field's
    right-hand sides."""
    setup = unit_setup(data.unit_points, data.unit_domain, opts, progress, data)
    t = time.perf_counter()
    rhs = right_hand_sides(setup, data.unit_vectors)
    seconds = dict(setup.seconds, divergence=time.perf_counter() - t)
    return PoissonProblems(setup.opts, setup.points, setup.ps, setup.A, rhs, data.unit_vectors,
                           setup.kind, seconds, dict(setup.stats), setup.domain,
                           setup.divergence_stencil, data.frame, data)


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
    unit = decompose_unit(data, opts, chosen, progress)
    unit.stats["seconds"]["total"] = time.perf_counter() - t_start
    return in_caller_units(unit, data)


def decompose_unit(data: Data, opts: HHDOptions, chosen: dict, progress, *,
                   split=None, reach_checked: bool = False, natural=None) -> HHDResult:
    """The unit-frame decomposition of ``data`` under ``opts`` (its condition
    resolved: :func:`resolved_options`, which also gave ``chosen``); ``auto``'s
    window split (``"boundary_flux" in chosen``, natural) falls back to the
    orthogonal condition where the natural parts cancel
    (:func:`~taichi_hh.hhd.auto.window_split`).  ``split(data, opts)``: how a
    condition with Poisson rows is solved (default: a one-off
    :class:`~taichi_hh.hhd.operator_split.OperatorSplit`); ``reach_checked``:
    the points' reach of the boundary checked already (a series);
    ``natural``: the natural decomposition's set-up of these points
    (:class:`~taichi_hh.hhd.natural.NaturalSetup`, a series), None: its own."""
    if "boundary_flux" in chosen and opts.boundary_condition == "natural":
        unit, opts, chosen = window_split(
            lambda o: _decompose_unit(data, o, progress, split, reach_checked, natural), opts,
            chosen)
    else:
        unit = _decompose_unit(data, opts, progress, split, reach_checked, natural)
    unit.stats.update(chosen)
    return unit


def scaled_stats(stats: dict, frame: Frame, inverse: bool = False) -> dict:
    """A copy of a decomposition's ``stats`` with its lengths (spacing,
    support) and compatibility sums (derivatives) from the unit ``frame`` to
    the caller's units, or back with ``inverse``."""
    out = dict(stats)
    for name, scale in (("spacing", frame.length), ("support", frame.length),
                        ("compatibility_phi", frame.derivative),
                        ("compatibility_psi", frame.derivative)):
        if out.get(name) is not None:
            out[name] = out[name] / scale if inverse else out[name] * scale
    return out


def in_caller_units(unit: HHDResult, data: Data, domain=None) -> HHDResult:
    """The unit-frame decomposition of the valid rows mapped back to every row
    of the caller's input, in the caller's units; ``domain``: the result's
    domain in those units, made already (a series on the same points).  A
    natural split's arrays at the nodes (:func:`natural_at_nodes`) are its
    own, new arrays (:func:`_natural_unit`): with every row valid they are
    scaled in place (a copy's new pages cost 0.75 ms a snapshot at 13k
    points, and the result would hold its arrays twice); ``unit`` is not to
    be read after."""
    f = data.frame
    own = data.all_valid and natural_at_nodes(unit.options)
    stats = scaled_stats(unit.stats, f)
    stats["n_invalid"] = data.n_invalid
    stats["frame"] = f.as_dict()
    stats["flags"] = data.flags + list(unit.stats.get("flags", []))
    state = runtime.state()
    stats["arch"], stats["precision"] = state.arch, state.precision

    def rows(values, scale):
        if own:
            values *= scale
            return values
        return data.rows(values, scale)
    return HHDResult(points=data.points, vectors=data.vectors,
                     curl_free=rows(unit.curl_free, f.speed),
                     div_free=rows(unit.div_free, f.speed),
                     harmonic=rows(unit.harmonic, f.speed),
                     phi=rows(unit.phi, f.potential), psi=rows(unit.psi, f.potential),
                     divergence=rows(unit.divergence, f.derivative),
                     curl=rows(unit.curl, f.derivative), stats=stats, options=unit.options,
                     pointset=unit.pointset, valid=data.valid, frame=f,
                     domain=data.domain if data.domain is not None
                     else domain if domain is not None else f.domain_from_unit(unit.domain))


def _decompose_unit(data: Data, opts: HHDOptions, progress, split=None,
                    reach_checked: bool = False, natural=None) -> HHDResult:
    """Steps (a)-(e) on the valid rows in the unit frame under one condition."""
    if natural_at_nodes(opts):
        return _natural_unit(data, opts, progress, reach_checked, natural)
    if split is not None:
        return split(data, opts)
    return OperatorSplit(data, opts, keep=False).split([data], progress)[0]


#: the options of the SPH operator at the points: the natural decomposition
#: with all of them at the default's values takes div v and curl v from fits
#: of v at its grid nodes instead (:func:`natural_at_nodes`)
POINT_OPERATOR_OPTIONS = ("kernel", "support_ratio", "adaptive_support", "support_neighbours",
                          "divergence", "boundary", "remove_mean")


@functools.lru_cache(maxsize=64)
def natural_at_nodes(opts: HHDOptions) -> bool:
    """Whether the natural decomposition takes div v and curl v from fits of v
    at its grid nodes (:func:`~taichi_hh.hhd.natural.natural_decomposition`:
    no operator at the points, no neighbour search): with the default
    method's point operator (:data:`POINT_OPERATOR_OPTIONS` as
    ``METHODS["default"]`` has them).  Any other kernel, support or
    divergence variant, the ``petronetto`` fake particles or ``remove_mean``
    asks for the SPH operator at the points (its div v and curl v
    reconstructed at the nodes, :func:`~taichi_hh.hhd.natural.natural_potentials`).
    (Answered once per options: a series asks per snapshot, and the
    comparisons took 50 us.)"""
    default = METHODS["default"]
    return opts.boundary_condition == "natural" and all(
        getattr(opts, name) == getattr(default, name) for name in POINT_OPERATOR_OPTIONS)


class _LazyPointSet:
    """The decomposition's :class:`~taichi_hh.sph.pointset.PointSet`, built on
    first use (the natural decomposition at the nodes needs none; the
    critical points and diagnostics read one)."""

    def __init__(self, make):
        self._make, self._ps = make, None

    @property
    def built(self) -> bool:
        """Whether the point set has been made (read, or asked for) yet."""
        return self._ps is not None

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        if self._ps is None:
            self._ps = self._make()
        return getattr(self._ps, name)


def check_natural_reach(pts, domain, spacing: float, opts: HHDOptions, data: Data) -> None:
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


def _natural_unit(data: Data, opts: HHDOptions, progress,
                  reach_checked: bool = False, natural=None) -> HHDResult:
    """:func:`_decompose_unit` of the natural decomposition at the grid nodes
    (:func:`natural_at_nodes`): no point set (one is built if the result's
    ``pointset`` is read), div v and curl v from the nodes' fits of v, the
    energy check with the points' cell areas
    (:class:`~taichi_hh.hhd.natural.NaturalSplit`), the harmonic check with
    the nodes' fits of h.  Its arrays are the split's new ones, held nowhere
    else (:func:`in_caller_units` scales them in place)."""
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
    if not reach_checked:
        check_natural_reach(pts, domain, spacing, opts, data)
    stats = {"n_points": n, "n_boundary": 0, "n_ghosts": 0, "support": support,
             "spacing": spacing}
    check_point_count(n, stats, stacklevel=6)
    seconds["setup"] = time.perf_counter() - t
    say("natural potentials")
    t = time.perf_counter()
    if natural is not None:                # a series on these points: its set-up kept
        split = natural.split(vec)
    else:
        split = natural_decomposition(pts, vec, domain, spacing,
                                      evaluation=opts.natural_evaluation)
    # "divergence": div v and curl v (the nodes' fits and the points' values)
    seconds["divergence"] = sum(split.seconds.get(k, 0.0) for k in ("fit", "divergence"))
    seconds["natural"] = time.perf_counter() - t - seconds["divergence"]
    stats["natural_grid"] = split.grid.shape
    stats["mean_neighbours"] = split.mean_fit_points
    say("checks")
    t = time.perf_counter()
    d, r, h = split.d, split.div_free, split.harmonic           # h = v - d - r
    check_energy(stats, vec, d, r, h, split.volume, opts, stacklevel=6,
                 energies=split.energies)
    flag_harmonic(stats, dict(zip(("divergence", "curl"), split.harmonic_ratios())), opts,
                  stacklevel=6)
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
