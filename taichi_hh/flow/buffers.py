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
    pressure_gradient: object       # grad q / rho
    # the measured divergence D w (walls at rest)
    measured_velocity: object
    measured_divergence: object
    # the orthogonal clean-up
    multiplier: object              # lam
    cleanup_correction: object      # M^-1 D^T lam
    cleanup_scratch: object         # M^-1 D^T x inside the clean-up's operator
    # particle shifting and the volume error
    concentration_gradient: object
    number_density: object
    volume: object
    # the gradient's self coefficients (per particle) and pair coefficients, and
    # the density-weighted pressure-gradient pair coefficients (per pair, grown
    # on demand)
    gradient_self: object
    gradient_pairs: object = None
    pair_gradient: object = None

    @classmethod
    def allocate(cls, capacity: int) -> "FlowBuffers":
        size = max(capacity, 1)
        vectors = {"wall_velocity", "velocity_laplacian", "velocity", "velocity_with_walls",
                   "pressure_gradient", "measured_velocity", "cleanup_correction", "cleanup_scratch",
                   "concentration_gradient", "gradient_self"}
        per_pair = {"gradient_pairs", "pair_gradient"}
        return cls(**{f.name: (_vectors if f.name in vectors else _scalars)(size)
                      for f in fields(cls) if f.name not in per_pair})

    def gradient_arrays(self, n_pairs: int):
        """``(G, s)`` for :meth:`Operators.gradient_coefficients`: ``G`` grown by a
        quarter when ``n_pairs`` outgrows it."""
        if self.gradient_pairs is None or self.gradient_pairs.shape[0] < n_pairs:
            self.gradient_pairs = _vectors(max(n_pairs + n_pairs // 4, 1))
        return self.gradient_pairs, self.gradient_self

    def copy_of_pair_vectors(self, G, m: int):
        """A copy of the first ``m`` per-pair vectors of ``G`` in ``pair_gradient``,
        grown by a quarter when ``m`` outgrows it."""
        if self.pair_gradient is None or self.pair_gradient.shape[0] < m:
            self.pair_gradient = _vectors(max(m + m // 4, 1))
        _copy_vectors(m, G, self.pair_gradient)
        return self.pair_gradient
