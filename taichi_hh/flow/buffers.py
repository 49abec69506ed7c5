"""The flow's work arrays (:class:`FlowBuffers`): allocated once per particle
capacity and reused by every step, so that a step allocates no Taichi ndarray of
its own (Taichi 1.7 frees dropped vector ndarrays only with the patch in
:mod:`taichi_hh.runtime`; allocating per step also costs time)."""
from dataclasses import dataclass, fields

import taichi as ti

from .. import runtime


def _scalars(size: int):
    return ti.ndarray(runtime.real_dtype(), shape=(size,))


def _vectors(size: int):
    return ti.Vector.ndarray(2, runtime.real_dtype(), shape=(size,))


@ti.kernel
def _copy_vectors(m: ti.i32, src: ti.types.ndarray(), dst: ti.types.ndarray()):
    for k in range(m):
        dst[k] = src[k]


@dataclass
class FlowBuffers:
    """One array per intermediate of a step, each ``capacity`` rows (per particle),
    except ``pair_gradient`` (per pair, grown on demand)."""
    # predict
    wall_velocity: object           # the velocity with the walls' viscous condition
    velocity_laplacian: object      # nu lap v
    # project: the right-hand side and the pressure-gradient correction
    velocity: object                # w
    velocity_with_walls: object     # w, the walls carrying the fluid's extrapolated w
    divergence: object              # div w (fluid rows)
    wall_rhs: object                # the wall rows' right-hand side
    pressure: object                # q of one pass
    pressure_gradient: object       # grad q / rho
    # the measured divergence D w (walls at rest)
    measured_velocity: object
    measured_divergence: object
    # the orthogonal clean-up
    multiplier: object              # lam
    cleanup_correction: object      # M^-1 D^T lam
    # particle shifting and the volume error
    concentration_gradient: object
    number_density: object
    volume: object
    # the density-weighted pressure-gradient coefficients, per pair
    pair_gradient: object = None

    @classmethod
    def allocate(cls, capacity: int) -> "FlowBuffers":
        size = max(capacity, 1)
        vectors = {"wall_velocity", "velocity_laplacian", "velocity", "velocity_with_walls",
                   "pressure_gradient", "measured_velocity", "cleanup_correction",
                   "concentration_gradient"}
        return cls(**{f.name: (_vectors if f.name in vectors else _scalars)(size)
                      for f in fields(cls) if f.name != "pair_gradient"})

    def copy_of_pair_vectors(self, G):
        """A copy of the per-pair vectors ``G`` in ``pair_gradient`` (its first
        ``len(G)`` entries), grown by a quarter when ``G`` outgrows it."""
        m = G.shape[0]
        if self.pair_gradient is None or self.pair_gradient.shape[0] < m:
            self.pair_gradient = _vectors(m + m // 4)
        _copy_vectors(m, G, self.pair_gradient)
        return self.pair_gradient
