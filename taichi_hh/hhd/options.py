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

from dataclasses import dataclass, replace

BOUNDARY_METHODS = ("collocation", "petronetto", "colin", "none")
#: boundary conditions of the decomposition (:func:`~taichi_hh.hhd.decompose.decompose`)
BOUNDARY_CONDITIONS = ("neumann", "normal-parallel", "natural")
#: evaluations of the natural decomposition's convolution (:mod:`taichi_hh.hhd.natural`)
NATURAL_EVALUATIONS = ("fft", "direct")
PRECONDITIONERS = ("auto", "multilevel", "jacobi")


@dataclass(frozen=True)
class HHDOptions:
    """Numerical choices of :func:`~taichi_hh.hhd.decompose.decompose` (bundles: :data:`METHODS`)."""
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
    # MultilevelPreconditioner options, as (name, value) pairs (a dict is accepted):
    # first-level cells of a quarter of the median support, rows with |a_ii| < 0.1 sum |a_ij|
    # aggregated with their strongest neighbour, l1 smoothing, two post-sweeps, omega 0.85
    # for the default's rows (docs/notes/linalg.md, docs/notes/scattered.md)
    multilevel_options: tuple = (("cells", 0.25), ("l1", True), ("omega", 0.85), ("post", 2),
                                 ("weak", 0.1))
    tol: float = 1e-8
    max_iterations: int | None = None
    seed: int = 0                       # for sampled fake/boundary particles
    boundary_condition: str = "neumann"  # neumann | normal-parallel | natural (decompose doc)
    natural_evaluation: str = "fft"     # fft | direct: the natural HHD's convolution

    def __post_init__(self):
        if isinstance(self.multilevel_options, dict):
            object.__setattr__(self, "multilevel_options",
                               tuple(sorted(self.multilevel_options.items())))
        if self.boundary not in BOUNDARY_METHODS:
            raise ValueError(f"boundary must be one of {BOUNDARY_METHODS}, got {self.boundary!r}")
        if not (self.support_ratio > 0):
            raise ValueError(f"support_ratio must be positive, got {self.support_ratio}")
        if not 1 <= self.support_neighbours <= 24:
            raise ValueError(f"support_neighbours must be 1..24, got {self.support_neighbours}")
        if self.positive_rows is not None and not self.positive_rows >= 1:
            raise ValueError(f"positive_rows must be None or a number >= 1, got "
                             f"{self.positive_rows!r}")
        if not (self.tol > 0):
            raise ValueError(f"tol must be positive, got {self.tol}")
        if self.boundary_condition not in BOUNDARY_CONDITIONS:
            raise ValueError(f"boundary_condition must be one of {BOUNDARY_CONDITIONS}, "
                             f"got {self.boundary_condition!r}")
        if self.natural_evaluation not in NATURAL_EVALUATIONS:
            raise ValueError(f"natural_evaluation must be one of {NATURAL_EVALUATIONS}, "
                             f"got {self.natural_evaluation!r}")
        if self.boundary_condition == "normal-parallel" and self.boundary != "collocation":
            raise ValueError("boundary_condition='normal-parallel' puts its Dirichlet rows on "
                             "the boundary particles of boundary='collocation', got "
                             f"boundary={self.boundary!r}")
        if self.preconditioner not in PRECONDITIONERS:
            raise ValueError(f"preconditioner must be one of {PRECONDITIONERS}, "
                             f"got {self.preconditioner!r}")
        if self.preconditioner == "multilevel" and self.solver != "bicgstab":
            raise ValueError("the multilevel preconditioner works with solver='bicgstab'")


METHODS = {
    "default": HHDOptions(),
    "petronetto2010": HHDOptions(kernel="quartic", support_ratio=2.0, adaptive_support=False,
                                 divergence="difference",
                                 gradient="difference", laplacian="brookshaw",
                                 neumann_gradient="difference", boundary="petronetto",
                                 kappa=1e-3, bordered=False, tol=1e-6,
                                 preconditioner="jacobi"),
    "colin2006": HHDOptions(kernel="poly6", support_ratio=2.0, adaptive_support=False,
                            divergence="colin_difference",
                            gradient="colin_difference", laplacian="colin_difference",
                            neumann_gradient="colin_difference", boundary="colin",
                            bordered=False, solver="cgnr", preconditioner="jacobi", tol=1e-4,
                            max_iterations=20000),
}

#: per-method options of project() that differ from the :data:`METHODS` bundles:
#: Colin solves the plain (not bordered) stacked system by CG on the normal
#: equations, here to the least-squares solution with normal residual 1e-4
#: (tighter tolerances stall: docs/notes/hhd.md)
PROJECT_OVERRIDES = {"colin2006": {"bordered": False, "tol": 1e-4, "max_iterations": 20000},
                     # the projection keeps the fixed support and quadratic fits it was
                     # measured with (Colin Table 1 on lattices); on scattered points
                     # it takes the decomposition's (project.SCATTERED_OPTIONS)
                     "default": {"support_ratio": 2.5, "adaptive_support": False,
                                 "divergence": "quadratic", "gradient": "quadratic"}}


def options_for(method: str = "default", **overrides) -> HHDOptions:
    """The bundle ``method`` of :data:`METHODS` with single fields ``overrides``."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {tuple(METHODS)}")
    return replace(METHODS[method], **overrides)
