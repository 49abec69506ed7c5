"""The SPH Poisson layer, above the operators and the generic solvers: the
assembled Poisson rows of the decomposition and the flow (:mod:`.matrix`:
:class:`~taichi_hh.poisson.matrix.PoissonMatrix`, its ``pair_rows()``) and the
multilevel preconditioner built on them (:mod:`.multilevel`).  It reads SPH
stencils and the neighbour grid (:mod:`taichi_hh.sph`) and solves with
:mod:`taichi_hh.linalg`, which knows nothing of particles."""
