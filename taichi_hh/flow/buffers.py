"""The flow's work arrays (:class:`FlowBuffers`): allocated once per particle
capacity and reused by every step, so that a step allocates no Taichi ndarray of
its own (Taichi 1.7 frees dropped vector ndarrays only with the patch in
:mod:`taichi_hh.runtime`; allocating per step also costs time)."""
from dataclasses import dataclass, fields

from .. import runtime


def _scalars(size: int):
    return runtime.array(runtime.real_dtype(), size)


def _vectors(size: int):
    return runtime.array(runtime.real_dtype(), size, vector=2)


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
    divergence: object              # div w (fluid rows), wall_rhs (wall rows), the border row
    first_guess: object             # the pressure solve's first guess (and border unknown)
    q_by_id: object                 # the last pressure impulse, by particle id
    q_prev_by_id: object            # the one before
    pressure_gradient: object       # grad q / rho
    # the measured divergence D w (walls at rest)
    measured_velocity: object
    measured_divergence: object
    # the orthogonal clean-up
    multiplier: object              # lam
    cleanup_correction: object      # M^-1 D^T lam
    cleanup_scratch: object         # M^-1 D^T x inside the clean-up's operator
    # particle shifting, the advected positions and the volume error
    concentration_gradient: object
    new_position: object
    number_density: object
    volume: object
    # the self coefficients (per particle) of the gradient, of the viscous
    # Laplacian and of a Poisson Laplacian computed on its own, and the per-pair
    # coefficients (grown on demand): the gradient's, the density-weighted
    # pressure gradient's, the Laplacian's and the density-weighted (Poisson)
    # Laplacian's
    gradient_self: object
    laplacian_self: object
    poisson_self: object
    # the vorticity of the frames (TwoPhaseFlow.vorticity): the fluid-only
    # gradient's self coefficients and the curl
    vorticity_self: object
    vorticity: object
    gradient_pairs: object = None
    pair_gradient: object = None
    laplacian_pairs: object = None
    weighted_laplacian: object = None
    # the fluid-only gradient's pair coefficients, grown on demand apart from the
    # step's (a flow whose frames show no vorticity never allocates them)
    vorticity_pairs: object = None

    @classmethod
    def allocate(cls, capacity: int) -> "FlowBuffers":
        size = max(capacity, 1)
        vectors = {"wall_velocity", "velocity_laplacian", "velocity", "velocity_with_walls",
                   "pressure_gradient", "measured_velocity", "cleanup_correction", "cleanup_scratch",
                   "concentration_gradient", "new_position", "gradient_self",
                   "vorticity_self"}
        bordered = {"divergence", "first_guess"}       # the bordered system's length
        return cls(**{f.name: (_vectors if f.name in vectors else _scalars)(
                          size + (f.name in bordered))
                      for f in fields(cls) if f.name not in _PER_PAIR + ("vorticity_pairs",)})

    def grow_pairs(self, n_pairs: int) -> None:
        """Every per-pair array at least ``n_pairs`` rows (grown by a quarter when
        outgrown): a step allocates none while the pair count stays below it."""
        if self.gradient_pairs is None or self.gradient_pairs.shape[0] < n_pairs:
            size = max(n_pairs + n_pairs // 4, 1)
            for name in _PER_PAIR:
                setattr(self, name, (_vectors if name in ("gradient_pairs", "pair_gradient")
                                     else _scalars)(size))

    def gradient_arrays(self, n_pairs: int):
        """``(G, s)`` for :meth:`Operators.gradient_coefficients`."""
        self.grow_pairs(n_pairs)
        return self.gradient_pairs, self.gradient_self

    def laplacian_arrays(self, n_pairs: int):
        """``(C, s)`` for :meth:`Operators.laplacian_coefficients`."""
        self.grow_pairs(n_pairs)
        return self.laplacian_pairs, self.laplacian_self

    def vorticity_arrays(self, n_pairs: int):
        """``(G, s)`` of the vorticity's gradient (grown like the step's arrays)."""
        if self.vorticity_pairs is None or self.vorticity_pairs.shape[0] < n_pairs:
            self.vorticity_pairs = _vectors(max(n_pairs + n_pairs // 4, 1))
        return self.vorticity_pairs, self.vorticity_self


#: the per-pair arrays of :class:`FlowBuffers`
_PER_PAIR = ("gradient_pairs", "pair_gradient", "laplacian_pairs", "weighted_laplacian")
