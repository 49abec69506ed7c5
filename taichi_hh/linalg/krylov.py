"""Matrix-free Krylov solvers on Taichi ndarrays: BiCGSTAB (one right-hand side
or several at once), CG and CGNR.

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
``A.accepts_columns`` (optional, default False)
    True when ``apply`` and ``apply_dot`` also take vectors of ``cols``-vectors
    (:mod:`taichi_hh.linalg.columns`) and return the dot products per column:
    :func:`bicgstab_columns` then iterates all columns together.
``A.apply_transpose(x, y)`` (optional)
    Writes ``y[:n] = A.T @ x[:m]``; needed by :func:`cgnr`.
``A.normal_diagonal(d)`` (optional)
    Writes the diagonal of ``A.T @ A`` (squared column norms) into ``d[:n]``;
    needed by :func:`cgnr` with the Jacobi preconditioner.

:class:`~taichi_hh.linalg.csr.CSRMatrix` implements all of it but columns.

Solvers
-------
:func:`bicgstab` and :func:`bicgstab_columns` (van der Vorst 1992, right
preconditioning), :func:`cg` (Hestenes & Stiefel 1952, Jacobi preconditioning)
and :func:`cgnr` (CG on the normal equations ``A^T A x = A^T b``, as Colin et
al. 2006 Sec. 3.5 do for their stacked boundary system) share one driver:
each right-hand side (column) has its own state, stopping tests and counters
(:mod:`taichi_hh.linalg.stopping`), and an iteration steps the running columns
together, a mask freezing the stopped ones (as scipy's iterative solvers handle
several right-hand sides).  One column is the k = 1 case of the same loop.
The stopping tests, per column:

* converged: the relative residual ``||b - A x|| / ||b||`` is at most ``tol``.
  The iterations update the residual by recurrence; when the recurrence
  claims convergence the residual is recomputed as ``b - A x`` and iterating
  continues from it if the true one is still above ``tol`` (at most
  ``stopping.MAX_RESIDUAL_REPLACEMENTS`` times, then ``"stagnation"``).  The reported
  ``relative_residual`` is always the recomputed one.
* ``"breakdown"``: a quantity the method divides by is negligible relative to
  its scale, i.e. ``|<a, b>| <= eps * ||a|| ||b||`` with ``eps`` the machine
  epsilon of the real type (below it a dot product is rounding noise):
  BiCGSTAB's ``rho = <r_hat, r>``, ``<r_hat, v>`` and ``omega``'s ``<t, s>``;
  CG's ``<p, A p>`` and ``<r, M^-1 r>``; CGNR's ``||A p|| = 0``.  A breakdown
  restarts the column from its true residual (for BiCGSTAB a new shadow
  residual ``r_hat = r``, the standard remedy); it is reported when it recurs
  more than ``stopping.MAX_BREAKDOWN_RESTARTS`` times or the restart itself breaks down.
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

The kernels and their cost model: :mod:`taichi_hh.linalg.krylov_kernels`.
"""
import math
import os
import time
from collections import OrderedDict
from typing import Callable, Optional, Protocol, runtime_checkable

import numpy as np
import taichi as ti

from taichi_hh import runtime
from taichi_hh.errors import InputError, SolverError
from taichi_hh.linalg.krylov_kernels import solver_kernels
from taichi_hh.linalg.stopping import (FAILURE_REASONS, STAGNATION_WINDOW, Column, Monitor,
                                       Settings, SolveResult, State, checked_settings,
                                       failure_message)

__all__ = ["LinearOperator", "SolveResult", "Workspace", "get_workspace",
           "clear_workspace_cache", "bicgstab", "bicgstab_columns", "cg", "cgnr",
           "FAILURE_REASONS", "STAGNATION_WINDOW"]

#: set to 1: :func:`bicgstab_columns` iterates the columns together on CUDA too
JOINT_COLUMNS_VARIABLE = "TAICHI_HH_JOINT_COLUMNS"


@runtime_checkable
class LinearOperator(Protocol):
    """Structural type of the operators the solvers accept (see module doc)."""

    n: int

    def apply(self, x, y) -> None: ...

    def diagonal(self, d) -> None: ...


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
        self._vectors: dict[tuple[str, int, int], object] = {}

    @property
    def vectors(self) -> dict:
        """The work vectors made so far, by ``(name, size, cols)`` (a copy)."""
        return dict(self._vectors)

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
    return isinstance(v, ti.Ndarray)


def _check_ndarray(v, size: int, name: str) -> None:
    if len(v.shape) != 1 or v.shape[0] < size or v.dtype != runtime.real_dtype():
        raise InputError(f"{name} must be a 1-D {runtime.real_dtype()} ndarray of length "
                         f">= {size}, got shape {tuple(v.shape)} dtype {v.dtype}")


def _as_real_numpy(v, shape: tuple, name: str) -> np.ndarray:
    arr = np.asarray(v)
    if arr.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {arr.shape}")
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise InputError(f"{name} must be real, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=runtime.np_real())


def _load_rhs(b, m: int, ws: Workspace, cols: int = 1):
    """b itself when it is a suitable ndarray, else a workspace copy (``cols``
    columns: b of shape (m, cols))."""
    if _is_ndarray(b):
        _check_ndarray(b, m, "b")
        return b
    nd = ws.vector("b", m, cols)
    nd.from_numpy(_as_real_numpy(b, (m,) if cols == 1 else (m, cols), "b"))
    return nd


def _initial_x(x0, n: int, k, cols: int = 1):
    """A fresh ndarray for the solution (it outlives the workspace): x0 or 0
    (several columns start at 0)."""
    if cols > 1:
        return runtime.array(None, n, cols)
    x = ti.ndarray(runtime.real_dtype(), shape=(n,))
    if x0 is None:
        k.fill(x, 0.0, n)
    elif _is_ndarray(x0):
        _check_ndarray(x0, n, "x0")
        k.copy(x0, x, n)
    else:
        x.from_numpy(_as_real_numpy(x0, (n,), "x0"))
    return x


def _per_column(values, cols: int) -> np.ndarray:
    """A kernel's per-column result (a float for one column, a Taichi vector
    for several) as a float array."""
    if cols == 1:
        return np.array([values], dtype=float)
    return np.asarray(values.to_numpy(), dtype=float)


def _is_preconditioner_object(preconditioner) -> bool:
    return callable(getattr(preconditioner, "apply", None))


def _jacobi(preconditioner, A, ws: Workspace, n: int, k, method: str, *, normal: bool = False):
    """The inverse preconditioner diagonal ``dinv`` (ones without preconditioner
    or with a preconditioner object, which is applied separately)."""
    dinv = ws.vector("dinv", n)
    if _is_preconditioner_object(preconditioner) and (normal or method != "bicgstab"):
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


# --------------------------------------------------------------------------
# Methods.  restart(mask) recomputes the masked columns' residuals from x;
# step(active) is one iteration of the active columns, the others frozen.
# Both return (relative residuals, monitored values, breakdown details or None),
# one per column; the monitored value is the relative residual except for
# least-squares CGNR.  CG and CGNR take one column.
# --------------------------------------------------------------------------

class _Method:
    name = ""

    def __init__(self, A, b, x, dinv, k, n: int, bnorm: np.ndarray):
        self.A, self.b, self.x, self.dinv, self.k, self.n = A, b, x, dinv, k, n
        self.bnorm = bnorm
        self.cols = len(bnorm)
        self.btol = float(np.finfo(runtime.np_real()).eps)
        self.applies = 0
        self.normal_residual = None
        self._fused = callable(getattr(A, "apply_dot", None))

    def _apply(self, x, y) -> None:
        self.A.apply(x, y)
        self.applies += 1

    def _apply_dot(self, x, y, a):
        """y = A x and (<a, y>, <y, y>): in the apply's own loop when the
        operator offers ``apply_dot`` (one pass over y fewer), else after it."""
        self.applies += 1
        if self._fused:
            return self.A.apply_dot(x, y, a)
        self.A.apply(x, y)
        return self.k.dot2(a, y, self.n)

    def _relres(self, rr) -> np.ndarray:
        """||r|| / ||b|| per column from ||r||^2 (NaN where that is negative)."""
        rr = np.atleast_1d(np.asarray(rr, dtype=float))
        scale = np.where(self.bnorm > 0.0, self.bnorm, 1.0)
        with np.errstate(invalid="ignore"):
            return np.where(rr >= 0.0, np.sqrt(np.abs(rr)) / scale, math.nan)

    def _arg(self, values):
        """Per-column scalars as a kernel argument: a float for one column."""
        return float(values[0]) if self.cols == 1 else values

    def _host(self, values) -> np.ndarray:
        return _per_column(values, self.cols)

    def zero_solution(self) -> None:
        """x = 0, the exact solution of b = 0 whatever x0 (one column: the only
        case with a warm start; several columns start at 0)."""
        if self.cols == 1:
            self.k.fill(self.x, 0.0, self.n)


class _BiCGSTAB(_Method):
    name = "bicgstab"

    def __init__(self, A, b, x, dinv, k, n, bnorm, ws: Workspace, M=None):
        super().__init__(A, b, x, dinv, k, n, bnorm)
        v = ws.vector
        cols = self.cols
        self.r, self.r_hat, self.p = v("r", n, cols), v("r_hat", n, cols), v("p", n, cols)
        self.v, self.t, self.z = v("v", n, cols), v("t", n, cols), v("z", n, cols)
        self.beta_slot = v("beta", 1, cols)
        self.rr, self.rho, self.rhat2 = np.zeros(cols), np.zeros(cols), np.zeros(cols)
        # A preconditioner object: the kernels' z = dinv * (.) (dinv = 1) is
        # overwritten by z = M^-1 (.) right after each of them.
        self.M = M
        self._z_pending = False

    def restart(self, mask):
        self._apply(self.x, self.t)
        rr = self._host(self.k.bicg_restart(self._arg(mask.astype(float)), self.b, self.t,
                                            self.r, self.r_hat, self.p, self.z, self.dinv,
                                            self.n))
        self.rr = np.where(mask, rr, self.rr)
        self.rho = np.where(mask, rr, self.rho)
        self.rhat2 = np.where(mask, rr, self.rhat2)
        # z = M^-1 p is needed only if the iteration goes on (here and after each
        # step): a solve's last iteration and the restart that confirms
        # convergence skip that application of M
        self._z_pending = self.M is not None
        relres = self._relres(rr)
        return relres, relres, [None] * self.cols

    def step(self, active):
        if self._z_pending:
            self.M.apply(self.p, self.z)
            self._z_pending = False
        rv, vv = self._apply_dot(self.z, self.v, self.r_hat)
        ss, alpha, half_flag = (self._host(a) for a in self.k.bicg_half(
            rv, vv, self._arg(self.rho), self._arg(self.rhat2), self._arg(active.astype(float)),
            self.x, self.r, self.v, self.z, self.dinv, self.btol, self.n))
        failures = [None] * self.cols
        for c in np.flatnonzero(half_flag):     # x and r untouched
            failures[c] = "<r_hat, A M^-1 p> vanished"
        going = active * (1.0 - half_flag)
        if going.any():     # else all broke down: no second half, restarts follow
            if self.M is not None:
                self.M.apply(self.r, self.z)        # r holds s
            ts, tt = self._apply_dot(self.z, self.t, self.r)
            rr, rho, omega_flag, rho_flag = (self._host(a) for a in self.k.bicg_full(
                ts, tt, self._arg(ss), self._arg(alpha), self._arg(self.rho),
                self._arg(self.rhat2), self._arg(going), self.x, self.r, self.r_hat, self.p,
                self.v, self.t, self.z, self.dinv, self.btol, self.n, self.beta_slot))
            if self.k.bicg_direction is not None:     # the GPU's schedule: a kernel apart
                self.k.bicg_direction(ts, tt, self._arg(going), self.r, self.p, self.v, self.z,
                                      self.dinv, self.n, self.beta_slot)
            self.rr = np.where(going > 0.0, rr, self.rr)
            self.rho = np.where(going > 0.0, rho, self.rho)
            self._z_pending = self.M is not None     # z = M^-1 p: in the next step, if any
            for c in np.flatnonzero(rho_flag):
                failures[c] = ("rho = <r_hat, r> vanished (residual orthogonal to the "
                               "shadow residual)")
            for c in np.flatnonzero(omega_flag):
                failures[c] = "omega = <t, s>/<t, t> vanished (A M^-1 s orthogonal to s)"
        relres = self._relres(self.rr)
        return relres, relres, failures


class _CG(_Method):
    name = "cg"

    def __init__(self, A, b, x, dinv, k, n, bnorm, ws: Workspace):
        super().__init__(A, b, x, dinv, k, n, bnorm)
        self.r, self.p, self.q = ws.vector("r", n), ws.vector("p", n), ws.vector("q", n)

    def restart(self, mask):
        self._apply(self.x, self.q)
        rr, self.rz, zz = self.k.cg_restart(self.b, self.q, self.r, self.p, self.dinv, self.n)
        relres = self._relres(rr)
        failure = None
        if abs(self.rz) <= self.btol * math.sqrt(rr) * math.sqrt(zz):
            failure = "<r, M^-1 r> vanished (preconditioner not definite)"
        return relres, relres, [failure]

    def step(self, active):
        self._apply(self.p, self.q)
        rr, self.rz, pq_flag, rz_flag = self.k.cg_step(
            self.x, self.r, self.p, self.q, self.dinv, self.rz, self.btol, self.n)
        relres = self._relres(rr)
        failure = None
        if pq_flag:
            failure = "<p, A p> vanished (A singular or indefinite)"
        elif rz_flag:
            failure = "<r, M^-1 r> vanished (preconditioner not definite)"
        return relres, relres, [failure]


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
        value = np.array([self.normal_residual]) if self.least_squares else relres
        return relres, value, [failure]

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

    def restart(self, mask):
        self._apply(self.x, self.w)
        rr = self.k.nr_residual(self.b, self.w, self.r, self.m)
        self.zz = self._direction(0.0)
        return self._status(rr, self.zz, self._least_squares_reached(rr))

    def step(self, active):
        self._apply(self.p, self.w)
        rr, flag = self.k.nr_update(self.x, self.r, self.p, self.w, self.gamma, self.m, self.n)
        if flag:   # x and r untouched
            return self._status(rr, self.zz, "||A p|| vanished (A rank deficient)")
        self.zz = self._direction(self.gamma)
        return self._status(rr, self.zz, self._least_squares_reached(rr))


# --------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------

def _iterate(method: _Method, columns: list, cap: int) -> None:
    """Run ``method`` until every column has stopped (converged or failed).

    Each round first restarts the columns that wait for their true residual
    (the start, a claimed convergence, a breakdown, a failure's report), then
    stops the columns at the iteration cap (tested before every step), then
    steps the running ones together.  A column that stops is frozen in the
    kernels (its mask entry 0) while the others go on."""
    while True:
        waiting = np.array([col.restart is not None for col in columns])
        if waiting.any():
            relres, value, failure = method.restart(waiting)
            for c in np.flatnonzero(waiting):
                columns[c].restarted(float(relres[c]), float(value[c]), failure[c])
        for col in columns:
            if col.state is State.RUNNING and col.restart is None \
                    and col.monitor.iterations >= cap:
                col.fail("max_iterations", f"iteration cap {cap} reached")
        if any(col.restart is not None for col in columns):
            continue
        active = np.array([col.state is State.RUNNING for col in columns])
        if not active.any():
            return
        relres, value, failure = method.step(active.astype(float))
        for c in np.flatnonzero(active):
            columns[c].stepped(float(relres[c]), float(value[c]), failure[c])


def _solve(method: _Method, settings: Settings, t0: float, raise_on_failure: bool) -> list:
    """The solve of every column of ``method``; one :class:`SolveResult` each."""
    columns = [Column(Monitor(settings)) for _ in range(method.cols)]
    for col, bnorm in zip(columns, method.bnorm):
        col.settle_by_rhs(float(bnorm))
    if (method.bnorm == 0.0).any():
        method.zero_solution()
    _iterate(method, columns, settings.max_iterations)
    return _results(method, columns, t0, raise_on_failure)


def _results(method: _Method, columns: list, t0: float, raise_on_failure: bool) -> list:
    seconds = time.perf_counter() - t0
    if method.cols > 1:
        X = method.x.to_numpy().reshape(-1, method.cols)[: method.n].astype(np.float64)
    results = []
    for c, col in enumerate(columns):
        converged = col.state is State.CONVERGED
        message = "" if converged else failure_message(
            method.name, col.reason, col.monitor.iterations, col.relres, col.detail)
        one = method.cols == 1
        results.append(SolveResult(
            x_ndarray=method.x if one else None, n=method.n, _x=None if one else X[:, c].copy(),
            converged=converged, reason=col.reason, iterations=col.monitor.iterations,
            relative_residual=float(col.relres),
            history=np.asarray(col.monitor.history, dtype=float), seconds=seconds,
            applies=method.applies, method=method.name, message=message,
            normal_residual=method.normal_residual, detail="" if converged else col.detail))
    if raise_on_failure:
        for res in results:
            if not res.converged:
                raise SolverError(res.message, reason=res.reason, iteration=res.iterations,
                                  residual=res.relative_residual)
    return results


def _solve_square(cls, A, b, x0, preconditioner, raise_on_failure, workspace, *settings_args,
                  cols: int = 1) -> list:
    t0 = time.perf_counter()
    runtime.ensure_init()
    _, n = _check_operator(A, cls.name, square=True)
    settings = checked_settings(cls.name, n, *settings_args)
    ws = workspace or get_workspace(n)
    k, kc = solver_kernels(n), solver_kernels(n, cols)
    b_nd = _load_rhs(b, n, ws, cols)
    x = _initial_x(x0, n, k, cols)
    dinv = _jacobi(preconditioner, A, ws, n, k, cls.name)
    bnorm = np.sqrt(_per_column(kc.norm2(b_nd, n), cols))
    extra = {"M": preconditioner} if _is_preconditioner_object(preconditioner) else {}
    method = cls(A, b_nd, x, dinv, kc, n, bnorm, ws, **extra)
    return _solve(method, settings, t0, raise_on_failure)


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
    ``"jacobi"``, None or an object with ``apply(r, z)`` (``z = M^-1 r``).
    callback: ``callback(iteration, relative_residual)`` after every
    iteration.  workspace: work vectors to use (default: a cached one per
    size).  Stopping tests and failure reasons: module doc.
    """
    return _solve_square(_BiCGSTAB, A, b, x0, preconditioner, raise_on_failure, workspace,
                         tol, max_iterations, stagnation_window, divergence_factor, callback)[0]


def bicgstab_columns(A, B, *, tol: float = 1e-6, max_iterations: Optional[int] = None,
                     preconditioner: Optional[str] = "jacobi", raise_on_failure: bool = True,
                     stagnation_window: int = STAGNATION_WINDOW,
                     divergence_factor: float = 1e6,
                     workspace: Optional[Workspace] = None) -> list:
    """Solve ``A x_c = b_c`` for every column ``b_c`` of ``B`` (shape ``(n, cols)``)
    with BiCGSTAB, the columns together: each iteration applies ``A`` and the
    preconditioner once to all columns, so an operator bound by memory traffic
    (the SPH Poisson rows at large N) reads its coefficients once for all of
    them.  Each column runs its own BiCGSTAB from x = 0, with the iterates,
    the stopping tests and the failures of :func:`bicgstab`; a column that
    stops (converged or failed) is frozen while the others go on.  Returns
    one :class:`SolveResult` per column (``seconds`` and ``applies`` are the
    joint solve's); with ``raise_on_failure`` the first failed column's
    :class:`~taichi_hh.errors.SolverError` is raised.

    The joint iteration needs an operator and a preconditioner object that take
    several columns (``accepts_columns``, module doc); otherwise the columns
    are solved one after the other.  Other arguments as :func:`bicgstab`.
    """
    _, n = _check_operator(A, "bicgstab", square=True)
    B = np.asarray(B)
    if B.ndim != 2 or B.shape[0] != n or B.shape[1] < 1:
        raise InputError(f"bicgstab_columns: B must have shape ({n}, cols), got {B.shape}")
    cols = B.shape[1]
    kwargs = dict(tol=tol, max_iterations=max_iterations, preconditioner=preconditioner,
                  raise_on_failure=raise_on_failure, stagnation_window=stagnation_window,
                  divergence_factor=divergence_factor, workspace=workspace)
    M = preconditioner if _is_preconditioner_object(preconditioner) else None
    # Not on CUDA: Taichi 1.7.4's CUDA backend faulted (misaligned address) in
    # the several-column BiCGSTAB kernels; one column at a time runs there
    # unless $TAICHI_HH_JOINT_COLUMNS=1 (to try it: benchmarks/
    # bicg_columns_probe.py, docs/arch.md)
    joint = (cols > 1 and getattr(A, "accepts_columns", False)
             and callable(getattr(A, "apply_dot", None))
             and (M is None or getattr(M, "accepts_columns", False))
             and (runtime.state().arch != "cuda"
                  or os.environ.get(JOINT_COLUMNS_VARIABLE, "") == "1"))
    if not joint:
        return [bicgstab(A, B[:, c], **kwargs) for c in range(cols)]
    return _solve_square(_BiCGSTAB, A, B, None, preconditioner, raise_on_failure, workspace,
                         tol, max_iterations, stagnation_window, divergence_factor, None,
                         cols=cols)


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
                         tol, max_iterations, stagnation_window, divergence_factor, callback)[0]


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
    settings = checked_settings("cgnr", n, tol, max_iterations, stagnation_window,
                                divergence_factor, callback)
    ws = workspace or get_workspace(n, m)
    k = solver_kernels(max(m, n))
    b_nd = _load_rhs(b, m, ws)
    x = _initial_x(x0, n, k)
    bnorm = math.sqrt(k.norm2(b_nd, m))
    dinv = _jacobi(preconditioner, A, ws, n, k, "cgnr", normal=True)
    atb = ws.vector("z", n)
    A.apply_transpose(b_nd, atb)
    atb_norm = math.sqrt(k.norm2(atb, n))
    method = _CGNR(A, b_nd, x, dinv, k, n, np.array([bnorm]), ws, m, atb_norm, least_squares)
    method.applies = 1
    if least_squares and atb_norm == 0.0 and 0.0 < bnorm < math.inf:
        # b is orthogonal to range(A): x = 0 is the least-squares solution.
        k.fill(x, 0.0, n)
        method.normal_residual = 0.0
        column = Column(Monitor(settings))
        column.converge(1.0, 0.0)
        return _results(method, [column], t0, raise_on_failure)[0]
    return _solve(method, settings, t0, raise_on_failure)[0]
