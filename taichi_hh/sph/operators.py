"""SPH differential operators in 2D as precomputed pair coefficients.

One mechanism serves every variant.  For a particle ``i`` with neighbours
``j`` (from a :class:`~taichi_hh.sph.neighbors.PairList`), every operator is

    gradient   grad f_i = sum_j G_ij (f_j - f_i) + s_i f_i          (G_ij a 2-vector)
    divergence div v_i  = sum_j G_ij . (v_j - v_i) + s_i . v_i
    curl       curl v_i = div (J v)_i,  J(v1, v2) = (v2, -v1)       (Petronetto Eq. 4)
    Laplacian  lap f_i  = sum_j C_ij (f_j - f_i) + c_i f_i          (C_ij a scalar)

The variant only changes the coefficients, computed once per particle
configuration (:meth:`Operators.gradient_coefficients`,
:meth:`Operators.laplacian_coefficients`); applying an operator is then a
gather over the pair list, like a sparse matrix-vector product.  Difference
forms have ``s_i = 0`` and are therefore exactly zero on constants.

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

Operators evaluate at every particle of the set, taking all particles
(fluid, boundary, ghost) as neighbours; the caller decides which rows it uses.
"""

from dataclasses import dataclass

from enum import IntEnum

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import NeighbourError
from .kernels import kernel_id, kernel_terms
from .particles import BOUNDARY, FLUID, GHOST
from .support import pair_support

ALL_KINDS = (FLUID, BOUNDARY, GHOST)


def kind_bits(kinds) -> int:
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

# A correction matrix whose smallest/largest eigenvalue ratio falls below this
# is treated as singular: the neighbourhood is too small or degenerate
# (collinear) for the corrected operators.
SINGULAR_RATIO = 1e-6


def _variant_id(name: str, table) -> int:
    if name not in table:
        raise ValueError(f"unknown operator variant {name!r}; choose one of {table}")
    return table.index(name)      # == the enum value: the tables list the enums in order


# ---------------------------------------------------------------------------
# Taichi kernels

@ti.kernel
def number_density(kernel_id: ti.template(), pos: ti.types.ndarray(), mass: ti.types.ndarray(),
             n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
             adaptive: ti.template(), hs: ti.types.ndarray(),
             rho: ti.types.ndarray(), vol: ti.types.ndarray()):
    """rho_i = sum_j m_j W_ij including j = i (Petronetto Sec. 5a); V_i = m_i / rho_i.
    ``H`` the support, or (``adaptive``) per particle ``hs`` (:mod:`taichi_hh.sph.support`)."""
    for i in range(n):
        W0, _F0, _L0 = kernel_terms(kernel_id, 0.0, pair_support(adaptive, hs, i, i, H))
        s = mass[i] * W0
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            W, _F, _L = kernel_terms(kernel_id, (pos[i] - pos[j]).norm(),
                                     pair_support(adaptive, hs, i, j, H))
            s += mass[j] * W
        rho[i] = s
        vol[i] = mass[i] / s


@ti.func
def _sym2_eig_ratio(a, b, c):
    """min/max |eigenvalue| of the symmetric matrix [[a, b], [b, c]]."""
    m = 0.5 * (a + c)
    d = ti.sqrt(0.25 * (a - c) * (a - c) + b * b)
    l1 = ti.abs(m + d)
    l2 = ti.abs(m - d)
    hi = ti.max(l1, l2)
    lo = ti.min(l1, l2)
    ratio = 0.0
    if hi > 0.0:
        ratio = lo / hi
    return ratio


@ti.func
def _src_mass(mass: ti.template(), kind: ti.template(), j, src_kinds):
    """m_j if particle j's kind is a wanted source, else 0: every coefficient is
    proportional to m_j, so masked neighbours simply drop out of every sum."""
    m = 0.0
    if (src_kinds >> kind[j]) & 1:
        m = mass[j]
    return m


@ti.func
def _correction_matrix(kernel_id: ti.template(), i, pos: ti.template(), mass: ti.template(),
                       rho: ti.template(), offsets: ti.template(), nbrs: ti.template(), H,
                       adaptive: ti.template(), hs: ti.template(), kind: ti.template(), src_kinds):
    """M_i = sum_j V_j grad W_ij (x) (x_j - x_i); symmetric positive for these kernels."""
    M = ti.Matrix.zero(float, 2, 2)
    for k in range(offsets[i], offsets[i + 1]):
        j = nbrs[k]
        mj = _src_mass(mass, kind, j, src_kinds)
        x = pos[j] - pos[i]
        _W, F, _L = kernel_terms(kernel_id, x.norm(), pair_support(adaptive, hs, i, j, H))
        M += (mj / rho[j]) * (-F) * x.outer_product(x)
    return M


def _n_monomials(order) -> int:
    return 5 if order == 2 else 9


@ti.func
def _monomials(order: ti.template(), u):
    """(x, y, x^2, xy, y^2) of u, and for order 3 the cubics after them."""
    if ti.static(order == 2):
        return ti.Vector([u[0], u[1], u[0] * u[0], u[0] * u[1], u[1] * u[1]])
    else:
        return ti.Vector([u[0], u[1], u[0] * u[0], u[0] * u[1], u[1] * u[1],
                          u[0] * u[0] * u[0], u[0] * u[0] * u[1], u[0] * u[1] * u[1],
                          u[1] * u[1] * u[1]])


#: the exponents (of x, of y) of the monomials of _monomials, in order
_MONOMIAL_EXPONENTS = ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))


@ti.func
def _mls_fit_rows(order: ti.template(), kernel_id: ti.template(), i, pos: ti.template(),
                  mass: ti.template(), rho: ti.template(), offsets: ti.template(),
                  nbrs: ti.template(), H, adaptive: ti.template(), hs: ti.template(),
                  kind: ti.template(), src_kinds):
    """Cholesky factor of M = sum_j V_j W_ij p_j p_j^T with p the monomials of
    ``order`` (2 or 3) of x_ji / H_i; returns (factor, ok).  ok is False when a
    pivot falls below SINGULAR_RATIO of the diagonal scale (too few neighbours,
    or all on one conic (cubic)).

    M's entries are the moments S_ab = sum_j V_j W_ij u^a v^b of degree 2 to
    2 * order (u, v = x_ji / H_i), each entry the moment of its two
    monomials' summed exponents: 25 sums per pair for the cubic fit where the
    matrix's lower half has 45 (12 and 15 for the quadratic)."""
    m = ti.static(_n_monomials(order))
    D = ti.static(2 * order + 1)                 # exponents 0 .. 2 * order
    S = ti.Vector.zero(float, D * D)             # S[a * D + b], 2 <= a + b <= 2 * order
    Hi = pair_support(adaptive, hs, i, i, H)      # the monomials' length scale
    for k in range(offsets[i], offsets[i + 1]):
        j = nbrs[k]
        mj = _src_mass(mass, kind, j, src_kinds)
        x = pos[j] - pos[i]
        W, _F, _L = kernel_terms(kernel_id, x.norm(), pair_support(adaptive, hs, i, j, H))
        u = x / Hi
        pu = ti.Vector.zero(float, D)            # V_j W u^a
        pv = ti.Vector.zero(float, D)            # v^b
        pu[0] = (mj / rho[j]) * W
        pv[0] = 1.0
        for e in ti.static(range(1, D)):
            pu[e] = pu[e - 1] * u[0]
            pv[e] = pv[e - 1] * u[1]
        for a in ti.static(range(D)):
            for b in ti.static(range(D - a)):
                if ti.static(a + b >= 2):
                    S[a * D + b] += pu[a] * pv[b]
    M = ti.Matrix.zero(float, m, m)
    for r in ti.static(range(m)):
        for c in ti.static(range(r + 1)):        # the lower half: all the factor reads
            ar, br = ti.static(_MONOMIAL_EXPONENTS[r])
            ac, bc = ti.static(_MONOMIAL_EXPONENTS[c])
            M[r, c] = S[(ar + ac) * D + br + bc]
    return _cholesky_factor(order, M)


@ti.func
def _cholesky_factor(order: ti.template(), M):
    """(L, ok): the Cholesky factor of the moment matrix M (monomials of ``order``);
    ok is False when a pivot falls below SINGULAR_RATIO of the diagonal scale."""
    m = ti.static(_n_monomials(order))
    scale = 0.0
    for a in ti.static(range(m)):
        scale = ti.max(scale, M[a, a])
    Lf = ti.Matrix.zero(float, m, m)
    ok = scale > 0.0
    for a in ti.static(range(m)):
        for b in ti.static(range(a + 1)):
            acc = M[a, b]
            for c in ti.static(range(b)):
                acc -= Lf[a, c] * Lf[b, c]
            if ti.static(a == b):
                if acc <= SINGULAR_RATIO * scale:
                    ok = False
                    acc = scale
                Lf[a, a] = ti.sqrt(acc)
            else:
                Lf[a, b] = acc / Lf[b, b]
    return Lf, ok


@ti.func
def _cholesky_solve(order: ti.template(), Lf, rhs):
    m = ti.static(_n_monomials(order))
    y = ti.Vector.zero(float, m)
    for a in ti.static(range(m)):
        acc = rhs[a]
        for c in ti.static(range(a)):
            acc -= Lf[a, c] * y[c]
        y[a] = acc / Lf[a, a]
    z = ti.Vector.zero(float, m)
    for a in ti.static(range(m - 1, -1, -1)):
        acc = y[a]
        for c in ti.static(range(a + 1, m)):
            acc -= Lf[c, a] * z[c]
        z[a] = acc / Lf[a, a]
    return z


@ti.func
def _gradient_rows(order: ti.template(), Lf):
    """Rows 0-1 of M^-1 (M = Lf Lf^T symmetric: the solutions of M z = e_0, e_1),
    the fitted gradient's weights per monomial: one solve per particle, so that
    each pair's coefficient is two dot products."""
    m = ti.static(_n_monomials(order))
    e0 = ti.Vector.zero(float, m)
    e1 = ti.Vector.zero(float, m)
    e0[0] = 1.0
    e1[1] = 1.0
    z0 = _cholesky_solve(order, Lf, e0)
    z1 = _cholesky_solve(order, Lf, e1)
    R = ti.Matrix.zero(float, 2, m)
    for a in ti.static(range(m)):
        R[0, a] = z0[a]
        R[1, a] = z1[a]
    return R


@ti.kernel
def _gradient_coeffs(kernel_id: ti.template(), variant: ti.template(), pos: ti.types.ndarray(),
                     mass: ti.types.ndarray(), rho: ti.types.ndarray(), n: ti.i32,
                     offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
                     adaptive: ti.template(), hs: ti.types.ndarray(),
                     G: ti.types.ndarray(), s: ti.types.ndarray(),
                     kind: ti.types.ndarray(), row_kinds: ti.i32, src_kinds: ti.i32) -> ti.i32:
    """Returns the largest row whose correction matrix is singular, or -1."""
    bad = -1
    for i in range(n):
        if (row_kinds >> kind[i]) & 1 == 0:    # row not wanted: zero coefficients
            for k in range(offsets[i], offsets[i + 1]):
                G[k] = ti.Vector.zero(float, 2)
            s[i] = ti.Vector.zero(float, 2)
            continue
        L = ti.Matrix.identity(float, 2)
        Lf = ti.Matrix.identity(float, 5)
        # the cubic fit's factor (a 1 x 1 placeholder for the other variants)
        Lc = ti.Matrix.identity(float, ti.static(9 if variant == GradientVariant.CUBIC else 1))
        linear = 0
        cubic = 0
        if ti.static(variant == GradientVariant.CUBIC):
            Lc, ok3 = _mls_fit_rows(3, kernel_id, i, pos, mass, rho, offsets, nbrs, H, adaptive,
                                    hs, kind, src_kinds)
            cubic = ti.select(ok3, 1, 0)
        if ti.static(variant == GradientVariant.QUADRATIC or variant == GradientVariant.CUBIC):
            ok = True
            if cubic == 0:
                Lf, ok = _mls_fit_rows(2, kernel_id, i, pos, mass, rho, offsets, nbrs, H, adaptive,
                                       hs, kind, src_kinds)
            if not ok:
                # Too few neighbours for a quadratic fit (e.g. a corner): this
                # particle falls back to the linearly corrected gradient, and only
                # if that is singular too is the set refused.
                M = _correction_matrix(kernel_id, i, pos, mass, rho, offsets, nbrs, H, adaptive, hs,
                                       kind, src_kinds)
                if _sym2_eig_ratio(M[0, 0], M[0, 1], M[1, 1]) < SINGULAR_RATIO:
                    ti.atomic_max(bad, i)
                else:
                    L = M.inverse()
                    linear = 1
        if ti.static(variant == GradientVariant.CORRECTED):
            M = _correction_matrix(kernel_id, i, pos, mass, rho, offsets, nbrs, H, adaptive, hs,
                                       kind, src_kinds)
            if _sym2_eig_ratio(M[0, 0], M[0, 1], M[1, 1]) < SINGULAR_RATIO:
                ti.atomic_max(bad, i)
            else:
                L = M.inverse()
        gsum = ti.Vector.zero(float, 2)
        # the fitted gradient's weights: rows 0-1 of M^-1, scaled by 1 / H_i
        Hi = pair_support(adaptive, hs, i, i, H)
        R2 = ti.Matrix.zero(float, 2, 5)
        R3 = ti.Matrix.zero(float, 2, ti.static(9 if variant == GradientVariant.CUBIC else 1))
        if ti.static(variant == GradientVariant.QUADRATIC or variant == GradientVariant.CUBIC):
            if cubic:
                if ti.static(variant == GradientVariant.CUBIC):
                    R3 = _gradient_rows(3, Lc) / Hi
            elif not linear:
                R2 = _gradient_rows(2, Lf) / Hi
                if ti.static(variant == GradientVariant.CUBIC):
                    # the quadratic fallback as the leading columns of the
                    # cubic rows: one product per pair below, no branch
                    for a in ti.static(range(2)):
                        for b in ti.static(range(5)):
                            R3[a, b] = R2[a, b]
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            mj = _src_mass(mass, kind, j, src_kinds)
            xij = pos[i] - pos[j]
            Hij = pair_support(adaptive, hs, i, j, H)
            W, F, _L = kernel_terms(kernel_id, xij.norm(), Hij)
            gw = F * xij
            coef = ti.Vector.zero(float, 2)
            if ti.static(variant == GradientVariant.BASIC or variant == GradientVariant.DIFFERENCE):
                coef = (mj / rho[j]) * gw
            elif ti.static(variant == GradientVariant.COLIN_DIFFERENCE):
                coef = (mj / rho[i]) * gw
            elif ti.static(variant == GradientVariant.SYMMETRIC):
                coef = rho[i] * mj / (rho[j] * rho[j]) * gw
                # f_i terms: rho_i m_j f_i / rho_i^2, plus sum_j G f_i from the difference form
                gsum += (mj / rho[i]) * gw + coef
            elif ti.static(variant == GradientVariant.CORRECTED):
                coef = (mj / rho[j]) * (L @ gw)
            else:
                if linear:
                    coef = (mj / rho[j]) * (L @ gw)
                else:
                    # rows 0-1 of M^-1 (V_j W_ij p_j) / H: the fitted gradient's weights
                    u = -xij / Hi
                    c = (mj / rho[j]) * W
                    if ti.static(variant == GradientVariant.CUBIC):
                        coef = c * (R3 @ _monomials(3, u))
                    else:
                        coef = c * (R2 @ _monomials(2, u))
            G[k] = coef
            if ti.static(variant == GradientVariant.BASIC):
                gsum += coef   # sum_j G f_j = sum_j G (f_j - f_i) + (sum_j G) f_i
        s[i] = gsum
    return bad


@ti.func
def _add_laplacian_moments(u, P, Q, x, r, V, F):
    """One pair's share of the corrected Laplacian's moments (x = x_j - x_i,
    r = |x|, V = m_j / rho_j, F = W'(r) / r): u rows sum V q_k grad W, P rows
    sum w q_k (exx, eyy, exy), Q rows sum w x_a (exx, eyy, exy), with
    q = (x^2, y^2, xy) and w = -2 V F."""
    gw = -F * x
    q = ti.Vector([x[0] * x[0], x[1] * x[1], x[0] * x[1]])
    e = x / r
    ee = ti.Vector([e[0] * e[0], e[1] * e[1], e[0] * e[1]])
    w = -2.0 * V * F
    for a in ti.static(range(3)):
        for b in ti.static(range(2)):
            u[a, b] += V * q[a] * gw[b]
        for b in ti.static(range(3)):
            P[a, b] += w * q[a] * ee[b]
    for a in ti.static(range(2)):
        for b in ti.static(range(3)):
            Q[a, b] += w * x[a] * ee[b]
    return u, P, Q


@ti.func
def _laplacian_correction(M, u, P, Q):
    """(M^-1, Bxx, Byy, Bxy, ok) of the renormalised Laplacian from its first
    pass's sums (``_laplacian_coeffs``): B makes the stencil exact on x^2, y^2,
    xy; ok is False when M or the 3 x 3 system is singular."""
    Linv = ti.Matrix.identity(float, 2)
    Bxx = 1.0
    Byy = 1.0
    Bxy = 0.0
    ok = True
    if _sym2_eig_ratio(M[0, 0], M[0, 1], M[1, 1]) < SINGULAR_RATIO:
        ok = False
    else:
        Linv = M.inverse()
        A = ti.Matrix.zero(float, 3, 3)
        for a in ti.static(range(3)):
            g = Linv @ ti.Vector([u[a, 0], u[a, 1]])
            for b in ti.static(range(3)):
                t = P[a, b] - g[0] * Q[0, b] - g[1] * Q[1, b]
                A[a, b] = t * (2.0 if b == 2 else 1.0)
        rhs = ti.Vector([2.0, 2.0, 0.0])   # traces of the Hessians of x^2, y^2, xy
        scale = ti.abs(A).max()
        det = A.determinant()
        if scale == 0.0 or ti.abs(det) < 1e-9 * scale * scale * scale:
            ok = False
        else:
            b = A.inverse() @ rhs
            Bxx = b[0]
            Byy = b[1]
            Bxy = b[2]
    return Linv, Bxx, Byy, Bxy, ok


@ti.kernel
def _laplacian_coeffs(kernel_id: ti.template(), variant: ti.template(), pos: ti.types.ndarray(),
                      mass: ti.types.ndarray(), rho: ti.types.ndarray(), n: ti.i32,
                      offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
                      adaptive: ti.template(), hs: ti.types.ndarray(),
                      C: ti.types.ndarray(), s: ti.types.ndarray(),
                      kind: ti.types.ndarray(), row_kinds: ti.i32, src_kinds: ti.i32,
                      with_gradient: ti.template(), G: ti.types.ndarray(),
                      sG: ti.types.ndarray(), Cw: ti.types.ndarray(),
                      Gw: ti.types.ndarray(), grad_one: ti.types.ndarray()) -> ti.i32:
    """Returns the largest row whose correction matrix is singular, or -1.
    ``with_gradient`` (the corrected variant only): also the corrected gradient's
    coefficients ``G``, ``sG``, the same values as ``_gradient_coeffs`` computes,
    and both weighted by the pair's mean density, ``Cw`` = C 2 / (rho_i + rho_j)
    and ``Gw`` = G 2 rho_i / (rho_i + rho_j) (as ``_weight_by_mean_density`` and
    ``weight_gradient_by_mean_density``), and ``grad_one`` = sum_j V_j grad W_ij,
    the basic gradient of f = 1 (particle shifting's concentration gradient), from
    the same pair passes: the two-phase flow needs all of them."""
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
                j = nbrs[k]
                mj = _src_mass(mass, kind, j, src_kinds)
                _W, _F, Lw = kernel_terms(kernel_id, (pos[i] - pos[j]).norm(),
                                          pair_support(adaptive, hs, i, j, H))
                c = (mj / rho[j]) * Lw
                C[k] = c
                csum += c
            selfc = csum + (mass[i] / rho[i]) * L0
        elif ti.static(variant == LaplacianVariant.COLIN_DIFFERENCE):
            grho = ti.Vector.zero(float, 2)
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                mj = _src_mass(mass, kind, j, src_kinds)
                xij = pos[i] - pos[j]
                _W, F, _L = kernel_terms(kernel_id, xij.norm(), pair_support(adaptive, hs, i, j, H))
                grho += mj * F * xij
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                mj = _src_mass(mass, kind, j, src_kinds)
                xij = pos[i] - pos[j]
                _W, F, Lw = kernel_terms(kernel_id, xij.norm(), pair_support(adaptive, hs, i, j, H))
                C[k] = (mj / rho[i]) * (Lw - 2.0 / rho[i] * F * xij.dot(grho))
        elif ti.static(variant == LaplacianVariant.BROOKSHAW):
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                mj = _src_mass(mass, kind, j, src_kinds)
                _W, F, _L = kernel_terms(kernel_id, (pos[i] - pos[j]).norm(),
                                         pair_support(adaptive, hs, i, j, H))
                C[k] = -2.0 * (mj / rho[j]) * F
        else:                                # renormalised, exact on quadratics
            M = ti.Matrix.zero(float, 2, 2)
            Mg = ti.Matrix.zero(float, 2, 2)   # the gradient's (with_gradient), as
                                               # _correction_matrix sums it
            g1 = ti.Vector.zero(float, 2)      # grad_one (with_gradient)
            u = ti.Matrix.zero(float, 3, 2)    # rows: sum V q_k grad W, q = (x^2, y^2, xy)
            P = ti.Matrix.zero(float, 3, 3)    # rows k: sum w q_k (exx, eyy, exy)
            Q = ti.Matrix.zero(float, 2, 3)    # rows a: sum w x_a (exx, eyy, exy)
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                mj = _src_mass(mass, kind, j, src_kinds)
                x = pos[j] - pos[i]
                r = x.norm()
                _W, F, _L = kernel_terms(kernel_id, r, pair_support(adaptive, hs, i, j, H))
                V = mj / rho[j]
                gw = -F * x                     # grad_i W_ij = F x_ij = -F x_ji
                M += V * gw.outer_product(x)
                if ti.static(with_gradient):
                    Mg += (mj / rho[j]) * (-F) * x.outer_product(x)
                    g1 += V * gw
                    Gw[k] = ti.Vector([F, r])   # kept for the next two loops (then Gw)
                u, P, Q = _add_laplacian_moments(u, P, Q, x, r, V, F)
            Linv, Bxx, Byy, Bxy, ok = _laplacian_correction(M, u, P, Q)
            if not ok:
                ti.atomic_max(bad, i)
            Lg = ti.Matrix.identity(float, 2)
            if ti.static(with_gradient):
                grad_one[i] = g1
                if _sym2_eig_ratio(Mg[0, 0], Mg[0, 1], Mg[1, 1]) < SINGULAR_RATIO:
                    ti.atomic_max(bad, i)
                else:
                    Lg = Mg.inverse()
            # sigma = sum_j a_ij x_ji is linear in B: Q (Bxx, Byy, 2 Bxy) from the
            # first pass, so one more pass writes C_ij = a_ij - V_j beta . grad W_ij
            # (and, for the flow, the gradient and both density-weighted copies)
            sigma = Q @ ti.Vector([Bxx, Byy, 2.0 * Bxy])
            beta = Linv.transpose() @ sigma
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                mj = _src_mass(mass, kind, j, src_kinds)
                x = pos[j] - pos[i]
                r = 0.0
                F = 0.0
                if ti.static(with_gradient):
                    r = Gw[k][1]
                    F = Gw[k][0]
                else:
                    r = x.norm()
                    _W, F, _L = kernel_terms(kernel_id, r, pair_support(adaptive, hs, i, j, H))
                e = x / r
                V = mj / rho[j]
                C[k] = V * F * (beta.dot(x) - 2.0 * (Bxx * e[0] * e[0] + Byy * e[1] * e[1]
                                                     + 2.0 * Bxy * e[0] * e[1]))
                if ti.static(with_gradient):
                    # _gradient_coeffs' corrected coefficient (x_ij = -x exactly)
                    G[k] = V * (Lg @ (F * (-x)))
                    Cw[k] = C[k] * (2.0 / (rho[i] + rho[j]))
                    Gw[k] = G[k] * (2.0 * rho[i] / (rho[i] + rho[j]))
            if ti.static(with_gradient):
                sG[i] = ti.Vector.zero(float, 2)
        s[i] = selfc
    return bad


@ti.func
def _decomposition_pair(kernel_id: ti.template(), pos: ti.template(), mass: ti.template(),
                        rho: ti.template(), adaptive: ti.template(), hs: ti.template(), H,
                        Hi, i, j):
    """What both passes of :func:`_decomposition_coeffs` need of pair (i, j):
    x = x_j - x_i, r = |x|, W, F = W'/r, V = m_j / rho_j and the cubic monomials
    of x / Hi (recomputed in the second pass: storing them would cost more
    memory traffic than the arithmetic)."""
    x = pos[j] - pos[i]
    r = x.norm()
    W, F, _L = kernel_terms(kernel_id, r, pair_support(adaptive, hs, i, j, H))
    V = mass[j] / rho[j]
    p = _monomials(3, x / Hi)
    return x, r, W, F, V, p


@ti.kernel
def _decomposition_coeffs(kernel_id: ti.template(), pos: ti.types.ndarray(),
                          mass: ti.types.ndarray(), rho: ti.types.ndarray(), n: ti.i32,
                          offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
                          adaptive: ti.template(), hs: ti.types.ndarray(),
                          kind: ti.types.ndarray(), G3: ti.types.ndarray(), s3: ti.types.ndarray(),
                          G2: ti.types.ndarray(), s2: ti.types.ndarray(), C: ti.types.ndarray(),
                          sC: ti.types.ndarray()) -> (ti.i32, ti.i32, ti.i32):
    """The default decomposition's three stencils from two passes over each row's
    pairs (one for every sum, one for every coefficient), the values of
    ``_gradient_coeffs`` and ``_laplacian_coeffs`` up to round-off:

    ``G3`` the cubic gradient of the FLUID rows over FLUID sources (div v, curl v),
    ``G2`` the quadratic gradient of the FLUID and BOUNDARY rows over every
    particle (Neumann rows, d and r), ``C`` the corrected Laplacian of the FLUID
    rows over every particle; the fallbacks are theirs (cubic -> quadratic ->
    corrected; quadratic -> corrected).  The quadratic moments are the cubic
    ones' leading 5 x 5 block plus the non-FLUID sources' share.  Returns the
    largest singular row of each (-1 if none)."""
    bad3 = -1
    bad2 = -1
    badL = -1
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
        M3 = ti.Matrix.zero(float, 9, 9)   # cubic moments over FLUID sources (lower half)
        Mb = ti.Matrix.zero(float, 5, 5)   # quadratic moments over the other sources
        M = ti.Matrix.zero(float, 2, 2)    # the Laplacian's sums (_laplacian_coeffs)
        u = ti.Matrix.zero(float, 3, 2)
        P = ti.Matrix.zero(float, 3, 3)
        Q = ti.Matrix.zero(float, 2, 3)
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            x, r, W, F, V, p = _decomposition_pair(kernel_id, pos, mass, rho, adaptive, hs, H,
                                                   Hi, i, j)
            cp = (V * W) * p                    # one multiply-add per moment below
            if kind[j] == FLUID:
                for a in ti.static(range(9)):
                    for b in ti.static(range(a + 1)):
                        M3[a, b] += cp[a] * p[b]
            else:
                for a in ti.static(range(5)):
                    for b in ti.static(range(a + 1)):
                        Mb[a, b] += cp[a] * p[b]
            if fluid_row:
                gw = -F * x
                M += V * gw.outer_product(x)
                u, P, Q = _add_laplacian_moments(u, P, Q, x, r, V, F)
        # the divergence's cubic fit, else quadratic (the leading block), else linear
        R3 = ti.Matrix.zero(float, 2, 9)
        L3 = ti.Matrix.identity(float, 2)
        linear3 = 0
        if fluid_row:
            Lc, ok3 = _cholesky_factor(3, M3)
            if ok3:
                R3 = _gradient_rows(3, Lc) / Hi
            else:
                M2f = ti.Matrix.zero(float, 5, 5)
                for a in ti.static(range(5)):
                    for b in ti.static(range(a + 1)):
                        M2f[a, b] = M3[a, b]
                Lq, okq = _cholesky_factor(2, M2f)
                if okq:
                    R2f = _gradient_rows(2, Lq) / Hi
                    for a in ti.static(range(2)):
                        for b in ti.static(range(5)):
                            R3[a, b] = R2f[a, b]
                else:
                    Mc = _correction_matrix(kernel_id, i, pos, mass, rho, offsets, nbrs, H,
                                            adaptive, hs, kind, ti.static(1 << int(FLUID)))
                    if _sym2_eig_ratio(Mc[0, 0], Mc[0, 1], Mc[1, 1]) < SINGULAR_RATIO:
                        ti.atomic_max(bad3, i)
                    else:
                        L3 = Mc.inverse()
                        linear3 = 1
        # the Neumann rows' quadratic fit over every particle, else linear
        M2 = ti.Matrix.zero(float, 5, 5)
        for a in ti.static(range(5)):
            for b in ti.static(range(a + 1)):
                M2[a, b] = M3[a, b] + Mb[a, b]
        R2 = ti.Matrix.zero(float, 2, 5)
        L2 = ti.Matrix.identity(float, 2)
        linear2 = 0
        L2f, ok2 = _cholesky_factor(2, M2)
        if ok2:
            R2 = _gradient_rows(2, L2f) / Hi
        else:
            Mc = _correction_matrix(kernel_id, i, pos, mass, rho, offsets, nbrs, H, adaptive, hs,
                                    kind, ti.static(kind_bits(ALL_KINDS)))
            if _sym2_eig_ratio(Mc[0, 0], Mc[0, 1], Mc[1, 1]) < SINGULAR_RATIO:
                ti.atomic_max(bad2, i)
            else:
                L2 = Mc.inverse()
                linear2 = 1
        # the Laplacian (two passes: sigma from Q, as _laplacian_coeffs)
        beta = ti.Vector.zero(float, 2)
        Bxx = 0.0
        Byy = 0.0
        Bxy = 0.0
        if fluid_row:
            Linv, bxx, byy, bxy, okL = _laplacian_correction(M, u, P, Q)
            if not okL:
                ti.atomic_max(badL, i)
            Bxx = bxx
            Byy = byy
            Bxy = bxy
            beta = Linv.transpose() @ (Q @ ti.Vector([Bxx, Byy, 2.0 * Bxy]))
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            x, r, W, F, V, p = _decomposition_pair(kernel_id, pos, mass, rho, adaptive, hs, H,
                                                   Hi, i, j)
            gw = F * (-x)                       # grad_i W_ij = F x_ij
            g3 = ti.Vector.zero(float, 2)
            if fluid_row and kind[j] == FLUID:
                if linear3:
                    g3 = V * (L3 @ gw)
                else:
                    g3 = (V * W) * (R3 @ p)
            G3[k] = g3
            if linear2:
                G2[k] = V * (L2 @ gw)
            else:
                p2 = ti.Vector([p[0], p[1], p[2], p[3], p[4]])
                G2[k] = (V * W) * (R2 @ p2)
            cl = 0.0
            if fluid_row:
                e = x / r
                cl = V * F * (beta.dot(x) - 2.0 * (Bxx * e[0] * e[0] + Byy * e[1] * e[1]
                                                   + 2.0 * Bxy * e[0] * e[1]))
            C[k] = cl
    return bad3, bad2, badL


@ti.kernel
def _weight_by_mean_density(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                            rho: ti.types.ndarray(), C: ti.types.ndarray(),
                            out: ti.types.ndarray()):
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


@ti.kernel
def _apply_difference_stencil(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                              coef: ti.types.ndarray(), s: ti.types.ndarray(),
                              f: ti.types.ndarray(), out: ti.types.ndarray()):
    """out_i = s_i f_i + sum_j coef_ij (f_j - f_i): the gradient (coef a 2-vector)
    and the Laplacian (coef a scalar) of a scalar field, one kernel for both."""
    for i in range(n):
        fi = f[i]
        acc = s[i] * fi
        for k in range(offsets[i], offsets[i + 1]):
            acc += coef[k] * (f[nbrs[k]] - fi)
        out[i] = acc


@ti.kernel
def _apply_divergence(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                      G: ti.types.ndarray(), s: ti.types.ndarray(), v: ti.types.ndarray(),
                      rotate: ti.i32, out: ti.types.ndarray()):
    # rotate = 1 evaluates div(J v) = curl v with J(v1, v2) = (v2, -v1)
    for i in range(n):
        vi = v[i]
        if rotate:
            vi = ti.Vector([vi[1], -vi[0]])
        acc = s[i].dot(vi)
        for k in range(offsets[i], offsets[i + 1]):
            vj = v[nbrs[k]]
            if rotate:
                vj = ti.Vector([vj[1], -vj[0]])
            acc += G[k].dot(vj - vi)
        out[i] = acc


@ti.kernel
def _apply_divergence_curl(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                           G: ti.types.ndarray(), s: ti.types.ndarray(), v: ti.types.ndarray(),
                           out: ti.types.ndarray()):
    """out_i = (div v_i, curl v_i) in one pass over the pairs: the values of
    ``_apply_divergence`` with rotate 0 and 1."""
    for i in range(n):
        vi = v[i]
        ri = ti.Vector([vi[1], -vi[0]])
        acc = s[i].dot(vi)
        rot = s[i].dot(ri)
        for k in range(offsets[i], offsets[i + 1]):
            vj = v[nbrs[k]]
            rj = ti.Vector([vj[1], -vj[0]])
            acc += G[k].dot(vj - vi)
            rot += G[k].dot(rj - ri)
        out[i] = ti.Vector([acc, rot])


@ti.kernel
def _apply_gradient_pair(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                         G: ti.types.ndarray(), s: ti.types.ndarray(), f: ti.types.ndarray(),
                         out_a: ti.types.ndarray(), out_b: ti.types.ndarray()):
    """The gradients of two scalar fields (the columns of ``f``) in one pass over
    the pairs: the values of ``_apply_difference_stencil`` on each."""
    for i in range(n):
        fi = f[i]
        acc_a = s[i] * fi[0]
        acc_b = s[i] * fi[1]
        for k in range(offsets[i], offsets[i + 1]):
            fj = f[nbrs[k]]
            acc_a += G[k] * (fj[0] - fi[0])
            acc_b += G[k] * (fj[1] - fi[1])
        out_a[i] = acc_a
        out_b[i] = acc_b


@ti.kernel
def _laplacian_diagonal(n: ti.i32, offsets: ti.types.ndarray(), C: ti.types.ndarray(),
                        s: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(n):
        d = s[i]
        for k in range(offsets[i], offsets[i + 1]):
            d -= C[k]
        out[i] = d


@ti.func
def shepard_weight(kernel_id: ti.template(), pos: ti.template(), vol: ti.template(), i, j, H):
    """V_j W_ij: the weight of particle j in the Shepard sum at i (Petronetto Eq. 14);
    ``H`` the pair's support."""
    W, _F, _L = kernel_terms(kernel_id, (pos[i] - pos[j]).norm(), H)
    return vol[j] * W


@ti.func
def shepard_sums(kernel_id: ti.template(), i, offsets: ti.template(), nbrs: ti.template(),
                 pos: ti.template(), vol: ti.template(), kind: ti.template(), H,
                 adaptive: ti.template(), hs: ti.template(), src_kinds, f: ti.template(), num,
                 den):
    """(num + sum_j V_j W_ij f_j, den + sum_j V_j W_ij) over the neighbours j of i
    whose kind is in the bit mask ``src_kinds``: the numerator and denominator of
    the Shepard-normalised sum of ``f`` (scalar or vector), continued from
    ``num``, ``den`` (the caller's own terms, added first)."""
    for k in range(offsets[i], offsets[i + 1]):
        j = nbrs[k]
        if (src_kinds >> kind[j]) & 1:
            w = shepard_weight(kernel_id, pos, vol, i, j, pair_support(adaptive, hs, i, j, H))
            num += w * f[j]
            den += w
    return num, den


@ti.kernel
def _shepard(kernel_id: ti.template(), pos: ti.types.ndarray(), vol: ti.types.ndarray(), n: ti.i32,
             offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
             adaptive: ti.template(), hs: ti.types.ndarray(),
             f: ti.types.ndarray(), out: ti.types.ndarray(), kind: ti.types.ndarray(),
             src_kinds: ti.i32):
    """Shepard-normalised interpolation (Petronetto Eq. 14) from the neighbours of
    the given kinds, the particle itself included when its kind is one of them."""
    for i in range(n):
        W0, _F0, _L0 = kernel_terms(kernel_id, 0.0, pair_support(adaptive, hs, i, i, H))
        num = out[i] * 0.0
        den = 0.0
        if (src_kinds >> kind[i]) & 1:
            num += vol[i] * W0 * f[i]
            den += vol[i] * W0
        num, den = shepard_sums(kernel_id, i, offsets, nbrs, pos, vol, kind, H, adaptive, hs,
                                src_kinds, f, num, den)
        if den > 0.0:
            out[i] = num / den
        else:
            out[i] = num * 0.0


# ---------------------------------------------------------------------------

@dataclass
class GradientStencil:
    """Pair coefficients G_ij and self coefficients s_i of one gradient variant."""
    G: object
    s: object
    variant: str
    row_kinds: tuple = ALL_KINDS
    source_kinds: tuple = ALL_KINDS


@dataclass
class LaplacianStencil:
    """Pair coefficients C_ij and self coefficients c_i of one Laplacian variant."""
    C: object
    s: object
    variant: str
    row_kinds: tuple = ALL_KINDS
    source_kinds: tuple = ALL_KINDS


class Operators:
    """SPH operators on a binned particle set and its pair list.

    ``particles`` must carry mass; call :meth:`compute_density` (summation)
    or fill ``density``/``volume`` yourself before building coefficients.
    supports: optional per-slot kernel supports (a Taichi array, slot order),
    the adaptive support of :mod:`taichi_hh.sph.support` (pairs then use
    ``max(H_i, H_j)``; ``support`` is their largest); default the fixed ``support``.
    """

    def __init__(self, particles, pairs, support: float, kernel: str = "wendland",
                 supports=None):
        runtime.ensure_init()
        self.particles = particles
        self.pairs = pairs
        self.support = float(support)
        self.kernel = kernel
        self.kernel_id = int(kernel_id(kernel))    # a plain int: the kernels take it as a template
        # stands in for the gradient arrays of a Laplacian-only coefficient build
        self._no_vectors = runtime.array(runtime.real_dtype(), 1, vector=2)
        self._no_scalars = runtime.array(runtime.real_dtype(), 1)
        self.supports = supports
        if supports is None:                       # fixed support: never read by the kernels
            supports = runtime.array(runtime.real_dtype(), 1)
        self.adaptive = int(self.supports is not None)
        self._hs = supports

    def support_args(self):
        """``(H, adaptive, hs)``: the support arguments of the operator kernels."""
        return self.support, self.adaptive, self._hs

    @property
    def n(self) -> int:
        return self.particles.n

    def _pair_args(self):
        return self.pairs.offsets, self.pairs.neighbours

    def compute_density(self) -> None:
        p = self.particles
        number_density(self.kernel_id, p.position, p.mass, p.n, *self._pair_args(),
                       *self.support_args(), p.density, p.volume)

    def _check_bad(self, what: str, bad: int) -> None:
        if bad >= 0:
            p = self.particles
            pos = p.position.to_numpy()[bad]
            orig = int(p.original_index.to_numpy()[bad])
            count = int(self.pairs.counts()[bad])
            support = (self.support if self.supports is None
                       else float(self.supports.to_numpy()[bad]))
            raise NeighbourError(
                f"{what}: the correction matrix of particle {orig} at ({pos[0]:.6g}, {pos[1]:.6g}) "
                f"is singular: it has {count} neighbours within the kernel support "
                f"{support:.6g}, too few or all on one line. Increase the support "
                "(support_ratio) or use an uncorrected variant.")

    def gradient_coefficients(self, variant: str = "corrected",
                              row_kinds=ALL_KINDS, source_kinds=ALL_KINDS,
                              density_weighted: bool = False, into=None) -> GradientStencil:
        """Coefficients of a gradient variant for the rows whose particle kind is in
        ``row_kinds`` (other rows get zeros: e.g. ghosts, which need no derivatives),
        summing over the neighbours whose kind is in ``source_kinds``.  into: the
        arrays ``(G, s)`` to write (2-vector ndarrays of at least as many rows as
        pairs and particles), for a caller that keeps them across particle
        configurations; default new ones."""
        vid = _variant_id(variant, GRADIENT_VARIANTS)
        p = self.particles
        real = runtime.real_dtype()
        if into is None:
            G = runtime.array(real, max(self.pairs.n_pairs, 1), vector=2, zeroed=False)
            s = runtime.array(real, max(p.n, 1), vector=2, zeroed=False)
        else:
            G, s = into
            if G.shape[0] < self.pairs.n_pairs or s.shape[0] < p.n:
                raise ValueError(f"gradient arrays too small: {G.shape[0]} pair and {s.shape[0]} "
                                 f"particle rows for {self.pairs.n_pairs} pairs, {p.n} particles")
        bad = _gradient_coeffs(self.kernel_id, vid, p.position, p.mass, p.density, p.n,
                               *self._pair_args(), *self.support_args(), G, s, p.kind,
                               kind_bits(row_kinds), kind_bits(source_kinds))
        self._check_bad(f"{variant} gradient", bad)
        if density_weighted:
            if variant in ("basic", "symmetric"):
                raise ValueError("density weighting needs a difference-form gradient")
            weight_gradient_by_mean_density(p.n, *self._pair_args(), p.density, G, G)
        return GradientStencil(G, s, variant, tuple(row_kinds), tuple(source_kinds))

    def laplacian_coefficients(self, variant: str = "corrected",
                               row_kinds=ALL_KINDS, source_kinds=ALL_KINDS,
                               density_weighted: bool = False, into=None,
                               gradient_into=None):
        """Coefficients of a Laplacian variant for the rows of the given kinds,
        summing over neighbours of the given kinds.  ``density_weighted`` turns it
        into div(grad f / rho) (pair coefficient times 2 / (rho_i + rho_j)); only
        for the difference forms, whose self coefficient is zero.  into: the
        arrays ``(C, s)`` to write (scalar ndarrays of at least as many rows as
        pairs and particles); default new ones.  gradient_into (corrected variant
        only, what the two-phase flow needs): arrays ``(G, s, Cw, Gw, grad_one)``;
        then the corrected gradient's coefficients ``(G, s)`` of the same rows and
        sources (the values :meth:`gradient_coefficients` gives), both stencils
        weighted by the pair's mean density (``Cw``, ``Gw``: the values of
        ``density_weighted=True``) and, per row, ``grad_one`` = sum_j V_j grad W_ij
        (the basic gradient of 1) come from the same pair passes, and the result
        is the four stencils ``(Laplacian, gradient, weighted Laplacian, weighted
        gradient)``, the weighted ones sharing the self coefficients (zero for
        these difference forms)."""
        vid = _variant_id(variant, LAPLACIAN_VARIANTS)
        p = self.particles
        real = runtime.real_dtype()
        if into is None:
            C = runtime.array(real, max(self.pairs.n_pairs, 1), zeroed=False)
            s = runtime.array(real, max(p.n, 1), zeroed=False)
        else:
            C, s = into
            if C.shape[0] < self.pairs.n_pairs or s.shape[0] < p.n:
                raise ValueError(f"Laplacian arrays too small: {C.shape[0]} pair and {s.shape[0]} "
                                 f"particle rows for {self.pairs.n_pairs} pairs, {p.n} particles")
        with_gradient = gradient_into is not None
        if with_gradient:
            if variant != "corrected" or density_weighted:
                raise ValueError("gradient_into: only with the corrected Laplacian, "
                                 "not density weighted (the weighted copies come with it)")
            G, sG, Cw, Gw, grad_one = gradient_into
            if min(G.shape[0], Cw.shape[0], Gw.shape[0]) < self.pairs.n_pairs \
                    or min(sG.shape[0], grad_one.shape[0]) < p.n:
                raise ValueError(f"gradient arrays too small for {self.pairs.n_pairs} pairs, "
                                 f"{p.n} particles")
        else:
            G = sG = Gw = grad_one = self._no_vectors
            Cw = self._no_scalars
        bad = _laplacian_coeffs(self.kernel_id, vid, p.position, p.mass, p.density, p.n,
                                *self._pair_args(), *self.support_args(), C, s, p.kind,
                                kind_bits(row_kinds), kind_bits(source_kinds), with_gradient,
                                G, sG, Cw, Gw, grad_one)
        self._check_bad(f"{variant} Laplacian", bad)
        if density_weighted:
            if variant == "basic":
                raise ValueError("density weighting needs a difference-form Laplacian")
            _weight_by_mean_density(p.n, *self._pair_args(), p.density, C, C)
        rows, sources = tuple(row_kinds), tuple(source_kinds)
        lap = LaplacianStencil(C, s, variant, rows, sources)
        if with_gradient:
            return (lap, GradientStencil(G, sG, variant, rows, sources),
                    LaplacianStencil(Cw, s, variant, rows, sources),
                    GradientStencil(Gw, sG, variant, rows, sources))
        return lap

    def decomposition_coefficients(self):
        """The default decomposition's three stencils from one kernel
        (``_decomposition_coeffs``): ``(divergence, gradient, laplacian)``, what
        ``gradient_coefficients("cubic", (FLUID,), (FLUID,))``,
        ``gradient_coefficients("quadratic", (FLUID, BOUNDARY))`` and
        ``laplacian_coefficients("corrected", (FLUID,))`` give, up to round-off."""
        p = self.particles
        real = runtime.real_dtype()
        npairs, size = max(self.pairs.n_pairs, 1), max(p.n, 1)
        G3, G2 = (runtime.array(real, npairs, vector=2, zeroed=False) for _ in range(2))
        s3, s2 = (runtime.array(real, size, vector=2, zeroed=False) for _ in range(2))
        C = runtime.array(real, npairs, zeroed=False)
        sC = runtime.array(real, size, zeroed=False)
        bad = _decomposition_coeffs(self.kernel_id, p.position, p.mass, p.density, p.n,
                                    *self._pair_args(), *self.support_args(), p.kind,
                                    G3, s3, G2, s2, C, sC)
        for what, b in zip(("cubic gradient", "quadratic gradient", "corrected Laplacian"), bad):
            self._check_bad(what, b)
        return (GradientStencil(G3, s3, "cubic", (FLUID,), (FLUID,)),
                GradientStencil(G2, s2, "quadratic", (FLUID, BOUNDARY), ALL_KINDS),
                LaplacianStencil(C, sC, "corrected", (FLUID,), ALL_KINDS))

    def density_weighted(self, st: LaplacianStencil, into=None) -> LaplacianStencil:
        """A copy of a difference-form Laplacian's coefficients times
        2 / (rho_i + rho_j): what ``laplacian_coefficients(..., density_weighted=True)``
        returns, without computing the coefficients again.  into: the pair array
        to write (at least as many rows as pairs); default a new one."""
        if st.variant == "basic":
            raise ValueError("density weighting needs a difference-form Laplacian")
        if into is None:
            into = runtime.array(runtime.real_dtype(), st.C.shape)
        elif into.shape[0] < self.pairs.n_pairs:
            raise ValueError(f"Laplacian array too small: {into.shape[0]} rows for "
                             f"{self.pairs.n_pairs} pairs")
        _weight_by_mean_density(self.particles.n, *self._pair_args(), self.particles.density,
                                st.C, into)
        return LaplacianStencil(into, st.s, st.variant, st.row_kinds, st.source_kinds)

    # ---- applies (Taichi arrays in, Taichi arrays out) --------------------------
    def gradient(self, st: GradientStencil, f, out) -> None:
        _apply_difference_stencil(self.n, *self._pair_args(), st.G, st.s, f, out)

    def divergence(self, st: GradientStencil, v, out) -> None:
        _apply_divergence(self.n, *self._pair_args(), st.G, st.s, v, 0, out)

    def curl(self, st: GradientStencil, v, out) -> None:
        _apply_divergence(self.n, *self._pair_args(), st.G, st.s, v, 1, out)

    def divergence_and_curl(self, st: GradientStencil, v, out) -> None:
        """``out`` (2-vectors): (div v, curl v), one pass for both."""
        _apply_divergence_curl(self.n, *self._pair_args(), st.G, st.s, v, out)

    def gradients(self, st: GradientStencil, f2, out_a, out_b) -> None:
        """The gradients of the two columns of ``f2`` (2-vectors) into ``out_a``,
        ``out_b``, one pass for both."""
        _apply_gradient_pair(self.n, *self._pair_args(), st.G, st.s, f2, out_a, out_b)

    def laplacian(self, st: LaplacianStencil, f, out) -> None:
        _apply_difference_stencil(self.n, *self._pair_args(), st.C, st.s, f, out)

    def laplacian_diagonal(self, st: LaplacianStencil, out) -> None:
        _laplacian_diagonal(self.n, self.pairs.offsets, st.C, st.s, out)

    def shepard(self, f, out, source_kinds=ALL_KINDS) -> None:
        """Shepard interpolation of f (scalar or vector) at every particle from the
        neighbours of the given kinds; 0 where there are none."""
        p = self.particles
        _shepard(self.kernel_id, p.position, p.volume, p.n, *self._pair_args(), *self.support_args(),
                 f, out, p.kind, kind_bits(source_kinds))
