"""Null-divergence projection of a particle velocity field (Colin, Egli & Lin
2006, Sec. 3.7 (d)-(e)), repeated ``iterations`` times:

    solve  lap q = div w  with  dq/dn = 0  (Eqs. 28-29, 31-38),
    update w <- w - grad q  (Eqs. 25, 41),

recording after each pass Colin's two measures over the inside particles: the
maximum |div| and the sum of squared div (their Table 1).

Configurations (``method``) reuse :data:`taichi_hh.hhd.METHODS`:
``colin2006`` is their formulation (poly6, DGAF, Laplacian Eq. 21, a layer of
wall particles at rest carrying normals, CG on the normal equations);
``default`` is ours (consistent operators; one pass leaves only the
discretisation-level divergence, which further passes reduce).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from . import runtime
from .errors import InputError
from .hhd import _validate, options_for
from .particles import BOUNDARY, FLUID, GHOST
from .pointset import PointSet
from .poisson import PoissonMatrix


@dataclass
class ProjectionResult:
    points: np.ndarray
    vectors: np.ndarray            # the projected (null-divergence) field
    initial: np.ndarray
    max_divergence: np.ndarray     # per pass, index 0 = before projecting
    sum_sq_divergence: np.ndarray
    divergence: np.ndarray         # SPH divergence of the result at the points
    stats: dict = field(default_factory=dict)


def wall_layer(domain, spacing: float, width: float, points=None, lattice: bool = True):
    """Wall particles outside ``domain`` within ``width`` of it and their outward
    normals (Colin Sec. 3.6: a boundary layer as wide as the support).

    For a :class:`~taichi_hh.domain.Box` and ``lattice=True`` the layer continues
    the lattice of spacing ``spacing`` aligned with the box (Colin Fig. 4);
    otherwise it is a blue-noise band.  Corner normals point along the diagonal.
    """
    from .domain import Box
    if lattice and isinstance(domain, Box):
        lo, hi = np.asarray(domain.lo), np.asarray(domain.hi)
        k = int(math.ceil(width / spacing)) + 1
        nx = int(round((hi[0] - lo[0]) / spacing))
        ny = int(round((hi[1] - lo[1]) / spacing))
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


def project(points, vectors, domain=None, *, iterations: int = 1, method: str = "default",
            wall_velocity=None, progress=None, **options) -> ProjectionResult:
    """Project ``vectors`` at ``points`` onto null divergence, ``iterations`` times.

    wall_velocity: velocity of the wall particles of the ``colin2006`` layer
    (default 0: walls at rest).  Other options as :func:`taichi_hh.decompose`.
    """
    if int(iterations) != iterations or iterations < 1:
        raise InputError(f"iterations must be a positive integer, got {iterations}")
    opts = options_for(method, **options)
    runtime.ensure_init()
    pts, vec, domain = _validate(points, vectors, domain)
    say = progress or (lambda stage: None)
    n = len(pts)
    spacing = math.sqrt(domain.area / n)
    support = opts.support_ratio * spacing
    t0 = time.perf_counter()

    if opts.boundary == "colin":
        bpts, bnrm = wall_layer(domain, spacing, support, pts)
        boundary = (bpts, bnrm)
    elif opts.boundary == "collocation":
        from .hhd import _far_from
        bpts, bnrm, _ = domain.sample_boundary(spacing)
        keep = _far_from(bpts, pts, 0.25 * spacing, domain)
        boundary = (bpts[keep], bnrm[keep])
    elif opts.boundary == "none":
        boundary = None
    else:
        raise InputError("project() supports boundary='collocation', 'colin' or 'none'")
    ps = PointSet(pts, kernel=opts.kernel, support=support, area=domain.area, boundary=boundary)
    ops = ps.ops
    kind = ps.particles.get("kind")
    fluid = kind == FLUID

    # wall particles join the divergence sums with their (rest) velocity in
    # Colin's formulation; ours differentiates the data alone
    walls_move = opts.boundary == "colin"
    div_sources = (FLUID, BOUNDARY) if walls_move else (FLUID,)
    st_div = ops.gradient_coefficients(opts.divergence, row_kinds=(FLUID,),
                                       source_kinds=div_sources)
    st_grad = ops.gradient_coefficients(opts.gradient, row_kinds=(FLUID,))
    A = PoissonMatrix(ops, laplacian=opts.laplacian, gradient=opts.neumann_gradient,
                      kappa=opts.kappa, bordered=opts.bordered)

    w = np.zeros((ps.n_total, 2))
    w[ps.slot_of] = vec
    if walls_move and wall_velocity is not None:
        w[~fluid] = np.asarray(wall_velocity, dtype=np.float64)
    real = runtime.np_real()
    w_nd = ps.new_array(2)
    div_nd = ps.new_array(1)
    q_nd = ps.new_array(1)
    g_nd = ps.new_array(2)

    def divergence():
        w_nd.from_numpy(w.astype(real))
        ops.divergence(st_div, w_nd, div_nd)
        d = div_nd.to_numpy()[: ps.n_total].astype(np.float64)
        d[~fluid] = 0.0
        return d

    div = divergence()
    max_div = [np.abs(div[fluid]).max()]
    sum_sq = [float((div[fluid] ** 2).sum())]
    iters, q_prev, border = [], None, 0.0
    for k in range(iterations):
        say(f"projection {k + 1}/{iterations}")
        res = A.solve(div, x0=None, method=opts.solver, tol=opts.tol,
                      max_iterations=opts.max_iterations)
        iters.append(res.iterations)
        q_nd.from_numpy(res.x.astype(real))
        ops.gradient(st_grad, q_nd, g_nd)
        grad = g_nd.to_numpy()[: ps.n_total].astype(np.float64)
        w[fluid] -= grad[fluid]
        div = divergence()
        max_div.append(np.abs(div[fluid]).max())
        sum_sq.append(float((div[fluid] ** 2).sum()))
    stats = {"iterations": iters, "seconds": time.perf_counter() - t0,
             "n_boundary": int((kind == BOUNDARY).sum()), "support": support}
    return ProjectionResult(points=pts, vectors=w[ps.slot_of], initial=vec,
                            max_divergence=np.array(max_div), sum_sq_divergence=np.array(sum_sq),
                            divergence=div[ps.slot_of], stats=stats)
