"""Two-phase incompressible SPH by projection (Petronetto et al. 2010 Sec. 6d,
Colin et al. 2006 Sec. 3.7): :class:`TwoPhaseFlow`.

One time step (:meth:`TwoPhaseFlow.step`), after the neighbour search and the
step's operators (:func:`taichi_hh.flow.operators.build_step_operators`: the
viscous Laplacian, the gradient, the pressure gradient and the Poisson matrix
as one :class:`~taichi_hh.flow.operators.StepOperators` record, which the
phases below read):

1. predict   v* = v + dt (g + nu lap v)                  (explicit viscosity)
2. project   solve div(grad q / rho) = div w,  w <- w - grad q / rho,
             starting from w = v*, repeated ``projection_passes`` times or until
             max |div w| dt is below ``div_tol`` (the iterated projection of Colin
             Sec. 3.7; q = dt p is the pressure impulse; the solve starts from the
             last two steps' p extrapolated in time, ``warm_start``)
2b. clean up (``exact_projection``, off by default) solve (D M^-1 D^T) lam = D w,
             w <- w - M^-1 D^T lam: the orthogonal step of
             :mod:`taichi_hh.hhd.project` with the mass-weighted norm (below)
3. advect    x <- x + dt v  (optionally plus a particle-shifting displacement,
             :mod:`taichi_hh.flow.shifting`)

The velocity w stays on the Taichi side through the step (``buffers.velocity``);
:attr:`TwoPhaseFlow.step_callback` sees the step at the points of
:data:`STEP_EVENTS` (instrumentation, e.g. :mod:`taichi_hh.validation.conditioning`).

Density-weighted projection: with two densities the pressure equation is
div(grad p / rho) = div v* / dt and the correction v* - dt grad p / rho; a
constant-coefficient projection would remove gravity whatever the density and
nothing would rise.  The inter-particle coefficient of the pressure Laplacian
is 2 / (rho_i + rho_j) (Cummins & Rudman 1999), which stays finite and
continuous across the interface.

Walls: a lattice layer of wall particles, as wide as the kernel support, at rest
outside the box (:func:`taichi_hh.geometry.walls.box_wall_lattice`).  Their
pressure follows the fluid next to them by the Shepard sum plus the hydrostatic
term (Adami, Hu & Adams 2012), p_w = sum_f S_wf (p_f + rho_f g . (x_w - x_f)),
so that a fluid at rest under gravity stays at rest; in the pressure equation's
right-hand side they carry the Shepard-extrapolated fluid velocity and their
rows add the normal-velocity term (no penetration); in the viscous term they
carry minus it (no slip) or, with ``walls="free-slip"``, its mirror image
(:mod:`taichi_hh.flow.walls`).

Measured divergence: ``D`` is the corrected divergence (the pressure gradient's
stencil, ``gradient``) of the fluid rows with the wall particles at rest, which
also encodes no penetration.  The step reports max |D w| and ||D w|| over the
fluid before (w = v*) and after the projection.  The Poisson step alone cannot
drive D w to the solver tolerance (its Laplacian is not D (1/rho) G, module doc
of :mod:`taichi_hh.hhd.project`); the clean-up removes the rest: with M =
diag(mass) over the fluid and the walls not unknowns, w - M^-1 D^T lam is the
field closest to w in sum_i m_i |u_i|^2 with D u = 0.  Jacobi-CG stops at
||D w|| <= cleanup_tol ||D v*|| (never below 1e3 machine epsilons of ||w|| / dx;
skipped when already there; warm-started from the previous lam with
``cleanup_warm_start``); a failed solve raises :class:`BlowUpError`.  It is off
by default: S = D M^-1 D^T is the square of a smoothing operator, badly
conditioned at the scenes' kernel support, and the clean-up costs tens of steps'
time for no gain in the volume error (docs/notes/flow.md).

Time step: dt = min(cfl dx / max|v|, viscous_cfl dx^2 / nu, force_cfl sqrt(dx / |g|),
dt_max): the advective, viscous and body-force limits (Monaghan 1992; Morris et
al. 1997).  The viscous term is explicit, so its limit is the forward-Euler one
of the corrected Laplacian with the mirrored walls, nu dt / dx^2 <= 0.66
(measured, docs/notes/flow.md); ``viscous_cfl`` = 0.25 keeps a margin of 2.6.
Nothing else is modelled: no surface tension, no turbulence model.
"""
import math

import numpy as np

from .. import runtime
from ..errors import BlowUp, InputError, SolverError
from ..geometry.walls import box_wall_lattice
from ..linalg import krylov as solvers
from ..sph.adjoint import NormalOperator
from ..sph.kernels import kernel_numpy
from ..sph.neighbors import GridSpec, PairList, bin_particles
from ..sph.operators import Operators, number_density
from ..sph.particles import FLUID, WALL, Particles
from .buffers import FlowBuffers
from .clock import STAGES, StageClock
from .operators import StepOperators, build_step_operators
from .params import WALL_CONDITIONS, WARM_STARTS, FlowParams, WallVelocity
from . import update
from .shifting import concentration_gradient, shifting_coefficients
from .walls import wall_rhs, wall_velocity

__all__ = ["TwoPhaseFlow", "FlowParams", "BlowUpError", "StageClock", "STAGES",
           "WALL_CONDITIONS", "WallVelocity", "StepOperators", "STEP_EVENTS"]

#: The points of a step at which :attr:`TwoPhaseFlow.step_callback` is called, in
#: order, with what its ``data`` dict holds (the flow's own objects: read them,
#: copy what you keep, change nothing):
#:
#: * ``"operators"``: ``operators`` (the step's :class:`StepOperators`), ``dt``
#: * ``"projected"``: ``operators``, ``dt``, ``iterations`` (per pass),
#:   ``norm_before`` (||D v*||, the predicted field's measured divergence)
#: * ``"clean_up"`` (with ``exact_projection``, before the clean-up):
#:   ``operators``, ``velocity`` (w, numpy, by slot), ``divergence`` (D w, 0 on
#:   the walls), ``norm_before``
#: * ``"advected"``: ``info`` (the step's diagnostics, before ``seconds``)
STEP_EVENTS = ("operators", "projected", "clean_up", "advected")


class BlowUpError(BlowUp):
    """The simulation left the regime it can represent (non-finite values,
    particles leaving the box, a failed pressure solve)."""


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
        _check_params(params)
        if params.walls not in WALL_CONDITIONS:
            raise InputError(f"walls must be one of {WALL_CONDITIONS}, got {params.walls!r}")
        if params.warm_start not in WARM_STARTS:
            raise InputError(f"warm_start must be one of {WARM_STARTS}, got {params.warm_start!r}")
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
        p.append(walls, mass=rho0.mean() * vol, kind=WALL, phase=-1, normal=wall_normal)
        p.set("density", np.r_[rho0, np.full(len(walls), rho0.mean())])
        p.set("volume", np.full(p.n, vol))
        lo = np.array([x0, y0]) - self.support
        hi = np.array([x1, y1]) + self.support
        self.spec = GridSpec.covering(lo, hi, self.support)
        # the neighbour grid (binned on first use), the pair list and the
        # operators on it: the same objects every step
        self.grid = None
        self.pairs = PairList()
        self.ops = Operators(p, self.pairs, self.support, params.kernel)
        self.buffers = FlowBuffers.allocate(p.capacity)
        # the last step's operators (its Poisson matrix's arrays serve the next one)
        self.step_operators: StepOperators | None = None
        self.last_dt = 0.0                     # the last step's dt (0: no step yet)
        # C_0, the number density of the initial lattice (volume_error)
        self._c0 = _lattice_number_density(params.kernel, self.dx, self.support)
        # the last pressure impulse and the one before, by particle id (Taichi
        # arrays: buffers.q_by_id, q_prev_by_id), and the time steps of both (the
        # solve's first guess)
        self.dt_history = (0.0, 0.0)
        self.lam_by_id = np.zeros(p.n)          # last clean-up multiplier, by particle id
        self.border = 0.0
        self._gx, self._gy = (float(c) for c in params.gravity)
        self.clock = StageClock()
        #: None, or ``callback(flow, event, data)`` called at each of
        #: :data:`STEP_EVENTS` inside :meth:`step` (instrumentation: it must not
        #: change the flow; what it costs is charged to the step's stages)
        self.step_callback = None

    @property
    def q_by_id(self) -> np.ndarray:
        """The last step's pressure impulse q = dt p by particle id (a numpy copy)."""
        return self.buffers.q_by_id.to_numpy()[: self.particles.n].astype(np.float64)

    @q_by_id.setter
    def q_by_id(self, values) -> None:
        _upload_rows(self.buffers.q_by_id, np.asarray(values, dtype=np.float64))

    @property
    def q_prev_by_id(self) -> np.ndarray:
        """The impulse of the step before (the extrapolated first guess's)."""
        return self.buffers.q_prev_by_id.to_numpy()[: self.particles.n].astype(np.float64)

    @q_prev_by_id.setter
    def q_prev_by_id(self, values) -> None:
        _upload_rows(self.buffers.q_prev_by_id, np.asarray(values, dtype=np.float64))

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
        """The wall particles: the box's lattice continued outward, kept where they
        see fluid (the first fluid layer sits dx/2 inside the box)."""
        x0, y0, x1, y1 = self.params.box
        return box_wall_lattice((x0, y0), (x1, y1), self.dx, self.support - self.dx)

    # ---- diagnostics -------------------------------------------------------------
    def time_step(self, vmax: float) -> float:
        params = self.params
        g = math.hypot(*params.gravity)
        limits = [params.dt_max]
        if vmax > 0:
            limits.append(params.cfl * self.dx / vmax)
        if params.nu > 0:
            limits.append(params.viscous_cfl * self.dx ** 2 / params.nu)
        if g > 0:
            limits.append(params.force_cfl * math.sqrt(self.dx / g))
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
        err = np.abs(self._number_density_ratio()[p.get("kind") == FLUID] - 1.0)
        return float(err.mean()), float(err.max())

    def _number_density_ratio(self) -> np.ndarray:
        """C_i / C_0 per particle slot (:meth:`volume_error`)."""
        p = self.particles
        if self.grid is None:         # no neighbour search yet
            self.update_neighbours()
        c, scratch = self.buffers.number_density, self.buffers.volume
        number_density(self.ops.kernel_id, p.position, p.volume, p.n, self.pairs.offsets,
                       self.pairs.neighbours, *self.ops.support_args(), c, scratch)
        C = c.to_numpy()[: p.n]
        return C / self._c0

    def vorticity(self) -> np.ndarray:
        """Vorticity ``dv_y/dx - dv_x/dy`` of each fluid particle, in id order (the
        order of :meth:`fluid_state` and :meth:`particle_data`): the corrected SPH
        curl (Bonet & Lok 1999: exact on linear velocity fields) over the fluid
        neighbours, on the flow's own pair list, without a neighbour search of
        its own (only before the first step does it search, as
        :meth:`volume_error` does).  The pairs are the last step's, found before
        it advected the particles by at most ``cfl`` spacings: a neighbour that
        came within the support since is missed until the next step, where its
        kernel weight is near zero.  Walls are left out: at a no-slip wall the
        value is the one-sided estimate from the fluid side."""
        p, buf = self.particles, self.buffers
        if self.grid is None:         # no neighbour search yet
            self.update_neighbours()
        st = self.ops.gradient_coefficients("corrected", row_kinds=(FLUID,),
                                            source_kinds=(FLUID,),
                                            into=buf.vorticity_arrays(self.pairs.n_pairs))
        self.ops.curl(st, p.velocity, buf.vorticity)
        ids = p.get("original_index")
        fluid = p.get("kind") == FLUID
        order = np.argsort(ids[fluid])
        return buf.vorticity.to_numpy()[: p.n][fluid][order].astype(np.float64)

    def kinetic_energy(self) -> float:
        p = self.particles
        fluid = p.get("kind") == FLUID
        v = p.get("velocity")[fluid]
        return float(0.5 * (p.get("mass")[fluid] * (v ** 2).sum(axis=1)).sum())

    # ---- one step ----------------------------------------------------------------
    # step() runs the phases below in order; update_neighbours, first_guess,
    # measured_divergence, clean_up and advect are public so that a test or an
    # instrument can run one phase on a flow's current state.
    def step(self, dt: float | None = None) -> dict:
        """One time step (see the module doc).  Returns its diagnostics: dt, pressure
        solver ``iterations``, projection ``passes``, ``cleanup_iterations`` (0 when
        off or skipped), ``max_div_before``/``max_div`` and ``div_norm_before``/
        ``div_norm`` (max and 2-norm of the measured divergence D w over the fluid
        before and after the projection, module doc), max speed and
        ``seconds`` (its wall time by stage, see :attr:`timings`)."""
        if dt is not None and not (math.isfinite(dt) and dt > 0):
            raise InputError(f"step(dt): the time step must be a positive finite number, "
                             f"got {dt!r}")
        self.clock.start()
        try:
            return self._step(dt)
        finally:
            self.clock.abort()          # only if _step raised (it stops the clock itself)

    def _step(self, dt: float | None) -> dict:
        # the diagnostics come back as kernel return values (module flow.update)
        self.clock.lap("other", "setup")
        self.update_neighbours()
        p, buf = self.particles, self.buffers
        vmax = math.sqrt(update.max_speed2(p.n, p.kind, p.velocity))
        dt = self.time_step(vmax) if dt is None else float(dt)
        self.clock.lap("other", "setup")

        last = self.step_operators
        ops = self.step_operators = build_step_operators(
            self.params, self.ops, buf, reuse=last.poisson if last is not None else None,
            lap=self.clock.lap)
        self._notify("operators", operators=ops, dt=dt)
        self._predict(ops.viscous, dt)                                           # 1.
        div_before, sq_before, _ = self._divergence_stats(ops.gradient)
        norm_before = math.sqrt(sq_before)
        iterations = self._project(ops, dt)                                      # 2.
        div_after, sq_after, speed2 = self._divergence_stats(ops.gradient)
        self.clock.lap("operators", "divergence")
        self._notify("projected", operators=ops, dt=dt, iterations=iterations,
                     norm_before=norm_before)
        cleanup_iterations = 0
        if self.params.exact_projection:                                         # 2b.
            cleanup_iterations = self.clean_up(norm_before, ops.gradient)
            if cleanup_iterations:
                div_after, sq_after, speed2 = self._divergence_stats(ops.gradient)
                self.clock.lap("operators", "cleanup")
        self.advect(dt, math.sqrt(speed2), ops.concentration_gradient)          # 3.

        self.time += dt
        self.last_dt = dt
        self.step_count += 1
        info = {"dt": dt, "iterations": int(sum(iterations)), "passes": len(iterations),
                "cleanup_iterations": cleanup_iterations,
                "max_div_before": div_before, "max_div": div_after,
                "div_norm_before": norm_before, "div_norm": math.sqrt(sq_after),
                "max_speed": math.sqrt(speed2)}
        self._notify("advected", info=info)
        self.clock.lap("other", "advect")
        info["seconds"] = self.clock.stop()
        return info

    def _notify(self, event: str, **data) -> None:
        """Call :attr:`step_callback` (if any) at ``event`` of :data:`STEP_EVENTS`."""
        if self.step_callback is not None:
            self.step_callback(self, event, data)

    def update_neighbours(self):
        """Bin the particles (reordering them by cell) and build the pair list."""
        p = self.particles
        self.grid = bin_particles(p, self.spec, grid=self.grid)
        self.clock.lap("neighbours", "bin")
        self.pairs.build(p.position, p.n, p.position, self.grid, self.support)
        self.clock.lap("neighbours", "pairs")

    def _predict(self, viscous, dt):
        """Step 1: w = v + dt (g + nu lap v) on the fluid, 0 on the walls (into
        ``buffers.velocity``), the walls carrying the viscous condition (``walls``)
        for the viscous Laplacian's stencil ``viscous`` (None when nu = 0)."""
        params, p, ops, buf = self.params, self.particles, self.ops, self.buffers
        if viscous is not None:
            mode = WallVelocity.FREE_SLIP if params.walls == "free-slip" else WallVelocity.NO_SLIP
            wall_velocity(ops.kernel_id, p.n, self.pairs.offsets, self.pairs.neighbours,
                          p.position, p.volume, p.kind, self.support, p.velocity, mode, p.normal,
                          buf.wall_velocity)
            ops.laplacian(viscous, buf.wall_velocity, buf.velocity_laplacian)
        update.predict(p.n, p.kind, p.velocity, buf.velocity_laplacian, int(viscous is not None),
                       float(params.nu), dt, self._gx, self._gy, buf.velocity)
        self.clock.lap("operators", "predict")

    def _project(self, ops: StepOperators, dt):
        """Step 2, the iterated density-weighted projection of w (``buffers.velocity``):
        up to ``projection_passes`` solves of A q = div w (A = ``ops.poisson``, the
        wall rows: ``wall_rhs``), each followed by w <- w - grad q / rho on the
        fluid.  Stores the summed q by particle id (the next step's first guess);
        returns the solver iterations per pass."""
        params, p, buf = self.params, self.particles, self.buffers
        A = ops.poisson
        iterations = []
        b = self._pressure_rhs(ops.gradient, (dt * self._gx, dt * self._gy))
        self.clock.lap("operators", "divergence")
        M = A.preconditioner_for(params.preconditioner, "bicgstab",
                                 {"cycle": params.multilevel_cycle})
        for k in range(params.projection_passes):
            x0 = self._write_first_guess(dt) if k == 0 else None
            try:
                # b, x0: Taichi arrays of the bordered system (b's border row is 0)
                res = solvers.bicgstab(A, b, x0, tol=params.solver_tol, preconditioner=M)
            except SolverError as exc:
                raise BlowUpError(f"pressure solve failed at t={self.time:.4g}: {exc}") from exc
            self.clock.lap("solve")
            iterations.append(res.iterations)
            border = update.store_impulse(p.n, p.original_index, res.x_ndarray, int(k > 0),
                                          buf.q_by_id, buf.q_prev_by_id)
            if k == 0:
                self.border = float(border)
            # the solver's own array of x (its first n entries are q): no host copy
            self.ops.gradient(ops.pressure_gradient, res.x_ndarray, buf.pressure_gradient)
            update.correct(p.n, p.kind, p.density, buf.pressure_gradient, buf.velocity)
            if k + 1 == params.projection_passes:
                self.clock.lap("operators", "correction")
                break           # the next pass's right-hand side would go unused
            b = self._pressure_rhs(ops.gradient, (0.0, 0.0))  # gravity is balanced by now
            self.clock.lap("operators", "correction")
            if update.divergence_stats(p.n, p.kind, b, buf.velocity)[0] * dt < params.div_tol:
                break
        self.dt_history = (self.dt_history[1], dt)
        return iterations

    def _write_first_guess(self, dt):
        """The pressure solve's starting point, by particle slot, into
        ``buffers.first_guess`` (returned), its last entry the border unknown: with
        ``warm_start = "extrapolated"`` (and two previous steps) the pressure p =
        q / dt of the last two steps extrapolated linearly in time to this one,
        times dt; else the last step's impulse q.  The extrapolation saves about
        15% of the BiCGSTAB iterations of the droplet (docs/notes/flow.md)."""
        p, buf = self.particles, self.buffers
        dt_before, dt_last = self.dt_history
        extrapolate = self.params.warm_start == "extrapolated" and dt_before > 0 and dt_last > 0
        update.first_guess(p.n, p.original_index, buf.q_by_id, buf.q_prev_by_id,
                           int(extrapolate), dt, dt_last if extrapolate else 1.0,
                           dt_before if extrapolate else 1.0, self.border, buf.first_guess)
        return buf.first_guess

    def first_guess(self, dt) -> np.ndarray:
        """:meth:`_write_first_guess`'s values of the particles, as numpy."""
        return self._write_first_guess(dt).to_numpy()[: self.particles.n].astype(np.float64)

    def _pressure_rhs(self, st_grad, gdt):
        """The Poisson right-hand side of w (``buffers.velocity``), a Taichi array of
        the bordered system: div w on the fluid rows (the walls carrying the fluid's
        extrapolated w), the wall condition ``wall_rhs`` on the wall rows, 0 on the
        border row."""
        p, ops, pairs, buf = self.particles, self.ops, self.pairs, self.buffers
        wall_velocity(ops.kernel_id, p.n, pairs.offsets, pairs.neighbours, p.position, p.volume,
                      p.kind, self.support, buf.velocity, WallVelocity.COPY, p.normal,
                      buf.velocity_with_walls)
        ops.divergence(st_grad, buf.velocity_with_walls, buf.divergence)
        # the wall rows (and the border row) over the divergence's
        wall_rhs(ops.kernel_id, p.n, pairs.offsets, pairs.neighbours, p.position, p.volume,
                 p.density, p.kind, p.normal, buf.velocity, gdt[0], gdt[1], self.support,
                 buf.divergence)
        return buf.divergence

    def _divergence_stats(self, st) -> tuple:
        """(max |D w|, ||D w||^2, max |w|^2) over the fluid rows, w =
        ``buffers.velocity`` (0 on the walls, so D sees them at rest: module doc)."""
        p, buf = self.particles, self.buffers
        self.ops.divergence(st, buf.velocity, buf.measured_divergence)
        return update.divergence_stats(p.n, p.kind, buf.measured_divergence, buf.velocity)

    def measured_divergence(self, st) -> np.ndarray:
        """D w of w = ``buffers.velocity`` (module doc): the divergence of stencil
        ``st`` (the corrected gradient of the fluid rows), w being 0 on the walls
        (so D sees them at rest); numpy, by slot, 0 on wall rows."""
        p, buf = self.particles, self.buffers
        self.ops.divergence(st, buf.velocity, buf.measured_divergence)
        fluid = p.get("kind") == FLUID
        return np.where(fluid, buf.measured_divergence.to_numpy()[: p.n].astype(np.float64), 0.0)

    def clean_up(self, norm_before, st) -> int:
        """Step 2b, the orthogonal clean-up (module doc): the mass-weighted projection
        of w = ``buffers.velocity`` (0 on the walls) onto ``D u = 0`` over the
        fluid, walls at rest, in place.  ``norm_before``: ||D w*|| of the predicted
        field.  Solves (D M^-1 D^T) lam = D w by Jacobi-CG to ||D w_final|| <=
        cleanup_tol * ||D w*|| (2-norms over the fluid rows; skipped when already
        there), then w <- w - M^-1 D^T lam on the fluid.  Returns the CG
        iterations, 0 when skipped (w unchanged)."""
        params, p, buf = self.params, self.particles, self.buffers
        real = runtime.np_real()
        fluid = p.get("kind") == FLUID
        ids = p.get("original_index")
        d = self.measured_divergence(st)
        w = buf.velocity.to_numpy()[: p.n].astype(np.float64)
        self._notify("clean_up", operators=self.step_operators, velocity=w, divergence=d,
                     norm_before=norm_before)
        norm = math.sqrt(float((d ** 2).sum()))
        # never chase rounding: the divergence of a field varying by its own size
        # over one spacing, times 1e3 machine epsilons
        eps = float(np.finfo(real).eps)
        floor = 1e3 * eps * math.sqrt(float((w[fluid] ** 2).sum())) / self.dx
        tol = params.solver_tol if params.cleanup_tol is None else params.cleanup_tol
        target = max(tol * norm_before, floor)
        if norm <= target:
            return 0
        S = NormalOperator(self.ops, self.pairs, st, p.mass, p.n, rows=(FLUID,), cols=(FLUID,),
                           scratch=self.buffers.cleanup_scratch)
        x0 = self.lam_by_id[ids] if params.cleanup_warm_start else None
        self.clock.lap("operators", "cleanup")
        try:
            # iteration cap: 1700 were needed at 11k unknowns (docs/notes/flow.md)
            res = solvers.cg(S, d, x0=x0, tol=target / norm, preconditioner="jacobi",
                             max_iterations=max(5000, 2 * p.n))
        except SolverError as exc:
            raise BlowUpError(f"orthogonal clean-up solve failed at t={self.time:.4g}: {exc}") \
                from exc
        self.clock.lap("solve", "cleanup")
        lam = res.x[: p.n].astype(np.float64)
        lam[~fluid] = 0.0
        self.lam_by_id[ids] = lam
        _upload_rows(buf.multiplier, lam.astype(real))
        S.correction(buf.multiplier, buf.cleanup_correction)
        update.remove(p.n, p.kind, buf.cleanup_correction, buf.velocity)
        return res.iterations

    def advect(self, dt, vmax, have_concentration_gradient: bool = False) -> None:
        """Step 3: x <- x + dt w (+ the shifting displacement) on the fluid; the new
        positions and velocities go to the particles.  Raises :class:`BlowUpError`
        on non-finite values or many particles pushed out of the box (a few are put
        back just inside: the walls are impermeable).  With shifting, the
        concentration gradient is computed unless the step's operators came with
        it (``have_concentration_gradient``)."""
        params, p, buf = self.params, self.particles, self.buffers
        diffusion, cap = 0.0, 0.0
        if params.shifting > 0:
            self.clock.lap("other", "advect")
            if not have_concentration_gradient:
                concentration_gradient(self.ops.kernel_id, p.n, self.pairs.offsets,
                                       self.pairs.neighbours, p.position, p.mass, p.density,
                                       p.kind, self.support, buf.concentration_gradient)
            diffusion, cap = shifting_coefficients(params.shifting, self.support, vmax, dt,
                                                   self.dx)
            self.clock.lap("operators", "shifting")
        x0, y0, x1, y1 = (float(c) for c in params.box)
        total, out = update.advect(p.n, p.kind, p.position, buf.velocity,
                                   int(params.shifting > 0), buf.concentration_gradient,
                                   diffusion, cap, dt, x0, y0, x1, y1, buf.new_position)
        if not math.isfinite(total):
            raise BlowUpError(f"non-finite positions or velocities at t={self.time:.4g}",
                              cause="non-finite")
        # a particle pushed through a wall is put back just inside (walls are
        # impermeable); many at once means the step is unstable
        if out > max(3, 0.001 * self.n_fluid):
            raise BlowUpError(f"{int(out)} particles left the box at t={self.time:.4g}",
                              cause="left-box")
        update.commit(p.n, p.kind, buf.new_position, buf.velocity, 0.01 * self.dx,
                      x0, y0, x1, y1, p.position, p.velocity)

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

    def particle_data(self) -> dict:
        """Per fluid particle, in id order: ``position``, ``velocity``, ``phase``,
        ``id``, ``pressure`` (the last step's pressure, its impulse q over dt; 0
        before the first step) and ``volume_error`` (C_i / C_0 - 1, the signed
        value whose magnitude :meth:`volume_error` averages)."""
        ratio = self._number_density_ratio()    # first: it may bin, i.e. reorder, the particles
        p = self.particles
        kind = p.get("kind")
        ids = p.get("original_index")
        fluid = kind == FLUID
        order = np.argsort(ids[fluid])
        fluid_ids = ids[fluid][order]
        dt = self.last_dt
        return {"position": p.get("position")[fluid][order],
                "velocity": p.get("velocity")[fluid][order],
                "phase": p.get("phase")[fluid][order], "id": fluid_ids,
                "pressure": self.q_by_id[fluid_ids] / dt if dt > 0 else np.zeros(len(fluid_ids)),
                "volume_error": ratio[fluid][order] - 1.0}

    def state_dict(self) -> dict:
        pos, vel, phase, _ = self.fluid_state()
        return {"positions": pos, "velocities": vel, "phases": phase, "time": self.time,
                "step": self.step_count, "spacing": self.dx, "q_by_id": self.q_by_id,
                "border": self.border, "lam_by_id": self.lam_by_id,
                "q_prev_by_id": self.q_prev_by_id, "dt_before_last": self.dt_history[0],
                "last_dt": self.dt_history[1]}

    @classmethod
    def from_state(cls, state: dict, params: FlowParams) -> "TwoPhaseFlow":
        flow = cls(state["positions"], state["phases"], float(state["spacing"]), params,
                   velocity=state["velocities"], time=float(state["time"]))
        flow.step_count = int(state["step"])
        if len(state["q_by_id"]) == len(flow.q_by_id):
            flow.q_by_id = np.asarray(state["q_by_id"], dtype=np.float64)
        flow.border = float(state["border"])
        q_prev = state.get("q_prev_by_id")    # absent in older checkpoints: no extrapolation
        if q_prev is not None and len(q_prev) == len(flow.q_prev_by_id):
            flow.q_prev_by_id = np.asarray(q_prev, dtype=np.float64)
            flow.dt_history = (float(state["dt_before_last"]), float(state["last_dt"]))
            if flow.dt_history[1] > 0:
                flow.last_dt = flow.dt_history[1]
        lam = state.get("lam_by_id")          # absent in older checkpoints: cold start
        if lam is not None and len(lam) == len(flow.lam_by_id):
            flow.lam_by_id = np.asarray(lam, dtype=np.float64)
        return flow


def _upload_rows(arr, values: np.ndarray) -> None:
    """arr[:len(values)] = values (the rows beyond kept) in one host copy."""
    full = arr.to_numpy()
    full[: len(values)] = values
    arr.from_numpy(full)


def _check_params(params) -> None:
    """Refuse parameters no flow can run with, naming the first one."""
    def finite(name, value, low, strict=True):
        ok = math.isfinite(value) and (value > low if strict else value >= low)
        if not ok:
            raise InputError(f"FlowParams.{name} must be a finite number "
                             f"{'>' if strict else '>='} {low:g}, got {value!r}")
    finite("nu", float(params.nu), 0.0, strict=False)
    for rho in params.densities:
        finite("densities", float(rho), 0.0)
    for name in ("support_ratio", "cfl", "viscous_cfl", "force_cfl", "dt_max", "solver_tol"):
        finite(name, float(getattr(params, name)), 0.0)
    finite("shifting", float(params.shifting), 0.0, strict=False)
    if not all(math.isfinite(float(g)) for g in params.gravity):
        raise InputError(f"FlowParams.gravity must be finite, got {params.gravity!r}")
    if int(params.projection_passes) < 1:
        raise InputError(f"FlowParams.projection_passes must be >= 1, got {params.projection_passes!r}")


def _lattice_number_density(kernel: str, dx: float, support: float) -> float:
    """sum_j dx^2 W(|x_j|) over a full square lattice (self included)."""
    k = int(math.ceil(support / dx)) + 1
    g = np.arange(-k, k + 1) * dx
    X, Y = np.meshgrid(g, g)
    W, _, _ = kernel_numpy(kernel, np.hypot(X, Y).ravel(), support)
    return float(dx * dx * W.sum())
