"""The operators of one flow step (:class:`StepOperators`), all built by
:func:`build_step_operators` from the step's particles and pair list.

A step needs, on the pair list of its neighbour search:

* the viscous Laplacian of the fluid rows (none when nu = 0),
* the corrected gradient of the fluid rows, whose divergence is the measured
  ``D`` (module doc of :mod:`taichi_hh.flow.twophase`),
* the pressure gradient: that gradient, times 2 / (rho_i + rho_j) with
  ``pair_density_gradient``,
* the bordered, density-weighted Poisson matrix of the pressure equation,
* with shifting, the concentration gradient (``buffers.concentration_gradient``).

How they are computed depends on the parameters, in one place here:

* the default (every variant ``corrected``, ``pair_density_gradient``, nu > 0):
  one pair pass gives the viscous Laplacian, the gradient, both density-weighted
  copies (the Poisson Laplacian and the pressure gradient) and the
  concentration gradient (``Operators.laplacian_coefficients(gradient_into=)``);
* otherwise the gradient has its own pass and the Poisson Laplacian is the
  viscous one weighted by the pair densities when the two variants agree (and
  nu > 0), else computed density-weighted on its own.

The Poisson matrix is then always made the same way, from the Laplacian
stencil, with the gradient stencil for its Neumann rows: the flow has no
BOUNDARY particles (its walls are Shepard rows) and no near-boundary term, so
that gradient is multiplied by zero and any stencil at hand gives the identical
matrix.  Every array is one of the flow's :class:`~taichi_hh.flow.buffers.FlowBuffers`
(the matrix reuses the previous step's): a step allocates none.
"""
from dataclasses import dataclass

from ..poisson.matrix import PoissonMatrix
from ..sph.operators import GradientStencil, LaplacianStencil, \
    weight_gradient_by_mean_density
from ..sph.particles import FLUID


@dataclass(frozen=True)
class StepOperators:
    """What one step's phases apply (module doc)."""
    viscous: LaplacianStencil | None        # nu lap v of the fluid rows; None when nu = 0
    gradient: GradientStencil               # the fluid rows' gradient: D, the measured divergence
    pressure_gradient: GradientStencil      # grad q / rho's stencil
    poisson: PoissonMatrix                  # bordered, density weighted
    concentration_gradient: bool            # buffers.concentration_gradient already computed


def fused(params) -> bool:
    """Whether the default's single pair pass applies (module doc)."""
    return (params.nu > 0 and params.viscous_laplacian == params.gradient
            == params.pressure_laplacian == "corrected" and params.pair_density_gradient)


def build_step_operators(params, ops, buffers, reuse: PoissonMatrix | None = None,
                         lap=None) -> StepOperators:
    """The step's operators on ``ops`` (its particles and pair list), written into
    ``buffers``; ``reuse``: the previous step's Poisson matrix, whose arrays the
    new one overwrites.  lap: ``lap(stage, detail)``, the flow clock's, called
    after each part (default: none)."""
    lap = lap or (lambda stage, detail=None: None)
    n_pairs = ops.pairs.n_pairs
    buffers.grow_pairs(n_pairs)
    rows = (FLUID,)
    viscous = poisson_laplacian = None
    concentration = False
    if fused(params):
        viscous, gradient, poisson_laplacian, pressure_gradient = ops.laplacian_coefficients(
            "corrected", row_kinds=rows, into=buffers.laplacian_arrays(n_pairs),
            gradient_into=(buffers.gradient_pairs, buffers.gradient_self,
                           buffers.weighted_laplacian, buffers.pair_gradient,
                           buffers.concentration_gradient))
        concentration = True
        lap("operators", "viscous_coefficients")
    else:
        if params.nu > 0:
            viscous = ops.laplacian_coefficients(params.viscous_laplacian, row_kinds=rows,
                                                 into=buffers.laplacian_arrays(n_pairs))
            lap("operators", "viscous_coefficients")
        gradient = ops.gradient_coefficients(params.gradient, row_kinds=rows,
                                             into=buffers.gradient_arrays(n_pairs))
        pressure_gradient = gradient
        if params.pair_density_gradient:
            # the same coefficients times 2 / (rho_i + rho_j): what
            # gradient_coefficients(..., density_weighted=True) computes, without
            # building the (correction-matrix) coefficients a second time
            p = ops.particles
            weight_gradient_by_mean_density(p.n, ops.pairs.offsets, ops.pairs.neighbours,
                                            p.density, gradient.G, buffers.pair_gradient)
            pressure_gradient = GradientStencil(buffers.pair_gradient, gradient.s,
                                                gradient.variant, gradient.row_kinds,
                                                gradient.source_kinds)
        lap("operators", "gradient_coefficients")
        if viscous is not None and params.viscous_laplacian == params.pressure_laplacian:
            poisson_laplacian = ops.density_weighted(viscous, into=buffers.weighted_laplacian)
        else:
            poisson_laplacian = ops.laplacian_coefficients(
                params.pressure_laplacian, row_kinds=rows, density_weighted=True,
                into=(buffers.weighted_laplacian, buffers.poisson_self))
    poisson = PoissonMatrix(ops, laplacian=poisson_laplacian, gradient=gradient, kappa=0.0,
                            bordered=True, reuse=reuse)
    lap("operators", "poisson_assembly")
    return StepOperators(viscous, gradient, pressure_gradient, poisson, concentration)
