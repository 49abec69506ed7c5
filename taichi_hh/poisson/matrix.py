"""The SPH Poisson problem ``L phi = b`` with Neumann boundaries, as one
assembled, matrix-free row system.

Every particle owns one row, chosen by its kind (``particles.kind``):

``FLUID``     Laplacian row (any variant of :mod:`taichi_hh.sph.operators`) plus the
              ridge term ``kappa`` (Petronetto Sec. 6a: ``(L + kappa I) phi = b``),
              plus, for Petronetto's boundary treatment, ``-n . grad phi`` on the
              particles within ``sqrt(m/rho)/pi`` of the boundary (Sec. 4: the
              Neumann term moved to the left-hand side, ``near_weight = -1``).
``BOUNDARY``  Neumann row ``n_i . grad phi_i = g_i`` with the particle's normal
              (Colin Eqs. 35-37; ``g = 0`` for the homogeneous condition), or with
              ``dirichlet=True`` the Dirichlet row ``phi_i = g_i``.
``GHOST``     Shepard row ``phi_g - sum_k S_gk phi_k = 0`` over the fluid
              neighbours ``k`` of a fake particle, ``S_gk = V_k W_gk / sum V W``
              (Petronetto Sec. 5b: the fake particle's potential replaced by the
              Shepard sum of real unknowns, Eq. 14).  Keeping it as a row instead
              of substituting it leaves the same solution and a one-ring stencil.

The rows are assembled once into pair coefficients ``K`` and a diagonal ``D``:
``(A x)_i = D_i x_i + sum_k K_k x_{j(k)}``, so each apply is an SpMV-like
gather.  The transpose (for CG on the normal equations, Colin Sec. 3.5) is a
gather too: the neighbour relation is symmetric, and ``reverse[k]`` indexes
pair (j, i) for pair k = (i, j).
"""
from functools import lru_cache
from typing import NamedTuple

import numpy as np
import taichi as ti

from .. import runtime

from ..linalg import krylov as solvers
from ..linalg import lanes as lanes_mod
from ..linalg.columns import columns_of, zeros
from ..errors import InputError, NeighbourError, SolverError
from ..sph.operators import GradientStencil, LaplacianStencil, shepard_sums, shepard_weight
from ..sph.particles import BOUNDARY, FLUID
from ..sph.support import pair_support


@ti.kernel
def _assemble(kernel_id: ti.template(), n: ti.i32, offsets: ti.types.ndarray(),
              nbrs: ti.types.ndarray(), pos: ti.types.ndarray(), vol: ti.types.ndarray(),
              kind: ti.types.ndarray(), normal: ti.types.ndarray(), near: ti.types.ndarray(),
              C: ti.types.ndarray(), sC: ti.types.ndarray(), G: ti.types.ndarray(),
              sG: ti.types.ndarray(), kappa: float, H: float, adaptive: ti.template(),
              hs: ti.types.ndarray(), K: ti.types.ndarray(), D: ti.types.ndarray(), orphan: ti.types.ndarray()):
    for i in range(n):
        ki = kind[i]
        if ki == FLUID:
            nb = near[i] * normal[i]
            d = sC[i] + nb.dot(sG[i]) + kappa
            for k in range(offsets[i], offsets[i + 1]):
                c = C[k] + nb.dot(G[k])
                K[k] = c
                d -= c
            D[i] = d
        elif ki == BOUNDARY:
            nrm = normal[i]
            d = nrm.dot(sG[i])
            for k in range(offsets[i], offsets[i + 1]):
                c = nrm.dot(G[k])
                K[k] = c
                d -= c
            D[i] = d
        else:
            # the Shepard row (Petronetto Eq. 14): phi_g - sum_k S_gk phi_k = 0
            _num, den = shepard_sums(kernel_id, i, offsets, nbrs, pos, vol, kind, H, adaptive, hs,
                                     1 << FLUID, vol, 0.0, 0.0)
            if den <= 0.0:
                ti.atomic_max(orphan[0], i)
                den = 1.0
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                c = 0.0
                if kind[j] == FLUID:
                    c = -shepard_weight(kernel_id, pos, vol, i, j,
                                        pair_support(adaptive, hs, i, j, H)) / den
                K[k] = c
            D[i] = 1.0


@ti.func
def _apply_row(i, cols: ti.template(), n, offsets: ti.template(), nbrs: ti.template(),
               K: ti.template(), D: ti.template(), x: ti.template(), y: ti.template(),
               bordered, e: ti.template(), w: ti.template(), a: ti.template()):
    """Row i of y = A x (bordered: + e_i x[n]); returns its terms of <a, y>,
    <y, y> and the border row's w . x, packed (:func:`~taichi_hh.linalg.lanes.pack3`)."""
    xi = x[i]
    acc = D[i] * xi
    for k in range(offsets[i], offsets[i + 1]):
        acc += K[k] * x[nbrs[k]]
    wx = zeros(cols)
    if bordered:
        acc += e[i] * x[n]
        wx = w[i] * xi
    y[i] = acc
    return lanes_mod.pack3(cols, a[i] * acc, acc * acc, wx)


@ti.func
def _apply_rows_body(cols: ti.template(), lanes: ti.template(), n, offsets: ti.template(),
                     nbrs: ti.template(), K: ti.template(), D: ti.template(),
                     x: ti.template(), y: ti.template(), bordered, e: ti.template(),
                     w: ti.template(), c, a: ti.template(), part: ti.template()):
    """y = A x; bordered: y[:n] += e x[n], y[n] = w . x[:n] + c x[n].  Returns
    (<a, y>, <y, y>), reduced in the same loop (BiCGSTAB's dot products
    without another pass over y); per column when x holds several.  On a GPU
    (``lanes``) the sums go through ``part`` (:mod:`taichi_hh.linalg.lanes`)."""
    total = lanes_mod.fold_entries(n, _apply_row, (cols, n, offsets, nbrs, K, D, x, y, bordered,
                                                   e, w, a), 3, cols, lanes_mod.ADD, lanes, False,
                                   part)
    ay = lanes_mod.unpack(cols, total, 0)
    yy = lanes_mod.unpack(cols, total, 1)
    border = lanes_mod.unpack(cols, total, 2)
    if bordered:
        yn = border + c * x[n]
        y[n] = yn
        ay += a[n] * yn
        yy += yn * yn
    return ay, yy


@lru_cache(maxsize=None)
def _apply_rows_kernel(precision: str, cols: int, lanes: bool):
    """:func:`_apply_rows_body` on ``cols`` columns, for the runtime's precision:
    a kernel's return type is fixed when it is defined (a vector type made
    before ``ti.init`` would be f32 whatever the precision), so one kernel per
    column count and real type, made on first use."""
    real = ti.f64 if precision == "f64" else ti.f32
    dots = real if cols == 1 else ti.types.vector(cols, real)

    @ti.kernel
    def apply_rows(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                   K: ti.types.ndarray(), D: ti.types.ndarray(), x: ti.types.ndarray(),
                   y: ti.types.ndarray(), bordered: ti.i32, e: ti.types.ndarray(),
                   w: ti.types.ndarray(), c: real, a: ti.types.ndarray(),
                   part: ti.types.ndarray()) -> (dots, dots):
        return _apply_rows_body(cols, lanes, n, offsets, nbrs, K, D, x, y, bordered, e, w, c,
                                a, part)

    return apply_rows


@ti.kernel
def _apply_rows_transpose(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                          reverse: ti.types.ndarray(), K: ti.types.ndarray(),
                          D: ti.types.ndarray(), x: ti.types.ndarray(), y: ti.types.ndarray(),
                          bordered: ti.i32, e: ti.types.ndarray(), w: ti.types.ndarray(),
                          c: float):
    lam = 0.0
    if bordered:
        lam = x[n]
    border = 0.0
    for i in range(n):
        xi = x[i]
        acc = D[i] * xi
        for k in range(offsets[i], offsets[i + 1]):
            acc += K[reverse[k]] * x[nbrs[k]]
        if bordered:
            acc += w[i] * lam
            border += e[i] * xi
        y[i] = acc
    if bordered:
        y[n] = border + c * lam


@ti.kernel
def _column_sq_norms(n: ti.i32, offsets: ti.types.ndarray(), reverse: ti.types.ndarray(),
                     K: ti.types.ndarray(), D: ti.types.ndarray(), out: ti.types.ndarray(),
                     bordered: ti.i32, e: ti.types.ndarray(), w: ti.types.ndarray(), c: float):
    border = 0.0
    for i in range(n):
        acc = D[i] * D[i]
        for k in range(offsets[i], offsets[i + 1]):
            v = K[reverse[k]]
            acc += v * v
        if bordered:
            acc += w[i] * w[i]
            border += e[i] * e[i]
        out[i] = acc
    if bordered:
        out[n] = border + c * c


@ti.kernel
def _copy_diagonal(n: ti.i32, D: ti.types.ndarray(), out: ti.types.ndarray(), bordered: ti.i32,
                   c: float):
    for i in range(n):
        out[i] = D[i]
    if bordered:
        out[n] = c


def _padded(values: np.ndarray, size: int) -> np.ndarray:
    """``values`` followed by zeros up to ``size`` entries."""
    out = np.zeros(size, dtype=values.dtype)
    out[: len(values)] = values
    return out


#: from this many particles on, ``preconditioner="auto"`` picks the multilevel
#: cycle: faster than Jacobi from about a thousand on (docs/notes/linalg.md)
MULTILEVEL_MIN_N = 1000


#: in single precision the residual b - A x computed in f32 stalls near
#: eps_f32 x sum_j |a_ij x_j| / |b| (measured 1.1e-4 at 3k random points, and
#: the coefficients grow as 1/spacing^2): tolerances below this are reached by
#: iterative refinement, the residual in double precision on the host
#: (:meth:`PoissonMatrix.solve_columns`)
SINGLE_PRECISION_TOL = 1e-4
#: systems of at most this many unknowns that BiCGSTAB leaves at its default
#: iteration cap or stagnating are solved by dense LU on the host instead
#: (PoissonMatrix.solve and solve_columns): 118 clustered points made the projection's Poisson
#: step take 848-900 iterations against the cap of 1000, so whether it met
#: tol depended on rounding (the units fuzz property found it)
DIRECT_MAX = 2000
#: each refinement sweep's f32 solve lowers the double-precision residual by this
REFINEMENT_STEP = 1e-3
#: sweeps before a refinement that stops gaining is given up
MAX_REFINEMENTS = 12


class PairRows(NamedTuple):
    """The rows of a :class:`PoissonMatrix` over its particles, as a
    preconditioner reads them: row ``i`` is ``diagonal[i] x_i + sum_k values[k]
    x[neighbours[k]]``, k in ``offsets[i] .. offsets[i + 1]`` (Taichi arrays;
    a border unknown is not among them).  Where the rows live: the particles'
    ``positions``, the kernel ``support`` (the largest) and per-particle
    ``supports`` (None: fixed), and ``grid``, the pair list's neighbour grid
    when the particles are sorted by its cells (else None).  ``bordered``: the
    matrix has a border unknown (its corner entry ``border_c``), which the
    preconditioner leaves to Jacobi."""
    n: int
    offsets: object
    neighbours: object
    values: object
    diagonal: object
    positions: object
    support: float
    supports: object
    grid: object
    bordered: bool
    border_c: float


class PoissonMatrix:
    """Assembled SPH Poisson rows over every particle; a solver linear operator.

    ops: :class:`~taichi_hh.sph.operators.Operators` on the particle set (with
    densities computed); boundary rows use ``particles.normal``.
    laplacian, gradient: operator variants of the fluid rows and of the Neumann
    (boundary) rows, or stencils already computed with those rows (e.g. shared
    with another use of the same coefficients; used as given).  ``gradient="quadratic"`` makes the Neumann rows exact on
    quadratics; the first-order ``corrected`` gradient errs by about support x
    curvature on a one-sided boundary neighbourhood, which then pollutes the
    whole solution.
    kappa: ridge term added to the fluid rows (Petronetto Sec. 6a).
    density_weighted: fluid rows discretise div(grad phi / rho) instead (the
    two-phase pressure equation), pair coefficients times 2 / (rho_i + rho_j).
    near: per-slot weights of the ``n . grad`` term on fluid rows (Petronetto's
    boundary treatment: -1 within sqrt(m/rho)/pi of the boundary), or None.
    bordered: for pure-Neumann problems, append one unknown ``lambda`` and one
    row: ``A phi + lambda e = b`` on the fluid rows and ``sum_i V_i phi_i + c
    lambda = 0``.  The bordered matrix is non-singular, ``lambda`` absorbs the
    discrete incompatibility of ``b`` (``e`` is 1 on fluid rows), and ``phi``
    is fixed up to nothing: gradients are unaffected, since the only freedom
    removed is the additive constant.  ``|c| = sum V`` keeps the row's scale
    (and gives it a diagonal for Jacobi).  Its sign: the fluid rows give
    ``A 1 = kappa e``, so ``(1, -kappa)`` is a null vector when ``sum V - c
    kappa = 0``.  With kappa = 0 either sign is regular and ``c = +sum V``
    takes fewer iterations; with a ridge ``c = +sum V`` is singular at
    exactly kappa = 1, so ``c = -sum V``, regular for every kappa > 0
    (docs/notes/linalg.md).
    dirichlet: boundary particles get Dirichlet rows ``phi_i = b_i`` instead of
    Neumann rows (the normal-parallel decomposition; not with ``bordered``).
    reuse: a previous matrix no longer needed (e.g. the last time step's) whose
    arrays this one overwrites when they are large enough: no new arrays.
    overwrite_laplacian: the matrix's pair values are written over the given
    Laplacian stencil's (each pair's value reads only that pair's
    coefficients), which the caller must not use afterwards: one pair-sized
    array fewer (360 MB and 1 s of allocation at 1M points).  A stencil this
    matrix computes itself is always overwritten.
    """

    def __init__(self, ops, *, laplacian: str = "corrected", gradient: str = "quadratic",
                 kappa: float = 0.0, near=None, bordered: bool = False,
                 density_weighted: bool = False, dirichlet: bool = False, reuse=None,
                 overwrite_laplacian: bool = False):
        runtime.ensure_init()
        p = ops.particles
        self.ops = ops
        self.n_particles = p.n
        self.bordered = bool(bordered)
        self.n = p.n + (1 if self.bordered else 0)
        self.kappa = float(kappa)
        real = runtime.real_dtype()
        if isinstance(laplacian, LaplacianStencil):     # precomputed: used as given
            if density_weighted:
                raise ValueError("density_weighted applies to a variant name; pass "
                                 "ops.density_weighted(stencil) instead")
            self.lap = laplacian
        else:
            self.lap = ops.laplacian_coefficients(laplacian, row_kinds=(FLUID,),
                                                  density_weighted=density_weighted)
            overwrite_laplacian = True
        if isinstance(gradient, GradientStencil):
            self.grad = gradient
        else:
            self.grad = ops.gradient_coefficients(gradient, row_kinds=(FLUID, BOUNDARY))
        npairs = max(ops.pairs.n_pairs, 1)
        size = max(self.n_particles, 1)
        # a caller that reuses arrays gets a quarter more pair rows than needed, so
        # that a slowly growing pair count reallocates rarely
        room = npairs + npairs // 4 if reuse is not None else npairs
        if reuse is not None and not (reuse.K.shape[0] >= npairs and reuse.D.shape[0] >= size):
            reuse = None
        self._reused = reuse
        if reuse is not None:
            reuse._reused = None            # no chain of past matrices
        self._multilevel = None             # (options, MultilevelPreconditioner): multilevel()
        self._host_rows = None              # host_apply's float64 rows, made on first use
        if reuse is not None:
            self.K = reuse.K
        elif overwrite_laplacian and self.lap.C.shape[0] >= npairs:
            self.K = self.lap.C
        else:
            self.K = runtime.array(real, room)
        # written in full below (by _assemble, fill and from_numpy): not zero-filled
        self.D = reuse.D if reuse is not None else runtime.array(real, size, zeroed=False)
        self._zero_near = near is None
        if near is None:
            if reuse is not None and reuse._zero_near:
                near = reuse.near
            else:
                near = runtime.array(real, size, zeroed=False)
                near.fill(0.0)
        self.near = near
        orphan = self._orphan = reuse._orphan if reuse is not None else runtime.array(ti.i32, 1)
        orphan.fill(-1)
        pr = ops.pairs
        _assemble(ops.kernel_id, p.n, pr.offsets, pr.neighbours, p.position, p.volume, p.kind,
                  p.normal, near, self.lap.C, self.lap.s, self.grad.G, self.grad.s, self.kappa,
                  *ops.support_args(), self.K, self.D, orphan)
        # the Laplacian's coefficients are spent (C may now hold K); the
        # gradient's stay: the decomposition reuses them for the components
        self.lap = None
        bad = int(orphan.to_numpy()[0])
        if bad >= 0:
            raise NeighbourError(
                f"ghost particle at {p.position.to_numpy()[bad].tolist()} has no fluid "
                "neighbour within the kernel support: its Shepard row is undefined")
        kind = p.kind.to_numpy()[: p.n]
        if dirichlet:
            if bordered:
                raise ValueError("Dirichlet rows make the problem regular: no bordering")
            off, _ = pr.to_numpy()
            rows = np.repeat(np.arange(p.n), np.diff(off))
            K = self.K.to_numpy()
            K[: len(rows)][kind[rows] == BOUNDARY] = 0.0
            self.K.from_numpy(K)
            D = self.D.to_numpy()
            D[: p.n][kind == BOUNDARY] = 1.0
            self.D.from_numpy(D)
        # border vectors (unused unless bordered)
        vol = p.volume.to_numpy()[: p.n]
        fluid = (kind == FLUID).astype(runtime.np_real())
        if reuse is not None:
            self.border_e, self.border_w = reuse.border_e, reuse.border_w
            size = self.border_e.shape[0]
        else:
            self.border_e = runtime.array(real, size, zeroed=False)
            self.border_w = runtime.array(real, size, zeroed=False)
        self.border_e.from_numpy(_padded(fluid, size))
        self.border_w.from_numpy(_padded(fluid * vol, size))
        # the corner's sign (class doc): regular for every kappa >= 0
        self.border_c = float((fluid * vol).sum()) * (1.0 if self.kappa == 0.0 else -1.0)

    def _border(self):
        return int(self.bordered), self.border_e, self.border_w, self.border_c

    # ---- linear operator protocol (see taichi_hh.linalg.krylov) ------------------------
    def apply(self, x, y) -> None:
        self.apply_dot(x, y, y)

    #: apply and apply_dot take one column or several (:mod:`taichi_hh.linalg.columns`)
    accepts_columns = True

    def apply_dot(self, x, y, a) -> tuple:
        """y = A x; returns (<a, y>, <y, y>) (see :mod:`taichi_hh.linalg.krylov`),
        per column (numpy arrays) when x holds several."""
        pr = self.ops.pairs
        cols = columns_of(x)
        lanes = lanes_mod.on()
        kernel = _apply_rows_kernel(runtime.state().precision, cols, lanes)
        out = kernel(self.n_particles, pr.offsets, pr.neighbours, self.K, self.D, x, y,
                     *self._border(), a, lanes_mod.partials(3, cols) if lanes else a)
        return out if cols == 1 else tuple(np.asarray(v.to_numpy()) for v in out)

    def diagonal(self, d) -> None:
        _copy_diagonal(self.n_particles, self.D, d, int(self.bordered), self.border_c)

    def _reverse_index(self):
        return self.ops.pairs.reverse_index()

    def apply_transpose(self, x, y) -> None:
        pr = self.ops.pairs
        _apply_rows_transpose(self.n_particles, pr.offsets, pr.neighbours, self._reverse_index(),
                              self.K, self.D, x, y, *self._border())

    def normal_diagonal(self, d) -> None:
        pr = self.ops.pairs
        _column_sq_norms(self.n_particles, pr.offsets, self._reverse_index(), self.K, self.D, d,
                         *self._border())

    def to_scipy(self):
        """The assembled matrix as scipy.sparse CSR (for tests and reference solves)."""
        import scipy.sparse as sp
        off, nb = self.ops.pairs.to_numpy()
        n = self.n_particles
        K = self.K.to_numpy()[: len(nb)]
        rows = np.repeat(np.arange(n), np.diff(off))
        A = sp.csr_matrix((K, (rows, nb)), shape=(self.n, self.n))
        diag = np.zeros(self.n)
        diag[:n] = self.D.to_numpy()[:n]
        A = A + sp.diags(diag)
        if self.bordered:
            e = self.border_e.to_numpy()[:n]
            w = self.border_w.to_numpy()[:n]
            B = sp.lil_matrix((self.n, self.n))
            B[:n, n] = e[:, None]
            B[n, :n] = w[None, :]
            B[n, n] = self.border_c
            A = A + B.tocsr()
        return A.tocsr()

    def pair_rows(self) -> PairRows:
        """The particle rows as arrays (:class:`PairRows`)."""
        ops, pr = self.ops, self.ops.pairs
        return PairRows(self.n_particles, pr.offsets, pr.neighbours, self.K, self.D,
                        ops.particles.position, ops.support, ops.supports, pr.grid,
                        self.bordered, self.border_c)

    # ---- solve ---------------------------------------------------------------------
    def multilevel(self, **options):
        """The :class:`~taichi_hh.poisson.multilevel.MultilevelPreconditioner` of this
        matrix (built on first use, then cached; new ``options`` rebuild it)."""
        from .multilevel import MultilevelPreconditioner
        cached = self._multilevel
        if cached is None or cached[0] != options:
            # the matrix this one reuses (no longer needed) hands on its cycle's arrays
            previous = None
            if self._reused is not None:
                previous = self._reused._multilevel
                self._reused._multilevel = None
                self._reused = None
            self._multilevel = (dict(options), MultilevelPreconditioner(
                self, **options, reuse=previous[1] if previous is not None else None))
        return self._multilevel[1]

    def preconditioner_for(self, preconditioner, method: str = "bicgstab",
                           multilevel_options: dict | None = None):
        """Resolve a preconditioner name: ``"auto"`` is the multilevel cycle for
        BiCGSTAB from ``MULTILEVEL_MIN_N`` unknowns on (fewer: Jacobi, which is
        as fast there), Jacobi otherwise; ``"multilevel"`` builds (or reuses) the
        cycle (with ``multilevel_options``, e.g. ``{"cycle": "V"}``); ``"jacobi"``,
        None and preconditioner objects pass through."""
        if preconditioner == "auto":
            preconditioner = ("multilevel" if method == "bicgstab"
                              and self.n_particles >= MULTILEVEL_MIN_N else "jacobi")
        if preconditioner == "multilevel":
            if method != "bicgstab":
                raise InputError(f"the multilevel preconditioner works with bicgstab, not "
                                 f"{method!r}")
            return self.multilevel(**(multilevel_options or {}))
        return preconditioner

    def solve_columns(self, B, *, tol: float = 1e-8, preconditioner="auto",
                      multilevel_options: dict | None = None, **kwargs) -> list:
        """Solve for the columns of ``B`` (shape ``(n_particles, cols)``) with
        BiCGSTAB, the columns together
        (:func:`~taichi_hh.linalg.krylov.bicgstab_columns`: the matrix and the
        preconditioner read once per iteration for all of them).  Returns one result
        per column, as :meth:`solve` does; ``kwargs`` as
        :func:`~taichi_hh.linalg.krylov.bicgstab_columns`."""
        kwargs["preconditioner"] = self.preconditioner_for(preconditioner, "bicgstab",
                                                           multilevel_options)
        B = np.asarray(B, dtype=np.float64)
        if B.ndim != 2 or B.shape[0] != self.n_particles:
            raise InputError(f"right-hand sides must have shape ({self.n_particles}, cols), "
                             f"got {B.shape}")
        if self.bordered:
            B = np.vstack([B, np.zeros((1, B.shape[1]))])
        if runtime.state().precision == "f32" and tol < SINGLE_PRECISION_TOL:
            results = self._refined_columns(B, tol, kwargs)
        else:
            raise_on_failure = kwargs.pop("raise_on_failure", True)
            results = solvers.bicgstab_columns(self, B, tol=tol, raise_on_failure=False,
                                               **kwargs)
            for c, res in enumerate(results):
                if res.converged:
                    continue
                failure = SolverError(res.message, reason=res.reason,
                                      iteration=res.iterations, residual=res.relative_residual)
                try:                # a small system at the default cap: as solve() does
                    results[c] = self.solve_densely_instead(B[:, c], tol, failure, "bicgstab",
                                                      kwargs)
                except SolverError:
                    if raise_on_failure:
                        raise
        for res in results:
            res.border = float(res.x[-1]) if self.bordered else 0.0
            if self.bordered:
                res.x = res.x[: self.n_particles]
        return results

    def solve_densely_instead(self, b: np.ndarray, tol: float, failure: SolverError, method: str,
                              kwargs: dict):
        """The small system BiCGSTAB failed on (at its default cap or stagnating)
        solved by dense LU in double precision (:data:`DIRECT_MAX`); ``failure``
        raised again where that does not apply or does not reach ``tol``."""
        import time
        if (method != "bicgstab" or self.n > DIRECT_MAX or kwargs.get("max_iterations")
                is not None or failure.reason not in ("max_iterations", "stagnation")):
            raise failure
        t = time.perf_counter()
        dense = self.host_apply(np.eye(self.n))
        try:
            x = np.linalg.solve(dense, b)
        except np.linalg.LinAlgError:
            raise failure from None
        norm = float(np.linalg.norm(b))
        rel = float(np.linalg.norm(b - dense @ x) / norm) if norm > 0 else 0.0
        if not rel <= tol:
            raise failure
        res = solvers.SolveResult(
            x_ndarray=None, converged=True, reason="converged", iterations=failure.iteration,
            relative_residual=rel, history=np.array([failure.residual, rel]),
            seconds=time.perf_counter() - t, applies=self.n, method="bicgstab, then dense LU",
            message=f"BiCGSTAB stopped ({failure.reason} at iteration {failure.iteration}, "
                    f"relative residual {failure.residual:.3g}); solved by dense LU",
            n=self.n)
        res.x = x
        return res

    def host_apply(self, X: np.ndarray) -> np.ndarray:
        """``A X`` in double precision on the host (columns of ``X``, shape ``(n,
        cols)``): the matrix's stored coefficients, exactly as the kernels read
        them, in float64 arithmetic."""
        cached = self._host_rows
        if cached is None:
            off, nb = self.ops.pairs.to_numpy()
            n = self.n_particles
            rows = np.repeat(np.arange(n), np.diff(off))
            cached = self._host_rows = (
                rows, nb.astype(np.int64), self.K.to_numpy()[: len(nb)].astype(np.float64),
                self.D.to_numpy()[:n].astype(np.float64),
                self.border_e.to_numpy()[:n].astype(np.float64),
                self.border_w.to_numpy()[:n].astype(np.float64))
        rows, nb, K, D, e, w = cached
        n = self.n_particles
        Y = np.empty_like(X)
        for c in range(X.shape[1]):
            x = X[:n, c]
            y = D * x + np.bincount(rows, weights=K * x[nb], minlength=n)
            if self.bordered:
                y += e * X[n, c]
                Y[n, c] = float(w @ x) + self.border_c * X[n, c]
            Y[:n, c] = y
        return Y

    def _refined_columns(self, B: np.ndarray, tol: float, kwargs: dict, X0=None) -> list:
        """Mixed-precision iterative refinement for single precision: each sweep
        solves ``A e = r`` in f32 to :data:`REFINEMENT_STEP` and adds ``e`` to
        ``x`` in f64, with ``r = b - A x`` computed in f64 (:meth:`host_apply`),
        until ``|r| <= tol |b|`` per column.  Results as :func:`bicgstab_columns`'s,
        ``iterations`` summed over the sweeps.  Raises
        :class:`~taichi_hh.errors.SolverError` when a sweep no longer gains."""
        cols = B.shape[1]
        norms = np.linalg.norm(B, axis=0)
        X = np.zeros_like(B) if X0 is None else np.array(X0, dtype=np.float64)
        R = B - self.host_apply(X) if X0 is not None else B.copy()
        rel = np.where(norms > 0, np.linalg.norm(R, axis=0) / np.where(norms > 0, norms, 1),
                       0.0)
        iterations = np.zeros(cols, dtype=int)
        cap = kwargs.get("max_iterations")
        last = [None] * cols
        history = [[] for _ in range(cols)]
        inner = dict(kwargs, raise_on_failure=False)
        for sweep in range(MAX_REFINEMENTS):
            active = np.flatnonzero(rel > tol)
            if active.size == 0:
                break
            if cap is not None:
                inner["max_iterations"] = max(1, cap - int(iterations[active].max()))
            scaled = R[:, active] / norms[active]
            found = solvers.bicgstab_columns(self, scaled, tol=REFINEMENT_STEP, **inner)
            for c, res in zip(active, found):
                step = res.x.astype(np.float64)
                if not np.isfinite(step).all():
                    raise SolverError(f"bicgstab failed in single precision: {res.message}",
                                      reason=res.reason, iteration=int(iterations[c]),
                                      residual=float(rel[c]))
                X[:, c] += step * norms[c]
                iterations[c] += res.iterations
                last[c] = res
            R = B - self.host_apply(X)
            before = rel.copy()
            rel = np.where(norms > 0, np.linalg.norm(R, axis=0) / np.where(norms > 0, norms, 1),
                           0.0)
            for c in active:
                history[c].append(float(rel[c]))
            stalled = [c for c in active if rel[c] > tol and rel[c] > 0.5 * before[c]]
            if stalled:
                c = stalled[0]
                raise SolverError(
                    f"bicgstab failed: stagnation in single precision at iteration "
                    f"{iterations[c]} (relative residual {rel[c]:.3e}, computed in double "
                    f"precision; tol {tol:g}): refinement sweep {sweep + 1} gained less than "
                    f"a factor 2; single precision cannot resolve this system to tol: use "
                    f"precision='f64' or a larger tol", reason="stagnation",
                    iteration=int(iterations[c]), residual=float(rel[c]))
            if cap is not None and (iterations[active] >= cap).any() and (rel > tol).any():
                c = int(active[np.argmax(iterations[active])])
                raise SolverError(
                    f"bicgstab failed: iteration cap reached: {iterations[c]} iterations of "
                    f"at most {cap} (relative residual {rel[c]:.3e}, tol {tol:g})",
                    reason="max_iterations", iteration=int(iterations[c]),
                    residual=float(rel[c]))
        else:
            if (rel > tol).any():
                c = int(np.argmax(rel))
                raise SolverError(f"bicgstab failed: {MAX_REFINEMENTS} refinement sweeps in "
                                  f"single precision left relative residual {rel[c]:.3e} > "
                                  f"tol {tol:g}", reason="stagnation",
                                  iteration=int(iterations[c]), residual=float(rel[c]))
        results = []
        for c in range(cols):
            res = last[c]
            if res is None:                  # a zero right-hand side: x = 0
                res = solvers.bicgstab_columns(self, B[:, c:c + 1], tol=tol, **kwargs)[0]
            res._x = X[:, c].copy()
            res.iterations = int(iterations[c])
            res.relative_residual = float(rel[c])
            res.converged, res.reason = True, "converged"
            res.message = (f"converged in {iterations[c]} iterations over {len(history[c])} "
                           "single-precision refinement sweeps")
            results.append(res)
        return results

    def solve(self, b, x0=None, *, method: str = "bicgstab", tol: float = 1e-8,
              border0: float = 0.0, preconditioner="auto",
              multilevel_options: dict | None = None, **kwargs):
        """Solve for particle-slot values ``b`` (length n_particles); returns a
        :class:`solvers.SolveResult` whose ``x`` has the particle values (and, when
        bordered, ``result.border`` = lambda, the right-hand side's incompatibility).
        x0, border0: warm start (e.g. the previous step's ``x`` and ``border``).
        preconditioner: ``"auto"`` (default), ``"multilevel"``, ``"jacobi"``,
        None or an object with ``apply(r, z)`` (see :meth:`preconditioner_for`)."""
        solve = {"bicgstab": solvers.bicgstab, "cg": solvers.cg, "cgnr": solvers.cgnr}
        if method not in solve:
            raise ValueError(f"unknown solver {method!r}; choose one of {tuple(solve)}")
        kwargs["preconditioner"] = self.preconditioner_for(preconditioner, method,
                                                           multilevel_options)
        b = np.asarray(b, dtype=np.float64)
        if b.shape != (self.n_particles,):
            raise InputError(f"right-hand side must have shape ({self.n_particles},), "
                             f"got {b.shape}")
        if self.bordered:
            b = np.append(b, 0.0)
            if x0 is not None:
                x0 = np.append(np.asarray(x0, dtype=np.float64), border0)
        try:
            if method == "bicgstab" and runtime.state().precision == "f32" \
                    and tol < SINGLE_PRECISION_TOL:
                # the residual in double precision (solve_columns)
                res = self._refined_columns(b[:, None], tol, kwargs,
                                            None if x0 is None else x0[:, None])[0]
            else:
                res = solve[method](self, b, x0, tol=tol, **kwargs)
        except SolverError as exc:
            res = self.solve_densely_instead(b, tol, exc, method, kwargs)
        res.border = float(res.x[-1]) if self.bordered else 0.0
        if self.bordered:
            res.x = res.x[: self.n_particles]
        return res
