"""Null-divergence projection of a particle velocity field (Colin, Egli & Lin
2006, Sec. 3.7 (d)-(e)), repeated ``iterations`` times, recording after each
pass Colin's two measures over the data points: the maximum |div| and the sum
of squared div (their Table 1).

Three schemes (``scheme``; each method has its own default):

``neumann`` (``method="default"``)
    Each pass is one Poisson step with our consistent operators (``poisson``
    below: corrected Laplacian, quadratic gradient, ``dq/dn = 0`` rows on
    boundary particles along the boundary), which gives the projection its
    meaning (the normal flux of the data is kept, as in Colin's Eq. 29 and in
    the divergence-free part ``r + h`` of :func:`taichi_hh.decompose`), then
    one ``orthogonal`` step, which removes what the Poisson step left exactly
    and with the smallest change.  One pass leaves ``D w`` at the solver
    tolerance, so further passes find nothing to do: repeated passes are
    bounded whatever the geometry.  Measured on the Gaussian field of
    :mod:`taichi_hh.validation.fields` on blue noise: the result differs from the exact
    ``r + h`` by 1.8% (2k points) and 0.3% (13k points) of mean |v|, where the
    orthogonal scheme alone differs by 12% and 17% (it changes the normal
    flux), and the Poisson step repeated alone diverges at 2k points (max
    |div| 13.7, 2.8, 0.77, 0.26, 1.6, 43 over five passes).

    Measured divergence: ``D``, the quadratic (MLS) divergence over the data
    points, i.e. ``PointSet(points, kernel, support).divergence(v, "quadratic")``.
    Colin's examples 3 and 4 carry a net flux through the walls, so no field
    keeping their normal flux is divergence-free: there the orthogonal step
    changes the flux as little as it can.

``orthogonal``
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
    it, so the system is consistent for every input and CG converges (about
    150 Jacobi-CG iterations at 2k and at 13k blue-noise points).  The
    projection is idempotent and never increases ``sum V |w|^2``, and a field
    with ``D w = 0`` (e.g. a rigid rotation, on which the quadratic
    divergence is exact) is returned unchanged.  No condition is imposed on
    the normal velocity: the continuous analogue is the Leray projection with
    ``q = 0`` on the boundary, which changes the normal flux.

    Measured divergence: ``D`` as for ``neumann``.

``poisson`` (``method="colin2006"``)
    Colin's algorithm: solve ``lap q = div w`` with ``dq/dn = 0`` (Eqs. 28-29,
    31-38) and update ``w <- w - grad q`` (Eqs. 25, 41).  With
    ``method="colin2006"``: poly6, DGAF (Eq. 13) divergence and gradient,
    Laplacian Eq. 21, a layer of wall particles at rest as wide as the
    support, continuing the lattice for a box (Sec. 3.6, Fig. 4), carrying
    outward normals (diagonal at the corners) whose rows enforce
    ``n . grad q = 0`` (Eq. 37), the square stacked system solved by CG on
    the normal equations (Sec. 3.5) to the least-squares solution (the
    stacked system is not consistent in general).  The wall particles' zero
    velocity joins the divergence sums.  Measured divergence: Colin's Eq. 33
    (DGAF over inside and wall particles) at the inside particles.  With
    ``method="default", scheme="poisson"`` the same loop runs with our
    operators (corrected Laplacian, quadratic gradient and Neumann rows on
    boundary particles along the boundary, bordered BiCGSTAB); measured
    divergence: the quadratic divergence over the data points.
"""

import math
import time
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from .. import runtime

from ..linalg import krylov as solvers
from ..errors import InputError, SolverError
from .decompose import validate_input, options_for
from ..sph.particles import BOUNDARY, FLUID
from ..sph.adjoint import NormalOperator
from ..sph.pointset import PointSet
from ..linalg.poisson import PoissonMatrix

SCHEMES = ("neumann", "orthogonal", "poisson")

#: per-method defaults of project() that differ from the decompose() bundles
#: of :data:`taichi_hh.hhd.decompose.METHODS`: Colin solves the plain (not bordered)
#: stacked system by CG on the normal equations, here to the least-squares
#: solution with normal residual 1e-4 (measured: tighter tolerances stall, the
#: scaled stacked matrix of examples 2-5 having a condition number of about
#: 1e5 besides its constant null vector, so CGNR's rate follows 1e10).
PROJECT_OVERRIDES = {"colin2006": {"bordered": False, "tol": 1e-4, "max_iterations": 20000}}


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
        lo, hi = np.asarray(domain.lo), np.asarray(domain.hi)
        k = int(math.ceil(width / spacing)) + 1
        nx = max(int(round((hi[0] - lo[0]) / spacing)), 1)
        ny = max(int(round((hi[1] - lo[1]) / spacing)), 1)
        gx = lo[0] + (np.arange(-k, nx + k) + 0.5) * (hi[0] - lo[0]) / nx
        gy = lo[1] + (np.arange(-k, ny + k) + 0.5) * (hi[1] - lo[1]) / ny
        P = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
        outside = ~domain.contains(P)
        P = P[outside]
        dist = domain.signed_distance(P)
        P = P[dist <= width]
    else:
        P = domain.sample_ghosts(spacing, width, avoid=points)
    _, _, nrm, _ = domain.closest_boundary(P)
    return P, nrm


# ---------------------------------------------------------------------------

def project(points, vectors, domain=None, *, iterations: int = 1, method: str = "default",
            scheme: str | None = None, wall_velocity=None, progress=None,
            history: bool = False, **options) -> ProjectionResult:
    """Project ``vectors`` at ``points`` onto null divergence, ``iterations`` times.

    points, vectors: (N, 2) arrays; domain: :class:`~taichi_hh.geometry.domain.Box` or
    :class:`~taichi_hh.geometry.domain.Polygon` (default: the points' bounding box).
    method: ``"default"`` or ``"colin2006"`` (or another bundle of
    :data:`taichi_hh.hhd.decompose.METHODS`; keyword ``options`` override single fields of
    :class:`~taichi_hh.hhd.decompose.HHDOptions`, e.g. ``support_ratio``, ``kernel``,
    ``divergence``, ``tol``).  scheme: ``"neumann"``, ``"orthogonal"`` or
    ``"poisson"`` (module doc; default: neumann for ``default``, poisson for
    any other method).  wall_velocity: velocity of the ``colin2006`` wall
    particles (default 0: walls at rest).  progress: ``callable(stage)``.

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
    if scheme != "poisson" and opts.boundary == "colin":
        raise InputError(f"scheme {scheme!r} measures the divergence of the data alone: it "
                         "does not take Colin's wall particles (boundary='colin'); use "
                         "boundary='collocation'")
    runtime.ensure_init()
    pts, vec, domain = validate_input(points, vectors, domain)
    say = progress or (lambda stage: None)
    n = len(pts)
    spacing = math.sqrt(domain.area / n)
    support = opts.support_ratio * spacing
    t0 = time.perf_counter()

    poisson_step = scheme in ("neumann", "poisson")
    real = runtime.np_real()
    ps = st_div = A = st_grad = None
    if poisson_step:
        boundary = None
        if opts.boundary == "colin":
            boundary = wall_layer(domain, spacing, support, pts)
        elif opts.boundary == "collocation":
            from .decompose import far_from
            bpts, bnrm, _ = domain.sample_boundary(spacing)
            keep = far_from(bpts, pts, 0.25 * spacing, domain)
            boundary = (bpts[keep], bnrm[keep])
        elif opts.boundary != "none":
            raise InputError("project() supports boundary='collocation', 'colin' or 'none'")
        ps = PointSet(pts, kernel=opts.kernel, support=support, area=domain.area,
                      boundary=boundary)
        kind = ps.particles.get("kind")
        fluid = kind == FLUID
        # wall particles join the divergence sums with their (rest) velocity in
        # Colin's formulation; ours differentiates the data alone
        walls_move = opts.boundary == "colin"
        st_div = ps.ops.gradient_coefficients(
            opts.divergence, row_kinds=(FLUID,),
            source_kinds=(FLUID, BOUNDARY) if walls_move else (FLUID,))
        st_grad = ps.ops.gradient_coefficients(opts.gradient, row_kinds=(FLUID,))
        A = PoissonMatrix(ps.ops, laplacian=opts.laplacian, gradient=opts.neumann_gradient,
                          kappa=opts.kappa, bordered=opts.bordered)
        w_slots = np.zeros((ps.n_total, 2))
        if walls_move and wall_velocity is not None:
            w_slots[~fluid] = np.asarray(wall_velocity, dtype=np.float64)
        nd = [ps.new_array(2), ps.new_array(1), ps.new_array(1), ps.new_array(2)]
        n_boundary = int((kind == BOUNDARY).sum())
    # the orthogonal step and the measure of the neumann/orthogonal schemes: D over
    # the data points alone, exactly PointSet(points).divergence(v, divergence)
    ps0 = S = st0 = None
    if scheme != "poisson":
        ps0 = PointSet(pts, kernel=opts.kernel, support=support, area=domain.area)
        st0 = ps0.ops.gradient_coefficients(opts.divergence, row_kinds=(FLUID,),
                                            source_kinds=(FLUID,))
        S = NormalOperator.of_pointset(ps0, st0)
        nd0 = [ps0.new_array(2), ps0.new_array(1), ps0.new_array(1), ps0.new_array(2)]
        n_boundary = 0 if ps is None else n_boundary

    def poisson_divergence(w):
        w_slots[ps.slot_of] = w
        nd[0].from_numpy(w_slots.astype(real))
        ps.ops.divergence(st_div, nd[0], nd[1])
        return ps.download(nd[1])

    def data_divergence(w):
        nd0[0].from_numpy(_to_slots(ps0, w).astype(real))
        ps0.ops.divergence(st0, nd0[0], nd0[1])
        return ps0.download(nd0[1])

    measure = poisson_divergence if scheme == "poisson" else data_divergence
    w = vec.copy()
    div = measure(w)
    first = _measures(div)
    max_div, sum_sq = [first[0]], [first[1]]
    # "already divergence-free": |D w| at most tol times the larger of the
    # input's |D w| and |w| / spacing (the divergence of a field varying by its
    # own size over one spacing), and never below rounding level; so feeding a
    # projected field back in does nothing rather than chase rounding errors
    eps = float(np.finfo(real).eps)
    scale = math.sqrt(float((w ** 2).sum())) / spacing
    floor = 1e3 * eps * scale
    done = max(opts.tol * max(math.sqrt(first[1]), scale), floor)
    extra = {"least_squares": True} if opts.solver == "cgnr" else {}
    iters, stage_iters, residuals = [], [], []
    fields = [vec.copy()] if history else None
    for k in range(iterations):
        say(f"projection {k + 1}/{iterations}")
        counts = []
        if poisson_step:
            b = poisson_divergence(w) if scheme == "neumann" else div
            if scheme == "neumann" and math.sqrt(float((div ** 2).sum())) <= done:
                counts.append(0)          # nothing left to remove
            else:
                # the stacked colin system is inconsistent in general: its
                # least-squares solution, as CG on A^T A q = A^T b gives
                rhs = np.zeros(ps.n_total)
                rhs[ps.slot_of] = b
                res = A.solve(rhs, x0=None, method=opts.solver, tol=opts.tol,
                              max_iterations=opts.max_iterations,
                              preconditioner=opts.preconditioner, **extra)
                counts.append(res.iterations)
                nd[2].from_numpy(res.x.astype(real))
                ps.ops.gradient(st_grad, nd[2], nd[3])
                w = w - ps.download(nd[3])
                div = measure(w)
        if S is not None:
            bnorm = math.sqrt(float((div ** 2).sum()))
            if bnorm <= done:
                counts.append(0)
            else:
                res = solvers.cg(S, _to_slots(ps0, div), tol=done / bnorm,
                                 max_iterations=opts.max_iterations, preconditioner="jacobi")
                counts.append(res.iterations)
                nd0[2].from_numpy(np.resize(res.x.astype(real), max(ps0.n_total, 1)))
                S.correction(nd0[2], nd0[3])
                w = w - ps0.download(nd0[3])
                div = measure(w)
        iters.append(sum(counts))
        stage_iters.append(tuple(counts))
        residuals.append(math.sqrt(float((div ** 2).sum())))
        m, q = _measures(div)
        max_div.append(m)
        sum_sq.append(q)
        if history:
            fields.append(w.copy())
        _check_pass(k + 1, w, vec, max_div, method, scheme)
    if scheme == "poisson" and opts.boundary == "colin":
        what = (f"{opts.divergence} divergence over the data and wall particles at rest "
                f"({opts.kernel}, support {support:.4g}) at the data points")
    else:
        what = (f"{opts.divergence} divergence over the data points "
                f"({opts.kernel}, support {opts.support_ratio:g} spacings)")
    stats = {"iterations": iters, "stage_iterations": stage_iters,
             "divergence_norm": residuals, "seconds": time.perf_counter() - t0,
             "scheme": scheme, "n_boundary": n_boundary, "support": support,
             "spacing": spacing, "divergence_operator": what}
    return ProjectionResult(points=pts, vectors=w, initial=vec,
                            max_divergence=np.array(max_div), sum_sq_divergence=np.array(sum_sq),
                            divergence=div, stats=stats, history=fields)


#: a pass that multiplies the smallest max |div| so far by more than this, or
#: leaves speeds above SPEED_GROWTH times the input's, is a diverging projection
DIVERGENCE_GROWTH = 10.0
SPEED_GROWTH = 100.0


def _check_pass(k, w, vec, max_div, method, scheme):
    """Raise SolverError('divergence') when pass k made things worse instead of
    returning the garbage: e.g. Colin's operators on disordered points, where the
    discrete Laplacian is not the divergence of the discrete gradient and
    repeated passes amplify the mismatch (stability map, benchmarks/)."""
    speed_in = float(np.abs(vec).max())
    speed = float(np.abs(w).max())
    best = min(max_div[:-1])
    if not np.isfinite(w).all():
        why = "the field became non-finite"
    elif max_div[-1] > DIVERGENCE_GROWTH * max(best, 1e-300) and max_div[-1] > max_div[0]:
        why = (f"max |div| grew to {max_div[-1]:.3e} from {best:.3e} (input: "
               f"{max_div[0]:.3e})")
    elif speed > SPEED_GROWTH * max(speed_in, 1e-300):
        why = f"max |w| reached {speed:.3e}, {speed / speed_in:.0f} times the input's"
    else:
        return
    raise SolverError(f"projection diverged at pass {k} (method {method!r}, scheme "
                      f"{scheme!r}): {why}; these operators are not stable on these points "
                      "(use method='default')", reason="divergence", iteration=k,
                      residual=float(max_div[-1]))


def _to_slots(ps, values):
    """Caller-order values -> slot order (the data points fill every slot here)."""
    values = np.asarray(values, dtype=np.float64)
    out = np.zeros((ps.n_total,) + values.shape[1:])
    out[ps.slot_of] = values
    return out


def _measures(div):
    return float(np.abs(div).max()) if div.size else 0.0, float((div ** 2).sum())
