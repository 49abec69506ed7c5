"""The pieces the stencil kernels (:mod:`taichi_hh.sph.stencils`) are composed of.

* :func:`pair_terms`: what a pair (i, j) contributes to anything: x = x_j - x_i,
  r = |x|, W, F = W'(r) / r, the kernel's Laplacian, m_j and V_j = m_j / rho_j
  (zero for a neighbour whose kind is not a wanted source);
* per-pair sums: :func:`add_fit_moments` (the least-squares fits' moments),
  :func:`add_correction` (the linear correction matrix, Bonet & Lok 1999),
  :func:`add_laplacian_moments` (the renormalised Laplacian's sums);
* per-row solves from those sums: :func:`gradient_fit` (cubic -> quadratic ->
  linear fit, the fallbacks included), :func:`linear_correction`,
  :func:`laplacian_correction`;
* per-pair coefficients from a row's solve: :func:`fitted_gradient_coefficient`,
  :func:`corrected_gradient_coefficient`, :func:`corrected_laplacian_coefficient`.

A kernel loops over its rows and their pairs and calls these; the formulas
live here once.  Each keeps the exact expressions (operand order, x_ij or
x_ji) the kernels had before they were shared: Taichi compiles with fast math,
so a rewritten expression may round differently in the last bit, and the
stencils are kept bit-identical.
"""

import taichi as ti

from .kernels import kernel_terms
from .particles import BOUNDARY
from .support import pair_support

#: a neighbour lies beyond a boundary row's wall line when its offset's
#: component along the row's outward normal exceeds this fraction of its
#: length (:func:`beyond_wall`; below it: on the line, as rounding leaves the
#: other samples of a straight wall)
WALL_SIDE_TOL = 1e-6

# A correction matrix whose smallest/largest eigenvalue ratio falls below this
# is treated as singular: the neighbourhood is too small or degenerate
# (collinear) for the corrected operators.
SINGULAR_RATIO = 1e-6


# ---------------------------------------------------------------------------
# pair terms

@ti.func
def pair_terms(kernel_id: ti.template(), pos: ti.template(), mass: ti.template(),
               rho: ti.template(), kind: ti.template(), src_kinds, adaptive: ti.template(),
               hs: ti.template(), H, i, j):
    """(x, r, W, F, Lw, m, V) of pair (i, j): x = x_j - x_i, r = |x|, the kernel's
    W, W'(r)/r and Laplacian at r, m = m_j and V = m_j / rho_j, both zero when
    j's kind is not in the bit mask ``src_kinds``: every coefficient is
    proportional to m_j, so masked neighbours simply drop out of every sum."""
    m = 0.0
    if (src_kinds >> kind[j]) & 1:
        m = mass[j]
    x = pos[j] - pos[i]
    r = x.norm()
    W, F, Lw = kernel_terms(kernel_id, r, pair_support(adaptive, hs, i, j, H))
    return x, r, W, F, Lw, m, m / rho[j]


@ti.func
def beyond_wall(kind: ti.template(), normal: ti.template(), i, x):
    """Whether the neighbour at offset ``x = x_j - x_i`` lies beyond the
    tangent line of boundary row i's wall (``normal_i . x > 0``): such a
    neighbour is left out of the row's fitted and corrected gradients, its
    Neumann row, which then reads the solution on its own side of the wall
    only.  Near a re-entrant corner (and along a wall curving away from the
    fluid) the line runs on through the fluid, and a fit over both sides of
    it reaches around the corner, where the solution is singular: such rows
    lose their one-sided sign, and the matrix gets eigenvalues of the wrong
    sign at the corners, which the multilevel cycle amplifies (a coast with
    two islands took 14/13 iterations against a box's 8/8; one-sided: 8/8;
    docs/notes/hhd.md).  False for every other row."""
    out = False
    if kind[i] == BOUNDARY:
        out = normal[i].dot(x) > WALL_SIDE_TOL * x.norm()
    return out


# ---------------------------------------------------------------------------
# the linear correction (Bonet & Lok)

@ti.func
def sym2_eig_ratio(a, b, c):
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
def add_correction(M, V, F, x):
    """One pair's share of M_i = sum_j V_j grad W_ij (x) (x_j - x_i) (x = x_j - x_i)."""
    return M + V * (-F) * x.outer_product(x)


@ti.func
def correction_matrix(kernel_id: ti.template(), i, pos: ti.template(), mass: ti.template(),
                      rho: ti.template(), offsets: ti.template(), nbrs: ti.template(), H,
                      adaptive: ti.template(), hs: ti.template(), kind: ti.template(), src_kinds,
                      normal: ti.template()):
    """M_i over the neighbours of the given kinds (not beyond a boundary row's
    wall: :func:`beyond_wall`), in a pass of its own (the fits' fallback);
    symmetric positive for these kernels."""
    M = ti.Matrix.zero(float, 2, 2)
    for k in range(offsets[i], offsets[i + 1]):
        x, _r, _W, F, _Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                              adaptive, hs, H, i, nbrs[k])
        if not beyond_wall(kind, normal, i, x):
            M = add_correction(M, V, F, x)
    return M


@ti.func
def linear_correction(M):
    """(M^-1, ok): ok is False (and the inverse the identity) when M is singular."""
    L = ti.Matrix.identity(float, 2)
    ok = True
    if sym2_eig_ratio(M[0, 0], M[0, 1], M[1, 1]) < SINGULAR_RATIO:
        ok = False
    else:
        L = M.inverse()
    return L, ok


# ---------------------------------------------------------------------------
# the least-squares fits (moving least squares of order 2 and 3)

def n_monomials(order) -> int:
    return 5 if order == 2 else 9


@ti.func
def monomials(order: ti.template(), u):
    """(x, y, x^2, xy, y^2) of u, and for order 3 the cubics after them."""
    if ti.static(order == 2):
        return ti.Vector([u[0], u[1], u[0] * u[0], u[0] * u[1], u[1] * u[1]])
    else:
        return ti.Vector([u[0], u[1], u[0] * u[0], u[0] * u[1], u[1] * u[1],
                          u[0] * u[0] * u[0], u[0] * u[0] * u[1], u[0] * u[1] * u[1],
                          u[1] * u[1] * u[1]])


#: the exponents (of x, of y) of the monomials of ``monomials``, in order
MONOMIAL_EXPONENTS = ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))


@ti.func
def fit_moments_zero(order: ti.template()):
    """The moment sums of a fit of ``order``: S[a, b] = sum_j V_j W_ij u^a v^b."""
    return ti.Matrix.zero(float, 2 * order + 1, 2 * order + 1)


@ti.func
def add_fit_moments(order: ti.template(), S, c, u):
    """One pair's share of the moments S[a, b] += c u^a v^b, 2 <= a + b <= 2 order
    (c = V_j W_ij, (u, v) = x_ji / H_i): the fit's moment matrix has an entry per
    pair of monomials, but each entry is the moment of their summed exponents, so
    25 sums per pair make the cubic fit's 45 (12 the quadratic's 15)."""
    D = ti.static(2 * order + 1)                 # exponents 0 .. 2 * order
    pu = ti.Vector.zero(float, D)                # c u^a
    pv = ti.Vector.zero(float, D)                # v^b
    pu[0] = c
    pv[0] = 1.0
    for e in ti.static(range(1, D)):
        pu[e] = pu[e - 1] * u[0]
        pv[e] = pv[e - 1] * u[1]
    for a in ti.static(range(D)):
        for b in ti.static(range(D - a)):
            if ti.static(a + b >= 2):
                S[a, b] += pu[a] * pv[b]
    return S


@ti.func
def fit_moments(order: ti.template(), kernel_id: ti.template(), i, pos: ti.template(),
                mass: ti.template(), rho: ti.template(), offsets: ti.template(),
                nbrs: ti.template(), H, adaptive: ti.template(), hs: ti.template(),
                kind: ti.template(), src_kinds, normal: ti.template()):
    """The moments of a fit of ``order`` of row i over the sources ``src_kinds``
    (not beyond a boundary row's wall: :func:`beyond_wall`), in a pass of its own."""
    S = fit_moments_zero(order)
    Hi = pair_support(adaptive, hs, i, i, H)      # the monomials' length scale
    for k in range(offsets[i], offsets[i + 1]):
        x, _r, W, _F, _Lw, _m, V = pair_terms(kernel_id, pos, mass, rho, kind, src_kinds,
                                              adaptive, hs, H, i, nbrs[k])
        if not beyond_wall(kind, normal, i, x):
            u = x / Hi
            S = add_fit_moments(order, S, V * W, u)
    return S


@ti.func
def moment_matrix(order: ti.template(), S):
    """The lower half of M = sum_j V_j W_ij p_j p_j^T (p the monomials of
    ``order``) from the moments S (of this order or higher): all the factor reads."""
    m = ti.static(n_monomials(order))
    M = ti.Matrix.zero(float, m, m)
    for r in ti.static(range(m)):
        for c in ti.static(range(r + 1)):
            ar, br = ti.static(MONOMIAL_EXPONENTS[r])
            ac, bc = ti.static(MONOMIAL_EXPONENTS[c])
            M[r, c] = S[ar + ac, br + bc]
    return M


@ti.func
def cholesky_factor(order: ti.template(), M):
    """(L, ok): the Cholesky factor of the moment matrix M (monomials of ``order``);
    ok is False when a pivot falls below SINGULAR_RATIO of the diagonal scale
    (too few neighbours, or all on one conic)."""
    m = ti.static(n_monomials(order))
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
def cholesky_solve(order: ti.template(), Lf, rhs):
    m = ti.static(n_monomials(order))
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
def gradient_rows(order: ti.template(), Lf):
    """Rows 0-1 of M^-1 (M = Lf Lf^T symmetric: the solutions of M z = e_0, e_1),
    the fitted gradient's weights per monomial: one solve per particle, so that
    each pair's coefficient is two dot products."""
    m = ti.static(n_monomials(order))
    e0 = ti.Vector.zero(float, m)
    e1 = ti.Vector.zero(float, m)
    e0[0] = 1.0
    e1[1] = 1.0
    z0 = cholesky_solve(order, Lf, e0)
    z1 = cholesky_solve(order, Lf, e1)
    R = ti.Matrix.zero(float, 2, m)
    for a in ti.static(range(m)):
        R[0, a] = z0[a]
        R[1, a] = z1[a]
    return R


@ti.func
def gradient_fit(order: ti.template(), S, Hi, kernel_id: ti.template(), i, pos: ti.template(),
                 mass: ti.template(), rho: ti.template(), offsets: ti.template(),
                 nbrs: ti.template(), H, adaptive: ti.template(), hs: ti.template(),
                 kind: ti.template(), src_kinds, normal: ti.template()):
    """The fitted gradient of row i from its moments S: ``(R, L, linear, ok)``.

    R: the weights per monomial of ``order`` (rows 0-1 of M^-1, scaled by
    1 / H_i).  A cubic fit the neighbours do not determine falls back to the
    quadratic one (R's leading columns, the cubic ones zero: one product per
    pair, no branch), a quadratic one to the linearly corrected gradient
    (``linear`` 1, ``L`` = M_i^-1); ok is False only when that is singular too.
    A fallback sums what it needs over the sources ``src_kinds`` in a pass of
    its own (:func:`fit_moments`, :func:`correction_matrix`): the few rows
    that need it pay for it, and each fit's sums keep one order whichever
    kernel asks (the compiler may vectorise a pass's sums differently)."""
    L = ti.Matrix.identity(float, 2)
    linear = 0
    ok = True
    fitted = 0
    Lc = ti.Matrix.identity(float, ti.static(n_monomials(order)))
    if ti.static(order == 3):
        ok3 = True
        Lc, ok3 = cholesky_factor(3, moment_matrix(3, S))
        fitted = ti.select(ok3, 1, 0)
    Lq = ti.Matrix.identity(float, 5)
    if fitted == 0:
        Mq = ti.Matrix.zero(float, 5, 5)
        if ti.static(order == 3):
            Mq = moment_matrix(2, fit_moments(2, kernel_id, i, pos, mass, rho, offsets, nbrs, H,
                                              adaptive, hs, kind, src_kinds, normal))
        else:
            Mq = moment_matrix(2, S)
        ok2 = True
        Lq, ok2 = cholesky_factor(2, Mq)
        if not ok2:
            # too few neighbours for a quadratic fit (e.g. a corner): the
            # linearly corrected gradient, and only if that is singular too is
            # the set refused
            L, ok = linear_correction(correction_matrix(kernel_id, i, pos, mass, rho, offsets,
                                                        nbrs, H, adaptive, hs, kind, src_kinds,
                                                        normal))
            # (linear only where L exists: the kernels bit for bit as before
            # the pieces were shared; the compiler's code differs otherwise)
            linear = ti.select(ok, 1, 0)
    R = ti.Matrix.zero(float, 2, ti.static(n_monomials(order)))
    if fitted:
        if ti.static(order == 3):
            R = gradient_rows(3, Lc) / Hi
    elif not linear:
        R2 = gradient_rows(2, Lq) / Hi
        for a in ti.static(range(2)):
            for b in ti.static(range(5)):
                R[a, b] = R2[a, b]
    return R, L, linear, ok


@ti.func
def corrected_gradient_coefficient(L, V, F, xij):
    """G_ij = V_j L_i grad W_ij of the linearly corrected gradient (L_i = M_i^-1,
    grad_i W_ij = F x_ij, x_ij = x_i - x_j)."""
    return V * (L @ (F * xij))


@ti.func
def fitted_gradient_coefficient(order: ti.template(), R, L, linear, mj, rho_j, W, F, xij, Hi):
    """G_ij of a fit from :func:`gradient_fit`: V_j W_ij (R p_j), p_j the monomials
    of ``order`` of x_ji / H_i, or for the linear fallback the corrected gradient's.
    (V_j = m_j / rho_j computed in each branch, as in the kernels before the fits
    were shared: hoisting it changes the compiler's fast-math rewrites in the
    last bit.)"""
    coef = ti.Vector.zero(float, 2)
    if linear:
        coef = corrected_gradient_coefficient(L, mj / rho_j, F, xij)
    else:
        u = -xij / Hi
        c = (mj / rho_j) * W
        coef = c * (R @ monomials(order, u))
    return coef


# ---------------------------------------------------------------------------
# the renormalised Laplacian

@ti.func
def laplacian_moments_zero():
    """(M, u, P, Q): the renormalised Laplacian's sums (:func:`add_laplacian_moments`)."""
    return (ti.Matrix.zero(float, 2, 2), ti.Matrix.zero(float, 3, 2),
            ti.Matrix.zero(float, 3, 3), ti.Matrix.zero(float, 2, 3))


@ti.func
def add_laplacian_moments(M, u, P, Q, x, r, V, F):
    """One pair's share of the corrected Laplacian's sums (x = x_j - x_i,
    r = |x|, V = m_j / rho_j, F = W'(r) / r): M = sum V grad W (x) x, u rows
    sum V q_k grad W, P rows sum w q_k (exx, eyy, exy), Q rows sum w x_a (exx,
    eyy, exy), with q = (x^2, y^2, xy) and w = -2 V F."""
    gw = -F * x                      # grad_i W_ij = F x_ij = -F x_ji
    M += V * gw.outer_product(x)
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
    return M, u, P, Q


@ti.func
def laplacian_correction(M, u, P, Q):
    """(beta, B, ok) of the renormalised Laplacian from its sums: B = (Bxx, Byy,
    Bxy) makes the stencil exact on x^2, y^2, xy; sigma = sum_j a_ij x_ji is
    linear in B, Q (Bxx, Byy, 2 Bxy), and beta = M^-T sigma folds the gradient
    term into the pair coefficients (:func:`corrected_laplacian_coefficient`).
    ok is False when M or the 3 x 3 system is singular."""
    Bxx = 1.0
    Byy = 1.0
    Bxy = 0.0
    Linv, ok = linear_correction(M)
    if ok:
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
    beta = Linv.transpose() @ (Q @ ti.Vector([Bxx, Byy, 2.0 * Bxy]))
    return beta, ti.Vector([Bxx, Byy, Bxy]), ok


@ti.func
def corrected_laplacian_coefficient(beta, B, x, r, V, F):
    """C_ij = a_ij - V_j beta . grad W_ij of the renormalised Laplacian."""
    e = x / r
    return V * F * (beta.dot(x) - 2.0 * (B[0] * e[0] * e[0] + B[1] * e[1] * e[1]
                                         + 2.0 * B[2] * e[0] * e[1]))
