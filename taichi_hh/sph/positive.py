"""Positive Laplacian rows where the corrected Laplacian loses its sign.

The corrected Laplacian (:mod:`taichi_hh.sph.operators`) is exact on
quadratics, and on most particles its row is positive: every pair
coefficient ``C_ij >= 0``, an M-matrix row that Jacobi smoothing and the
multilevel cycle handle well.  Where a particle's neighbourhood is lopsided
(uniformly random points, a data point a fraction of a spacing from the
boundary samples) the quadratic correction can give large negative
coefficients, or even a diagonal ``-sum_j C_ij`` of the wrong sign.  Such
rows are a few per thousand, mostly within a support of the boundary, but
they leave the preconditioned system a few outlying eigenvalues whose number
grows with the boundary's length: on uniformly random points BiCGSTAB's
residual then stalls at 1e-5..1e-4 for ten or more iterations (50k points:
20/18 iterations against 12/10 with those rows made positive;
docs/notes/scattered.md).

:func:`make_rows_positive` replaces each such row by the positive stencil
that is exact on quadratics and closest to the kernel's own positive
weights ``b_j = -2 V_j W'(r_ij) / r_ij`` (Brookshaw's) in relative entropy:

    minimise  sum_j w_j log(w_j / b_j) - w_j
    subject to  sum_j w_j d_j = 0,  sum_j w_j d_j d_j^T = 2 I,   d_j = x_j - x_i,

so that ``sum_j w_j (f_j - f_i) = lap f`` for every quadratic ``f`` and
``w_j > 0`` (the minimum-entropy construction of positive meshless
stencils, in the manner of Arroyo & Ortiz's local maximum-entropy
approximants; Seibold 2008 builds minimal positive stencils by linear
programming).  The solution is ``w_j = b_j exp(lambda . g_j)`` with
``g_j = (d, d d^T)`` (five monomials); ``lambda`` solves the convex dual by
Newton's method, batched over the rows.

**The wall.** Most flagged rows belong to data points a few hundredths to a
few tenths of a spacing from the boundary, with every neighbour but the
boundary samples on one side; about half of them admit no positive stencil
exact on quadratics from their pairs alone.  The boundary condition supplies
what the missing side would: on the wall point ``p = x_i + delta n`` closest
to the particle (outward normal ``n``), the solution meets the boundary
rows' homogeneous condition, so the row may be exact on quadratics *up to*
a multiple of it:

* Neumann (``d phi/dn = 0``): ``sum_j w_j (f_j - f_i) + c n . grad f(p) = lap f``
  with ``c`` of free sign; ``n . grad f(p) = 0`` for the solution, so the
  matrix row is the positive ``w`` alone and the right-hand side is
  unchanged (the wall term's moments are ``(n, 2 delta n n^T)``; in 1D it is
  the classic ``f'' = (f(x+h) - f(x) - h f'(0)) / (h delta + h^2 / 2)``);
* Dirichlet (``phi = 0``): ``p`` as one more neighbour of known value 0
  (a Shortley-Weller-like point), whose weight goes to the diagonal.

With the wall, every flagged row of the default's Neumann problem on
uniformly random points has a positive stencil (13k-200k points), and the
iterations stop growing with N: 9/10 at 13k, 11/10 at 50k, 13/10 at 200k
(docs/notes/scattered.md).  Rows that still admit none (near a corner,
where no single wall's condition applies) keep their corrected
coefficients and are counted.  Relaxing such rows to stencils exact only on
linear fields and on ``|x|^2`` instead made a spurious vortex at a point
0.0004 from the wall under the normal-parallel condition: every row stays
exact on quadratics.
"""

import numpy as np
import taichi as ti

from .. import runtime
from .kernels import kernel_terms
from .support import pair_support

#: Newton iterations of the dual problem at most (a feasible row converges in
#: 5-15; at 200k random points 15 reach 283 rows of 530, 60 reach 284), and
#: step halvings of its line search
MAX_NEWTON = 15
MAX_HALVINGS = 30
#: converged: the moment conditions' residual below this (scaled units: the
#: second moments are 2)
NEWTON_TOL = 1e-11


@ti.kernel
def _row_ratio(n: ti.i32, offsets: ti.types.ndarray(), C: ti.types.ndarray(),
               kind: ti.types.ndarray(), row_kind: ti.i32, ratio: ti.types.ndarray()):
    """ratio_i = sum_j |C_ij| / sum_j C_ij on rows of kind ``row_kind`` (1 on a
    positive row; infinite where the diagonal -sum_j C_ij is not negative),
    0 on other rows."""
    for i in range(n):
        out = 0.0
        if kind[i] == row_kind:
            total = 0.0
            size = 0.0
            for k in range(offsets[i], offsets[i + 1]):
                total += C[k]
                size += ti.abs(C[k])
            out = ti.math.inf
            if total > 0.0:
                out = size / total
        ratio[i] = out


@ti.kernel
def _gather_rows(kernel_id: ti.template(), rows: ti.types.ndarray(), m: ti.i32,
                 offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                 position: ti.types.ndarray(), volume: ti.types.ndarray(), H: float,
                 adaptive: ti.template(), hs: ti.types.ndarray(), scale: ti.types.ndarray(),
                 g: ti.types.ndarray(), prior: ti.types.ndarray()):
    """For row r = rows[q]: its pairs' monomials g (offsets d / h, h = the row's
    own support) and the kernel weights -2 V_j W'/r (0 on padding)."""
    for q in range(rows.shape[0]):
        i = rows[q]
        h = pair_support(adaptive, hs, i, i, H)
        scale[q] = h
        for a in range(m):
            prior[q, a] = 0.0
            for c in ti.static(range(5)):
                g[q, a, c] = 0.0
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            a = k - offsets[i]
            d = position[j] - position[i]
            r = d.norm()
            _W, F, _L = kernel_terms(kernel_id, r, pair_support(adaptive, hs, i, j, H))
            x = d[0] / h
            y = d[1] / h
            g[q, a, 0] = x
            g[q, a, 1] = y
            g[q, a, 2] = x * x
            g[q, a, 3] = x * y
            g[q, a, 4] = y * y
            prior[q, a] = -2.0 * volume[j] * F


@ti.kernel
def _scatter_rows(rows: ti.types.ndarray(), ok: ti.types.ndarray(), offsets: ti.types.ndarray(),
                  scale: ti.types.ndarray(), w: ti.types.ndarray(), self_weight: ti.types.ndarray(),
                  C: ti.types.ndarray(), s: ti.types.ndarray()):
    for q in range(rows.shape[0]):
        if ok[q]:
            i = rows[q]
            h2 = scale[q] * scale[q]
            for k in range(offsets[i], offsets[i + 1]):
                C[k] = w[q, k - offsets[i]] / h2
            s[i] = -self_weight[q] / h2


def positive_quadratic_weights(g: np.ndarray, prior: np.ndarray, target=None, free=None):
    """The minimum-relative-entropy positive weights exact on quadratics.

    g: ``(R, m, 5)`` monomials ``(x, y, x^2, xy, y^2)`` of each row's pair
    offsets in units of a length ``h`` (zero rows for padding); prior: ``(R, m)``
    positive weights (0 on padding); target: the moments (default the five of
    every quadratic, ``(0, 0, 2, 0, 2)``; g's columns must match it); free:
    optional ``(R, 5)`` moments of a term of free sign and size (a zero row:
    none), so that ``sum_j w_j g_j + c free = target`` for some ``c`` (the
    wall's flux term of :func:`make_rows_positive`).  Returns ``(w, ok)``:
    ``w`` (R, m) meeting the moments on the rows where ``ok`` (Newton
    converged: the row's pairs admit such a positive stencil), in units of
    ``h^-2``; on a row with a free term ``c = (target - sum_j w_j g_j) . free
    / |free|^2``.
    """
    target = np.array([0.0, 0.0, 2.0, 0.0, 2.0]) if target is None else np.asarray(target, float)
    ncol = target.size
    prior = np.asarray(prior, dtype=np.float64)
    # scale the prior so that it already meets the trace condition (sum w |d|^2 = 4)
    trace = (prior * (g[..., 0] ** 2 + g[..., 1] ** 2)).sum(axis=1)
    b = prior * np.where(trace > 0, 4.0 / np.where(trace > 0, trace, 1.0), 0.0)[:, None]
    lam = np.zeros((g.shape[0], ncol))
    # a free term c restricts the dual to lambda . free = 0 (c is its multiplier):
    # Newton steps are projected onto that plane, and so is the gradient
    if free is None:
        free = np.zeros((g.shape[0], ncol))
    free = np.asarray(free, dtype=np.float64)
    norm2 = (free * free).sum(axis=1)
    unit = free / np.sqrt(np.where(norm2 > 0, norm2, 1.0))[:, None]
    proj = np.eye(ncol)[None] - unit[:, :, None] * unit[:, None, :]

    def dual(lam_, rows):
        e = (g[rows] * lam_[:, None, :]).sum(axis=2)
        w_ = b[rows] * np.exp(np.minimum(e, 600.0))
        return w_, w_.sum(axis=1) - lam_ @ target

    def projected_gradient(w_):
        grad_ = np.matmul(w_[:, None, :], g)[:, 0] - target
        return np.matmul(proj, grad_[..., None])[..., 0]

    w, f = dual(lam, slice(None))
    stalled = np.zeros(g.shape[0], dtype=bool)
    eye = np.eye(ncol) * 1e-13
    for _ in range(MAX_NEWTON):
        grad = projected_gradient(w)
        active = (np.abs(grad).max(axis=1) > NEWTON_TOL) & ~stalled
        if not active.any():
            break
        idx = np.flatnonzero(active)
        ga, wa = g[idx], w[idx]
        hess = np.matmul((ga * wa[..., None]).transpose(0, 2, 1), ga)
        # weights overflowing or vanishing: the moments are out of reach (the
        # dual is unbounded below); those rows stop, unconverged
        scale = np.trace(hess, axis1=1, axis2=2)
        sound = np.isfinite(scale) & (scale > 1e-200)
        stalled[idx[~sound]] = True
        idx, hess = idx[sound], hess[sound]
        if idx.size == 0:
            break
        # Newton on the plane: P H P + (I - P) is regular where H is
        P = proj[idx]
        hess = np.matmul(np.matmul(P, hess), P) + (np.eye(ncol)[None] - P) * scale[sound][:, None, None]
        hess += eye * scale[sound][:, None, None]
        step = -np.linalg.solve(hess, grad[idx][..., None])[..., 0]
        slope = (grad[idx] * step).sum(axis=1)
        # backtracking on the rows whose step is not yet accepted
        todo = np.arange(idx.size)
        alpha = 1.0
        for _ls in range(MAX_HALVINGS):
            rows = idx[todo]
            trial = lam[rows] + alpha * step[todo]
            wt, ft = dual(trial, rows)
            # Armijo's test, with room for round-off near the minimum
            good = ft <= f[rows] + 1e-4 * alpha * slope[todo] + 1e-13 * np.abs(f[rows])
            sel = rows[good]
            lam[sel], w[sel], f[sel] = trial[good], wt[good], ft[good]
            todo = todo[~good]
            if todo.size == 0:
                break
            alpha *= 0.5
        # no decrease along the Newton direction: the dual is unbounded below
        # there (no positive stencil meets the moments) or flat to round-off
        stalled[idx[todo]] = True
    grad = projected_gradient(w)
    ok = np.isfinite(w).all(axis=1) & (np.abs(grad).max(axis=1) <= 1e3 * NEWTON_TOL)
    return w, ok


#: the wall conditions :func:`make_rows_positive` knows: the boundary rows'
#: homogeneous Neumann (d phi/dn = 0) or Dirichlet (phi = 0) condition
WALL_CONDITIONS = ("neumann", "dirichlet")


def wall_moments(offset: np.ndarray, normal: np.ndarray, condition: str) -> np.ndarray:
    """The five moments of the wall's term in a row (module doc), for a wall
    point at ``offset`` (R, 2; units of the row's length h) from the row's
    particle with outward unit ``normal`` (R, 2).  Neumann: ``n . grad f`` at
    the wall point, ``(n, 2 (e . n) n n^T)`` with the symmetric part's three
    entries; Dirichlet: the point's own monomials ``(e, e e^T)``."""
    e, n = np.asarray(offset, float), np.asarray(normal, float)
    if condition == "neumann":
        en = (e * n).sum(axis=1)
        return np.c_[n, 2 * en * n[:, 0] ** 2, 2 * en * n[:, 0] * n[:, 1], 2 * en * n[:, 1] ** 2]
    if condition == "dirichlet":
        return np.c_[e, e[:, 0] ** 2, e[:, 0] * e[:, 1], e[:, 1] ** 2]
    raise ValueError(f"wall condition must be one of {WALL_CONDITIONS}, got {condition!r}")


def make_rows_positive(ops, stencil, threshold: float, row_kind: int, wall=None) -> dict:
    """Replace, in place, the rows of Laplacian ``stencil`` (a difference form
    exact on quadratics, e.g. the corrected Laplacian) of particles of kind
    ``row_kind`` whose ``sum_j |C_ij| > threshold * sum_j C_ij`` (or whose
    diagonal is not negative) by the positive stencil exact on quadratics
    (module doc).

    wall: optional ``(closest, condition)``: ``closest(points)`` gives, for
    (R, 2) positions, the distance (R,) to the boundary and the outward unit
    normal (R, 2) there (NaN where no single wall applies, e.g. at a corner);
    ``condition`` one of :data:`WALL_CONDITIONS`, the homogeneous condition the
    solution meets on that wall.  A flagged row whose wall lies within its
    support may then use it (module doc).

    Returns counts: ``{"flagged", "replaced", "kept", "wall"}`` (kept: no
    positive quadratic stencil exists on that row's pairs; wall: replaced rows
    with a wall term)."""
    p, pr = ops.particles, ops.pairs
    n = p.n
    counts = {"flagged": 0, "replaced": 0, "kept": 0, "wall": 0}
    if n == 0 or pr.n_pairs == 0:
        return counts
    real = runtime.real_dtype()
    ratio = runtime.array(real, n)
    _row_ratio(n, pr.offsets, stencil.C, p.kind, int(row_kind), ratio)
    rows = np.flatnonzero(ratio.to_numpy() > threshold).astype(np.int32)
    if rows.size == 0:
        return counts
    off = pr.offsets.to_numpy()
    m = int((off[rows + 1] - off[rows]).max())
    rows_nd = runtime.array(ti.i32, rows.size)
    rows_nd.from_numpy(rows)
    scale = runtime.array(real, rows.size)
    g = runtime.array(real, (rows.size, m, 5))
    prior = runtime.array(real, (rows.size, m))
    H, adaptive, hs = ops.support_args()
    _gather_rows(ops.kernel_id, rows_nd, m, pr.offsets, pr.neighbours, p.position, p.volume,
                 H, adaptive, hs, scale, g, prior)
    g = g.to_numpy().astype(np.float64)
    prior = prior.to_numpy().astype(np.float64)
    h = scale.to_numpy().astype(np.float64)
    free = None
    has_wall = np.zeros(rows.size, dtype=bool)
    if wall is not None:
        closest, condition = wall
        distance, normal = closest(p.position.to_numpy()[rows].astype(np.float64))
        has_wall = np.isfinite(distance) & np.isfinite(normal).all(axis=1) & (distance < h)
        normal_or_0 = np.where(has_wall[:, None], np.nan_to_num(normal), 0.0)
        distance_or_0 = np.where(has_wall, np.nan_to_num(distance), 0.0)
        offset = distance_or_0[:, None] * normal_or_0 / h[:, None]
        moments = np.where(has_wall[:, None], wall_moments(offset, normal_or_0, condition), 0.0)
        if condition == "neumann":
            free = moments
        else:
            # the wall point as one more neighbour of known value 0: its weight
            # goes to the diagonal only.  Its prior balances the others' first
            # moment along the normal, as Shortley-Weller's weight does (of
            # order 1 / delta: within the exponential family of the weights
            # no finite multiplier reaches it from a prior of order one)
            along = -(prior * (g[..., 0] * normal_or_0[:, None, 0]
                               + g[..., 1] * normal_or_0[:, None, 1])).sum(axis=1)
            depth = np.maximum(distance_or_0 / h, 1e-6)
            wall_prior = np.maximum(prior.max(axis=1), along / depth)
            g = np.concatenate([g, moments[:, None, :]], axis=1)
            prior = np.concatenate([prior, np.where(has_wall, wall_prior, 0.0)[:, None]], axis=1)
    w, ok = positive_quadratic_weights(g, prior, free=free)
    self_weight = w[:, m] if w.shape[1] > m else np.zeros(rows.size)
    w_nd = runtime.array(real, (rows.size, m))
    w_nd.from_numpy(np.where(np.isfinite(w[:, :m]), w[:, :m], 0.0).astype(runtime.np_real()))
    self_nd = runtime.array(real, rows.size)
    self_nd.from_numpy(np.where(np.isfinite(self_weight), self_weight, 0.0).astype(runtime.np_real()))
    ok_nd = runtime.array(ti.i32, rows.size)
    ok_nd.from_numpy(ok.astype(np.int32))
    _scatter_rows(rows_nd, ok_nd, pr.offsets, scale, w_nd, self_nd, stencil.C, stencil.s)
    return {"flagged": int(rows.size), "replaced": int(ok.sum()), "kept": int((~ok).sum()),
            "wall": int((ok & has_wall).sum())}
