"""The Krylov solvers' Taichi kernels: vector operations and each method's fused
iteration steps, on one right-hand side or several (:mod:`taichi_hh.linalg.columns`).

Cost model: a kernel launch costs ~0.1 ms of Python-side argument handling
(more with more ndarray arguments), plus ~0.1 ms per parallel loop to wake
the CPU thread pool.  So each iteration is a few fused kernels, each a
sequence of loops with the scalar algebra between them done in the kernel,
returning its reductions as a tuple: BiCGSTAB uses 2 kernels besides its 2
operator applies (3 passes over the vectors; the new vectors' dot products
come from ``apply_dot``), CG 1 besides 1 apply, CGNR 2 besides 2.  Below
:data:`PARALLEL_MIN_SIZE` entries the loops run serially, which is faster
there than waking the thread pool.  Reductions accumulate in kernel-scope
locals (per-thread partial sums, no contended atomics) and come back as the
kernel's return values, so no extra launch reads them.
"""
from functools import lru_cache
from types import SimpleNamespace

import taichi as ti

from taichi_hh import runtime
from taichi_hh.linalg import lanes
from taichi_hh.linalg.columns import zeros

__all__ = ["PARALLEL_MIN_SIZE", "serial_below_threshold", "solver_kernels"]

# Vector sizes below which loops run on one thread: a serial pass over 1e5
# entries beats waking the thread pool (docs/notes/linalg.md).
PARALLEL_MIN_SIZE = 200_000


def serial_below_threshold(size: int) -> bool:
    """Whether loops over ``size`` entries run serially (:data:`PARALLEL_MIN_SIZE`
    on the CPU; never on a GPU, :func:`taichi_hh.runtime.on_gpu`)."""
    return size < PARALLEL_MIN_SIZE and not runtime.on_gpu()


def solver_kernels(size: int, cols: int = 1) -> SimpleNamespace:
    """The kernel set for vectors of ``size`` entries and ``cols`` columns in the
    current precision.  Every set has the vector kernels (``fill``, ``copy``,
    ``norm2``, ``dot2``, ``invert_diagonal``) and BiCGSTAB's (``bicg_restart``,
    ``bicg_half``, ``bicg_full``, ``bicg_direction``: None but under the
    GPU's schedule); the one-column set also CG's and CGNR's,
    which solve one right-hand side only."""
    runtime.ensure_init()
    return _build(runtime.state().precision, serial_below_threshold(size), cols, lanes.on())


@ti.func
def negligible(dot, aa, bb, btol):
    """|<a, b>| <= btol ||a|| ||b||, given <a, b>, ||a||^2 and ||b||^2: below it a
    dot product is rounding noise (the solvers' breakdown test)."""
    return ti.abs(dot) <= btol * ti.sqrt(aa) * ti.sqrt(bb)


@ti.func
def indicator(cond):
    """1.0 where cond holds, else 0.0 (per column)."""
    return ti.select(cond, 1.0, 0.0)


@ti.func
def _half_alpha(rv, vv, rho, rhat2, active, btol):
    """BiCGSTAB's alpha = rho / <r_hat, v> per column, 0 where the column is
    frozen or the dot product is rounding noise."""
    ok = active * (1.0 - indicator(negligible(rv, rhat2, vv, btol)))
    return ti.select(ok > 0.0, rho / rv, 0.0)


@ti.func
def bicg_omega(ts, tt, active):
    """BiCGSTAB's omega = <t, s> / <t, t> per column, 0 where frozen or t = 0."""
    return ti.select((tt > 0.0) & (active > 0.0), ts / tt, 0.0)


@ti.func
def bicg_flags(ts, tt, ss, rr, rho_new, rhat2, active, btol):
    """BiCGSTAB's breakdown flags per column: omega's (<t, s> rounding noise)
    and rho's (<r_hat, r> rounding noise).  Computed where they are used,
    not kept across the kernel's loops (docs/arch.md: CUDA)."""
    return (active * indicator(negligible(ts, tt, ss, btol)),
            active * indicator(negligible(rho_new, rhat2, rr, btol)))


def _with_partials(kernel, values: int, cols: int):
    def call(*args):
        return kernel(*args, lanes.partials(values, cols))
    return call


@lru_cache(maxsize=None)
def _build(precision: str, serial: bool, cols: int, in_lanes: bool = False) -> SimpleNamespace:
    """Compile-once kernel set.  Built lazily because the real type of the
    arguments and return values depends on the runtime precision; ``serial``,
    ``cols`` and ``in_lanes`` (the GPU's reductions, :mod:`taichi_hh.linalg.
    lanes`) are compile-time settings, not data."""
    kernels = _vector_kernels(precision, serial, cols, in_lanes)
    kernels.update(_bicgstab_kernels(precision, serial, cols, in_lanes))
    # the reducing kernels take their partials last (used on a GPU only)
    reducing = [("norm2", 1), ("dot2", 2), ("bicg_restart", 1), ("bicg_half", 1),
                ("bicg_full", 2)]
    if cols == 1:
        kernels.update(_cg_kernels(precision, serial, in_lanes))
        kernels.update(_cgnr_kernels(precision, serial, in_lanes))
        reducing += [("cg_restart", 3), ("cg_step", 3), ("nr_residual", 1),
                     ("nr_direction", 2), ("nr_update", 1)]
    for name, values in reducing:
        kernels[name] = _with_partials(kernels[name], values, cols)
    return SimpleNamespace(**kernels)


def _types(precision: str, cols: int):
    """(real, per-column scalar, column vector, real vector) Taichi types."""
    real = ti.f64 if precision == "f64" else ti.f32
    scal = real if cols == 1 else ti.types.vector(cols, real)
    return real, scal, ti.types.ndarray(dtype=scal, ndim=1), ti.types.ndarray(dtype=real, ndim=1)


def _vector_kernels(precision: str, serial: bool, cols: int, in_lanes: bool) -> dict:
    real, scal, vec, rvec = _types(precision, cols)

    @ti.kernel
    def fill(a: vec, value: real, n: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(n):
            a[i] = value * (zeros(cols) + 1.0)

    @ti.kernel
    def copy(src: vec, dst: vec, n: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(n):
            dst[i] = src[i]

    @ti.func
    def square_entry(i, a: ti.template()):
        return a[i] * a[i]

    @ti.func
    def dots_entry(i, a: ti.template(), y: ti.template()):
        return lanes.pack2(cols, a[i] * y[i], y[i] * y[i])

    @ti.kernel
    def norm2(a: vec, n: ti.i32, part: ti.types.ndarray()) -> scal:
        return lanes.fold_entries(n, square_entry, (a,), 1, cols, lanes.ADD, in_lanes, serial,
                                  part)

    @ti.kernel
    def dot2(a: vec, y: vec, n: ti.i32, part: ti.types.ndarray()) -> (scal, scal):
        """(<a, y>, <y, y>)."""
        total = lanes.fold_entries(n, dots_entry, (a, y), 2, cols, lanes.ADD, in_lanes, serial,
                                   part)
        return lanes.unpack(cols, total, 0), lanes.unpack(cols, total, 1)

    @ti.kernel
    def invert_diagonal(d: rvec, dinv: rvec, n: ti.i32) -> ti.i32:
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

    return dict(fill=fill, copy=copy, norm2=norm2, dot2=dot2, invert_diagonal=invert_diagonal)


def _bicgstab_kernels(precision: str, serial: bool, cols: int, in_lanes: bool) -> dict:
    """BiCGSTAB (right-preconditioned, M^-1 = dinv) on ``cols`` columns, each its
    own iteration: the scalars (alpha, omega, rho, ...) are per column, and so
    are ``active`` (1: iterating, 0: frozen, e.g. converged: x and r stay) and
    the restart's ``mask`` (1: restart this column).  Each kernel's entry work
    is one ``ti.func``, looped over the entries directly on the CPU and in
    lanes on a GPU (``in_lanes``: :mod:`taichi_hh.linalg.lanes`)."""
    real, scal, vec, rvec = _types(precision, cols)

    @ti.func
    def restart_entry(i, mask, b: ti.template(), ax: ti.template(), r: ti.template(),
                      r_hat: ti.template(), p: ti.template(), z: ti.template(),
                      dinv: ti.template()):
        restart = mask > 0.0
        ri = ti.select(restart, b[i] - ax[i], r[i])
        pi = ti.select(restart, ri, p[i])
        r[i] = ri
        r_hat[i] = ti.select(restart, ri, r_hat[i])
        p[i] = pi
        z[i] = dinv[i] * pi
        return ri * ri

    @ti.func
    def half_entry(i, rv, vv, rho, rhat2, active, btol, x: ti.template(), r: ti.template(),
                   v: ti.template(), z: ti.template(), dinv: ti.template()):
        alpha = _half_alpha(rv, vv, rho, rhat2, active, btol)
        x[i] += alpha * z[i]
        si = r[i] - alpha * v[i]
        r[i] = si
        z[i] = dinv[i] * si
        return si * si

    @ti.func
    def full_entry(i, ts, tt, active, x: ti.template(), r: ti.template(),
                   r_hat: ti.template(), t: ti.template(), z: ti.template()):
        omega = bicg_omega(ts, tt, active)
        x[i] += omega * z[i]
        ri = r[i] - omega * t[i]
        r[i] = ri
        return lanes.pack2(cols, ri * ri, r_hat[i] * ri)

    # Storage sharing (element-wise safe): s overwrites r, and z holds
    # phat = M^-1 p until the half step turns it into shat = M^-1 s.  The
    # per-column scalars come first among the arguments, and no kernel-scope
    # vector is read by a loop (docs/arch.md: Taichi 1.7 on CUDA).
    @ti.kernel
    def bicg_restart(mask: scal, b: vec, ax: vec, r: vec, r_hat: vec, p: vec, z: vec,
                     dinv: rvec, n: ti.i32, part: ti.types.ndarray()) -> scal:
        """In the masked columns r = b - A x and r_hat = p = r; z = M^-1 p.
        Returns ||r||^2."""
        return lanes.fold_entries(n, restart_entry, (mask, b, ax, r, r_hat, p, z, dinv), 1,
                                  cols, lanes.ADD, in_lanes, serial, part)

    @ti.kernel
    def bicg_half(rv: scal, vv: scal, rho: scal, rhat2: scal, active: scal, x: vec, r: vec,
                  v: vec, z: vec, dinv: rvec, btol: real, n: ti.i32,
                  part: ti.types.ndarray()) -> (scal, scal, scal):
        """Given v = A phat and its dots rv = <r_hat, v>, vv = <v, v> (from the
        apply): alpha = rho / rv; x += alpha phat; s = r - alpha v (into r);
        z = shat = M^-1 s.  Returns (||s||^2, alpha, breakdown flag); on
        breakdown alpha = 0 and x, r are unchanged."""
        ss = lanes.fold_entries(n, half_entry, (rv, vv, rho, rhat2, active, btol, x, r, v, z,
                                                dinv), 1, cols, lanes.ADD, in_lanes, serial, part)
        ok = active * (1.0 - indicator(negligible(rv, rhat2, vv, btol)))
        return ss, _half_alpha(rv, vv, rho, rhat2, active, btol), active - ok

    @ti.func
    def direction_entry(i, ts, tt, active, r: ti.template(), p: ti.template(),
                        v: ti.template(), z: ti.template(), dinv: ti.template(),
                        beta_slot: ti.template()):
        pi = r[i] + beta_slot[0] * (p[i] - bicg_omega(ts, tt, active) * v[i])
        p[i] = pi
        z[i] = dinv[i] * pi

    @ti.kernel
    def bicg_full(ts: scal, tt: scal, ss: scal, alpha: scal, rho: scal, rhat2: scal,
                  active: scal, x: vec, r: vec, r_hat: vec, p: vec, v: vec, t: vec, z: vec,
                  dinv: rvec, btol: real, n: ti.i32, beta_slot: vec,
                  part: ti.types.ndarray()) -> (scal, scal, scal, scal):
        """Given t = A shat and its dots ts = <s, t>, tt = <t, t> (from the apply)
        and ss = ||s||^2: omega = ts / tt; x += omega shat; r = s - omega t;
        then the next direction p = r + beta (p - omega v), z = phat = M^-1 p
        (with the sums in lanes, by :func:`bicg_direction` after it).
        Returns (||r||^2, rho_new, omega flag, rho flag).  ``beta_slot`` (one
        entry) carries beta from the sums to the direction's loop."""
        total = lanes.fold_entries(n, full_entry, (ts, tt, active, x, r, r_hat, t, z), 2, cols,
                                   lanes.ADD, in_lanes, serial, part)
        rr = lanes.unpack(cols, total, 0)
        rho_new = lanes.unpack(cols, total, 1)
        omega_flag, rho_flag = bicg_flags(ts, tt, ss, rr, rho_new, rhat2, active, btol)
        go = active * (1.0 - omega_flag) * (1.0 - rho_flag)
        beta_slot[0] = ti.select(go > 0.0, (rho_new / rho) * (alpha / bicg_omega(ts, tt, active)), 0.0)
        if ti.static(not in_lanes):
            ti.loop_config(serialize=serial)
            for i in range(n):
                direction_entry(i, ts, tt, active, r, p, v, z, dinv, beta_slot)
        omega_end, rho_end = bicg_flags(ts, tt, ss, rr, rho_new, rhat2, active, btol)
        return rr, rho_new, omega_end, rho_end

    @ti.kernel
    def bicg_direction(ts: scal, tt: scal, active: scal, r: vec, p: vec, v: vec, z: vec,
                       dinv: rvec, n: ti.i32, beta_slot: vec):
        """bicg_full's direction, p = r + beta (p - omega v), z = M^-1 p, as a
        kernel of its own after it: with the sums in lanes, the fold and this
        loop in one kernel gave p 1e13 off and z = 0 on two columns (Taichi
        1.7's SPIR-V, lavapipe; tests/test_lanes.py), as if the loop read its
        arrays wrongly."""
        for i in range(n):
            direction_entry(i, ts, tt, active, r, p, v, z, dinv, beta_slot)

    return dict(bicg_restart=bicg_restart, bicg_half=bicg_half, bicg_full=bicg_full,
                bicg_direction=bicg_direction if in_lanes else None)


def _cg_kernels(precision: str, serial: bool, in_lanes: bool) -> dict:
    """Preconditioned CG (M^-1 = dinv), one column; sums as in BiCGSTAB's
    kernels (in lanes on a GPU)."""
    real, _, vec, _ = _types(precision, 1)

    @ti.func
    def restart_entry(i, b: ti.template(), ax: ti.template(), r: ti.template(),
                      p: ti.template(), dinv: ti.template()):
        ri = b[i] - ax[i]
        zi = dinv[i] * ri
        r[i] = ri
        p[i] = zi
        return lanes.pack3(1, ri * ri, ri * zi, zi * zi)

    @ti.func
    def curvature_entry(i, p: ti.template(), q: ti.template()):
        return lanes.pack3(1, p[i] * q[i], p[i] * p[i], q[i] * q[i])

    @ti.func
    def update_entry(i, alpha, x: ti.template(), r: ti.template(), p: ti.template(),
                     q: ti.template(), dinv: ti.template()):
        x[i] += alpha * p[i]
        ri = r[i] - alpha * q[i]
        zi = dinv[i] * ri
        r[i] = ri
        return lanes.pack3(1, ri * ri, ri * zi, zi * zi)

    @ti.kernel
    def cg_restart(b: vec, ax: vec, r: vec, p: vec, dinv: vec, n: ti.i32,
                   part: ti.types.ndarray()) -> (real, real, real):
        """r = b - A x; p = M^-1 r.  Returns (||r||^2, <r, M^-1 r>, ||M^-1 r||^2)."""
        total = lanes.fold_entries(n, restart_entry, (b, ax, r, p, dinv), 3, 1, lanes.ADD,
                                   in_lanes, serial, part)
        return total[0], total[1], total[2]

    @ti.kernel
    def cg_step(x: vec, r: vec, p: vec, q: vec, dinv: vec, rz: real, btol: real,
                n: ti.i32, part: ti.types.ndarray()) -> (real, real, real, real):
        """alpha = rz/<p, q>; x += alpha p; r -= alpha q; p = M^-1 r + beta p.
        Returns (||r||^2, rz_new, <p,q> flag, rz flag); alpha = 0 on breakdown."""
        dots = lanes.fold_entries(n, curvature_entry, (p, q), 3, 1, lanes.ADD, in_lanes,
                                  serial, part)
        pq, pp, qq = dots[0], dots[1], dots[2]
        alpha = 0.0
        pq_flag = 1.0
        if not negligible(pq, pp, qq, btol):
            alpha = rz / pq
            pq_flag = 0.0
        sums = lanes.fold_entries(n, update_entry, (alpha, x, r, p, q, dinv), 3, 1, lanes.ADD,
                                  in_lanes, serial, part)
        rr, rz_new, zz = sums[0], sums[1], sums[2]
        rz_flag = 1.0 if negligible(rz_new, rr, zz, btol) else 0.0
        beta = 0.0
        if rz_flag == 0.0:
            beta = rz_new / rz
        ti.loop_config(serialize=serial)
        for i in range(n):
            p[i] = dinv[i] * r[i] + beta * p[i]
        return rr, rz_new, pq_flag, rz_flag

    return dict(cg_restart=cg_restart, cg_step=cg_step)


def _cgnr_kernels(precision: str, serial: bool, in_lanes: bool) -> dict:
    """CG on A^T A x = A^T b, preconditioned by M^-1 = dinv, one column; sums
    as in BiCGSTAB's kernels (in lanes on a GPU)."""
    real, _, vec, _ = _types(precision, 1)

    @ti.func
    def residual_entry(i, b: ti.template(), ax: ti.template(), r: ti.template()):
        ri = b[i] - ax[i]
        r[i] = ri
        return ri * ri

    @ti.func
    def gamma_entry(i, z: ti.template(), dinv: ti.template()):
        return lanes.pack2(1, z[i] * dinv[i] * z[i], z[i] * z[i])

    @ti.func
    def square_entry(i, w: ti.template()):
        return w[i] * w[i]

    @ti.func
    def update_entry(i, alpha, m, n, x: ti.template(), r: ti.template(), p: ti.template(),
                     w: ti.template()):
        rr = 0.0
        if i < n:
            x[i] += alpha * p[i]
        if i < m:
            ri = r[i] - alpha * w[i]
            r[i] = ri
            rr = ri * ri
        return rr

    @ti.kernel
    def nr_residual(b: vec, ax: vec, r: vec, m: ti.i32, part: ti.types.ndarray()) -> real:
        """r = b - A x.  Returns ||r||^2."""
        return lanes.fold_entries(m, residual_entry, (b, ax, r), 1, 1, lanes.ADD, in_lanes,
                                  serial, part)

    @ti.kernel
    def nr_direction(z: vec, p: vec, dinv: vec, gamma_old: real, n: ti.i32,
                     part: ti.types.ndarray()) -> (real, real):
        """z = A^T r: gamma = <z, M^-1 z>; p = M^-1 z + (gamma/gamma_old) p
        (a fresh start when gamma_old = 0).  Returns (gamma, ||z||^2)."""
        sums = lanes.fold_entries(n, gamma_entry, (z, dinv), 2, 1, lanes.ADD, in_lanes, serial,
                                  part)
        gamma, zz = sums[0], sums[1]
        beta = 0.0
        if gamma_old != 0.0:
            beta = gamma / gamma_old
        ti.loop_config(serialize=serial)
        for i in range(n):
            p[i] = dinv[i] * z[i] + beta * p[i]
        return gamma, zz

    @ti.kernel
    def nr_update(x: vec, r: vec, p: vec, w: vec, gamma: real, m: ti.i32,
                  n: ti.i32, part: ti.types.ndarray()) -> (real, real):
        """w = A p: alpha = gamma/||w||^2; x += alpha p; r -= alpha w.
        Returns (||r||^2, breakdown flag); alpha = 0 when A p = 0."""
        ww = lanes.fold_entries(m, square_entry, (w,), 1, 1, lanes.ADD, in_lanes, serial, part)
        alpha = 0.0
        flag = 1.0
        if ww > 0.0:
            alpha = gamma / ww
            flag = 0.0
        rr = lanes.fold_entries(ti.max(m, n), update_entry, (alpha, m, n, x, r, p, w), 1, 1,
                                lanes.ADD, in_lanes, serial, part)
        return rr, flag

    return dict(nr_residual=nr_residual, nr_direction=nr_direction, nr_update=nr_update)
