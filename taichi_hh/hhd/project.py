"""Null-divergence projection of a particle velocity field (Colin, Egli & Lin
2006, Sec. 3.7 (d)-(e)), repeated ``iterations`` times, recording after each
pass Colin's two measures over the data points: the maximum |div| and the sum
of squared div (their Table 1).

Two steps and three schemes built from them (``scheme``; each method has its
own default).  Measurements of each: docs/notes/hhd.md.

* The Poisson step (:class:`PoissonStep`):
    Colin's algorithm: solve ``lap q = div w`` with ``dq/dn = 0`` (Colin Eqs.
    28-29, 31-38) and update ``w <- w - grad q`` (Eqs. 25, 41).

* The orthogonal step (:class:`OrthogonalStep`):
    The discrete orthogonal projection onto the null space of the divergence
    operator ``D`` itself.  With ``V`` the particle volumes,

        solve  (D V^-1 D^T) lam = D w   (conjugate gradients),
        update w <- w - V^-1 D^T lam,

    i.e. the field closest to ``w`` in the volume-weighted norm
    ``sum_i V_i |u_i|^2`` among those with ``D u = 0`` at every data point.
    ``-V^-1 D^T`` is the gradient adjoint to ``D`` (summation by parts); on a
    symmetric neighbourhood (the interior of a lattice) it *is* the quadratic
    gradient, so the update is ``w - grad lam``.

    Why not ``lap q = div w`` with some Laplacian ``L`` and correction ``G``
    alone: the divergence left after one pass is ``(I - D G L^-1) D w``, zero
    only when ``L = D G``.  Different stencils (Colin's Eq. 21 against DGAF, or
    our corrected Laplacian against the quadratic gradient) disagree most on
    the shortest wavelengths, so each pass removes only the smooth part, and
    near corners the mismatch can amplify the rest.  The composite ``L = D G``
    removes the divergence exactly, but on a lattice ``G`` annihilates the
    three odd-even (checkerboard) modes besides constants, and it annihilates
    every harmonic quadratic exactly (so without a boundary condition it has a
    null space the size of the boundary data); with ``dq/dn = 0`` rows it is
    nearly singular near the walls, so Krylov solvers stall, and it is
    incompatible whenever the data carry a net flux through the boundary.
    The adjoint form has none of this: ``D V^-1 D^T`` is symmetric positive
    semi-definite, its null space is the null space of ``D^T`` (the
    checkerboard modes), and ``D w`` lies in the range of ``D``, orthogonal to
    it, so the system is consistent for every input and CG converges.  The
    projection is idempotent and never increases ``sum V |w|^2``, and a field
    with ``D w = 0`` (e.g. a rigid rotation, on which the quadratic
    divergence is exact) is returned unchanged.  No condition is imposed on
    the normal velocity: the continuous analogue is the Leray projection with
    ``q = 0`` on the boundary, which changes the normal flux.

* ``neumann`` (``method="default"``, :class:`NeumannProjection`):
    Each pass is one Poisson step with our consistent operators (corrected
    Laplacian, quadratic gradient, ``dq/dn = 0`` rows on boundary particles
    along the boundary), which gives the projection its meaning (the normal
    flux of the data is kept, as in Colin's Eq. 29 and in the divergence-free
    part ``r + h`` of :func:`taichi_hh.decompose`), then one orthogonal step,
    which removes what the Poisson step left exactly and with the smallest
    change.  One pass leaves ``D w`` at the solver tolerance, so further passes
    find nothing to do: repeated passes are bounded whatever the geometry (the
    Poisson step repeated alone is not).

    Measured divergence: ``D``, the quadratic (MLS) divergence over the data
    points, i.e. ``PointSet(points, kernel, support).divergence(v, "quadratic")``,
    on regular layouts (lattices, blue noise); on irregular ones (uniformly
    random, clustered, graded, strongly jittered) the default takes the
    decomposition's adaptive support and cubic divergence instead
    (:func:`choose_support`; ``stats["divergence_operator"]`` names it).
    Colin's examples 3 and 4 carry a net flux through the walls, so no field
    keeping their normal flux is divergence-free: there the orthogonal step
    changes the flux as little as it can.

* ``orthogonal`` (:class:`OrthogonalProjection`):
    The orthogonal step alone.  Measured divergence: ``D`` as for ``neumann``.

* ``poisson`` (``method="colin2006"``, :class:`PoissonProjection`):
    The Poisson step alone, Colin's algorithm.  With ``method="colin2006"``:
    poly6, DGAF (Eq. 13) divergence and gradient, Laplacian Eq. 21, a layer of
    wall particles at rest as wide as the support, continuing the lattice for
    a box (Sec. 3.6, Fig. 4), carrying outward normals (diagonal at the
    corners) whose rows enforce ``n . grad q = 0`` (Eq. 37), the square
    stacked system solved by CG on the normal equations (Sec. 3.5) to the
    least-squares solution (the stacked system is not consistent in general).
    The wall particles' zero velocity joins the divergence sums.  Measured
    divergence: Colin's Eq. 33 (DGAF over inside and wall particles) at the
    inside particles.  With ``method="default", scheme="poisson"`` the same
    loop runs with our operators (corrected Laplacian, quadratic gradient and
    Neumann rows on boundary particles along the boundary, bordered
    BiCGSTAB); measured divergence: the quadratic divergence over the data
    points.
"""

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import runtime

from ..linalg import krylov as solvers
from ..errors import AccuracyWarning, InputError, NeighbourError, SolverError
from .boundary import collocation_particles
from .inputs import prepare_data
from .options import METHODS, PROJECT_OVERRIDES, options_for
from ..sph.particles import BOUNDARY, FLUID
from ..geometry.walls import box_wall_lattice
from ..sph.adjoint import NormalOperator
from ..sph.pointset import PointSet
from ..poisson.matrix import PoissonMatrix


@dataclass
class ProjectionResult:
    points: np.ndarray
    vectors: np.ndarray            # the projected (null-divergence) field
    initial: np.ndarray
    max_divergence: np.ndarray     # per pass, index 0 = before projecting
    sum_sq_divergence: np.ndarray
    divergence: np.ndarray         # the measured divergence of the result at the points
    stats: dict = field(default_factory=dict)
    history: list | None = None    # with project(history=True): the field after each pass


def wall_layer(domain, spacing: float, width: float, points=None, lattice: bool = True):
    """Wall particles outside ``domain`` within ``width`` of it and their outward
    normals (Colin Sec. 3.6: a boundary layer as wide as the support).

    For a :class:`~taichi_hh.geometry.domain.Box` and ``lattice=True`` the layer continues
    the lattice of spacing ``spacing`` aligned with the box (Colin Fig. 4);
    otherwise it is a blue-noise band.  Corner normals point along the diagonal.
    """
    from ..geometry.domain import Box
    if lattice and isinstance(domain, Box):
        P = box_wall_lattice(domain.lo, domain.hi, spacing, width, closed=True)
    else:
        P = domain.sample_ghosts(spacing, width, avoid=points)
    _, _, nrm, _ = domain.closest_boundary(P)
    return P, nrm


# ---------------------------------------------------------------------------

class PoissonStep:
    """Colin's Poisson step: ``lap q = b`` with ``dq/dn = 0`` rows (Colin Eqs.
    28-29, 31-38), ``w <- w - grad q`` (Eqs. 25, 41), on the data points and
    the boundary particles of ``opts.boundary``: Colin's wall layer (``colin``,
    whose velocity joins the divergence sums) or samples along the boundary
    (``collocation``)."""

    def __init__(self, pts, domain, opts, spacing: float, support: float, wall_velocity=None):
        boundary = None
        if opts.boundary == "colin":
            boundary = wall_layer(domain, spacing, support, pts)
        elif opts.boundary == "collocation":
            boundary = collocation_particles(domain, pts, spacing)
        elif opts.boundary != "none":
            raise InputError("project() supports boundary='collocation', 'colin' or 'none'")
        self.opts = opts
        self.real = runtime.np_real()
        self.ps = ps = _pointset(pts, domain, opts, support, boundary=boundary)
        kind = ps.particles.get("kind")
        fluid = kind == FLUID
        # wall particles join the divergence sums with their (rest) velocity in
        # Colin's formulation; ours differentiates the data alone
        walls_move = opts.boundary == "colin"
        self.divergence_stencil = ps.ops.gradient_coefficients(
            opts.divergence, row_kinds=(FLUID,),
            source_kinds=(FLUID, BOUNDARY) if walls_move else (FLUID,))
        self.gradient_stencil = ps.ops.gradient_coefficients(opts.gradient, row_kinds=(FLUID,))
        self.matrix = PoissonMatrix(ps.ops, laplacian=opts.laplacian,
                                    gradient=opts.neumann_gradient, kappa=opts.kappa,
                                    bordered=opts.bordered)
        # the velocity per slot: the data at the data points, the walls' own elsewhere
        self.velocity_slots = np.zeros((ps.n_total, 2))
        if walls_move and wall_velocity is not None:
            self.velocity_slots[~fluid] = np.asarray(wall_velocity, dtype=np.float64)
        self.velocity_nd = ps.new_array(2)
        self.divergence_nd = ps.new_array(1)
        self.potential_nd = ps.new_array(1)
        self.gradient_nd = ps.new_array(2)
        self.n_boundary = int((kind == BOUNDARY).sum())
        # the stacked colin system is inconsistent in general: its least-squares
        # solution, as CG on A^T A q = A^T b gives
        self.solve_options = {"least_squares": True} if opts.solver == "cgnr" else {}

    def divergence(self, w) -> np.ndarray:
        """The divergence of ``w`` (data points' order) by this step's operator."""
        ps = self.ps
        self.velocity_slots[ps.slot_of] = w
        self.velocity_nd.from_numpy(self.velocity_slots.astype(self.real))
        ps.ops.divergence(self.divergence_stencil, self.velocity_nd, self.divergence_nd)
        return ps.download(self.divergence_nd)

    def apply(self, w, b):
        """``(w - grad q, solver iterations)`` with ``lap q = b`` at the data points."""
        ps, opts = self.ps, self.opts
        rhs = np.zeros(ps.n_total)
        rhs[ps.slot_of] = b
        res = self.matrix.solve(rhs, x0=None, method=opts.solver, tol=opts.tol,
                                max_iterations=opts.max_iterations,
                                preconditioner=opts.preconditioner,
                                multilevel_options=dict(opts.multilevel_options),
                                **self.solve_options)
        self.potential_nd.from_numpy(res.x.astype(self.real))
        ps.ops.gradient(self.gradient_stencil, self.potential_nd, self.gradient_nd)
        return w - ps.download(self.gradient_nd), res.iterations


#: the decomposition's options for scattered points: the default projection
#: takes them where the layout is irregular (:func:`choose_support`)
SCATTERED_OPTIONS = {name: getattr(METHODS["default"], name)
                     for name in ("adaptive_support", "support_ratio", "divergence")}

#: The default projection keeps its fixed support (``PROJECT_OVERRIDES["default"]``)
#: on layouts whose :func:`layout_irregularity` is at most this, and takes
#: :data:`SCATTERED_OPTIONS` above it.  Measured (benchmarks/projection_defaults.py,
#: gaussian field, unit square; irregularity in brackets): the fixed support
#: projects lattices (0) and blue noise (0.07) up to 64k points in 7-26
#: Poisson-step iterations, and a lattice jittered by +-0.15 spacings
#: (``jitter0.3``, 0.082) in 99 at 64k; but a lattice jittered by +-0.25 spacings
#: (``jitter0.5``, 0.147) takes 437 at 64k and by +-0.35 (0.22) stagnates there;
#: uniformly random points (0.51-0.54) stagnate from 4k (and at 1k return a
#: field 61% away from r + h), clustered (0.72-0.83) and 1:10 graded (0.60-0.62)
#: points have singular quadratic fits from 1k.  The adaptive support projects
#: every one of them (7-17 Poisson-step iterations).  0.12 lies between blue
#: noise and jitter0.5 (the statistic varies by under 0.01 over sizes and seeds).
IRREGULARITY_THRESHOLD = 0.12


def layout_irregularity(points) -> float:
    """The coefficient of variation (standard deviation / mean) of the
    points' nearest-neighbour distances: 0 on a lattice, about 0.07 on blue
    noise, 0.52 on uniformly random points (a Poisson process: sqrt(4/pi - 1)),
    above that on clustered ones.  Scale-free; one k-nearest search
    (:mod:`taichi_hh.sph.knn`).  0 for fewer than 3 points."""
    from ..sph.knn import KNearest
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 3:
        return 0.0
    d = KNearest(pts).kth_distance_among(1)
    mean = float(d.mean())
    return float(d.std() / mean) if mean > 0 else 0.0


def choose_support(points, method: str, options: dict):
    """``(overrides, choice)``: the options the default projection adds for
    these points, and how it chose (``choice["by"]``: ``"layout"``,
    ``"caller"`` or ``"method"``; ``choice["irregularity"]``: the measure, None
    where not taken).  With ``method="default"`` and no
    ``adaptive_support`` from the caller, points whose
    :func:`layout_irregularity` exceeds :data:`IRREGULARITY_THRESHOLD` get
    :data:`SCATTERED_OPTIONS` (those the caller did not set); other methods
    and explicit choices are left as they are."""
    if method != "default":
        return {}, {"support": None, "by": "method", "irregularity": None}
    if "adaptive_support" in options:
        given = "adaptive" if options["adaptive_support"] else "fixed"
        return {}, {"support": given, "by": "caller", "irregularity": None}
    irregularity = layout_irregularity(points)
    # the adaptive support needs more points than its neighbour count
    neighbours = options.get("support_neighbours", METHODS["default"].support_neighbours)
    if irregularity > IRREGULARITY_THRESHOLD and len(points) > neighbours:
        return ({k: v for k, v in SCATTERED_OPTIONS.items() if k not in options},
                {"support": "adaptive", "by": "layout", "irregularity": irregularity})
    return {}, {"support": "fixed", "by": "layout", "irregularity": irregularity}


def _scattered_remedy(opts) -> str:
    """What to try when the fixed support fails: on uniformly random,
    clustered or graded points the adaptive support works (docs/notes/hhd.md)."""
    if opts.adaptive_support:
        return ""
    args = ", ".join(f"{k}={v!r}" for k, v in SCATTERED_OPTIONS.items())
    return (f". For scattered (random, clustered, graded) points use the adaptive support: "
            f"project(..., {args})")


def _pointset(pts, domain, opts, support: float, boundary=None) -> PointSet:
    """The steps' point set: the fixed ``support``, or with
    ``opts.adaptive_support`` each point's own (``support_ratio`` local
    spacings, as :func:`~taichi_hh.hhd.decompose.decompose` sets it)."""
    if opts.adaptive_support:
        return PointSet(pts, kernel=opts.kernel, support_ratio=opts.support_ratio,
                        area=domain.area, boundary=boundary,
                        support_neighbours=opts.support_neighbours)
    return PointSet(pts, kernel=opts.kernel, support=support, area=domain.area,
                    boundary=boundary)


class OrthogonalStep:
    """The orthogonal projection onto the null space of ``D``, the divergence
    over the data points alone (exactly ``PointSet(points).divergence(v,
    divergence)``): ``(D V^-1 D^T) lam = D w`` by Jacobi-preconditioned CG,
    ``w <- w - V^-1 D^T lam`` (module doc)."""

    def __init__(self, pts, domain, opts, support: float):
        self.max_iterations = opts.max_iterations
        self.real = runtime.np_real()
        self.ps = ps = _pointset(pts, domain, opts, support)
        self.divergence_stencil = ps.ops.gradient_coefficients(
            opts.divergence, row_kinds=(FLUID,), source_kinds=(FLUID,))
        self.normal_operator = NormalOperator.of_pointset(ps, self.divergence_stencil)
        self.velocity_nd = ps.new_array(2)
        self.divergence_nd = ps.new_array(1)
        self.multiplier_nd = ps.new_array(1)
        self.correction_nd = ps.new_array(2)

    def divergence(self, w) -> np.ndarray:
        """``D w`` at the data points (their order)."""
        ps = self.ps
        self.velocity_nd.from_numpy(_to_slots(ps, w).astype(self.real))
        ps.ops.divergence(self.divergence_stencil, self.velocity_nd, self.divergence_nd)
        return ps.download(self.divergence_nd)

    def apply(self, w, div, done: float):
        """``(w', D w', CG iterations)`` for ``w`` with ``D w = div``: CG to
        ``|D w'| <= done``; a field already there is returned as it is."""
        norm = _norm(div)
        if norm <= done:
            return w, div, 0
        ps = self.ps
        res = solvers.cg(self.normal_operator, _to_slots(ps, div), tol=done / norm,
                         max_iterations=self.max_iterations, preconditioner="jacobi")
        self.multiplier_nd.from_numpy(np.resize(res.x.astype(self.real), max(ps.n_total, 1)))
        self.normal_operator.correction(self.multiplier_nd, self.correction_nd)
        w = w - ps.download(self.correction_nd)
        return w, self.divergence(w), res.iterations


class Projection:
    """One projection scheme on one point set: its steps, set up once, the
    divergence it measures (:meth:`divergence`), one pass (:meth:`pass_`) and
    the diagnostics (:attr:`n_boundary`, :meth:`divergence_operator`)."""

    def __init__(self, pts, domain, opts, wall_velocity=None):
        self.opts = opts
        self.spacing = math.sqrt(domain.area / len(pts))
        self.support = opts.support_ratio * self.spacing
        self.n_boundary = 0

    def divergence(self, w) -> np.ndarray:
        """The measured divergence of ``w`` at the data points."""
        raise NotImplementedError

    def pass_(self, w, div, done: float):
        """One pass on ``w`` whose measured divergence is ``div``: ``(w', div',
        solver iterations per step)``; ``done``: the level of ``|div|`` (2-norm)
        below which a field counts as divergence-free."""
        raise NotImplementedError

    def divergence_operator(self) -> str:
        opts = self.opts
        support = (f"adaptive support {opts.support_ratio:g} local spacings"
                   if opts.adaptive_support else f"support {opts.support_ratio:g} spacings")
        return f"{opts.divergence} divergence over the data points ({opts.kernel}, {support})"


class NeumannProjection(Projection):
    """Poisson step (kept normal flux) then orthogonal step (exact), measured by ``D``."""

    def __init__(self, pts, domain, opts, wall_velocity=None):
        super().__init__(pts, domain, opts, wall_velocity)
        self.poisson = PoissonStep(pts, domain, opts, self.spacing, self.support, wall_velocity)
        self.orthogonal = OrthogonalStep(pts, domain, opts, self.support)
        self.n_boundary = self.poisson.n_boundary

    def divergence(self, w):
        return self.orthogonal.divergence(w)

    def pass_(self, w, div, done):
        if _norm(div) <= done:
            poisson_iterations = 0          # nothing left to remove
        else:
            w, poisson_iterations = self.poisson.apply(w, self.poisson.divergence(w))
            div = self.divergence(w)
        w, div, orthogonal_iterations = self.orthogonal.apply(w, div, done)
        return w, div, (poisson_iterations, orthogonal_iterations)


class OrthogonalProjection(Projection):
    """The orthogonal step alone, measured by ``D``."""

    def __init__(self, pts, domain, opts, wall_velocity=None):
        super().__init__(pts, domain, opts, wall_velocity)
        self.orthogonal = OrthogonalStep(pts, domain, opts, self.support)

    def divergence(self, w):
        return self.orthogonal.divergence(w)

    def pass_(self, w, div, done):
        w, div, iterations = self.orthogonal.apply(w, div, done)
        return w, div, (iterations,)


class PoissonProjection(Projection):
    """The Poisson step alone (Colin's algorithm), measured by its own divergence."""

    def __init__(self, pts, domain, opts, wall_velocity=None):
        super().__init__(pts, domain, opts, wall_velocity)
        self.poisson = PoissonStep(pts, domain, opts, self.spacing, self.support, wall_velocity)
        self.n_boundary = self.poisson.n_boundary

    def divergence(self, w):
        return self.poisson.divergence(w)

    def pass_(self, w, div, done):
        w, iterations = self.poisson.apply(w, div)
        return w, self.divergence(w), (iterations,)

    def divergence_operator(self):
        opts = self.opts
        if opts.boundary != "colin":
            return super().divergence_operator()
        return (f"{opts.divergence} divergence over the data and wall particles at rest "
                f"({opts.kernel}, support {self.support:.4g}) at the data points")


PROJECTIONS = {"neumann": NeumannProjection, "orthogonal": OrthogonalProjection,
               "poisson": PoissonProjection}
SCHEMES = tuple(PROJECTIONS)


def project(points, vectors, domain=None, *, iterations: int = 1, method: str = "default",
            scheme: str | None = None, wall_velocity=None, progress=None,
            history: bool = False, **options) -> ProjectionResult:
    """Project ``vectors`` at ``points`` onto null divergence, ``iterations`` times.

    points, vectors: (N, 2) arrays; domain: :class:`~taichi_hh.geometry.domain.Box` or
    :class:`~taichi_hh.geometry.domain.Polygon` (default: the points' bounding box).
    method: ``"default"`` or ``"colin2006"`` (or another bundle of
    :data:`taichi_hh.hhd.options.METHODS`; keyword ``options`` override single fields of
    :class:`~taichi_hh.hhd.options.HHDOptions`, e.g. ``support_ratio``, ``kernel``,
    ``divergence``, ``tol``).  scheme: ``"neumann"``, ``"orthogonal"`` or
    ``"poisson"`` (module doc; default: neumann for ``default``, poisson for
    any other method).  wall_velocity: velocity of the ``colin2006`` wall
    particles (default 0: walls at rest).  progress: ``callable(stage)``.
    The default's support follows the layout (:func:`choose_support`): the
    fixed support of ``PROJECT_OVERRIDES["default"]`` (2.5 spacings, quadratic
    divergence, as measured on Colin's lattices) where the points are about as
    regular as a lattice or blue noise, and the decomposition's adaptive
    support, :data:`SCATTERED_OPTIONS` (3.5 local spacings, cubic divergence),
    where :func:`layout_irregularity` (the spread of the nearest-neighbour
    distances) exceeds :data:`IRREGULARITY_THRESHOLD` (jittered lattices
    beyond +-0.2 spacings, uniformly random, clustered, graded points), or
    where the fixed support's fits fail at set-up.  Passing
    ``adaptive_support`` decides it instead (``False``: the fixed support
    whatever the layout; ``True``: with ``support_ratio`` and ``divergence``
    from the caller or ``PROJECT_OVERRIDES``).  ``stats["support_choice"]``
    says which was used, ``stats["support_chosen_by"]`` why (``"layout"``,
    ``"fallback"``, ``"caller"`` or ``"method"``) and ``stats["irregularity"]``
    the measure.

    Returns a :class:`ProjectionResult`: ``max_divergence`` and
    ``sum_sq_divergence`` per pass (index 0 = the input), measured with the
    scheme's own divergence operator (module doc: the quadratic divergence over
    the data points for ``default``, Colin's Eq. 33 for ``colin2006``);
    ``stats["divergence_operator"]`` names it; ``stats["iterations"]`` has the
    solver iterations per pass, ``stats["stage_iterations"]`` the (Poisson,
    orthogonal) split.
    The orthogonal step solves to ``|D w| <= tol * max(|D w_input|, |w| /
    spacing)`` (2-norms; a pass that starts below it does nothing, and so does
    the Neumann scheme's Poisson step) by Jacobi-preconditioned CG whatever
    ``solver`` and ``preconditioner`` say (those apply to the Poisson step).
    history: keep the field after every pass in ``result.history`` (index 0 =
    the input).
    """
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) \
            or iterations < 1:
        raise InputError(f"iterations must be a positive integer, got {iterations!r}")
    scheme = scheme or ("neumann" if method == "default" else "poisson")
    if scheme not in SCHEMES:
        raise InputError(f"scheme must be one of {SCHEMES}, got {scheme!r}")
    opts = options_for(method, **{**PROJECT_OVERRIDES.get(method, {}), **options})
    if opts.boundary_condition != "neumann":
        raise InputError(f"boundary_condition={opts.boundary_condition!r} is a decomposition "
                         "option: a projection keeps the normal flux (Neumann)")
    if scheme != "poisson" and opts.boundary == "colin":
        raise InputError(f"scheme {scheme!r} measures the divergence of the data alone: it "
                         "does not take Colin's wall particles (boundary='colin'); use "
                         "boundary='collocation'")
    runtime.ensure_init()
    # the numerics run in the unit frame (hhd.units): any units, any magnitude
    data = prepare_data(points, vectors, domain, caller="project")
    frame = data.frame
    pts, vec, domain = data.unit_points, data.unit_vectors, data.unit_domain
    if wall_velocity is not None:
        wall_velocity = _wall_velocity(wall_velocity, opts) / frame.speed
    say = progress or (lambda stage: None)
    t0 = time.perf_counter()
    # the default's support from the layout: fixed on lattices and blue noise,
    # adaptive on irregular points (choose_support)
    extra, choice = choose_support(pts, method, options)
    if extra:
        opts = options_for(method, **{**PROJECT_OVERRIDES.get(method, {}), **extra, **options})
    try:
        projection = PROJECTIONS[scheme](pts, domain, opts, wall_velocity)
    except NeighbourError as exc:
        if not (choice["by"] == "layout" and not opts.adaptive_support):
            raise NeighbourError(str(exc) + _scattered_remedy(opts)) from None
        # a regular-looking layout with a sparse patch: the adaptive support
        # (the fixed support's fits fail while the point set is built, at once);
        # should it fail too, the fixed support's error is the one reported
        fixed_opts, fixed_error = opts, str(exc)
        opts = options_for(method, **{**PROJECT_OVERRIDES.get(method, {}),
                                      **{k: v for k, v in SCATTERED_OPTIONS.items()
                                         if k not in options}, **options})
        choice = {**choice, "support": "adaptive", "by": "fallback",
                  "fixed_support_error": " ".join(fixed_error.split())}
        try:
            projection = PROJECTIONS[scheme](pts, domain, opts, wall_velocity)
        except NeighbourError:
            raise NeighbourError(fixed_error + _scattered_remedy(fixed_opts)) from None

    w = vec.copy()
    div = projection.divergence(w)
    first = _measures(div)
    max_div, sum_sq = [first[0]], [first[1]]
    # "already divergence-free": |D w| at most tol times the larger of the
    # input's |D w| and |w| / spacing (the divergence of a field varying by its
    # own size over one spacing), and never below rounding level; so feeding a
    # projected field back in does nothing rather than chase rounding errors
    eps = float(np.finfo(runtime.np_real()).eps)
    scale = math.sqrt(float((w ** 2).sum())) / projection.spacing
    floor = 1e3 * eps * scale
    done = max(opts.tol * max(math.sqrt(first[1]), scale), floor)
    iters, stage_iters, residuals = [], [], []
    fields = [vec.copy()] if history else None
    flags = []
    for k in range(iterations):
        say(f"projection {k + 1}/{iterations}")
        try:
            w, div, counts = projection.pass_(w, div, done)
        except SolverError as exc:
            raise SolverError(str(exc) + _scattered_remedy(opts), reason=exc.reason,
                              iteration=exc.iteration, residual=exc.residual) from None
        iters.append(sum(counts))
        stage_iters.append(counts)
        residuals.append(_norm(div))
        m, q = _measures(div)
        max_div.append(m)
        sum_sq.append(q)
        if history:
            fields.append(w.copy())
        grew = _check_pass(k + 1, w, vec, max_div, method, scheme, floor, frame)
        if grew and not flags:
            flags.append(grew)
            warnings.warn(grew, AccuracyWarning, stacklevel=2)
    per_length = frame.derivative
    stats = {"flags": flags, "iterations": iters, "stage_iterations": stage_iters,
             "divergence_norm": [value * per_length for value in residuals],
             "seconds": time.perf_counter() - t0,
             "scheme": scheme, "n_boundary": projection.n_boundary,
             "support": projection.support * frame.length,
             "spacing": projection.spacing * frame.length,
             "divergence_operator": projection.divergence_operator(), "frame": frame.as_dict(),
             "support_choice": "adaptive" if opts.adaptive_support else "fixed",
             "support_chosen_by": choice["by"], "irregularity": choice["irregularity"],
             "arch": runtime.state().arch, "precision": runtime.state().precision}
    if "fixed_support_error" in choice:
        stats["fixed_support_error"] = choice["fixed_support_error"]
    runtime.release_launch_arguments(len(pts))
    return ProjectionResult(points=data.points, vectors=w * frame.speed, initial=data.vectors,
                            max_divergence=np.array(max_div) * per_length,
                            sum_sq_divergence=_squared_in(np.array(sum_sq), per_length),
                            divergence=div * per_length, stats=stats,
                            history=None if fields is None else [f * frame.speed for f in fields])


#: a pass that multiplies the smallest max |div| so far by more than this, or
#: leaves speeds above SPEED_GROWTH times the input's, is a diverging projection
DIVERGENCE_GROWTH = 10.0
SPEED_GROWTH = 100.0


#: growth of max |div| by less than this factor is rounding, not a diverging pass
DIVERGENCE_NOISE = 1.01


def _check_pass(k, w, vec, max_div, method, scheme, floor=0.0, frame=None):
    """Raise SolverError('divergence') when pass k made things worse instead of
    returning the garbage: e.g. Colin's operators on disordered points, where the
    discrete Laplacian is not the divergence of the discrete gradient and
    repeated passes amplify the mismatch (stability map, benchmarks/).  Growth
    below that (max |div| above the smallest so far, and above the rounding
    ``floor``) is returned as a message: the caller flags the result with it.
    ``frame``: the unit frame the values are in; messages quote the caller's units."""
    per_length = 1.0 if frame is None else frame.derivative
    shown = [m * per_length for m in max_div]
    speed_in = float(np.abs(vec).max())
    speed = float(np.abs(w).max())
    best = min(max_div[:-1])
    if not np.isfinite(w).all():
        why = "the field became non-finite"
    elif max_div[-1] > DIVERGENCE_GROWTH * max(best, 1e-300) and max_div[-1] > max_div[0]:
        why = (f"max |div| grew to {shown[-1]:.3e} from {best * per_length:.3e} (input: "
               f"{shown[0]:.3e})")
    elif speed > SPEED_GROWTH * max(speed_in, 1e-300):
        why = (f"max |w| reached {speed * (1.0 if frame is None else frame.speed):.3e}, "
               f"{speed / speed_in:.0f} times the input's")
    else:
        if max_div[-1] > DIVERGENCE_NOISE * best and max_div[-1] > floor:
            return (f"projection pass {k} raised max |div| from {best * per_length:.3e} to "
                    f"{shown[-1]:.3e} (input: {shown[0]:.3e}; method {method!r}, scheme "
                    f"{scheme!r}): these operators are not stable on these points and "
                    "further passes may diverge ("
                    + ("use method='default')" if method != "default"
                       else "use the default scheme)"))
        return None
    raise SolverError(f"projection diverged at pass {k} (method {method!r}, scheme "
                      f"{scheme!r}): {why}; these operators are not stable on these points"
                      + (" (use method='default')" if method != "default" else
                         " (use the default scheme)" if scheme != "neumann" else ""),
                      reason="divergence", iteration=k,
                      residual=float(shown[-1]))


def _wall_velocity(value, opts) -> np.ndarray:
    """``wall_velocity`` checked: a finite (2,) velocity (or one number for
    both components) of Colin's wall particles, which only ``boundary="colin"``
    has; raises :class:`~taichi_hh.errors.InputError`."""
    if opts.boundary != "colin":
        raise InputError("wall_velocity is the velocity of Colin's wall particles: it applies "
                         f"with method='colin2006' (boundary='colin'), not boundary="
                         f"{opts.boundary!r}")
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf" or arr.shape not in ((), (2,)):
        raise InputError(f"wall_velocity must be two real numbers (u, v) or one, got "
                         f"{value!r}")
    arr = np.broadcast_to(arr.astype(np.float64), (2,)).copy()
    if not np.isfinite(arr).all():
        raise InputError(f"wall_velocity must be finite, got {arr.tolist()}")
    return arr


def _squared_in(values: np.ndarray, unit: float) -> np.ndarray:
    """Sums of squares in the unit frame times ``unit**2``: inf or 0 where the
    caller's units take them beyond double precision (a field of 1e160)."""
    with np.errstate(over="ignore", under="ignore"):
        return values * unit * unit


def _to_slots(ps, values):
    """Caller-order values -> slot order (the data points fill every slot here)."""
    values = np.asarray(values, dtype=np.float64)
    out = np.zeros((ps.n_total,) + values.shape[1:])
    out[ps.slot_of] = values
    return out


def _norm(div) -> float:
    return math.sqrt(float((div ** 2).sum()))


def _measures(div):
    return float(np.abs(div).max()) if div.size else 0.0, float((div ** 2).sum())
