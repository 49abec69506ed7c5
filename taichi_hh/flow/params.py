"""The flow's settings (:class:`FlowParams`) and the wall conditions they name."""
import math
import warnings
from dataclasses import dataclass
from enum import IntEnum

from ..errors import AccuracyWarning

#: Largest time-step factors of the measured stable, accurate range
#: (docs/notes/app.md, "Hostile input"): beyond
#: them :class:`FlowParams` warns (:class:`~taichi_hh.errors.AccuracyWarning`).
STABLE_LIMITS = {"cfl": 0.5, "force_cfl": 1.0, "viscous_cfl": 0.66}

#: The viscous wall conditions (``FlowParams.walls``).
WALL_CONDITIONS = ("no-slip", "free-slip")

#: The pressure solve's first guesses (``FlowParams.warm_start``).
WARM_STARTS = ("extrapolated", "previous")


class WallVelocity(IntEnum):
    """What the wall particles carry (:func:`taichi_hh.flow.walls.wall_velocity`):
    the fluid's Shepard-extrapolated velocity (the pressure equation's right-hand
    side), minus it (no slip), or its mirror image (free slip).  An ``IntEnum``:
    Taichi kernels compare a ``ti.i32`` argument with its members directly."""
    COPY = 0
    NO_SLIP = 1
    FREE_SLIP = 2


WALL_COPY, WALL_NO_SLIP, WALL_FREE_SLIP = WallVelocity.COPY, WallVelocity.NO_SLIP, \
    WallVelocity.FREE_SLIP


@dataclass
class FlowParams:
    """Settings of a :class:`~taichi_hh.flow.twophase.TwoPhaseFlow` (the scenes and
    checkpoints name these fields).  Time-step limits: module doc of
    :mod:`taichi_hh.flow.twophase`; measurements behind the defaults:
    docs/notes/flow.md."""
    box: tuple = (0.0, 0.0, 1.0, 2.0)          # x0, y0, x1, y1
    gravity: tuple = (0.0, -1.0)
    nu: float = 2e-3                            # kinematic viscosity, both phases
    densities: tuple = (1.0, 2.0)               # rest density per phase index
    kernel: str = "wendland"
    support_ratio: float = 3.0                  # support / particle spacing
    cfl: float = 0.25
    viscous_cfl: float = 0.25                   # stable up to 0.66 (docs/notes/flow.md)
    force_cfl: float = 0.25
    dt_max: float = 0.02
    projection_passes: int = 1
    div_tol: float = 1e-3                       # on max |div v| * dt (relative volume change)
    solver_tol: float = 1e-4
    # the pressure solve's first guess: "extrapolated" (the last two steps' pressure,
    # linearly in time) or "previous" (the last step's) (docs/notes/flow.md)
    warm_start: str = "extrapolated"
    preconditioner: str = "auto"                # of the pressure BiCGSTAB: auto | multilevel | jacobi
    # the multilevel cycle of the pressure solve: V takes fewer BiCGSTAB
    # iterations here than the W-cycle the decompositions use (docs/notes/flow.md)
    multilevel_cycle: str = "V"
    pressure_laplacian: str = "corrected"
    gradient: str = "corrected"
    viscous_laplacian: str = "corrected"
    shifting: float = 0.0                       # particle-shifting coefficient (0 = off)
    # viscous wall condition (WALL_CONDITIONS): "no-slip" (the scenes), or "free-slip"
    # (the setting of the linear Rayleigh-Taylor theory, benchmarks/rt_growth.py)
    walls: str = "no-slip"
    pair_density_gradient: bool = True          # grad q / rho with pair-mean densities
    # orthogonal clean-up after the passes: ||div|| to cleanup_tol (module doc of
    # twophase); off by default: it costs tens of steps' time (docs/notes/flow.md)
    exact_projection: bool = False
    cleanup_tol: float | None = None            # of the clean-up; None: solver_tol
    cleanup_warm_start: bool = True             # start the clean-up CG from last step's lam

    def __post_init__(self):
        beyond = [f"{name} = {getattr(self, name):g} (measured up to {limit:g})"
                  for name, limit in STABLE_LIMITS.items()
                  if isinstance(getattr(self, name), (int, float))
                  and math.isfinite(getattr(self, name)) and getattr(self, name) > limit]
        if beyond:
            warnings.warn("time-step limits beyond the measured stable range: "
                          + ", ".join(beyond) + "; expect large volume errors or a blow-up "
                          "(docs/notes/app.md)", AccuracyWarning, stacklevel=3)
