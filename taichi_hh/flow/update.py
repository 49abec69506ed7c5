"""The flow step's per-particle updates and reductions as Taichi kernels: the
velocity stays on the Taichi side through the step (predict, correct, advect), and
the diagnostics come back as kernel return values instead of host copies."""
import taichi as ti

from ..linalg import lanes
from ..sph.particles import FLUID


def max_speed2(n: int, kind, v) -> float:
    """max |v_i|^2 over the fluid rows (0 without fluid)."""
    return _max_speed2(n, kind, v, lanes.on(), lanes.partials(1))


@ti.func
def _speed2(i, kind: ti.template(), v: ti.template()):
    return ti.select(kind[i] == FLUID, v[i].dot(v[i]), 0.0)


@ti.kernel
def _max_speed2(n: ti.i32, kind: ti.types.ndarray(), v: ti.types.ndarray(),
                in_lanes: ti.template(), part: ti.types.ndarray()) -> float:
    return lanes.fold_entries(n, _speed2, (kind, v), 1, 1, lanes.MAX, in_lanes, False, part)


@ti.kernel
def predict(n: ti.i32, kind: ti.types.ndarray(), v: ti.types.ndarray(),
            lap: ti.types.ndarray(), viscous: ti.i32, nu: float, dt: float, gx: float,
            gy: float, w: ti.types.ndarray()):
    """w = v + dt (g + nu lap v) on the fluid rows (``lap``: lap v, read when
    ``viscous``), 0 on the others."""
    for i in range(n):
        # g built here, not before the loop: a kernel-scope vector read by a
        # loop faults on CUDA (Taichi 1.7; docs/arch.md)
        g = ti.Vector([gx, gy])
        if kind[i] == FLUID:
            a = g
            if viscous:
                a = g + nu * lap[i]
            w[i] = v[i] + dt * a
        else:
            w[i] = ti.Vector.zero(float, 2)


def divergence_stats(n: int, kind, d, w) -> tuple:
    """(max |d_i|, sum d_i^2, max |w_i|^2) over the fluid rows."""
    return _divergence_stats(n, kind, d, w, lanes.on(), lanes.partials(3))


@ti.func
def _divergence_terms(i, kind: ti.template(), d: ti.template(), w: ti.template()):
    fluid = kind[i] == FLUID
    return ti.Vector([ti.select(fluid, ti.abs(d[i]), 0.0), ti.select(fluid, d[i] * d[i], 0.0),
                      ti.select(fluid, w[i].dot(w[i]), 0.0)])


@ti.kernel
def _divergence_stats(n: ti.i32, kind: ti.types.ndarray(), d: ti.types.ndarray(),
                      w: ti.types.ndarray(), in_lanes: ti.template(),
                      part: ti.types.ndarray()) -> (float, float, float):
    total = lanes.fold_entries(n, _divergence_terms, (kind, d, w), 3, 1,
                               (lanes.MAX, lanes.ADD, lanes.MAX), in_lanes, False, part)
    return total[0], total[1], total[2]


@ti.kernel
def correct(n: ti.i32, kind: ti.types.ndarray(), rho: ti.types.ndarray(),
            grad_q: ti.types.ndarray(), w: ti.types.ndarray()):
    """w <- w - grad q / rho on the fluid rows (the projection's correction)."""
    for i in range(n):
        if kind[i] == FLUID:
            w[i] -= grad_q[i] / rho[i]


@ti.kernel
def remove(n: ti.i32, kind: ti.types.ndarray(), c: ti.types.ndarray(), w: ti.types.ndarray()):
    """w <- w - c on the fluid rows (the clean-up's correction M^-1 D^T lam)."""
    for i in range(n):
        if kind[i] == FLUID:
            w[i] -= c[i]


def advect(n: int, kind, pos, w, shifting: int, grad_c, diffusion: float, cap: float,
           dt: float, x0: float, y0: float, x1: float, y1: float, new_pos) -> tuple:
    """new_pos = pos + dt w + dr on the fluid rows (pos elsewhere), with the
    shifting displacement dr = -diffusion grad C no longer than ``cap`` (when
    ``shifting``; :mod:`taichi_hh.flow.shifting`).  Returns (sum of |new_pos| + |w|
    over the fluid, non-finite when any value is, and the count of fluid
    particles outside the box).  Nothing is written to the particles: see
    :func:`commit`."""
    total, out = _advect(n, kind, pos, w, shifting, grad_c, diffusion, cap, dt, x0, y0, x1, y1,
                         new_pos, lanes.on(), lanes.partials(2))
    return total, int(round(out))


@ti.func
def _advect_entry(i, kind: ti.template(), pos: ti.template(), w: ti.template(), shifting,
                  grad_c: ti.template(), diffusion, cap, dt, x0, y0, x1, y1,
                  new_pos: ti.template()):
    """Particle i's new position (written); returns (its |x| + |w| when fluid,
    1 when a fluid particle left the box)."""
    x = pos[i]
    terms = ti.Vector([0.0, 0.0])
    if kind[i] == FLUID:
        step = dt * w[i]
        if shifting:
            dr = -diffusion * grad_c[i]
            norm = dr.norm()
            if norm > cap:
                dr *= cap / norm
            step = dt * w[i] + dr
        x = x + step
        terms[0] = ti.abs(x[0]) + ti.abs(x[1]) + ti.abs(w[i][0]) + ti.abs(w[i][1])
        if not (x[0] > x0 and x[0] < x1 and x[1] > y0 and x[1] < y1):
            terms[1] = 1.0
    new_pos[i] = x
    return terms


@ti.kernel
def _advect(n: ti.i32, kind: ti.types.ndarray(), pos: ti.types.ndarray(),
            w: ti.types.ndarray(), shifting: ti.i32, grad_c: ti.types.ndarray(),
            diffusion: float, cap: float, dt: float, x0: float, y0: float, x1: float,
            y1: float, new_pos: ti.types.ndarray(), in_lanes: ti.template(),
            part: ti.types.ndarray()) -> (float, float):
    sums = lanes.fold_entries(n, _advect_entry, (kind, pos, w, shifting, grad_c, diffusion, cap,
                                                 dt, x0, y0, x1, y1, new_pos), 2, 1, lanes.ADD,
                              in_lanes, False, part)
    return sums[0], sums[1]      # the count exact in a float


@ti.kernel
def commit(n: ti.i32, kind: ti.types.ndarray(), new_pos: ti.types.ndarray(),
           w: ti.types.ndarray(), eps: float, x0: float, y0: float, x1: float, y1: float,
           pos: ti.types.ndarray(), vel: ti.types.ndarray()):
    """pos = new_pos, a fluid particle outside the box put back ``eps`` inside it
    (the walls are impermeable); vel = w on the fluid, 0 elsewhere."""
    for i in range(n):
        x = new_pos[i]
        if kind[i] == FLUID:
            if not (x[0] > x0 and x[0] < x1 and x[1] > y0 and x[1] < y1):
                x = ti.Vector([ti.min(ti.max(x[0], x0 + eps), x1 - eps),
                               ti.min(ti.max(x[1], y0 + eps), y1 - eps)])
            vel[i] = w[i]
        else:
            vel[i] = ti.Vector.zero(float, 2)
        pos[i] = x


@ti.kernel
def first_guess(n: ti.i32, ids: ti.types.ndarray(), q: ti.types.ndarray(),
                q_prev: ti.types.ndarray(), extrapolate: ti.i32, dt: float, dt_last: float,
                dt_before: float, border: float, x0: ti.types.ndarray()):
    """x0_i = the pressure solve's first guess at slot i from the impulses by
    particle id: q, or (``extrapolate``) dt times p = q / dt of the last two steps
    continued linearly in time; x0_n = ``border`` (the bordered system's unknown)."""
    for i in range(n):
        qi = q[ids[i]]
        if extrapolate:
            p_last = qi / dt_last
            p_before = q_prev[ids[i]] / dt_before
            qi = dt * (p_last + (p_last - p_before) * (dt / dt_last))
        x0[i] = qi
    x0[n] = border


@ti.kernel
def store_impulse(n: ti.i32, ids: ti.types.ndarray(), x: ti.types.ndarray(),
                  accumulate: ti.i32, q: ti.types.ndarray(), q_prev: ti.types.ndarray()) -> float:
    """The solved impulse x by particle id: q_prev <- q, q <- x (``accumulate``:
    q <- q + x, a further projection pass).  Returns x_n, the border unknown."""
    for i in range(n):
        k = ids[i]
        if accumulate:
            q[k] += x[i]
        else:
            q_prev[k] = q[k]
            q[k] = x[i]
    return x[n]
