"""Matrix-free Krylov solvers on Taichi ndarrays: BiCGSTAB, CG and CGNR.

Linear operator protocol
------------------------
The solvers never see a matrix, only an object ``A`` with

``A.n`` (int)
    Number of unknowns (columns).
``A.m`` (int, optional)
    Number of equations (rows); taken equal to ``n`` when absent.  BiCGSTAB
    and CG need ``m == n``.
``A.apply(x, y)``
    Writes ``y[:m] = A @ x[:n]``.  ``x`` and ``y`` are 1-D real Taichi ndarrays
    (dtype :func:`taichi_hh.runtime.real_dtype`) whose length may exceed the
    active size; entries beyond it are left alone.
``A.diagonal(d)``
    Writes the diagonal ``A[i, i]`` into ``d[:n]`` (needed for the Jacobi
    preconditioner of BiCGSTAB and CG).
``A.apply_dot(x, y, a)`` (optional)
    Writes ``y = A x`` like ``apply`` and returns ``(<a, y>, <y, y>)`` over the
    ``m`` rows, reduced in the apply's own loop: BiCGSTAB needs both dot
    products of each new vector, and this saves it a pass over memory per
    apply.  Without it the solver computes them after ``apply``.
``A.apply_transpose(x, y)`` (optional)
    Writes ``y[:n] = A.T @ x[:m]``; needed by :func:`cgnr`.
``A.normal_diagonal(d)`` (optional)
    Writes the diagonal of ``A.T @ A`` (squared column norms) into ``d[:n]``;
    needed by :func:`cgnr` with the Jacobi preconditioner.

:class:`CSRMatrix` implements all of it.

Solvers
-------
:func:`bicgstab` (van der Vorst 1992, right Jacobi preconditioning),
:func:`cg` (Hestenes & Stiefel 1952, Jacobi preconditioning) and :func:`cgnr`
(CG on the normal equations ``A^T A x = A^T b``, as Colin et al. 2006 Sec. 3.5
do for their stacked boundary system) share one driver and one set of
stopping tests:

* converged: the relative residual ``||b - A x|| / ||b||`` is at most ``tol``.
  The iterations update the residual by recurrence; when the recurrence
  claims convergence the residual is recomputed as ``b - A x`` and iterating
  continues from it if the true one is still above ``tol`` (at most
  ``_MAX_RESIDUAL_REPLACEMENTS`` times, then ``"stagnation"``).  The reported
  ``relative_residual`` is always the recomputed one.
* ``"breakdown"``: a quantity the method divides by is negligible relative to
  its scale, i.e. ``|<a, b>| <= eps * ||a|| ||b||`` with ``eps`` the machine
  epsilon of the real type (below it a dot product is rounding noise):
  BiCGSTAB's ``rho = <r_hat, r>``, ``<r_hat, v>`` and ``omega``'s ``<t, s>``;
  CG's ``<p, A p>`` and ``<r, M^-1 r>``; CGNR's ``||A p|| = 0``.
* ``"stagnation"``: the smallest monitored residual of the last
  ``max(stagnation_window, iterations / 3)`` iterations (``stagnation_window``
  defaults to ``STAGNATION_WINDOW`` = 400) is not below ``(1 - 1e-3)``
  times the smallest of the window before (so it is tested from iteration
  ``2 * stagnation_window`` on).  Windows are compared rather than the best
  value ever, because CG and BiCGSTAB residuals are not monotone.
* ``"divergence"``: the monitored residual exceeds ``divergence_factor``
  (default 1e6) times ``max(initial relative residual, 1)``, i.e. the scale of
  ``max(||r0||, ||b||)``, so a good warm start does not raise false alarms.
* ``"non-finite"``: NaN/inf in ``b`` (found before iterating, from ``||b||``),
  in the initial residual (``x0`` or the operator) or in any iterate.  This is
  a :class:`~taichi_hh.errors.SolverError` like every other failure, so that
  ``raise_on_failure=False`` covers it too.
* ``"max_iterations"``: the iteration cap (default ``max(1000, n)``) is reached.

Failures raise :class:`~taichi_hh.errors.SolverError` (``reason``,
``iteration``, ``residual``) or, with ``raise_on_failure=False``, return a
:class:`SolveResult` with ``converged=False`` and the same ``reason`` and
message.  Invalid input (wrong shapes or dtypes, a non-square operator for
BiCGSTAB/CG, a zero or non-finite diagonal entry under Jacobi) raises
:class:`~taichi_hh.errors.InputError` regardless of ``raise_on_failure``.

Cost model
----------
A kernel launch costs ~0.1 ms of Python-side argument handling (more with
more ndarray arguments), plus ~0.1 ms per parallel loop to wake the CPU
thread pool.  So each iteration is a few fused kernels, each a sequence of
loops with the scalar algebra between them done in the kernel, returning its
reductions as a tuple: BiCGSTAB uses 2 operator applies + 2 kernels (3
passes over the vectors besides the applies, whose dot products come from
``apply_dot``), CG 1 + 1, CGNR 2 + 2.  Below ``PARALLEL_MIN_SIZE`` unknowns the vector loops (and
:class:`CSRMatrix`'s) run serially, which is faster there than waking the
thread pool.
"""
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from types import SimpleNamespace
from typing import Callable, Optional, Protocol, runtime_checkable

import numpy as np

from taichi_hh import runtime
from taichi_hh.errors import InputError, SolverError
from taichi_hh.linalg.columns import zeros

__all__ = ["LinearOperator", "CSRMatrix", "SolveResult", "Workspace", "get_workspace",
           "clear_workspace_cache", "bicgstab", "bicgstab_columns", "cg", "cgnr",
           "FAILURE_REASONS",
           "PARALLEL_MIN_SIZE"]

# Vector sizes below which loops run on one thread: a serial pass over 1e5
# entries beats waking the thread pool (docs/notes/linalg.md).
PARALLEL_MIN_SIZE = 200_000

_MAX_RESIDUAL_REPLACEMENTS = 5
_MAX_BREAKDOWN_RESTARTS = 10
# Jacobi-BiCGSTAB plateaus for hundreds of iterations on the SPH Neumann
# systems before converging; shorter windows called those plateaus
# stagnation (docs/notes/linalg.md).
STAGNATION_WINDOW = 400
_STAGNATION_RTOL = 1e-3
FAILURE_REASONS = ("breakdown", "stagnation", "divergence", "non-finite", "max_iterations")


@runtime_checkable
class LinearOperator(Protocol):
    """Structural type of the operators the solvers accept (see module doc)."""

    n: int

    def apply(self, x, y) -> None: ...

    def diagonal(self, d) -> None: ...


# --------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------

def _ti():
    import taichi as ti
    return ti


def _serial(size: int) -> bool:
    return size < PARALLEL_MIN_SIZE


def _kernels(size: int) -> SimpleNamespace:
    """The kernel set for the current precision, serial or parallel by size."""
    runtime.ensure_init()
    return _build_kernels(runtime.state().precision, _serial(size))


@lru_cache(maxsize=None)
def _build_kernels(precision: str, serial: bool) -> SimpleNamespace:
    """Compile-once kernel set.  Built lazily because the real type of the
    arguments and return values depends on the runtime precision; ``serial``
    is a compile-time loop setting, not data.  Reductions accumulate in
    kernel-scope locals (per-thread partial sums, no contended atomics) and
    come back as the kernel's return tuple, so no extra launch reads them."""
    ti = _ti()
    real = ti.f64 if precision == "f64" else ti.f32
    vec = ti.types.ndarray(dtype=real, ndim=1)
    ivec = ti.types.ndarray(dtype=ti.i32, ndim=1)

    @ti.func
    def negligible(dot, aa, bb, btol):
        """|<a, b>| <= btol ||a|| ||b||, given <a, b>, ||a||^2 and ||b||^2."""
        return ti.abs(dot) <= btol * ti.sqrt(aa) * ti.sqrt(bb)

    # --- CSR matrix --------------------------------------------------------
    @ti.kernel
    def csr_matvec_dot(indptr: ivec, indices: ivec, data: vec, x: vec, y: vec, a: vec,
                       nrows: ti.i32) -> (real, real):
        """y = A x; returns (<a, y>, <y, y>) (plain applies pass a = y and ignore
        them: two multiply-adds a row)."""
        ay = 0.0
        yy = 0.0
        ti.loop_config(serialize=serial)
        for i in range(nrows):
            acc = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                acc += data[k] * x[indices[k]]
            y[i] = acc
            ay += a[i] * acc
            yy += acc * acc
        return ay, yy

    @ti.kernel
    def dot2(a: vec, y: vec, n: ti.i32) -> (real, real):
        """(<a, y>, <y, y>)."""
        ay = 0.0
        yy = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            ay += a[i] * y[i]
            yy += y[i] * y[i]
        return ay, yy

    @ti.kernel
    def csr_diagonal(indptr: ivec, indices: ivec, data: vec, d: vec, nrows: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(nrows):
            acc = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                if indices[k] == i:
                    acc += data[k]
            d[i] = acc

    @ti.kernel
    def csr_row_sq_norms(indptr: ivec, data: vec, d: vec, nrows: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(nrows):
            acc = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                acc += data[k] * data[k]
            d[i] = acc

    # --- generic vectors ---------------------------------------------------
    @ti.kernel
    def invert_diagonal(d: vec, dinv: vec, n: ti.i32) -> ti.i32:
        """dinv = 1/d; returns the first index with d zero or non-finite, or -1."""
        bad = n
        ti.loop_config(serialize=serial)
        for i in range(n):
            di = d[i]
            if di == 0.0 or di != di or ti.abs(di) == ti.math.inf:
                ti.atomic_min(bad, i)
                dinv[i] = 0.0
            else:
                dinv[i] = 1.0 / di
        return bad if bad < n else -1

    @ti.kernel
    def fill(a: vec, value: real, n: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(n):
            a[i] = value

    @ti.kernel
    def copy(src: vec, dst: vec, n: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(n):
            dst[i] = src[i]

    @ti.kernel
    def norm2(a: vec, n: ti.i32) -> real:
        acc = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            acc += a[i] * a[i]
        return acc

    bicg = _build_column_kernels(precision, serial, 1)

    # --- CG (preconditioned, M^-1 = dinv) -----------------------------------
    @ti.kernel
    def cg_restart(b: vec, ax: vec, r: vec, p: vec, dinv: vec, n: ti.i32) -> (real, real, real):
        """r = b - A x; p = M^-1 r.  Returns (||r||^2, <r, M^-1 r>, ||M^-1 r||^2)."""
        rr = 0.0
        rz = 0.0
        zz = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            ri = b[i] - ax[i]
            zi = dinv[i] * ri
            r[i] = ri
            p[i] = zi
            rr += ri * ri
            rz += ri * zi
            zz += zi * zi
        return rr, rz, zz

    @ti.kernel
    def cg_step(x: vec, r: vec, p: vec, q: vec, dinv: vec, rz: real, btol: real,
                n: ti.i32) -> (real, real, real, real):
        """alpha = rz/<p, q>; x += alpha p; r -= alpha q; p = M^-1 r + beta p.
        Returns (||r||^2, rz_new, <p,q> flag, rz flag); alpha = 0 on breakdown."""
        pq = 0.0
        pp = 0.0
        qq = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            pq += p[i] * q[i]
            pp += p[i] * p[i]
            qq += q[i] * q[i]
        alpha = 0.0
        pq_flag = 1.0
        if not negligible(pq, pp, qq, btol):
            alpha = rz / pq
            pq_flag = 0.0
        rr = 0.0
        rz_new = 0.0
        zz = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            x[i] += alpha * p[i]
            ri = r[i] - alpha * q[i]
            zi = dinv[i] * ri
            r[i] = ri
            rr += ri * ri
            rz_new += ri * zi
            zz += zi * zi
        rz_flag = 1.0 if negligible(rz_new, rr, zz, btol) else 0.0
        beta = 0.0
        if rz_flag == 0.0:
            beta = rz_new / rz
        ti.loop_config(serialize=serial)
        for i in range(n):
            p[i] = dinv[i] * r[i] + beta * p[i]
        return rr, rz_new, pq_flag, rz_flag

    # --- CGNR: CG on A^T A x = A^T b, preconditioned by M^-1 = dinv ----------
    @ti.kernel
    def nr_residual(b: vec, ax: vec, r: vec, m: ti.i32) -> real:
        """r = b - A x.  Returns ||r||^2."""
        rr = 0.0
        ti.loop_config(serialize=serial)
        for i in range(m):
            ri = b[i] - ax[i]
            r[i] = ri
            rr += ri * ri
        return rr

    @ti.kernel
    def nr_direction(z: vec, p: vec, dinv: vec, gamma_old: real, n: ti.i32) -> (real, real):
        """z = A^T r: gamma = <z, M^-1 z>; p = M^-1 z + (gamma/gamma_old) p
        (a fresh start when gamma_old = 0).  Returns (gamma, ||z||^2)."""
        gamma = 0.0
        zz = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            gamma += z[i] * dinv[i] * z[i]
            zz += z[i] * z[i]
        beta = 0.0
        if gamma_old != 0.0:
            beta = gamma / gamma_old
        ti.loop_config(serialize=serial)
        for i in range(n):
            p[i] = dinv[i] * z[i] + beta * p[i]
        return gamma, zz

    @ti.kernel
    def nr_update(x: vec, r: vec, p: vec, w: vec, gamma: real, m: ti.i32,
                  n: ti.i32) -> (real, real):
        """w = A p: alpha = gamma/||w||^2; x += alpha p; r -= alpha w.
        Returns (||r||^2, breakdown flag); alpha = 0 when A p = 0."""
        ww = 0.0
        ti.loop_config(serialize=serial)
        for i in range(m):
            ww += w[i] * w[i]
        alpha = 0.0
        flag = 1.0
        if ww > 0.0:
            alpha = gamma / ww
            flag = 0.0
        rr = 0.0
        ti.loop_config(serialize=serial)
        for i in range(ti.max(m, n)):
            if i < n:
                x[i] += alpha * p[i]
            if i < m:
                ri = r[i] - alpha * w[i]
                r[i] = ri
                rr += ri * ri
        return rr, flag

    return SimpleNamespace(
        csr_matvec_dot=csr_matvec_dot, dot2=dot2,
        csr_diagonal=csr_diagonal, csr_row_sq_norms=csr_row_sq_norms,
        invert_diagonal=invert_diagonal, fill=fill, copy=copy, norm2=norm2,
        bicg_restart=bicg.bicg_restart, bicg_half=bicg.bicg_half, bicg_full=bicg.bicg_full,
        cg_restart=cg_restart, cg_step=cg_step,
        nr_residual=nr_residual, nr_direction=nr_direction, nr_update=nr_update)


def _column_kernels(size: int, cols: int) -> SimpleNamespace:
    """BiCGSTAB's vector kernels for ``cols`` columns at once."""
    runtime.ensure_init()
    return _build_column_kernels(runtime.state().precision, _serial(size), cols)


@lru_cache(maxsize=None)
def _build_column_kernels(precision: str, serial: bool, cols: int) -> SimpleNamespace:
    """BiCGSTAB's vector kernels on ``cols`` columns (vectors of scalars, or of
    ``cols``-vectors: :mod:`taichi_hh.linalg.columns`), each column its own
    iteration: the scalars (alpha, omega, rho, ...) are per column, and so
    are ``active`` (1: iterating, 0: frozen, e.g. converged: x and r stay) and
    the restart's ``mask`` (1: restart this column).  One column is the plain
    BiCGSTAB of :func:`bicgstab`."""
    ti = _ti()
    real = ti.f64 if precision == "f64" else ti.f32
    scal = real if cols == 1 else ti.types.vector(cols, real)
    vec = ti.types.ndarray(dtype=scal, ndim=1)
    rvec = ti.types.ndarray(dtype=real, ndim=1)

    @ti.func
    def negligible(dot, aa, bb, btol):
        """|<a, b>| <= btol ||a|| ||b||, given <a, b>, ||a||^2 and ||b||^2."""
        return ti.abs(dot) <= btol * ti.sqrt(aa) * ti.sqrt(bb)

    @ti.func
    def indicator(cond):
        """1.0 where cond holds, else 0.0 (per column)."""
        return ti.select(cond, 1.0, 0.0)

    @ti.kernel
    def fill(a: vec, value: real, n: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(n):
            a[i] = value * (zeros(cols) + 1.0)

    @ti.kernel
    def norm2(a: vec, n: ti.i32) -> scal:
        acc = zeros(cols)
        ti.loop_config(serialize=serial)
        for i in range(n):
            acc += a[i] * a[i]
        return acc

    # --- BiCGSTAB (right-preconditioned, M^-1 = dinv) ----------------------
    # Storage sharing (element-wise safe): s overwrites r, and z holds
    # phat = M^-1 p until the half step turns it into shat = M^-1 s.
    @ti.kernel
    def bicg_restart(b: vec, ax: vec, r: vec, r_hat: vec, p: vec, z: vec, dinv: rvec,
                     mask: scal, n: ti.i32) -> scal:
        """In the masked columns r = b - A x and r_hat = p = r; z = M^-1 p.
        Returns ||r||^2."""
        rr = zeros(cols)
        restart = mask > 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            ri = ti.select(restart, b[i] - ax[i], r[i])
            pi = ti.select(restart, ri, p[i])
            r[i] = ri
            r_hat[i] = ti.select(restart, ri, r_hat[i])
            p[i] = pi
            z[i] = dinv[i] * pi
            rr += ri * ri
        return rr

    @ti.kernel
    def bicg_half(x: vec, r: vec, v: vec, z: vec, dinv: rvec, rv: scal, vv: scal,
                  rho: scal, rhat2: scal, active: scal, btol: real,
                  n: ti.i32) -> (scal, scal, scal):
        """Given v = A phat and its dots rv = <r_hat, v>, vv = <v, v> (from the
        apply): alpha = rho / rv; x += alpha phat; s = r - alpha v (into r);
        z = shat = M^-1 s.  Returns (||s||^2, alpha, breakdown flag); on
        breakdown alpha = 0 and x, r are unchanged."""
        ok = active * (1.0 - indicator(negligible(rv, rhat2, vv, btol)))
        alpha = ti.select(ok > 0.0, rho / rv, 0.0)
        flag = active - ok
        ss = zeros(cols)
        ti.loop_config(serialize=serial)
        for i in range(n):
            x[i] += alpha * z[i]
            si = r[i] - alpha * v[i]
            r[i] = si
            z[i] = dinv[i] * si
            ss += si * si
        return ss, alpha, flag

    @ti.kernel
    def bicg_full(x: vec, r: vec, r_hat: vec, p: vec, v: vec, t: vec, z: vec, dinv: rvec,
                  ts: scal, tt: scal, ss: scal, alpha: scal, rho: scal, rhat2: scal,
                  active: scal, btol: real, n: ti.i32) -> (scal, scal, scal, scal):
        """Given t = A shat and its dots ts = <s, t>, tt = <t, t> (from the apply)
        and ss = ||s||^2: omega = ts / tt; x += omega shat; r = s - omega t;
        then the next direction p = r + beta (p - omega v), z = phat = M^-1 p.
        Returns (||r||^2, rho_new, omega flag, rho flag)."""
        omega = ti.select((tt > 0.0) & (active > 0.0), ts / tt, 0.0)
        omega_flag = active * indicator(negligible(ts, tt, ss, btol))
        rr = zeros(cols)
        rho_new = zeros(cols)
        ti.loop_config(serialize=serial)
        for i in range(n):
            x[i] += omega * z[i]
            ri = r[i] - omega * t[i]
            r[i] = ri
            rr += ri * ri
            rho_new += r_hat[i] * ri
        rho_flag = active * indicator(negligible(rho_new, rhat2, rr, btol))
        go = active * (1.0 - omega_flag) * (1.0 - rho_flag)
        beta = ti.select(go > 0.0, (rho_new / rho) * (alpha / omega), 0.0)
        ti.loop_config(serialize=serial)
        for i in range(n):
            pi = r[i] + beta * (p[i] - omega * v[i])
            p[i] = pi
            z[i] = dinv[i] * pi
        return rr, rho_new, omega_flag, rho_flag

    return SimpleNamespace(fill=fill, norm2=norm2, bicg_restart=bicg_restart,
                           bicg_half=bicg_half, bicg_full=bicg_full)


# --------------------------------------------------------------------------
# CSR matrix
# --------------------------------------------------------------------------

class CSRMatrix:
    """A sparse matrix in compressed sparse row form, stored in Taichi ndarrays.

    Implements the linear operator protocol (``apply``, ``diagonal``,
    ``apply_transpose``, ``normal_diagonal``) with one gather loop per row,
    so there are no floating-point atomics and results are deterministic.
    The transpose is built in CSR on first use of ``apply_transpose``.

    ``shape`` defaults to square ``(len(indptr) - 1,) * 2``.  Duplicate
    entries are summed, as in scipy.
    """

    def __init__(self, indptr, indices, data, shape: Optional[tuple[int, int]] = None):
        runtime.ensure_init()
        indptr = np.asarray(indptr)
        indices = np.asarray(indices)
        data = np.asarray(data)
        nrows = indptr.size - 1
        m, n = (nrows, nrows) if shape is None else (int(shape[0]), int(shape[1]))
        _validate_csr(indptr, indices, data, m, n)
        self.m, self.n = m, n
        self.nnz = int(indices.size)
        self._host = (indptr.astype(np.int32), indices.astype(np.int32),
                      data.astype(runtime.np_real()))
        self._generation = runtime.generation()
        self._row_kernels, self._col_kernels = _kernels(m), _kernels(n)
        self._rows = _upload_csr(*self._host)
        self._cols = None   # transpose, built on demand

    @classmethod
    def from_scipy(cls, matrix) -> "CSRMatrix":
        """From any scipy.sparse matrix or array (converted to CSR)."""
        csr = matrix.tocsr()
        return cls(csr.indptr, csr.indices, csr.data, shape=csr.shape)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.m, self.n)

    def apply(self, x, y) -> None:
        """y[:m] = A @ x[:n]."""
        self.apply_dot(x, y, y)

    def apply_dot(self, x, y, a) -> tuple[float, float]:
        """y[:m] = A @ x[:n]; returns (<a, y>, <y, y>) over the m rows."""
        runtime.check_generation(self._generation, "CSRMatrix")
        indptr, indices, data = self._rows
        return self._row_kernels.csr_matvec_dot(indptr, indices, data, x, y, a, self.m)

    def apply_transpose(self, x, y) -> None:
        """y[:n] = A.T @ x[:m]."""
        indptr, indices, data = self._transpose()
        self._col_kernels.csr_matvec_dot(indptr, indices, data, x, y, y, self.n)

    def diagonal(self, d) -> None:
        """d[:min(m, n)] = diag(A)."""
        runtime.check_generation(self._generation, "CSRMatrix")
        indptr, indices, data = self._rows
        rows = min(self.m, self.n)
        self._row_kernels.csr_diagonal(indptr, indices, data, d, rows)

    def normal_diagonal(self, d) -> None:
        """d[:n] = diag(A.T @ A), the squared column norms."""
        indptr, _, data = self._transpose()
        self._col_kernels.csr_row_sq_norms(indptr, data, d, self.n)

    def _transpose(self):
        runtime.check_generation(self._generation, "CSRMatrix")
        if self._cols is None:
            indptr, indices, data = self._host
            rows = np.repeat(np.arange(self.m, dtype=np.int32), np.diff(indptr))
            order = np.argsort(indices, kind="stable")
            t_indptr = np.zeros(self.n + 1, dtype=np.int32)
            np.cumsum(np.bincount(indices, minlength=self.n), out=t_indptr[1:])
            self._cols = _upload_csr(t_indptr, rows[order], data[order])
        return self._cols


def _validate_csr(indptr, indices, data, m, n) -> None:
    if indptr.ndim != 1 or indices.ndim != 1 or data.ndim != 1:
        raise InputError("CSR arrays indptr, indices, data must be 1-D")
    if m < 1 or n < 1:
        raise InputError(f"CSR matrix must have at least one row and column, got shape ({m}, {n})")
    if indptr.size != m + 1:
        raise InputError(f"CSR indptr has {indptr.size} entries, expected rows + 1 = {m + 1}")
    if indices.size != data.size:
        raise InputError(f"CSR indices ({indices.size}) and data ({data.size}) differ in length")
    if not (np.issubdtype(indptr.dtype, np.integer) and np.issubdtype(indices.dtype, np.integer)):
        raise InputError("CSR indptr and indices must be integer arrays")
    if data.dtype == bool or not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
        raise InputError(f"CSR data must be real, got dtype {data.dtype}")
    if max(indices.size, n) >= 2**31:
        raise InputError("CSR matrix too large for 32-bit indices")
    if indptr[0] != 0 or indptr[-1] != indices.size or np.any(np.diff(indptr) < 0):
        raise InputError("CSR indptr must start at 0, be non-decreasing and end at nnz")
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise InputError(f"CSR column indices must lie in [0, {n})")
    if not np.all(np.isfinite(data)):
        bad = int(np.flatnonzero(~np.isfinite(data))[0])
        raise InputError(f"CSR data contains a non-finite value (entry {bad})")


def _upload_csr(indptr, indices, data):
    ti = _ti()
    out = []
    for arr, dtype in ((indptr, ti.i32), (indices, ti.i32), (data, runtime.real_dtype())):
        nd = runtime.array(dtype, max(arr.size, 1))   # Taichi has no empty ndarrays
        if arr.size:
            nd.from_numpy(np.ascontiguousarray(arr))
        out.append(nd)
    return tuple(out)


# --------------------------------------------------------------------------
# Workspace
# --------------------------------------------------------------------------

class Workspace:
    """Work vectors of one problem size, allocated on first use and reused.

    Solves sharing a workspace must not overlap (e.g. an operator whose
    ``apply`` runs another solve of the same size needs its own workspace).
    """

    def __init__(self, n: int, m: Optional[int] = None):
        runtime.ensure_init()
        self.n = int(n)
        self.m = self.n if m is None else int(m)
        self.precision = runtime.state().precision
        self.generation = runtime.generation()
        self._vectors: dict[tuple[str, int], object] = {}

    def vector(self, name: str, size: int, cols: int = 1):
        """The work vector ``name`` of length ``size``, of ``cols`` columns
        (:mod:`taichi_hh.linalg.columns`)."""
        runtime.check_generation(self.generation, "Workspace")
        key = (name, size, cols)
        if key not in self._vectors:
            self._vectors[key] = runtime.array(None, size, None if cols == 1 else cols)
        return self._vectors[key]


_WORKSPACES: "OrderedDict[tuple, Workspace]" = OrderedDict()
_WORKSPACE_CACHE_SIZE = 4


def get_workspace(n: int, m: Optional[int] = None) -> Workspace:
    """The cached workspace for (n, m, precision) in the current runtime
    (least recently used ones beyond a few are dropped)."""
    runtime.ensure_init()
    m = n if m is None else m
    key = (n, m, runtime.state().precision, runtime.generation())
    if key in _WORKSPACES:
        _WORKSPACES.move_to_end(key)
    else:
        _WORKSPACES[key] = Workspace(n, m)
        while len(_WORKSPACES) > _WORKSPACE_CACHE_SIZE:
            _WORKSPACES.popitem(last=False)
    return _WORKSPACES[key]


def clear_workspace_cache() -> None:
    _WORKSPACES.clear()


# --------------------------------------------------------------------------
# Results and stopping tests
# --------------------------------------------------------------------------

@dataclass
class SolveResult:
    """Outcome of a solve.  ``reason`` is ``"converged"`` or a failure reason.
    ``x``: the solution as numpy (copied from ``x_ndarray``, the solver's own
    Taichi array, on first access: a caller that only needs the Taichi array pays
    no host copy)."""

    x_ndarray: object
    converged: bool
    reason: str
    iterations: int
    relative_residual: float          # ||b - A x|| / ||b||, recomputed from x
    history: np.ndarray               # monitored residual: initial, then one per iteration
    seconds: float
    applies: int                      # operator applies, A and A^T
    method: str
    message: str = ""
    normal_residual: Optional[float] = None   # CGNR: ||A^T (b - A x)|| / ||A^T b||
    n: int = 0                                # unknowns: x is x_ndarray[:n]
    detail: str = ""                          # the failure's cause, as in message
    _x: Optional[np.ndarray] = field(default=None, repr=False)

    @property
    def x(self) -> np.ndarray:
        if self._x is None:
            self._x = self.x_ndarray.to_numpy()[: self.n]
        return self._x

    @x.setter
    def x(self, value) -> None:
        self._x = value


@dataclass
class _Settings:
    tol: float
    max_iterations: int
    stagnation_window: int
    divergence_factor: float
    callback: Optional[Callable]


@dataclass
class _Monitor:
    """Iteration count, residual history and the divergence/stagnation tests."""

    settings: _Settings
    iterations: int = 0
    history: list = field(default_factory=list)
    _scale: float = 1.0

    def start(self, value: float) -> None:
        if not self.history:
            self.history.append(value)
            self._scale = max(value, 1.0)

    def record(self, value: float) -> Optional[tuple[str, str]]:
        """Record one iteration's residual; returns (reason, detail) of a
        divergence or stagnation, or None."""
        self.iterations += 1
        self.history.append(value)
        if self.settings.callback is not None:
            self.settings.callback(self.iterations, value)
        s = self.settings
        if value > s.divergence_factor * self._scale:
            return ("divergence", f"residual grew above {s.divergence_factor:.0e} times "
                    f"its initial scale {self._scale:.3e}")
        # the window grows with the run (a third of it): slow solves (thousands of
        # iterations at large N) plateau for longer than fast ones
        w = max(s.stagnation_window, self.iterations // 3)
        if self.iterations >= 2 * w:
            # Window against window, not against the best ever: CG and BiCGSTAB
            # residuals are not monotone and may exceed the initial one for
            # tens of iterations before converging.
            recent = min(self.history[-w:])
            before = min(self.history[-2 * w:-w])
            if not recent < (1.0 - _STAGNATION_RTOL) * before:
                return ("stagnation", f"the last {w} iterations did not lower the residual "
                        f"below {recent:.3e}, the {w} before them reached {before:.3e}")
        return None


def _failure_message(method: str, reason: str, iteration: int, relres: float, detail: str) -> str:
    return (f"{method} failed: {reason} at iteration {iteration} "
            f"(relative residual {relres:.3e}): {detail}")


# --------------------------------------------------------------------------
# Input preparation
# --------------------------------------------------------------------------

def _check_operator(A, method: str, *, square: bool, transpose: bool = False) -> tuple[int, int]:
    """(m, n) of a valid operator."""
    n = getattr(A, "n", None)
    if not isinstance(n, (int, np.integer)) or n < 1 or not callable(getattr(A, "apply", None)):
        raise InputError(f"{method}: A must implement the linear operator protocol "
                         "(an int attribute n >= 1 and apply(x, y))")
    m = int(getattr(A, "m", n))
    if square and m != n:
        raise InputError(f"{method} needs a square operator, got m={m}, n={n}; use cgnr")
    if transpose and not callable(getattr(A, "apply_transpose", None)):
        raise InputError(f"{method}: A has no apply_transpose(x, y)")
    return m, int(n)


def _is_ndarray(v) -> bool:
    return isinstance(v, _ti().Ndarray)


def _check_ndarray(v, size: int, name: str) -> None:
    if len(v.shape) != 1 or v.shape[0] < size or v.dtype != runtime.real_dtype():
        raise InputError(f"{name} must be a 1-D {runtime.real_dtype()} ndarray of length "
                         f">= {size}, got shape {tuple(v.shape)} dtype {v.dtype}")


def _as_real_numpy(v, size: int, name: str) -> np.ndarray:
    arr = np.asarray(v)
    if arr.shape != (size,):
        raise InputError(f"{name} must have shape ({size},), got {arr.shape}")
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise InputError(f"{name} must be real, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=runtime.np_real())


def _load_rhs(b, m: int, ws: Workspace):
    """b itself when it is a suitable ndarray, else a workspace copy."""
    if _is_ndarray(b):
        _check_ndarray(b, m, "b")
        return b
    nd = ws.vector("b", m)
    nd.from_numpy(_as_real_numpy(b, m, "b"))
    return nd


def _initial_x(x0, n: int, k):
    """A fresh ndarray for the solution (it outlives the workspace): x0 or 0."""
    x = _ti().ndarray(runtime.real_dtype(), shape=(n,))
    if x0 is None:
        k.fill(x, 0.0, n)
    elif _is_ndarray(x0):
        _check_ndarray(x0, n, "x0")
        k.copy(x0, x, n)
    else:
        x.from_numpy(_as_real_numpy(x0, n, "x0"))
    return x


def _is_preconditioner_object(preconditioner) -> bool:
    return callable(getattr(preconditioner, "apply", None))


def _jacobi(preconditioner, A, ws: Workspace, n: int, k, method: str, *, normal: bool = False):
    """The inverse preconditioner diagonal ``dinv`` (ones without preconditioner
    or with a preconditioner object, which is applied separately)."""
    dinv = ws.vector("dinv", n)
    if _is_preconditioner_object(preconditioner) and normal:
        raise InputError(f"{method}: a preconditioner object is supported by bicgstab only; "
                         "use 'jacobi' or None")
    if preconditioner is None or _is_preconditioner_object(preconditioner):
        k.fill(dinv, 1.0, n)
        return dinv
    if preconditioner != "jacobi":
        raise InputError(f"{method}: preconditioner must be 'jacobi', None or an object "
                         f"with apply(r, z), got {preconditioner!r}")
    getter = "normal_diagonal" if normal else "diagonal"
    if not callable(getattr(A, getter, None)):
        raise InputError(f"{method}: the Jacobi preconditioner needs A.{getter}(d); "
                         "implement it or pass preconditioner=None")
    d = ws.vector("diag", n)
    getattr(A, getter)(d)
    bad = k.invert_diagonal(d, dinv, n)
    if bad >= 0:
        entry = (f"column {bad} of A is zero or non-finite (zero diagonal of A^T A)" if normal
                 else f"diagonal entry of row {bad} is zero or non-finite")
        raise InputError(f"{method}: Jacobi preconditioner: {entry}; "
                         "use preconditioner=None or reorder/scale the system")
    return dinv


def _settings(method, n, tol, max_iterations, stagnation_window, divergence_factor, callback):
    if not (tol > 0.0 and math.isfinite(tol)):
        raise InputError(f"{method}: tol must be a positive finite number, got {tol!r}")
    if max_iterations is None:
        max_iterations = max(1000, n)
    if max_iterations < 0:
        raise InputError(f"{method}: max_iterations must be >= 0, got {max_iterations}")
    if stagnation_window < 1:
        raise InputError(f"{method}: stagnation_window must be >= 1, got {stagnation_window}")
    if not divergence_factor > 1.0:
        raise InputError(f"{method}: divergence_factor must be > 1, got {divergence_factor}")
    return _Settings(float(tol), int(max_iterations), int(stagnation_window),
                     float(divergence_factor), callback)


# --------------------------------------------------------------------------
# Methods.  restart() recomputes the residual from x; step() is one iteration.
# Both return (relative residual, monitored value, breakdown detail or None);
# the monitored value is the relative residual except for least-squares CGNR.
# --------------------------------------------------------------------------

class _Method:
    name = ""

    def __init__(self, A, b, x, dinv, k, n: int, bnorm: float):
        self.A, self.b, self.x, self.dinv, self.k, self.n = A, b, x, dinv, k, n
        self.bnorm = bnorm
        self.btol = float(np.finfo(runtime.np_real()).eps)
        self.applies = 0
        self.normal_residual = None
        self._fused = callable(getattr(A, "apply_dot", None))

    def _apply(self, x, y) -> None:
        self.A.apply(x, y)
        self.applies += 1

    def _apply_dot(self, x, y, a) -> tuple[float, float]:
        """y = A x and (<a, y>, <y, y>): in the apply's own loop when the
        operator offers ``apply_dot`` (one pass over y fewer), else after it."""
        self.applies += 1
        if self._fused:
            return self.A.apply_dot(x, y, a)
        self.A.apply(x, y)
        return self.k.dot2(a, y, self.n)

    def _relres(self, rr: float) -> float:
        return math.sqrt(rr) / self.bnorm if rr >= 0.0 else math.nan


class _BiCGSTAB(_Method):
    name = "bicgstab"

    def __init__(self, A, b, x, dinv, k, n, bnorm, ws: Workspace, M=None):
        super().__init__(A, b, x, dinv, k, n, bnorm)
        v = ws.vector
        self.r, self.r_hat, self.p = v("r", n), v("r_hat", n), v("p", n)
        self.v, self.t, self.z = v("v", n), v("t", n), v("z", n)
        # A preconditioner object: the kernels' z = dinv * (.) (dinv = 1) is
        # overwritten by z = M^-1 (.) right after each of them.
        self.M = M
        self._z_pending = False

    def _precondition(self, src) -> None:
        if self.M is not None:
            self.M.apply(src, self.z)

    def restart(self):
        self._apply(self.x, self.t)
        rr = self.k.bicg_restart(self.b, self.t, self.r, self.r_hat, self.p, self.z,
                                 self.dinv, 1.0, self.n)
        # z = M^-1 p is needed only if the iteration goes on (here and after each
        # step): a solve's last iteration and the restart that confirms
        # convergence skip that application of M
        self._z_pending = self.M is not None
        self.rr = self.rho = self.rhat2 = rr
        relres = self._relres(rr)
        return relres, relres, None

    def step(self):
        if self._z_pending:
            self._precondition(self.p)
            self._z_pending = False
        rv, vv = self._apply_dot(self.z, self.v, self.r_hat)
        ss, alpha, half_flag = self.k.bicg_half(self.x, self.r, self.v, self.z, self.dinv, rv, vv,
                                         self.rho, self.rhat2, 1.0, self.btol, self.n)
        if half_flag:   # x and r untouched
            relres = self._relres(self.rr)
            return relres, relres, "<r_hat, A M^-1 p> vanished"
        self._precondition(self.r)      # r holds s
        ts, tt = self._apply_dot(self.z, self.t, self.r)
        rr, rho, omega_flag, rho_flag = self.k.bicg_full(
            self.x, self.r, self.r_hat, self.p, self.v, self.t, self.z, self.dinv,
            ts, tt, ss, alpha, self.rho, self.rhat2, 1.0, self.btol, self.n)
        self.rr, self.rho = rr, rho
        self._z_pending = self.M is not None     # z = M^-1 p: in the next step, if any
        relres = self._relres(rr)
        failure = None
        if omega_flag:
            failure = "omega = <t, s>/<t, t> vanished (A M^-1 s orthogonal to s)"
        elif rho_flag:
            failure = "rho = <r_hat, r> vanished (residual orthogonal to the shadow residual)"
        return relres, relres, failure


class _CG(_Method):
    name = "cg"

    def __init__(self, A, b, x, dinv, k, n, bnorm, ws: Workspace):
        super().__init__(A, b, x, dinv, k, n, bnorm)
        self.r, self.p, self.q = ws.vector("r", n), ws.vector("p", n), ws.vector("q", n)

    def restart(self):
        self._apply(self.x, self.q)
        rr, self.rz, zz = self.k.cg_restart(self.b, self.q, self.r, self.p, self.dinv, self.n)
        relres = self._relres(rr)
        failure = None
        if abs(self.rz) <= self.btol * math.sqrt(rr) * math.sqrt(zz):
            failure = "<r, M^-1 r> vanished (preconditioner not definite)"
        return relres, relres, failure

    def step(self):
        self._apply(self.p, self.q)
        rr, self.rz, pq_flag, rz_flag = self.k.cg_step(
            self.x, self.r, self.p, self.q, self.dinv, self.rz, self.btol, self.n)
        relres = self._relres(rr)
        failure = None
        if pq_flag:
            failure = "<p, A p> vanished (A singular or indefinite)"
        elif rz_flag:
            failure = "<r, M^-1 r> vanished (preconditioner not definite)"
        return relres, relres, failure


class _CGNR(_Method):
    name = "cgnr"

    def __init__(self, A, b, x, dinv, k, n, bnorm, ws: Workspace, m: int, atb_norm: float,
                 least_squares: bool):
        super().__init__(A, b, x, dinv, k, n, bnorm)
        self.m, self.atb_norm, self.least_squares = m, atb_norm, least_squares
        self.r, self.w = ws.vector("r", m), ws.vector("w", m)
        self.z, self.p = ws.vector("z", n), ws.vector("p", n)

    def _apply_transpose(self, x, y) -> None:
        self.A.apply_transpose(x, y)
        self.applies += 1

    def _status(self, rr: float, zz: float, failure):
        relres = self._relres(rr)
        if self.atb_norm > 0.0:
            self.normal_residual = math.sqrt(zz) / self.atb_norm
        else:
            self.normal_residual = 0.0 if zz == 0.0 else math.inf
        return relres, (self.normal_residual if self.least_squares else relres), failure

    def _least_squares_reached(self, rr: float) -> Optional[str]:
        if self.gamma == 0.0 and rr > 0.0 and not self.least_squares:
            return ("A^T r = 0 with r != 0: the least-squares solution is reached but the "
                    "system is inconsistent (least_squares=True accepts it)")
        return None

    def _direction(self, gamma_old: float) -> float:
        """z = A^T r, then the new search direction; returns ||z||^2."""
        self._apply_transpose(self.r, self.z)
        self.gamma, zz = self.k.nr_direction(self.z, self.p, self.dinv, gamma_old, self.n)
        return zz

    def restart(self):
        self._apply(self.x, self.w)
        rr = self.k.nr_residual(self.b, self.w, self.r, self.m)
        self.zz = self._direction(0.0)
        return self._status(rr, self.zz, self._least_squares_reached(rr))

    def step(self):
        self._apply(self.p, self.w)
        rr, flag = self.k.nr_update(self.x, self.r, self.p, self.w, self.gamma, self.m, self.n)
        if flag:   # x and r untouched
            return self._status(rr, self.zz, "||A p|| vanished (A rank deficient)")
        self.zz = self._direction(self.gamma)
        return self._status(rr, self.zz, self._least_squares_reached(rr))


# --------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------

def _iterate(method: _Method, mon: _Monitor) -> tuple[str, str, float]:
    """Run ``method`` until a stopping test fires.  Returns (reason, detail,
    true relative residual of the final x).

    A breakdown inside the iteration restarts the method from the true residual
    (for BiCGSTAB a new shadow residual ``r_hat = r``, the standard remedy); it is
    reported only when it recurs more than ``_MAX_BREAKDOWN_RESTARTS`` times or
    the restart itself breaks down.
    """
    s = mon.settings
    replacements = 0
    breakdowns = 0
    restart_cause = None
    while True:
        relres, value, failure = method.restart()
        if restart_cause is None:
            mon.start(value)
        if not (math.isfinite(relres) and math.isfinite(value)):
            return "non-finite", "the residual b - A x is not finite (NaN/inf in x0 or A)", relres
        if value <= s.tol:
            return "converged", "", relres
        if restart_cause == "claimed convergence":
            # The updated residual claimed convergence but the true one disagrees:
            # continue from the true residual, a bounded number of times.
            replacements += 1
            if replacements > _MAX_RESIDUAL_REPLACEMENTS:
                return "stagnation", (f"the updated residual reached tol but the true one "
                                      f"stays at {value:.3e}: tol is below the attainable "
                                      "accuracy"), relres
        if failure:
            return "breakdown", failure, relres
        while True:
            if mon.iterations >= s.max_iterations:
                return "max_iterations", f"iteration cap {s.max_iterations} reached", \
                    method.restart()[0]
            relres, value, failure = method.step()
            verdict = mon.record(value)
            if not (math.isfinite(relres) and math.isfinite(value)):
                return "non-finite", "NaN/inf appeared during the iteration", relres
            if value <= s.tol:
                restart_cause = "claimed convergence"
                break   # confirmed or refuted by the true residual in restart()
            if failure:
                breakdowns += 1
                if breakdowns > _MAX_BREAKDOWN_RESTARTS:
                    return "breakdown", (f"{failure}; {breakdowns - 1} restarts did not "
                                         "cure it"), method.restart()[0]
                restart_cause = "breakdown"
                break
            if verdict:
                return verdict + (method.restart()[0],)


def _finish(method: _Method, mon: _Monitor, reason: str, detail: str, relres: float,
            t0: float, raise_on_failure: bool) -> SolveResult:
    converged = reason == "converged"
    message = "" if converged else _failure_message(method.name, reason, mon.iterations,
                                                    relres, detail)
    result = SolveResult(x_ndarray=method.x, n=method.n,
                         converged=converged, reason=reason, iterations=mon.iterations,
                         relative_residual=relres, history=np.asarray(mon.history, dtype=float),
                         seconds=time.perf_counter() - t0, applies=method.applies,
                         method=method.name, message=message,
                         normal_residual=method.normal_residual,
                         detail="" if converged else detail)
    if not converged and raise_on_failure:
        raise SolverError(message, reason=reason, iteration=mon.iterations, residual=relres)
    return result


def _solve(method: _Method, settings: _Settings, t0: float, raise_on_failure: bool) -> SolveResult:
    mon = _Monitor(settings)
    if not math.isfinite(method.bnorm):
        reason, relres = "non-finite", math.nan
        detail = "b contains NaN or inf (found before iterating)"
        mon.start(math.nan)
    elif method.bnorm == 0.0:
        method.k.fill(method.x, 0.0, method.n)   # the exact solution, whatever x0
        reason, detail, relres = "converged", "", 0.0
        mon.start(0.0)
    else:
        reason, detail, relres = _iterate(method, mon)
    return _finish(method, mon, reason, detail, relres, t0, raise_on_failure)


# --------------------------------------------------------------------------
# Several right-hand sides at once
# --------------------------------------------------------------------------

@dataclass
class _Column:
    """One column's progress in :func:`bicgstab_columns`."""

    monitor: _Monitor
    bnorm: float
    state: str = "running"          # "running", "converged" or "handover"
    relres: float = math.nan
    replacements: int = 0
    breakdowns: int = 0


def bicgstab_columns(A, B, *, tol: float = 1e-6, max_iterations: Optional[int] = None,
                     preconditioner: Optional[str] = "jacobi", raise_on_failure: bool = True,
                     stagnation_window: int = STAGNATION_WINDOW,
                     divergence_factor: float = 1e6,
                     workspace: Optional[Workspace] = None) -> list:
    """Solve ``A x_c = b_c`` for every column ``b_c`` of ``B`` (shape ``(n, cols)``)
    with BiCGSTAB, the columns together: each iteration applies ``A`` and the
    preconditioner once to all columns, so an operator bound by memory traffic
    (the SPH Poisson rows at large N) reads its coefficients once for all of
    them.  Each column runs its own BiCGSTAB, with the iterates and the stopping
    tests of :func:`bicgstab`; a converged column is frozen while the others
    go on.  Returns one :class:`SolveResult` per column (``seconds`` and
    ``applies`` are the joint solve's).

    The joint iteration needs an operator and a preconditioner object that take
    several columns (an attribute ``accepts_columns = True``: apply and
    apply_dot then take vectors of ``cols``-vectors, :mod:`taichi_hh.linalg.columns`);
    otherwise the columns are solved one after the other.  A column that
    breaks down beyond the usual restarts, stagnates, diverges, turns
    non-finite or reaches the iteration cap is handed to :func:`bicgstab`,
    warm-started from its iterate with the iterations left, and goes on
    alone: its result (or :class:`~taichi_hh.errors.SolverError`) is that
    solve's, its iterations and history the two's together.  Other arguments
    as :func:`bicgstab`.
    """
    t0 = time.perf_counter()
    runtime.ensure_init()
    _, n = _check_operator(A, "bicgstab", square=True)
    B = np.asarray(B)
    if B.ndim != 2 or B.shape[0] != n or B.shape[1] < 1:
        raise InputError(f"bicgstab_columns: B must have shape ({n}, cols), got {B.shape}")
    cols = B.shape[1]
    single = dict(tol=tol, max_iterations=max_iterations, preconditioner=preconditioner,
                  raise_on_failure=raise_on_failure, stagnation_window=stagnation_window,
                  divergence_factor=divergence_factor, workspace=workspace)
    M = preconditioner if _is_preconditioner_object(preconditioner) else None
    joint = (cols > 1 and getattr(A, "accepts_columns", False)
             and callable(getattr(A, "apply_dot", None))
             and (M is None or getattr(M, "accepts_columns", False)))
    if not joint:
        return [bicgstab(A, B[:, c], **single) for c in range(cols)]
    settings = _settings("bicgstab", n, tol, max_iterations, stagnation_window,
                         divergence_factor, None)
    ws = workspace or get_workspace(n)
    k = _kernels(n)
    kc = _column_kernels(n, cols)
    b = ws.vector("b", n, cols)
    b.from_numpy(_as_real_numpy(B.reshape(-1), n * cols, "B").reshape(n, cols))
    dinv = _jacobi(preconditioner, A, ws, n, k, "bicgstab")
    vec = {name: ws.vector(name, n, cols) for name in ("r", "r_hat", "p", "v", "t", "z")}
    x = runtime.array(None, n, cols)
    bnorm = np.sqrt(np.asarray(kc.norm2(b, n).to_numpy(), dtype=float))
    columns = [_Column(_Monitor(settings), float(bn)) for bn in bnorm]
    btol = float(np.finfo(runtime.np_real()).eps)
    rho = np.zeros(cols)
    rhat2 = np.zeros(cols)
    applies = 0

    def relres(rr):
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(rr >= 0.0, np.sqrt(np.abs(rr)) / np.maximum(bnorm, 1e-300), np.nan)

    def restart(mask):
        """The true residual of the masked columns, restarted from it."""
        nonlocal applies
        A.apply_dot(x, vec["t"], vec["t"])
        applies += 1
        rr = np.asarray(kc.bicg_restart(b, vec["t"], vec["r"], vec["r_hat"], vec["p"], vec["z"],
                                        dinv, mask.astype(float), n).to_numpy(), dtype=float)
        rho[mask] = rr[mask]
        rhat2[mask] = rr[mask]
        return relres(rr)

    for col in columns:
        if not math.isfinite(col.bnorm):
            col.state = "handover"      # b non-finite: bicgstab reports it
        elif col.bnorm == 0.0:
            col.state, col.relres = "converged", 0.0   # x = 0, the exact solution
            col.monitor.start(0.0)
    running = np.array([c.state == "running" for c in columns])
    if running.any():
        start = restart(running)
        for c, col in enumerate(columns):
            if col.state == "running":
                col.monitor.start(start[c])
                col.relres = start[c]
                if not math.isfinite(start[c]):
                    col.state = "handover"
                elif start[c] <= settings.tol:
                    col.state = "converged"
    z_pending = M is not None
    while True:
        active = np.array([c.state == "running" for c in columns], dtype=float)
        if not active.any():
            break
        if z_pending:
            M.apply(vec["p"], vec["z"])
        rv, vv = A.apply_dot(vec["z"], vec["v"], vec["r_hat"])
        ss, alpha, half_flag = (np.asarray(a.to_numpy(), dtype=float) for a in kc.bicg_half(
            x, vec["r"], vec["v"], vec["z"], dinv, rv, vv, rho, rhat2, active, btol, n))
        if M is not None:
            M.apply(vec["r"], vec["z"])       # r holds s
        ts, tt = A.apply_dot(vec["z"], vec["t"], vec["r"])
        applies += 2
        # a column whose half step broke down keeps x and r: no second half either
        going = active * (1.0 - half_flag)
        rr, rho_new, omega_flag, rho_flag = (np.asarray(a.to_numpy(), dtype=float) for a in kc.bicg_full(
            x, vec["r"], vec["r_hat"], vec["p"], vec["v"], vec["t"], vec["z"], dinv,
            ts, tt, ss, alpha, rho, rhat2, going, btol, n))
        z_pending = M is not None
        value = relres(rr)
        check = np.zeros(cols, dtype=bool)      # to restart from the true residual
        for c, col in enumerate(columns):
            if not active[c]:
                continue
            rho[c] = rho_new[c]
            verdict = col.monitor.record(value[c])
            col.relres = value[c]
            if not math.isfinite(value[c]):
                col.state = "handover"
            elif value[c] <= settings.tol:
                check[c] = True             # claimed convergence: confirmed or refuted
            elif half_flag[c] or omega_flag[c] or rho_flag[c]:
                col.breakdowns += 1
                if col.breakdowns > _MAX_BREAKDOWN_RESTARTS:
                    col.state = "handover"
                else:
                    check[c] = True
            elif verdict or col.monitor.iterations >= settings.max_iterations:
                col.state = "handover"
        if check.any():
            true = restart(check)
            for c in np.flatnonzero(check):
                col = columns[c]
                col.relres = true[c]
                if not math.isfinite(true[c]):
                    col.state = "handover"
                elif true[c] <= settings.tol:
                    col.state = "converged"
                elif value[c] <= settings.tol:
                    col.replacements += 1
                    if col.replacements > _MAX_RESIDUAL_REPLACEMENTS:
                        col.state = "handover"
    seconds = time.perf_counter() - t0
    X = x.to_numpy().reshape(-1, cols)[:n].astype(np.float64)
    results = []
    for c, col in enumerate(columns):
        if col.state == "converged":
            results.append(SolveResult(
                x_ndarray=None, n=n, converged=True, reason="converged",
                iterations=col.monitor.iterations, relative_residual=float(col.relres),
                history=np.asarray(col.monitor.history, dtype=float), seconds=seconds,
                applies=applies, method="bicgstab", _x=X[:, c].copy()))
            continue
        # the column bicgstab reports on its own, from its iterate when finite
        x0 = X[:, c] if np.all(np.isfinite(X[:, c])) and math.isfinite(col.bnorm) else None
        rest = dict(single, raise_on_failure=False,
                    max_iterations=max(settings.max_iterations - col.monitor.iterations, 0))
        res = bicgstab(A, B[:, c], x0, **rest)
        res.iterations += col.monitor.iterations
        # its history goes on from the joint one's (its first entry: the same iterate)
        joint_history = np.asarray(col.monitor.history, dtype=float)
        res.history = np.concatenate([joint_history,
                                      res.history[1:] if joint_history.size else res.history])
        res.applies += applies
        res.seconds += seconds
        if not res.converged:
            if res.reason == "max_iterations":
                # the cap of the whole solve, not of the handover's remainder
                # (which is 0 when the joint iteration used it all up)
                res.detail = f"iteration cap {settings.max_iterations} reached"
            res.message = _failure_message("bicgstab", res.reason, res.iterations,
                                           res.relative_residual, res.detail)
            if raise_on_failure:
                raise SolverError(res.message, reason=res.reason, iteration=res.iterations,
                                  residual=res.relative_residual)
        results.append(res)
    return results


# --------------------------------------------------------------------------
# Public solvers
# --------------------------------------------------------------------------

def bicgstab(A, b, x0=None, *, tol: float = 1e-6, max_iterations: Optional[int] = None,
             preconditioner: Optional[str] = "jacobi", raise_on_failure: bool = True,
             callback: Optional[Callable[[int, float], None]] = None,
             stagnation_window: int = STAGNATION_WINDOW, divergence_factor: float = 1e6,
             workspace: Optional[Workspace] = None) -> SolveResult:
    """Solve ``A x = b`` with BiCGSTAB (van der Vorst 1992), right-preconditioned.

    Right preconditioning (``x`` advances along ``M^-1 p`` and ``M^-1 s`` with
    ``M = diag(A)``; Barrett et al. 1994, Templates, Fig. 2.10) keeps the
    recurrence residual the unpreconditioned ``b - A x``, so the stopping test
    ``||b - A x|| / ||b|| <= tol`` needs no extra work.  Each iteration costs
    two operator applies and two fused kernels.

    A: square linear operator (module doc).  b, x0: numpy arrays of shape
    ``(n,)`` or real Taichi ndarrays of length >= n; x0 is a warm start
    (default 0).  ``b = 0`` returns ``x = 0`` at once.  preconditioner:
    ``"jacobi"`` or None.  callback: ``callback(iteration, relative_residual)``
    after every iteration.  workspace: work vectors to use (default: a cached
    one per size).  Stopping tests and failure reasons: module doc.
    """
    return _solve_square(_BiCGSTAB, A, b, x0, preconditioner, raise_on_failure, workspace,
                         tol, max_iterations, stagnation_window, divergence_factor, callback)


def cg(A, b, x0=None, *, tol: float = 1e-6, max_iterations: Optional[int] = None,
       preconditioner: Optional[str] = "jacobi", raise_on_failure: bool = True,
       callback: Optional[Callable[[int, float], None]] = None,
       stagnation_window: int = STAGNATION_WINDOW, divergence_factor: float = 1e6,
       workspace: Optional[Workspace] = None) -> SolveResult:
    """Solve ``A x = b`` for symmetric definite ``A`` with Jacobi-preconditioned
    conjugate gradients (Hestenes & Stiefel 1952).

    Arguments and stopping tests as :func:`bicgstab`.  One operator apply and
    one fused kernel per iteration.  ``A`` may be negative definite (the
    Jacobi preconditioner then is too; the iteration is unchanged).
    """
    return _solve_square(_CG, A, b, x0, preconditioner, raise_on_failure, workspace,
                         tol, max_iterations, stagnation_window, divergence_factor, callback)


def _solve_square(cls, A, b, x0, preconditioner, raise_on_failure, workspace, *settings_args):
    t0 = time.perf_counter()
    runtime.ensure_init()
    _, n = _check_operator(A, cls.name, square=True)
    settings = _settings(cls.name, n, *settings_args)
    ws = workspace or get_workspace(n)
    k = _kernels(n)
    b_nd = _load_rhs(b, n, ws)
    x = _initial_x(x0, n, k)
    bnorm = math.sqrt(k.norm2(b_nd, n))
    dinv = _jacobi(preconditioner, A, ws, n, k, cls.name)
    if _is_preconditioner_object(preconditioner):
        if cls is not _BiCGSTAB:
            raise InputError(f"{cls.name}: a preconditioner object is supported by bicgstab "
                             "only; use 'jacobi' or None")
        method = cls(A, b_nd, x, dinv, k, n, bnorm, ws, M=preconditioner)
    else:
        method = cls(A, b_nd, x, dinv, k, n, bnorm, ws)
    return _solve(method, settings, t0, raise_on_failure)


def cgnr(A, b, x0=None, *, tol: float = 1e-6, max_iterations: Optional[int] = None,
         preconditioner: Optional[str] = "jacobi", least_squares: bool = False,
         raise_on_failure: bool = True, callback: Optional[Callable[[int, float], None]] = None,
         stagnation_window: int = STAGNATION_WINDOW, divergence_factor: float = 1e6,
         workspace: Optional[Workspace] = None) -> SolveResult:
    """Solve ``A x = b`` (A is m x n) by CG on the normal equations
    ``A^T A x = A^T b`` (CGNR; Saad 2003, Alg. 8.4), as Colin et al. 2006
    Sec. 3.5 do for their stacked (overdetermined) boundary system.

    Needs ``A.apply_transpose``.  ``preconditioner="jacobi"`` scales by
    ``diag(A^T A)`` (squared column norms, from ``A.normal_diagonal``).
    Converged when ``||b - A x|| / ||b|| <= tol`` (a consistent system).  With
    ``least_squares=True`` the monitored and tested quantity is instead the
    normal residual ``||A^T (b - A x)|| / ||A^T b||`` (the least-squares
    solution of an inconsistent system); ``result.normal_residual`` reports it
    either way.  Two applies (A, A^T) and two fused kernels per iteration; the
    rate follows cond(A)^2, so prefer BiCGSTAB for square systems.
    Other arguments as :func:`bicgstab`.
    """
    t0 = time.perf_counter()
    runtime.ensure_init()
    m, n = _check_operator(A, "cgnr", square=False, transpose=True)
    settings = _settings("cgnr", n, tol, max_iterations, stagnation_window, divergence_factor,
                         callback)
    ws = workspace or get_workspace(n, m)
    k = _kernels(max(m, n))
    b_nd = _load_rhs(b, m, ws)
    x = _initial_x(x0, n, k)
    bnorm = math.sqrt(k.norm2(b_nd, m))
    dinv = _jacobi(preconditioner, A, ws, n, k, "cgnr", normal=True)
    atb = ws.vector("z", n)
    A.apply_transpose(b_nd, atb)
    atb_norm = math.sqrt(k.norm2(atb, n))
    method = _CGNR(A, b_nd, x, dinv, k, n, bnorm, ws, m, atb_norm, least_squares)
    method.applies = 1
    if least_squares and atb_norm == 0.0 and 0.0 < bnorm < math.inf:
        # b is orthogonal to range(A): x = 0 is the least-squares solution.
        k.fill(x, 0.0, n)
        method.normal_residual = 0.0
        mon = _Monitor(settings)
        mon.start(0.0)
        return _finish(method, mon, "converged", "", 1.0, t0, raise_on_failure)
    return _solve(method, settings, t0, raise_on_failure)
