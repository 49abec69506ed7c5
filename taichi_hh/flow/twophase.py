"""Two-phase incompressible SPH by projection (Petronetto Sec. 6d, Colin Sec. 3.7).

One time step:

1. predict   v* = v + dt (g + nu lap v)                  (explicit viscosity)
2. project   solve div(grad q / rho) = div w,  w <- w - grad q / rho,
             starting from w = v*, repeated ``projection_passes`` times or until
             max |div w| is below ``div_tol`` (the iterated projection of Colin
             Sec. 3.7; q = dt p is the pressure impulse)
2b. clean up (``exact_projection``, off by default) solve (D M^-1 D^T) lam = D w,
             w <- w - M^-1 D^T lam: the orthogonal step of
             :mod:`taichi_hh.hhd.project` with the mass-weighted norm (below)
3. advect    x <- x + dt v  (optionally plus a particle-shifting displacement)

Density-weighted projection: with two densities the pressure equation is
div(grad p / rho) = div v* / dt and the correction v* - dt grad p / rho; a
constant-coefficient projection would remove gravity whatever the density and
nothing would rise.  The inter-particle coefficient of the pressure Laplacian
is 2 / (rho_i + rho_j) (Cummins & Rudman 1999), which stays finite and
continuous across the interface.

Walls: a layer of wall particles (lattice, as wide as the kernel support) at
rest outside the box.  Their pressure follows the fluid next to them by the
Shepard sum plus the hydrostatic term (the generalised wall condition of Adami,
Hu & Adams 2012):  p_w = sum_f S_wf (p_f + rho_f g . (x_w - x_f)),  so that a
fluid at rest under gravity stays at rest.  In the pressure equation's right-hand
side the walls carry the Shepard-extrapolated fluid velocity and their rows add
the normal-velocity term (no penetration); in the viscous term they carry minus
the Shepard-extrapolated fluid velocity (no slip), or with ``walls="free-slip"``
its mirror image (the normal component reversed: no shear stress).

Measured divergence and the exact projection: ``D`` is the corrected divergence
(the pressure gradient's stencil, ``gradient``) of the fluid rows with the wall
particles at rest, i.e. zero velocity, which also encodes no penetration: a
fluid velocity into a wall is a divergence of the rows next to it.  The
step's ``max_div_before`` and ``max_div`` are max |D w| over the fluid before
(w = v*) and after the projection, ``div_norm_before`` and ``div_norm`` the
2-norms.  The Poisson step alone cannot drive ``D w`` to the solver tolerance:
its Laplacian is not ``D (1/rho) G`` (module doc of :mod:`taichi_hh.hhd.project`),
and it leaves max |D w| at 3-20% of its value before (0.07-0.10 at 10k
particles and t = 1-1.3 of the droplet).  With ``exact_projection`` the clean-up
step removes the rest: M = diag(particle mass) over the fluid particles (the
density-weighted projection: ``M^-1 D^T lam`` is ``-grad lam / rho`` up to the
volume), the walls are not unknowns (their velocity stays zero, their rows are
not constraints, lam = 0 there), and ``w - M^-1 D^T lam`` is the field closest
to ``w`` in ``sum_i m_i |u_i|^2`` with ``D u = 0``.  Jacobi-CG stops at
``||D w|| <= cleanup_tol * ||D w*||`` (2-norms over the fluid rows, w* = v*;
``cleanup_tol`` defaults to ``solver_tol``;
never below 1e3 machine epsilons of ||w|| / dx, and skipped when already
there), so max |div| after <= cleanup_tol sqrt(N) max |div| before; a failed
solve raises :class:`BlowUpError`.  ``cleanup_warm_start`` starts it from the
previous step's lam (on by default when the clean-up is on).

Cost of the clean-up, measured on the droplet scene (10 368 particles, 30 steps
from t = 1, on and off back to back in one process): Jacobi-CG takes a median
1170 iterations per step with warm start (874-1658; 1690 without), 450 at 800
particles, and a step 29 times as long as without it (4.9 s against 0.17 s,
machine noisy), where the default 6 s run allows 0.08 s per step more.  Over
the 30 steps the clean-up changed the kinetic energy by -0.07% and the volume
error from 0.33% mean / 4.6% max to 0.38% / 5.1%.  Remedies tried: warm start
(-30% iterations), BiCGSTAB preconditioned by the pressure matrix's multilevel
cycle (worse: 700 iterations of two applies each at 800 particles).  Hence off
by default (the scenes' ``--exact-projection`` turns it on); the tests switch
it on.

Why it is slow (``benchmarks/projection_conditioning.py``: the droplet at t = 1,
10 368 particles, ``S`` assembled from the flow's coefficients): ``S`` is the
square of a smoothing operator.  The Wendland gradient of support 3 dx answers
a wave of wavenumber k about like k W^(k) (W^ the kernel's transform): small
over the whole upper part of the resolved band, and zero at the three odd-even
carriers (pi/dx, 0), (0, pi/dx), (pi/dx, pi/dx) of a lattice.  The
Jacobi-scaled ``S`` has condition number 5e5 and a broad band of small
eigenvalues (``--spectrum``: 837 of the 10 368 below 1e-3 of the largest,
2581 below 1e-2); its lowest eigenvectors are smooth envelopes times
a checkerboard carrier, where the particles still sit on the initial lattice.
No local smoother reaches that band, so Jacobi-CG needs 90 / 914 / 1778
iterations for 1e-2 / 1e-4 / 1e-6 of ||D w*||, and aggregation-CG (pyamg, plain
aggregation on geometric cells, Gauss-Seidel) 364 with the constants as
candidates and 174 with the three carriers added.  With the kernel support
2 dx the band shrinks to the carriers' neighbourhood (condition 5e3, 162
eigenvalues below 1e-2; Jacobi-CG 215, aggregation with the carriers 26), but
the flow is much less accurate there (the droplet at 10k particles run to t = 1
with each support: volume error 2.0% mean / 17% max against 0.24% / 2.8%), and
26 clean-up iterations at 1.7 ms would still add 0.044 s to its 0.13 s step
before any preconditioner; at 2.5 dx (volume error 0.68% / 8.0%) aggregation
with the carriers takes 78, 0.19 s.  So at the scenes' support the exact
projection costs at least 174 x 2.3 ms = 0.39 s a step, twice the step itself,
where the droplet's 3-minute budget leaves 0.08 s; at 2 dx it might fit, at
ten times the volume error.  The lever would be a gradient whose response
stays near k up to the carriers at no loss of accuracy (then ``S`` is four
Laplacians, one per carrier, and carrier-aware aggregation solves it in tens
of iterations).

Time step: dt = min(cfl dx / max|v|, viscous_cfl dx^2 / nu, force_cfl sqrt(dx / |g|),
dt_max): the advective, viscous and body-force limits (Monaghan 1992; Morris et
al. 1997).  The viscous term is explicit, so its limit is the forward-Euler
one for the viscous operator actually used: dt nu lambda_max <= 2, with
lambda_max the largest eigenvalue magnitude of the corrected Laplacian with
the mirrored no-slip walls.  Measured by power iteration on a 24 x 48 tank
(Wendland C2, support 3 dx), lattice and 20%-jittered alike: lambda_max =
3.03 / dx^2, so the limit is nu dt / dx^2 <= 0.66; ``viscous_cfl`` = 0.25
keeps a margin of 2.6 (the former 0.125, a factor 5.3, halved the step of
the viscous-limited Rayleigh-Taylor benchmark for nothing).  Nothing else is
modelled: no surface tension, no turbulence model.
"""
import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import BlowUp, InputError, SolverError
from ..sph.kernels import kernel_wfl
from ..sph.neighbors import GridSpec, PairList, bin_particles
from ..sph.operators import GradientStencil, Operators, weight_gradient_by_mean_density
from ..sph.particles import FLUID, GHOST, Particles
from ..linalg.poisson import PoissonMatrix
from ..sph.adjoint import NormalOperator
from ..linalg import krylov as solvers


#: The viscous wall conditions (``FlowParams.walls``).
WALL_CONDITIONS = ("no-slip", "free-slip")
#: What the wall particles carry (``_wall_velocity``): the fluid's extrapolated
#: velocity (pressure right-hand side), minus it (no slip), its mirror (free slip).
WALL_COPY, WALL_NO_SLIP, WALL_FREE_SLIP = 0, 1, 2

#: The stages of a time step whose wall time :attr:`TwoPhaseFlow.timings` accumulates.
STAGES = ("neighbours", "operators", "solve", "other")


class StageClock:
    """Wall time of a time step split into stages, accumulated over steps.

    Lap timing: :meth:`lap` charges the time since the previous lap (or since
    :meth:`start`) to a stage, so the stages of a step add up to its wall time
    exactly; :meth:`stop` charges what is left to ``"other"``.  ``detail`` keys
    name finer parts of a stage (e.g. ``"bin"`` and ``"pairs"`` of
    ``"neighbours"``).  Outside a step (between :meth:`stop` and :meth:`start`)
    laps are ignored.  Taichi kernels run synchronously on the CPU; on a GPU
    every lap calls ``ti.sync()`` first so that a stage is charged with the
    kernels it launched.
    """

    def __init__(self):
        self.totals = dict.fromkeys(STAGES, 0.0)
        self.detail = {}
        self.steps = 0
        self.last_step = dict.fromkeys(STAGES, 0.0)
        self._t = None
        self._sync = runtime.state().arch not in ("", "cpu")

    def _now(self) -> float:
        if self._sync:
            ti.sync()
        return _time.perf_counter()

    def start(self) -> None:
        self.last_step = dict.fromkeys(STAGES, 0.0)
        self._t = self._now()

    def lap(self, stage: str, detail: str | None = None) -> None:
        if self._t is None:
            return
        now = self._now()
        dt, self._t = now - self._t, now
        self.last_step[stage] += dt
        self.totals[stage] += dt
        key = f"{stage}.{detail or stage}"
        self.detail[key] = self.detail.get(key, 0.0) + dt

    def stop(self) -> dict:
        """End the step; returns its stage seconds (and ``"total"``)."""
        self.lap("other", "other")
        self._t = None
        self.steps += 1
        return {**self.last_step, "total": sum(self.last_step.values())}

    def abort(self) -> None:
        """A step that raised: charge its time so far to ``"other"`` and stop."""
        if self._t is not None:
            self.lap("other", "aborted")
            self._t = None

    def reset(self) -> None:
        self.totals = dict.fromkeys(STAGES, 0.0)
        self.detail = {}
        self.steps = 0


class BlowUpError(BlowUp):
    """The simulation left the regime it can represent (non-finite values,
    particles leaving the box, a failed pressure solve)."""


@dataclass
class FlowParams:
    box: tuple = (0.0, 0.0, 1.0, 2.0)          # x0, y0, x1, y1
    gravity: tuple = (0.0, -1.0)
    nu: float = 2e-3                            # kinematic viscosity, both phases
    densities: tuple = (1.0, 2.0)               # rest density per phase index
    kernel: str = "wendland"
    support_ratio: float = 3.0                  # support / particle spacing
    cfl: float = 0.25
    viscous_cfl: float = 0.25                  # stable up to 0.66 (module doc)
    force_cfl: float = 0.25
    dt_max: float = 0.02
    projection_passes: int = 1
    div_tol: float = 1e-3                       # on max |div v| * dt (relative volume change)
    solver_tol: float = 1e-6
    preconditioner: str = "auto"                # of the pressure BiCGSTAB: auto | multilevel | jacobi
    # the multilevel cycle of the pressure solve: V here (measured on the RT
    # Grenier case at 10k particles: 10-12 BiCGSTAB iterations per step with V,
    # 13-15 with the W-cycle that is the library default for decompositions)
    multilevel_cycle: str = "V"
    pressure_laplacian: str = "corrected"
    gradient: str = "corrected"
    viscous_laplacian: str = "corrected"
    shifting: float = 0.0                       # particle-shifting coefficient (0 = off)
    # viscous wall condition: "no-slip" (the scenes), or "free-slip" (the setting of
    # the linear Rayleigh-Taylor theory, benchmarks/rt_growth.py)
    walls: str = "no-slip"
    pair_density_gradient: bool = True          # grad q / rho with pair-mean densities
    # orthogonal clean-up after the passes: ||div|| to cleanup_tol (module doc);
    # off by default, it costs 29x the step at 10k particles (Jacobi-CG, ~1200 iterations)
    exact_projection: bool = False
    cleanup_tol: float | None = None            # of the clean-up; None: solver_tol
    cleanup_warm_start: bool = True             # start the clean-up CG from last step's lam


@ti.kernel
def _wall_rhs(kid: ti.template(), n: ti.i32, offsets: ti.types.ndarray(),
              nbrs: ti.types.ndarray(), pos: ti.types.ndarray(), vol: ti.types.ndarray(),
              rho: ti.types.ndarray(), kind: ti.types.ndarray(), normal: ti.types.ndarray(),
              w: ti.types.ndarray(), gdt_x: float, gdt_y: float, H: float,
              b: ti.types.ndarray()):
    """Right-hand side of the wall rows q_w - sum_f S_wf q_f = b_w with
    b_w = sum_f S_wf rho_f [g dt . (x_w - x_f) + ((w_f - g dt) . n_w)((x_w - x_f) . n_w)]:
    the wall's pressure impulse continues the fluid's hydrostatically (the
    generalised wall condition of Adami et al. 2012, exact at corners too) plus
    the normal gradient rho w.n that stops what is left of the normal velocity
    (no penetration)."""
    for i in range(n):
        if kind[i] == GHOST:
            num = 0.0
            den = 0.0
            nw = normal[i]
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                if kind[j] == FLUID:
                    d = pos[i] - pos[j]
                    W, _F, _L = kernel_wfl(kid, d.norm(), H)
                    gdt = ti.Vector([gdt_x, gdt_y])
                    num += vol[j] * W * rho[j] * (gdt.dot(d) + (w[j] - gdt).dot(nw) * d.dot(nw))
                    den += vol[j] * W
            b[i] = 0.0
            if den > 0.0:
                b[i] = num / den


@ti.kernel
def _wall_velocity(kid: ti.template(), n: ti.i32, offsets: ti.types.ndarray(),
                   nbrs: ti.types.ndarray(), pos: ti.types.ndarray(), vol: ti.types.ndarray(),
                   kind: ti.types.ndarray(), H: float, v: ti.types.ndarray(), mode: ti.i32,
                   normal: ti.types.ndarray(), out: ti.types.ndarray()):
    """out = v on fluid; on walls the Shepard value s of v over the fluid, as
    ``mode``: WALL_COPY s, WALL_NO_SLIP -s, WALL_FREE_SLIP s mirrored (its
    component normal to each wall the particle lies beyond reversed; both in a
    corner)."""
    for i in range(n):
        if kind[i] == FLUID:
            out[i] = v[i]
        else:
            num = ti.Vector.zero(float, 2)
            den = 0.0
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                if kind[j] == FLUID:
                    W, _F, _L = kernel_wfl(kid, (pos[i] - pos[j]).norm(), H)
                    num += vol[j] * W * v[j]
                    den += vol[j] * W
            out[i] = ti.Vector.zero(float, 2)
            if den > 0.0:
                factor = ti.Vector([1.0, 1.0])
                if mode == WALL_NO_SLIP:
                    factor = ti.Vector([-1.0, -1.0])
                elif mode == WALL_FREE_SLIP:
                    nrm = normal[i]
                    factor = ti.Vector([-1.0 if ti.abs(nrm[0]) > 0.1 else 1.0,
                                        -1.0 if ti.abs(nrm[1]) > 0.1 else 1.0])
                out[i] = factor * num / den


@ti.kernel
def _concentration_gradient(kid: ti.template(), n: ti.i32, offsets: ti.types.ndarray(),
                            nbrs: ti.types.ndarray(), pos: ti.types.ndarray(),
                            mass: ti.types.ndarray(), rho: ti.types.ndarray(),
                            kind: ti.types.ndarray(), H: float, out: ti.types.ndarray()):
    """grad C_i = sum_j V_j grad W_ij on fluid rows (0 elsewhere): the basic SPH
    gradient of f = 1 in one gather, without materialising its coefficients."""
    for i in range(n):
        g = ti.Vector.zero(float, 2)
        if kind[i] == FLUID:
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                xij = pos[i] - pos[j]
                _W, F, _L = kernel_wfl(kid, xij.norm(), H)
                g += (mass[j] / rho[j]) * (F * xij)
        out[i] = g


class TwoPhaseFlow:
    """State and time stepping of a two-phase flow in a closed box.

    points: (N, 2) fluid particle positions (inside the box); phases: (N,) ints
    indexing ``params.densities``; spacing: the initial particle spacing.
    """

    def __init__(self, points, phases, spacing: float, params: FlowParams = FlowParams(),
                 velocity=None, time: float = 0.0):
        runtime.ensure_init()
        pts = np.asarray(points, dtype=np.float64)
        phases = np.asarray(phases, dtype=np.int32)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
            raise InputError(f"points must be a non-empty (N, 2) array, got {pts.shape}")
        if phases.shape != (len(pts),):
            raise InputError(f"phases must have shape ({len(pts)},), got {phases.shape}")
        if phases.min() < 0 or phases.max() >= len(params.densities):
            raise InputError(f"phase indices must be in [0, {len(params.densities)})")
        if params.walls not in WALL_CONDITIONS:
            raise InputError(f"walls must be one of {WALL_CONDITIONS}, got {params.walls!r}")
        if params.cleanup_tol is not None and not 0 < params.cleanup_tol < 1:
            raise InputError(f"cleanup_tol must be in (0, 1), got {params.cleanup_tol!r}")
        x0, y0, x1, y1 = params.box
        if not np.all((pts[:, 0] > x0) & (pts[:, 0] < x1) & (pts[:, 1] > y0) & (pts[:, 1] < y1)):
            raise InputError("every fluid particle must lie strictly inside the box")
        self.params = params
        self.dx = float(spacing)
        self.support = params.support_ratio * self.dx
        self.n_fluid = len(pts)
        self.time = float(time)
        self.step_count = 0
        rho0 = np.asarray(params.densities, dtype=np.float64)[phases]
        vol = self.dx * self.dx
        walls = self._wall_layer()
        p = self.particles = Particles(len(pts) + len(walls))
        p.append(pts, velocity=velocity, mass=rho0 * vol, kind=FLUID, phase=phases)
        q = np.clip(walls, [x0, y0], [x1, y1])
        wall_normal = (walls - q) / np.linalg.norm(walls - q, axis=1)[:, None]
        p.append(walls, mass=rho0.mean() * vol, kind=GHOST, phase=-1, normal=wall_normal)
        p.set("density", np.r_[rho0, np.full(len(walls), rho0.mean())])
        p.set("volume", np.full(p.n, vol))
        lo = np.array([x0, y0]) - self.support
        hi = np.array([x1, y1]) + self.support
        self.spec = GridSpec.covering(lo, hi, self.support)
        self.pairs = PairList()
        self.q_by_id = np.zeros(p.n)            # last pressure impulse, by particle id
        self.lam_by_id = np.zeros(p.n)          # last clean-up multiplier, by particle id
        self.border = 0.0
        self._gx, self._gy = (float(c) for c in params.gravity)
        self.clock = StageClock()

    @property
    def timings(self) -> dict:
        """Wall seconds spent in :meth:`step`, accumulated over the steps since
        construction (or :meth:`reset_timings`), by stage: ``neighbours`` (binning,
        reorder, pair list), ``operators`` (viscous predictor, gradient/Laplacian
        coefficient builds and the Poisson assembly, divergence and wall rows,
        pressure-gradient correction, shifting), ``solve`` (the pressure Poisson
        solve, preconditioner set-up included, and the clean-up's CG with
        ``exact_projection``), ``other`` (time step, copies,
        advection, checks); ``total`` is their sum and ``steps`` the step count.
        Finer parts are in ``flow.clock.detail``.  Timing does not change any
        result."""
        t = dict(self.clock.totals)
        t["total"] = sum(self.clock.totals.values())
        t["steps"] = self.clock.steps
        return t

    def reset_timings(self) -> None:
        self.clock.reset()

    # ---- set-up ------------------------------------------------------------------
    def _wall_layer(self) -> np.ndarray:
        x0, y0, x1, y1 = self.params.box
        k = int(math.ceil(self.support / self.dx))
        nx = int(round((x1 - x0) / self.dx))
        ny = int(round((y1 - y0) / self.dx))
        gx = x0 + (np.arange(-k, nx + k) + 0.5) * (x1 - x0) / nx
        gy = y0 + (np.arange(-k, ny + k) + 0.5) * (y1 - y0) / ny
        P = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
        inside = (P[:, 0] > x0) & (P[:, 0] < x1) & (P[:, 1] > y0) & (P[:, 1] < y1)
        P = P[~inside]
        d = np.linalg.norm(P - np.clip(P, [x0, y0], [x1, y1]), axis=1)
        # keep walls that see fluid: the first fluid layer sits dx/2 inside the box
        return P[d < self.support - self.dx]

    # ---- one step ------------------------------------------------------------------
    def _neighbours(self):
        p = self.particles
        self.grid = bin_particles(p, self.spec)
        self.clock.lap("neighbours", "bin")
        self.pairs.build(p.position, p.n, p.position, self.grid, self.support)
        self.ops = Operators(p, self.pairs, self.support, self.params.kernel)
        self.clock.lap("neighbours", "pairs")

    def time_step(self, vmax: float) -> float:
        pr = self.params
        g = math.hypot(*pr.gravity)
        limits = [pr.dt_max]
        if vmax > 0:
            limits.append(pr.cfl * self.dx / vmax)
        if pr.nu > 0:
            limits.append(pr.viscous_cfl * self.dx ** 2 / pr.nu)
        if g > 0:
            limits.append(pr.force_cfl * math.sqrt(self.dx / g))
        return min(limits)

    def suggested_dt(self) -> float:
        """The stable time step for the current velocities (see the module doc)."""
        p = self.particles
        fluid = p.get("kind") == FLUID
        vel = p.get("velocity")[fluid]
        return self.time_step(float(np.sqrt((vel ** 2).sum(axis=1).max())))

    def volume_error(self) -> tuple:
        """(mean, max) of |C_i / C_0 - 1| over the fluid, C_i = sum_j V_j W_ij the
        particle number density (volume fraction) and C_0 its value on the initial
        lattice: how far the particles are from filling space uniformly."""
        p = self.particles
        if not hasattr(self, "ops"):
            self._neighbours()
        real = runtime.real_dtype()
        c = ti.ndarray(real, shape=(max(p.capacity, 1),))
        scratch = ti.ndarray(real, shape=(max(p.capacity, 1),))
        from ..sph.operators import number_density
        number_density(self.ops.kernel_id, p.position, p.volume, p.n, self.pairs.offsets,
                 self.pairs.neighbours, self.support, c, scratch)
        C = c.to_numpy()[: p.n]
        if not hasattr(self, "_c0"):
            self._c0 = _lattice_number_density(self.params.kernel, self.dx, self.support)
        err = np.abs(C[p.get("kind") == FLUID] / self._c0 - 1.0)
        return float(err.mean()), float(err.max())

    def kinetic_energy(self) -> float:
        p = self.particles
        fluid = p.get("kind") == FLUID
        v = p.get("velocity")[fluid]
        return float(0.5 * (p.get("mass")[fluid] * (v ** 2).sum(axis=1)).sum())

    def step(self, dt: float | None = None) -> dict:
        """One time step (see the module doc).  Returns its diagnostics: dt, pressure
        solver ``iterations``, projection ``passes``, ``cleanup_iterations`` (0 when
        off or skipped), ``max_div_before``/``max_div`` and ``div_norm_before``/
        ``div_norm`` (max and 2-norm of the measured divergence D w over the fluid
        before and after the projection, module doc), max speed and
        ``seconds`` (its wall time by stage, see :attr:`timings`)."""
        self.clock.start()
        try:
            return self._step(dt)
        finally:
            self.clock.abort()          # only if _step raised (it stops the clock itself)

    def _step(self, dt: float | None) -> dict:
        pr = self.params
        p = self.particles
        self.clock.lap("other", "setup")
        self._neighbours()
        kind = p.get("kind")
        ids = p.get("original_index")
        fluid = kind == FLUID
        ops = self.ops
        vel = p.get("velocity")
        vmax = float(np.sqrt((vel[fluid] ** 2).sum(axis=1).max()))
        dt = self.time_step(vmax) if dt is None else float(dt)
        self.clock.lap("other", "setup")

        # 1. predict: gravity and viscosity (walls: the mirrored velocity, ``walls``)
        real = runtime.np_real()
        v_nd = p.velocity
        ext = _ndarray_like(p, 2)
        _wall_velocity(ops.kernel_id, p.n, self.pairs.offsets, self.pairs.neighbours, p.position,
                       p.volume, p.kind, self.support, v_nd,
                       WALL_FREE_SLIP if pr.walls == "free-slip" else WALL_NO_SLIP,
                       p.normal, ext)
        lap_v = _ndarray_like(p, 2)
        if pr.nu > 0:
            self.clock.lap("operators", "predict")
            st_visc = ops.laplacian_coefficients(pr.viscous_laplacian, row_kinds=(FLUID,))
            self.clock.lap("operators", "viscous_coefficients")
            ops.laplacian(st_visc, ext, lap_v)
            visc = lap_v.to_numpy()[: p.n].astype(np.float64)
        else:
            visc = np.zeros((p.n, 2))
        w = vel.copy()
        w[fluid] += dt * (np.array(pr.gravity) + pr.nu * visc[fluid])
        w[~fluid] = 0.0
        self.clock.lap("operators", "predict")

        # 2. project (iterated, density-weighted); walls carry the extrapolated fluid
        # velocity in the divergence, the no-penetration condition enters their rows
        st_grad = ops.gradient_coefficients(pr.gradient, row_kinds=(FLUID,))
        st_pgrad = st_grad
        if pr.pair_density_gradient:
            # the same coefficients times 2 / (rho_i + rho_j): what
            # gradient_coefficients(..., density_weighted=True) computes, without
            # building the (correction-matrix) coefficients a second time
            G = ti.Vector.ndarray(2, runtime.real_dtype(), shape=st_grad.G.shape)
            G.copy_from(st_grad.G)
            weight_gradient_by_mean_density(p.n, self.pairs.offsets, self.pairs.neighbours,
                                             p.density, G)
            st_pgrad = GradientStencil(G, st_grad.s, st_grad.variant, st_grad.row_kinds,
                                       st_grad.source_kinds)
        self.clock.lap("operators", "gradient_coefficients")
        # The flow has no BOUNDARY particles (its walls are GHOST rows) and no
        # near-boundary term, so the Neumann gradient of the Poisson rows is
        # multiplied by zero: any stencil at hand gives the identical matrix.  The
        # pressure Laplacian is the viscous one weighted by the pair densities
        # when the variants agree (the default): computed once.
        if pr.nu > 0 and pr.viscous_laplacian == pr.pressure_laplacian:
            A = PoissonMatrix(ops, laplacian=ops.density_weighted(st_visc), gradient=st_grad,
                              kappa=0.0, bordered=True)
        else:
            A = PoissonMatrix(ops, laplacian=pr.pressure_laplacian, gradient=st_grad,
                              kappa=0.0, bordered=True, density_weighted=True)
        self.clock.lap("operators", "poisson_assembly")
        rho = p.get("density")
        q_total = np.zeros(p.n)
        iters = []
        w_nd = _ndarray_like(p, 2)
        wext_nd = _ndarray_like(p, 2)
        div_nd = _ndarray_like(p, 1)
        q_nd = _ndarray_like(p, 1)
        g_nd = _ndarray_like(p, 2)
        wall_b = _ndarray_like(p, 1)
        pr_ = self.pairs
        self.clock.lap("other", "setup")

        def divergence_and_walls(w, gdt):
            w_nd.from_numpy(w.astype(real))
            _wall_velocity(ops.kernel_id, p.n, pr_.offsets, pr_.neighbours, p.position, p.volume,
                           p.kind, self.support, w_nd, WALL_COPY, p.normal, wext_nd)
            ops.divergence(st_grad, wext_nd, div_nd)
            _wall_rhs(ops.kernel_id, p.n, pr_.offsets, pr_.neighbours, p.position, p.volume,
                      p.density, p.kind, p.normal, w_nd, gdt[0], gdt[1], self.support, wall_b)
            div = div_nd.to_numpy()[: p.n].astype(np.float64)
            return np.where(fluid, div, wall_b.to_numpy()[: p.n].astype(np.float64))

        d = self._measured_divergence(w, st_grad)
        div_before = float(np.abs(d).max())
        norm_before = math.sqrt(float((d ** 2).sum()))
        gdt = (dt * self._gx, dt * self._gy)
        b = divergence_and_walls(w, gdt)
        self.clock.lap("operators", "divergence")
        for k in range(pr.projection_passes):
            try:
                res = A.solve(b, x0=self.q_by_id[ids] if k == 0 else None, tol=pr.solver_tol,
                              preconditioner=pr.preconditioner,
                              multilevel_options={"cycle": pr.multilevel_cycle},
                              border0=self.border if k == 0 else 0.0)
            except SolverError as exc:
                raise BlowUpError(f"pressure solve failed at t={self.time:.4g}: {exc}") from exc
            self.clock.lap("solve")
            iters.append(res.iterations)
            q_total += res.x
            if k == 0:
                self.border = res.border
            q_nd.from_numpy(res.x.astype(real))
            ops.gradient(st_pgrad, q_nd, g_nd)
            grad_q = g_nd.to_numpy()[: p.n].astype(np.float64)
            w[fluid] -= grad_q[fluid] / rho[fluid, None]
            if k + 1 == pr.projection_passes:
                self.clock.lap("operators", "correction")
                break           # the next pass's right-hand side would go unused
            b = divergence_and_walls(w, (0.0, 0.0))   # gravity is balanced by now
            self.clock.lap("operators", "correction")
            if np.abs(b[fluid]).max() * dt < pr.div_tol:
                break
        self.q_by_id[ids] = q_total
        d = self._measured_divergence(w, st_grad)
        self.clock.lap("operators", "divergence")
        cleanup_iters = 0
        if pr.exact_projection:
            w, cleanup_iters = self._clean_up(w, d, norm_before, st_grad)
            if cleanup_iters:
                d = self._measured_divergence(w, st_grad)
                self.clock.lap("operators", "cleanup")
        div_after = float(np.abs(d).max())

        # 3. advect
        pos = p.get("position")
        shift = np.zeros_like(pos)
        if pr.shifting > 0:
            self.clock.lap("other", "advect")
            shift = self._shifting(pos, fluid, dt, np.sqrt((w[fluid] ** 2).sum(axis=1)).max())
            self.clock.lap("operators", "shifting")
        pos[fluid] += dt * w[fluid] + shift[fluid]
        w[~fluid] = 0.0
        if not (np.isfinite(pos).all() and np.isfinite(w).all()):
            raise BlowUpError(f"non-finite positions or velocities at t={self.time:.4g}",
                              cause="non-finite")
        x0, y0, x1, y1 = pr.box
        out = fluid & ~((pos[:, 0] > x0) & (pos[:, 0] < x1) & (pos[:, 1] > y0) & (pos[:, 1] < y1))
        if out.any():
            # a particle pushed through a wall: put it back just inside (walls are
            # impermeable); many at once means the step is unstable
            if out.sum() > max(3, 0.001 * self.n_fluid):
                raise BlowUpError(f"{int(out.sum())} particles left the box at t={self.time:.4g}",
                                  cause="left-box")
            eps = 0.01 * self.dx
            pos[out] = np.clip(pos[out], [x0 + eps, y0 + eps], [x1 - eps, y1 - eps])
        p.set("position", pos)
        p.set("velocity", w)
        self.time += dt
        self.step_count += 1
        info = {"dt": dt, "iterations": int(sum(iters)), "passes": len(iters),
                "cleanup_iterations": cleanup_iters,
                "max_div_before": div_before, "max_div": div_after,
                "div_norm_before": norm_before, "div_norm": math.sqrt(float((d ** 2).sum())),
                "max_speed": float(np.sqrt((w[fluid] ** 2).sum(axis=1)).max())}
        self.clock.lap("other", "advect")
        info["seconds"] = self.clock.stop()
        return info

    def _measured_divergence(self, w, st) -> np.ndarray:
        """D w (module doc): the divergence of stencil ``st`` (the corrected gradient
        of the fluid rows) with the wall particles at rest; 0 on wall rows."""
        p = self.particles
        fluid = p.get("kind") == FLUID
        w_nd = _ndarray_like(p, 2)
        w_nd.from_numpy(np.where(fluid[:, None], w, 0.0).astype(runtime.np_real()))
        out = _ndarray_like(p, 1)
        self.ops.divergence(st, w_nd, out)
        return np.where(fluid, out.to_numpy()[: p.n].astype(np.float64), 0.0)

    def _clean_up(self, w, d, norm_before, st):
        """The orthogonal clean-up step (module doc): the mass-weighted projection of
        ``w`` onto ``D u = 0`` over the fluid, walls at rest.  ``d = D w`` (fluid rows,
        0 on walls); ``norm_before``: ||D w*|| of the predicted field.  Solves
        (D M^-1 D^T) lam = D w by Jacobi-CG to ||D w_final|| <= cleanup_tol *
        ||D w*|| (2-norms over the fluid rows; skipped when already there) and
        returns (w - M^-1 D^T lam, CG iterations); (w, 0) when skipped."""
        pr, p = self.params, self.particles
        real = runtime.np_real()
        fluid = p.get("kind") == FLUID
        ids = p.get("original_index")
        norm = math.sqrt(float((d ** 2).sum()))
        # never chase rounding: the divergence of a field varying by its own size
        # over one spacing, times 1e3 machine epsilons
        eps = float(np.finfo(real).eps)
        floor = 1e3 * eps * math.sqrt(float((w[fluid] ** 2).sum())) / self.dx
        tol = pr.solver_tol if pr.cleanup_tol is None else pr.cleanup_tol
        target = max(tol * norm_before, floor)
        if norm <= target:
            return w, 0
        S = NormalOperator(self.ops, self.pairs, st, p.mass, p.n, rows=(FLUID,), cols=(FLUID,))
        x0 = self.lam_by_id[ids] if pr.cleanup_warm_start else None
        self.clock.lap("operators", "cleanup")
        try:
            # iteration cap: 1700 were needed at 11k unknowns (module doc)
            res = solvers.cg(S, d, x0=x0, tol=target / norm, preconditioner="jacobi",
                             max_iterations=max(5000, 2 * p.n))
        except SolverError as exc:
            raise BlowUpError(f"orthogonal clean-up solve failed at t={self.time:.4g}: {exc}") \
                from exc
        self.clock.lap("solve", "cleanup")
        lam = res.x[: p.n].astype(np.float64)
        lam[~fluid] = 0.0
        self.lam_by_id[ids] = lam
        lam_nd = _ndarray_like(p, 1)
        lam_pad = np.zeros(lam_nd.shape[0], dtype=real)
        lam_pad[: p.n] = lam
        lam_nd.from_numpy(lam_pad)
        corr = _ndarray_like(p, 2)
        S.correction(lam_nd, corr)
        w = w.copy()
        w[fluid] -= corr.to_numpy()[: p.n][fluid].astype(np.float64)
        return w, res.iterations

    def _shifting(self, pos, fluid, dt, vmax):
        """Particle shifting (Xu et al. 2009; Lind et al. 2012): move particles down the
        gradient of the particle concentration C_i = sum_j V_j W_ij,
        dr = -D grad C with D = shifting * support * vmax * dt."""
        ops, p = self.ops, self.particles
        g = _ndarray_like(p, 2)
        _concentration_gradient(ops.kernel_id, p.n, self.pairs.offsets, self.pairs.neighbours,
                                p.position, p.mass, p.density, p.kind, self.support, g)
        gradC = g.to_numpy()[: p.n].astype(np.float64)
        D = self.params.shifting * self.support * max(vmax, 1e-12) * dt
        shift = -D * gradC
        cap = 0.1 * self.dx                                 # never more than 0.1 dx per step
        norm = np.linalg.norm(shift, axis=1)
        big = norm > cap
        shift[big] *= (cap / norm[big])[:, None]
        shift[~fluid] = 0.0
        return shift

    # ---- state for diagnostics, frames and checkpoints -------------------------------
    def fluid_state(self):
        """(positions, velocities, phases, ids) of the fluid particles, by particle id."""
        p = self.particles
        kind = p.get("kind")
        ids = p.get("original_index")
        f = kind == FLUID
        order = np.argsort(ids[f])
        return (p.get("position")[f][order], p.get("velocity")[f][order],
                p.get("phase")[f][order], ids[f][order])

    def state_dict(self) -> dict:
        pos, vel, phase, _ = self.fluid_state()
        return {"positions": pos, "velocities": vel, "phases": phase, "time": self.time,
                "step": self.step_count, "spacing": self.dx, "q_by_id": self.q_by_id,
                "border": self.border, "lam_by_id": self.lam_by_id}

    @classmethod
    def from_state(cls, state: dict, params: FlowParams) -> "TwoPhaseFlow":
        flow = cls(state["positions"], state["phases"], float(state["spacing"]), params,
                   velocity=state["velocities"], time=float(state["time"]))
        flow.step_count = int(state["step"])
        if len(state["q_by_id"]) == len(flow.q_by_id):
            flow.q_by_id = np.asarray(state["q_by_id"], dtype=np.float64)
        flow.border = float(state["border"])
        lam = state.get("lam_by_id")          # absent in older checkpoints: cold start
        if lam is not None and len(lam) == len(flow.lam_by_id):
            flow.lam_by_id = np.asarray(lam, dtype=np.float64)
        return flow


def _lattice_number_density(kernel: str, dx: float, support: float) -> float:
    """sum_j dx^2 W(|x_j|) over a full square lattice (self included)."""
    from ..sph.kernels import kernel_numpy
    k = int(math.ceil(support / dx)) + 1
    g = np.arange(-k, k + 1) * dx
    X, Y = np.meshgrid(g, g)
    W, _, _ = kernel_numpy(kernel, np.hypot(X, Y).ravel(), support)
    return float(dx * dx * W.sum())


def _ndarray_like(p, ncomp: int):
    real = runtime.real_dtype()
    size = max(p.capacity, 1)
    if ncomp == 1:
        return ti.ndarray(real, shape=(size,))
    return ti.Vector.ndarray(ncomp, real, shape=(size,))
