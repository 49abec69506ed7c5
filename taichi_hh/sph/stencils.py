"""The operators' pair coefficients: one mechanism for every variant.

:mod:`taichi_hh.sph.operators` applies stencils; this module computes them, in
kernels composed of the shared pieces of :mod:`taichi_hh.sph.fits` (pair terms,
moment sums, fits with their fallbacks, per-pair coefficients); a variant is
a compile-time parameter of its kernel.  The kernels:
:func:`fit_gradient_stencil` (one gradient variant), :func:`fit_laplacian_stencil`
(one Laplacian variant; for the two-phase flow the corrected gradient and both
density-weighted copies from the same passes) and
:func:`fit_decomposition_stencils` (the default decomposition's three stencils
from two passes over each row's pairs).  A kernel with two passes recomputes
the pair terms in the second rather than storing them: the arithmetic costs
less than the memory traffic, and no output array serves as scratch.

Gradient variants (``V_j = m_j / rho_j``, ``grad W_ij = grad_i W(x_i - x_j)``):

``basic``            Colin Eq. 8:  sum_j V_j f_j grad W_ij
``difference``       Petronetto Eq. 8:  sum_j V_j (f_j - f_i) grad W_ij
``colin_difference`` Colin Eq. 13 (DGAF):  1/rho_i sum_j m_j (f_j - f_i) grad W_ij
``symmetric``        Colin Eq. 17 (SGAF):  rho_i sum_j m_j (f_i/rho_i^2 + f_j/rho_j^2) grad W_ij
``corrected``        Bonet & Lok 1999:  L_i sum_j V_j (f_j - f_i) grad W_ij,
                     L_i = (sum_j V_j grad W_ij (x) (x_j - x_i))^-1; exact on linear fields.
``quadratic``        weighted least-squares fit of a quadratic around i (weights V_j W_ij,
                     a 5x5 moment matrix per particle; moving least squares of order 2):
                     exact on quadratics, so second-order accurate even on one-sided
                     neighbourhoods.  Used for Neumann rows on the boundary, where the
                     first-order error of ``corrected`` (support x curvature) would
                     dominate the whole solution.  A particle whose neighbours do
                     not determine a quadratic (fewer than five, or all on one
                     conic: a sparse corner) falls back to ``corrected``.
``cubic``            the same fit with the cubic monomials too (a 9x9 moment matrix):
                     exact on cubics, so the gradient's error is third order.  On
                     uniformly random points the quadratic fit's second-order error
                     is noise that the divergence of a decomposition carries into the
                     potentials (docs/notes/scattered.md); the cubic fit removes it.
                     A particle whose neighbours do not determine a cubic falls back
                     to ``quadratic``, then to ``corrected``.

Laplacian variants:

``basic``            Colin Eq. 9:  sum_j V_j f_j lap W_ij (self term included)
``colin_difference`` Colin Eq. 21:  1/rho_i sum_j m_j (f_j - f_i)
                     (lap W_ij - 2/rho_i grad W_ij . grad rho_i), grad rho_i = sum_j m_j grad W_ij
``brookshaw``        Petronetto Eq. 10:  sum_j 2 V_j (f_i - f_j) x_ij . grad W_ij / |x_ij|^2
``corrected``        renormalised in the manner of Fatehi & Manzari 2011: with
                     w_ij = -2 V_j W'(r)/r, e = x_ji/|x_ji| and the corrected gradient,
                     lap f_i = B_i : sum_j w_ij [(f_j - f_i) - x_ji . grad~f_i] e (x) e,
                     the symmetric tensor B_i chosen so that every quadratic is
                     reproduced exactly (a 3x3 solve per particle).  Still a one-ring
                     stencil: the gradient term folds into C_ij.
"""

from enum import IntEnum

import taichi as ti

from .fits import (add_correction, beyond_wall, add_fit_moments, add_laplacian_moments,
                   corrected_gradient_coefficient, corrected_laplacian_coefficient,
                   correction_matrix, fit_moments, fit_moments_zero, fitted_gradient_coefficient,
                   gradient_fit, laplacian_correction, laplacian_moments_zero, linear_correction,
                   n_monomials, pair_terms)
from .kernels import kernel_terms
from .particles import BOUNDARY, FLUID, GHOST
from .support import pair_support

ALL_KINDS = (FLUID, BOUNDARY, GHOST)


def kind_bits(kinds) -> int:
    """The bit mask of a set of particle kinds, as the kernels take it."""
    return sum(1 << int(k) for k in kinds)


class GradientVariant(IntEnum):
    """The gradient stencils (the value selects the kernel branch at compile time)."""
    BASIC = 0               # Colin Eq. 8
    DIFFERENCE = 1          # Petronetto Eq. 8
    COLIN_DIFFERENCE = 2    # Colin Eq. 13 (DGAF)
    SYMMETRIC = 3           # Colin Eq. 17 (SGAF)
    CORRECTED = 4           # Bonet & Lok 1999: exact on linear fields
    QUADRATIC = 5           # least-squares quadratic fit: exact on quadratics
    CUBIC = 6               # least-squares cubic fit: exact on cubics


class LaplacianVariant(IntEnum):
    """The Laplacian stencils (the value selects the kernel branch at compile time)."""
    BASIC = 0               # Colin Eq. 9
    COLIN_DIFFERENCE = 1    # Colin Eq. 21
    BROOKSHAW = 2           # Petronetto Eq. 10
    CORRECTED = 3           # renormalised (Fatehi & Manzari 2011): exact on quadratics


#: the variants' option names, as ``decompose()`` and the CLI take them
GRADIENT_VARIANTS = tuple(v.name.lower() for v in GradientVariant)
LAPLACIAN_VARIANTS = tuple(v.name.lower() for v in LaplacianVariant)


def variant_id(name: str, table) -> int:
    """The enum value of variant ``name`` of ``table`` (GRADIENT_ or LAPLACIAN_VARIANTS)."""
    if name not in table:
        raise ValueError(f"unknown operator variant {name!r}; choose one of {table}")
    return table.index(name)      # == the enum value: the tables list the enums in order


# ---------------------------------------------------------------------------
# the kernels

@ti.kernel
def fit_gradient_stencil(kernel_id: ti.template(), variant: ti.template(),
                         pos: ti.types.ndarray(), mass: ti.types.ndarray(),
                         rho: ti.types.ndarray(), n: ti.i32, offsets: ti.types.ndarray(),
                         nbrs: ti.types.ndarray(), H: float, adaptive: ti.template(),
                         hs: ti.types.ndarray(), G: ti.types.ndarray(), s: ti.types.ndarray(),
                         kind: ti.types.ndarray(), row_kinds: ti.i32,
                         src_kinds: ti.i32, normal: ti.types.ndarray()) -> ti.i32:
    """G_ij, s_i of gradient ``variant`` (a :class:`GradientVariant`) for the rows of
    the kinds ``row_kinds`` (others get zeros) over the sources ``src_kinds``; the
    fitted and corrected variants of a boundary row over its wall's side
    (:func:`~taichi_hh.sph.fits.beyond_wall`: the Neumann rows).
    Returns the largest row whose correction matrix is singular, or -1."""
    bad = -1
    fitted = ti.static(variant == GradientVariant.QUADRATIC or variant == GradientVariant.CUBIC)
    order = ti.static(3 if variant == GradientVariant.CUBIC else 2)
    for i in range(n):
        if (row_kinds >> kind[i]) & 1 == 0:    # row not wanted: zero coefficients
            for k in range(offsets[i], offsets[i + 1]):
                G[k] = ti.Vector.zero(float, 2)
            s[i] = ti.Vector.zero(float, 2)
            continue
        Hi = pair_support(adaptive, hs, i, i, H)      # the monomials' length scale
        R = ti.Matrix.zero(float, 2, ti.static(n_monomials(order)))
        L = ti.Matrix.identity(float, 2)
        linear = 0
        if ti.static(fitted):
            S = fit_moments(order, kernel_id, i, pos, mass, rho, offsets, nbrs, H, adaptive, hs,
                            kind, src_kinds, normal)
            ok = True
            R, L, linear, ok = gradient_fit(order, S, Hi, kernel_id, i, pos, mass, rho, offsets,
                                            nbrs, H, adaptive, hs, kind, src_kinds, normal)
            if not ok:
                ti.atomic_max(bad, i)
        if ti.static(variant == GradientVariant.CORRECTED):
            ok = True
            L, ok = linear_correction(correction_matrix(kernel_id, i, pos, mass, rho, offsets,
                                                        nbrs, H, adaptive, hs, kind, src_kinds,
                                                        normal))
            if not ok:
                ti.atomic_max(bad, i)
        gsum = ti.Vector.zero(float, 2)
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            _x, _r, W, F, _Lw, mj, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                  adaptive, hs, H, i, j)
            # the stencils' formulas in x_ij = x_i - x_j, as written (the
            # compiler's fast-math rewrites of -x_ji differ in the last bit)
            xij = pos[i] - pos[j]
            gw = F * xij                      # grad_i W_ij
            coef = ti.Vector.zero(float, 2)
            if ti.static(variant == GradientVariant.BASIC or variant == GradientVariant.DIFFERENCE):
                coef = V * gw
            elif ti.static(variant == GradientVariant.COLIN_DIFFERENCE):
                coef = (mj / rho[i]) * gw
            elif ti.static(variant == GradientVariant.SYMMETRIC):
                coef = rho[i] * mj / (rho[j] * rho[j]) * gw
                # f_i terms: rho_i m_j f_i / rho_i^2, plus sum_j G f_i from the difference form
                gsum += (mj / rho[i]) * gw + coef
            elif ti.static(variant == GradientVariant.CORRECTED):
                if not beyond_wall(kind, normal, i, -xij):
                    coef = corrected_gradient_coefficient(L, V, F, xij)
            else:
                if not beyond_wall(kind, normal, i, -xij):
                    coef = fitted_gradient_coefficient(order, R, L, linear, mj, rho[j], W, F, xij,
                                                       Hi)
            G[k] = coef
            if ti.static(variant == GradientVariant.BASIC):
                gsum += coef   # sum_j G f_j = sum_j G (f_j - f_i) + (sum_j G) f_i
        s[i] = gsum
    return bad


@ti.kernel
def fit_laplacian_stencil(kernel_id: ti.template(), variant: ti.template(),
                          pos: ti.types.ndarray(), mass: ti.types.ndarray(),
                          rho: ti.types.ndarray(), n: ti.i32, offsets: ti.types.ndarray(),
                          nbrs: ti.types.ndarray(), H: float, adaptive: ti.template(),
                          hs: ti.types.ndarray(), C: ti.types.ndarray(), s: ti.types.ndarray(),
                          kind: ti.types.ndarray(), row_kinds: ti.i32, src_kinds: ti.i32,
                          with_gradient: ti.template(), G: ti.types.ndarray(),
                          sG: ti.types.ndarray(), Cw: ti.types.ndarray(),
                          Gw: ti.types.ndarray(), grad_one: ti.types.ndarray()) -> ti.i32:
    """C_ij, c_i of Laplacian ``variant`` (a :class:`LaplacianVariant`) for the rows
    of the kinds ``row_kinds`` over the sources ``src_kinds``.  Returns the
    largest row whose correction matrix is singular, or -1.

    ``with_gradient`` (the corrected variant only): also the corrected
    gradient's coefficients ``G``, ``sG`` (the values of
    :func:`fit_gradient_stencil`), both weighted by the pair's mean density,
    ``Cw`` = C 2 / (rho_i + rho_j) and ``Gw`` = G 2 rho_i / (rho_i + rho_j) (as
    :func:`weight_laplacian_by_mean_density` and
    :func:`weight_gradient_by_mean_density`), and ``grad_one`` = sum_j V_j grad
    W_ij, the basic gradient of f = 1 (particle shifting's concentration
    gradient), from the same pair passes: the two-phase flow needs all of them."""
    bad = -1
    for i in range(n):
        if (row_kinds >> kind[i]) & 1 == 0:    # row not wanted: zero coefficients
            for k in range(offsets[i], offsets[i + 1]):
                C[k] = 0.0
                if ti.static(with_gradient):
                    G[k] = ti.Vector.zero(float, 2)
                    Cw[k] = 0.0
                    Gw[k] = ti.Vector.zero(float, 2)
            s[i] = 0.0
            if ti.static(with_gradient):
                sG[i] = ti.Vector.zero(float, 2)
                grad_one[i] = ti.Vector.zero(float, 2)
            continue
        selfc = 0.0
        if ti.static(variant == LaplacianVariant.BASIC):
            _W0, _F0, L0 = kernel_terms(kernel_id, 0.0, pair_support(adaptive, hs, i, i, H))
            csum = 0.0
            for k in range(offsets[i], offsets[i + 1]):
                _x, _r, _W, _F, Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                       adaptive, hs, H, i, nbrs[k])
                c = V * Lw
                C[k] = c
                csum += c
            selfc = csum + (mass[i] / rho[i]) * L0
        elif ti.static(variant == LaplacianVariant.COLIN_DIFFERENCE):
            grho = ti.Vector.zero(float, 2)
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                _x, _r, _W, F, _Lw, mj, _V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                        adaptive, hs, H, i, j)
                grho += mj * F * (pos[i] - pos[j])
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                _x, _r, _W, F, Lw, mj, _V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                       adaptive, hs, H, i, j)
                C[k] = (mj / rho[i]) * (Lw - 2.0 / rho[i] * F * (pos[i] - pos[j]).dot(grho))
        elif ti.static(variant == LaplacianVariant.BROOKSHAW):
            for k in range(offsets[i], offsets[i + 1]):
                _x, _r, _W, F, _Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                       adaptive, hs, H, i, nbrs[k])
                C[k] = -2.0 * V * F
        else:                                # renormalised, exact on quadratics
            M, u, P, Q = laplacian_moments_zero()
            Mg = ti.Matrix.zero(float, 2, 2)   # the gradient's correction (with_gradient)
            g1 = ti.Vector.zero(float, 2)      # grad_one (with_gradient)
            for k in range(offsets[i], offsets[i + 1]):
                x, r, _W, F, _Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                     adaptive, hs, H, i, nbrs[k])
                M, u, P, Q = add_laplacian_moments(M, u, P, Q, x, r, V, F)
                if ti.static(with_gradient):
                    Mg = add_correction(Mg, V, F, x)
                    g1 += V * (-F * x)
            beta, B, ok = laplacian_correction(M, u, P, Q)
            if not ok:
                ti.atomic_max(bad, i)
            Lg = ti.Matrix.identity(float, 2)
            if ti.static(with_gradient):
                grad_one[i] = g1
                okg = True
                Lg, okg = linear_correction(Mg)
                if not okg:
                    ti.atomic_max(bad, i)
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                x, r, _W, F, _Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                                     adaptive, hs, H, i, j)
                c = corrected_laplacian_coefficient(beta, B, x, r, V, F)
                C[k] = c
                if ti.static(with_gradient):
                    g = corrected_gradient_coefficient(Lg, V, F, -x)
                    G[k] = g
                    Cw[k] = c * (2.0 / (rho[i] + rho[j]))
                    Gw[k] = g * (2.0 * rho[i] / (rho[i] + rho[j]))
            if ti.static(with_gradient):
                sG[i] = ti.Vector.zero(float, 2)
        s[i] = selfc
    return bad


@ti.kernel
def fit_decomposition_stencils(kernel_id: ti.template(), pos: ti.types.ndarray(),
                               mass: ti.types.ndarray(), rho: ti.types.ndarray(), n: ti.i32,
                               offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
                               adaptive: ti.template(), hs: ti.types.ndarray(),
                               kind: ti.types.ndarray(), G3: ti.types.ndarray(),
                               s3: ti.types.ndarray(), G2: ti.types.ndarray(),
                               s2: ti.types.ndarray(), C: ti.types.ndarray(),
                               sC: ti.types.ndarray(),
                               normal: ti.types.ndarray()) -> (ti.i32, ti.i32, ti.i32):
    """The default decomposition's three stencils from two passes over each row's
    pairs (one for every sum, one for every coefficient), the values of
    :func:`fit_gradient_stencil` and :func:`fit_laplacian_stencil` up to
    round-off:

    ``G3`` the cubic gradient of the FLUID rows over FLUID sources (div v, curl v),
    ``G2`` the quadratic gradient of the FLUID and BOUNDARY rows over every
    particle (Neumann rows over their wall's side:
    :func:`~taichi_hh.sph.fits.beyond_wall`; d and r), ``C`` the corrected Laplacian of the FLUID
    rows over every particle; the fallbacks are theirs (cubic -> quadratic ->
    corrected; quadratic -> corrected).  The quadratic moments are the cubic
    ones' (over FLUID sources) plus the other sources' share.  Returns the
    largest singular row of each (-1 if none)."""
    bad3 = -1
    bad2 = -1
    badL = -1
    fluid_sources = ti.static(kind_bits((FLUID,)))
    all_sources = ti.static(kind_bits(ALL_KINDS))
    for i in range(n):
        ki = kind[i]
        s3[i] = ti.Vector.zero(float, 2)
        s2[i] = ti.Vector.zero(float, 2)
        sC[i] = 0.0
        if ki != FLUID and ki != BOUNDARY:          # no rows: zero coefficients
            for k in range(offsets[i], offsets[i + 1]):
                G3[k] = ti.Vector.zero(float, 2)
                G2[k] = ti.Vector.zero(float, 2)
                C[k] = 0.0
            continue
        fluid_row = ki == FLUID
        Hi = pair_support(adaptive, hs, i, i, H)      # the monomials' length scale
        S3 = fit_moments_zero(3)           # cubic moments over FLUID sources
        Sb = fit_moments_zero(2)           # quadratic moments over the other sources
        M, u, P, Q = laplacian_moments_zero()
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            x, r, W, F, _Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, all_sources,
                                                adaptive, hs, H, i, j)
            if beyond_wall(kind, normal, i, x):
                pass
            elif kind[j] == FLUID:
                S3 = add_fit_moments(3, S3, V * W, x / Hi)
            else:
                Sb = add_fit_moments(2, Sb, V * W, x / Hi)
            if fluid_row:
                M, u, P, Q = add_laplacian_moments(M, u, P, Q, x, r, V, F)
        # the divergence's cubic fit over the data
        R3 = ti.Matrix.zero(float, 2, 9)
        L3 = ti.Matrix.identity(float, 2)
        linear3 = 0
        if fluid_row:
            ok3 = True
            R3, L3, linear3, ok3 = gradient_fit(3, S3, Hi, kernel_id, i, pos, mass, rho, offsets,
                                                nbrs, H, adaptive, hs, kind, fluid_sources, normal)
            if not ok3:
                ti.atomic_max(bad3, i)
        # the Neumann rows' quadratic fit over every particle
        for a in ti.static(range(5)):
            for b in ti.static(range(5 - a)):
                Sb[a, b] += S3[a, b]
        R2, L2, linear2, ok2 = gradient_fit(2, Sb, Hi, kernel_id, i, pos, mass, rho, offsets,
                                            nbrs, H, adaptive, hs, kind, all_sources, normal)
        if not ok2:
            ti.atomic_max(bad2, i)
        # the Laplacian
        beta = ti.Vector.zero(float, 2)
        B = ti.Vector.zero(float, 3)
        if fluid_row:
            okL = True
            beta, B, okL = laplacian_correction(M, u, P, Q)
            if not okL:
                ti.atomic_max(badL, i)
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            x, r, W, F, _Lw, m, V = pair_terms(kernel_id, pos, mass, rho, kind, all_sources,
                                                adaptive, hs, H, i, j)
            g3 = ti.Vector.zero(float, 2)
            if fluid_row and kind[j] == FLUID:
                g3 = fitted_gradient_coefficient(3, R3, L3, linear3, m, rho[j], W, F, -x, Hi)
            G3[k] = g3
            g2 = ti.Vector.zero(float, 2)
            if not beyond_wall(kind, normal, i, x):
                g2 = fitted_gradient_coefficient(2, R2, L2, linear2, m, rho[j], W, F, -x, Hi)
            G2[k] = g2
            cl = 0.0
            if fluid_row:
                cl = corrected_laplacian_coefficient(beta, B, x, r, V, F)
            C[k] = cl
    return bad3, bad2, badL


@ti.kernel
def weight_laplacian_by_mean_density(n: ti.i32, offsets: ti.types.ndarray(),
                                     nbrs: ti.types.ndarray(), rho: ti.types.ndarray(),
                                     C: ti.types.ndarray(), out: ti.types.ndarray()):
    """out_ij = C_ij 2 / (rho_i + rho_j) (``out`` may be ``C``): the Laplacian becomes
    div(grad f / rho) with the inter-particle coefficient 1/rho taken as the inverse
    mean density of the pair (Cummins & Rudman 1999); continuous across a density
    jump.  One pass: a weighted copy reads C once instead of copying it first."""
    for i in range(n):
        for k in range(offsets[i], offsets[i + 1]):
            out[k] = C[k] * (2.0 / (rho[i] + rho[nbrs[k]]))


@ti.kernel
def weight_gradient_by_mean_density(n: ti.i32, offsets: ti.types.ndarray(),
                                     nbrs: ti.types.ndarray(), rho: ti.types.ndarray(),
                                     G: ti.types.ndarray(), out: ti.types.ndarray()):
    """out_ij = G_ij 2 rho_i / (rho_i + rho_j) (``out`` may be ``G``): then
    (grad f)_i / rho_i pairs each difference with the pair's mean density, as the
    density-weighted Laplacian does."""
    for i in range(n):
        for k in range(offsets[i], offsets[i + 1]):
            out[k] = G[k] * (2.0 * rho[i] / (rho[i] + rho[nbrs[k]]))
