"""Numerical options of :func:`~taichi_hh.hhd.decompose.decompose` and
:func:`~taichi_hh.hhd.project.project`, and the bundles that name them.

:data:`METHODS`:

``default``         Wendland C2 with an adaptive support: 3.5 local spacings,
                    the spacing estimated from each point's 12 nearest
                    neighbours (:mod:`taichi_hh.sph.support`), so that uniformly
                    random, clustered and varying-density data keep well-posed
                    rows (docs/notes/scattered.md); div v and curl v by the
                    cubic (MLS) gradient over the data points (the quadratic
                    fit's error on random points is noise that the potentials
                    inherit); corrected
                    Laplacian (exact on quadratics) on the data points, its
                    rows that lose their sign made positive (sph.positive:
                    a few per thousand, near the boundary; they made the
                    iterations grow with N on random points), and
                    Neumann rows on boundary particles sampled along the
                    boundary, with the quadratic gradient (second order up to
                    the boundary); bordered system for the pure-Neumann
                    compatibility; BiCGSTAB to 1e-8 preconditioned by the
                    multilevel cycle (Jacobi below 1000 particles); d, r by
                    the quadratic gradient (the cubic one is no more accurate
                    there and makes the critical points' strengths overshoot:
                    docs/notes/scattered.md).
``petronetto2010``  as published: quartic kernel, difference gradient and
                    divergence (Petronetto Eqs. 8, 9), Brookshaw Laplacian
                    (Eq. 10), fake particles outside the boundary by
                    Poisson-disk sampling with the field extended by the
                    Shepard sum (Eq. 14) and their potentials by Shepard rows,
                    the Neumann term on particles within sqrt(m/rho)/pi of the
                    boundary, ridge kappa = 1e-3 (Sec. 6a), Jacobi-preconditioned
                    BiCGSTAB to residual 1e-6.
``colin2006``       Colin et al.'s operators: poly6 kernel, DGAF (Colin Eq. 13),
                    Laplacian Eq. 21, a layer of boundary particles with normals
                    whose rows enforce dq/dn = 0 (Eq. 37), CG on the normal
                    equations (Sec. 3.5) to the least-squares solution (the
                    stacked system is inconsistent and ill-conditioned).  Made
                    for projections on lattices: as a decomposition on blue
                    noise its components are wrong and flagged
                    (AccuracyWarning; docs/notes/hhd.md).
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

from ..checks import OptionSpec, check_names, check_option, did_you_mean
from ..errors import InputError

BOUNDARY_METHODS = ("collocation", "petronetto", "colin", "none")
#: boundary conditions of the decomposition (:func:`~taichi_hh.hhd.decompose.decompose`)
BOUNDARY_CONDITIONS = ("auto", "neumann", "normal-parallel", "no-flux", "natural")
#: evaluations of the natural decomposition's convolution (:mod:`taichi_hh.hhd.natural`)
NATURAL_EVALUATIONS = ("fft", "direct")
PRECONDITIONERS = ("auto", "multilevel", "jacobi")
#: linear solvers of the Poisson systems (:mod:`taichi_hh.linalg.krylov`)
SOLVERS = ("bicgstab", "cgnr")


# the kernels' and operator variants' names live with their Taichi code: read on use
def _kernels() -> tuple:
    from ..sph.kernels import KERNELS
    return KERNELS


def _gradient_variants() -> tuple:
    from ..sph.operators import GRADIENT_VARIANTS
    return GRADIENT_VARIANTS


def _laplacian_variants() -> tuple:
    from ..sph.operators import LAPLACIAN_VARIANTS
    return LAPLACIAN_VARIANTS


def _real(low=None, high=None, *, low_open=False, high_open=False, none=False) -> OptionSpec:
    return OptionSpec("real", low=low, high=high, low_open=low_open, high_open=high_open,
                      none=none)


#: the keywords of :class:`~taichi_hh.poisson.multilevel.MultilevelPreconditioner`
#: that ``multilevel_options`` may set, with the ranges it accepts (None: the
#: cycle's own default)
MULTILEVEL_OPTION_SPECS = {
    "cycle": OptionSpec("choice", choices=("V", "W")),
    "post": OptionSpec("int", low=1, high=3, none=True),
    "omega": _real(0, 2, low_open=True, high_open=True, none=True),
    "correction": _real(0, low_open=True, none=True),
    "l1": OptionSpec("bool"),
    "cells": _real(0, low_open=True, none=True),
    "weak": _real(0),
}

#: how each field of :class:`HHDOptions` is checked (one spec per field; every
#: value passes :func:`~taichi_hh.checks.check_option` in ``__post_init__``)
OPTION_SPECS = {
    "kernel": OptionSpec("choice", choices=_kernels),
    "support_ratio": _real(0, low_open=True),
    "adaptive_support": OptionSpec("bool"),
    "support_neighbours": OptionSpec("int", low=1, high=24),
    "divergence": OptionSpec("choice", choices=_gradient_variants),
    "gradient": OptionSpec("choice", choices=_gradient_variants),
    "laplacian": OptionSpec("choice", choices=_laplacian_variants),
    "neumann_gradient": OptionSpec("choice", choices=_gradient_variants),
    "positive_rows": _real(1, none=True),
    "boundary": OptionSpec("choice", choices=BOUNDARY_METHODS),
    "kappa": _real(0),
    "bordered": OptionSpec("bool"),
    "remove_mean": OptionSpec("bool"),
    "solver": OptionSpec("choice", choices=SOLVERS),
    "preconditioner": OptionSpec("choice", choices=PRECONDITIONERS),
    "multilevel_options": OptionSpec("options", fields=MULTILEVEL_OPTION_SPECS),
    "tol": _real(0, low_open=True),
    "max_iterations": OptionSpec("int", low=1, none=True),
    "seed": OptionSpec("int", low=0, none=True),
    "boundary_condition": OptionSpec("choice", choices=BOUNDARY_CONDITIONS),
    "natural_evaluation": OptionSpec("choice", choices=NATURAL_EVALUATIONS),
}


@dataclass(frozen=True)
class HHDOptions:
    """Numerical choices of :func:`~taichi_hh.hhd.decompose.decompose` (bundles: :data:`METHODS`).

    Every field is checked on construction by its entry of :data:`OPTION_SPECS`
    (:class:`~taichi_hh.errors.InputError` naming the field and the problem) and
    stored in canonical form: reals as float, integers as int, flags as bool."""
    kernel: str = "wendland"
    support_ratio: float = 3.5          # kernel support / (local) mean spacing
    # per-point support from the local spacing (sph.support); the boundary
    # samples then follow the data's spacing next to the wall (hhd.boundary)
    adaptive_support: bool = True
    support_neighbours: int = 12        # k of that local spacing estimate
    divergence: str = "cubic"           # gradient variant for div v and curl v
    gradient: str = "quadratic"         # gradient variant for d = grad phi, r = J grad psi
    laplacian: str = "corrected"        # Laplacian variant of the Poisson rows
    neumann_gradient: str = "quadratic"  # gradient variant of the Neumann rows
    # corrected-Laplacian rows with sum |C_ij| > positive_rows * sum C_ij (or a
    # diagonal of the wrong sign) replaced by the positive stencil exact on
    # quadratics (sph.positive); None: off
    positive_rows: float | None = 1.5
    boundary: str = "collocation"       # collocation | petronetto | colin | none
    kappa: float = 0.0                  # ridge term (Petronetto Sec. 6a)
    bordered: bool = True               # compatibility unknown for pure Neumann
    remove_mean: bool = False           # subtract the volume-weighted mean of div v, curl v
    solver: str = "bicgstab"            # bicgstab | cgnr
    preconditioner: str = "auto"        # auto | multilevel | jacobi (see PoissonMatrix.solve)
    # MultilevelPreconditioner options, as (name, value) pairs sorted by name (a dict is
    # accepted; names and values checked by MULTILEVEL_OPTION_SPECS):
    # first-level cells of a quarter of the median support, rows with |a_ii| < 0.1 sum |a_ij|
    # aggregated with their strongest neighbour, l1 smoothing, two post-sweeps, omega 0.85
    # for the default's rows (docs/notes/linalg.md, docs/notes/scattered.md)
    multilevel_options: tuple = (("cells", 0.25), ("l1", True), ("omega", 0.85), ("post", 2),
                                 ("weak", 0.1))
    tol: float = 1e-8
    max_iterations: int | None = None
    seed: int = 0                       # for sampled fake/boundary particles
    # auto (natural, or no-flux for a closed container: hhd.auto) | neumann |
    # normal-parallel | no-flux | natural (decompose doc)
    boundary_condition: str = "auto"
    natural_evaluation: str = "fft"     # fft | direct: the natural HHD's convolution

    def __post_init__(self):
        # every field by its spec (OPTION_SPECS), stored in canonical form (float,
        # int, bool, str; multilevel_options as (name, value) pairs sorted by name)
        for f in fields(self):
            spec = OPTION_SPECS.get(f.name)
            if spec is None:
                raise TypeError(f"HHDOptions.{f.name} has no entry in OPTION_SPECS")
            object.__setattr__(self, f.name, check_option(getattr(self, f.name), f.name, spec))
        # combinations
        if self.boundary_condition in ("normal-parallel", "no-flux") \
                and self.boundary != "collocation":
            raise InputError(f"boundary_condition={self.boundary_condition!r} puts Dirichlet "
                             "rows on the boundary particles of boundary='collocation', got "
                             f"boundary={self.boundary!r}")
        if self.preconditioner == "multilevel" and self.solver != "bicgstab":
            raise InputError("the multilevel preconditioner works with solver='bicgstab', got "
                             f"solver={self.solver!r}")


METHODS = {
    "default": HHDOptions(),
    "petronetto2010": HHDOptions(kernel="quartic", support_ratio=2.0, adaptive_support=False,
                                 divergence="difference",
                                 gradient="difference", laplacian="brookshaw",
                                 neumann_gradient="difference", boundary="petronetto",
                                 kappa=1e-3, bordered=False, tol=1e-6,
                                 preconditioner="jacobi", boundary_condition="neumann"),
    "colin2006": HHDOptions(kernel="poly6", support_ratio=2.0, adaptive_support=False,
                            divergence="colin_difference",
                            gradient="colin_difference", laplacian="colin_difference",
                            neumann_gradient="colin_difference", boundary="colin",
                            bordered=False, solver="cgnr", preconditioner="jacobi", tol=1e-4,
                            max_iterations=20000, boundary_condition="neumann"),
}

#: per-method options of project() that differ from the :data:`METHODS` bundles:
#: Colin solves the plain (not bordered) stacked system by CG on the normal
#: equations, here to the least-squares solution with normal residual 1e-4
#: (tighter tolerances stall: docs/notes/hhd.md)
PROJECT_OVERRIDES = {"colin2006": {"bordered": False, "tol": 1e-4, "max_iterations": 20000},
                     # the projection keeps the fixed support and quadratic fits it was
                     # measured with (Colin Table 1 on lattices) on regular layouts; on
                     # irregular ones project() takes the decomposition's adaptive support
                     # by itself (project.SCATTERED_OPTIONS, project.choose_support)
                     # and a projection keeps the normal flux: Neumann
                     "default": {"boundary_condition": "neumann",
                                 "support_ratio": 2.5, "adaptive_support": False,
                                 "divergence": "quadratic", "gradient": "quadratic"}}


def options_for(method: str = "default", **overrides) -> HHDOptions:
    """The bundle ``method`` of :data:`METHODS` with single fields ``overrides``.

    Raises :class:`~taichi_hh.errors.InputError` for an unknown method, an
    unknown option name (with the close spellings and the valid names) or a
    bad value (:data:`OPTION_SPECS`)."""
    if not isinstance(method, str) or method not in METHODS:
        raise InputError(f"unknown method {method!r}; choose one of {tuple(METHODS)}"
                         + did_you_mean(method, METHODS))
    check_names(overrides, OPTION_SPECS, what="option")
    return replace(METHODS[method], **overrides)
