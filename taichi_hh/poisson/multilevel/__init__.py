"""Multilevel (aggregation) preconditioner for the SPH Poisson rows.

Jacobi-preconditioned BiCGSTAB needs iterations growing like sqrt(N) on the
SPH Poisson systems; this preconditioner makes them grow slowly, from the
structure we already have: the neighbour grid.

Hierarchy
---------
Level 0 is the particle system, Jacobi-scaled: ``B = D^-1 A`` with ``D`` the
diagonal of ``A``.  Every row of ``B`` then reads ``x_i - sum_j w_ij x_j`` with
weights summing to one (Laplacian, Neumann and Shepard rows all vanish on
constants), whatever the row's kind and scale, so that summing rows of
different kinds into one aggregate keeps a consistent sign and scale.

Level 1 aggregates the particles by the cells of a grid: piecewise-constant
prolongation ``P`` (particle ``i`` takes its cell's value), restriction
``P^T`` (a cell sums its particles) and the Galerkin operator ``B_1 = P^T B P``.
Each further level aggregates 2 x 2 cells of the one below, down to the first
grid of at most ``COARSEST`` cells, solved by a dense pseudo-inverse (the
coarse operators of a pure Neumann problem are singular: constants are their
null space).  Empty cells are left out.  Every cell level is stored as one
sparse (CSR) matrix, so a pair may span any number of cells.

The cells' side (``cells``): by default the largest kernel support (the
flow's fixed support: each cell couples to its 3 x 3 block); with adaptive
support the largest is 1.5-4 times the median, and cells that large hold
30-120 particles, too coarse an aggregation for Jacobi smoothing to bridge
(the decomposition takes cells of a quarter of the median support: 1-1.5
particles each on level 1, which then acts as a second, Galerkin smoothing
level; docs/notes/scattered.md).

Cycle
-----
A W-cycle (or, as an option, a V-cycle) with damped Jacobi smoothing
(``omega``; one sweep from zero before the coarse correction, ``post`` sweeps
after it) on every level and the coarse correction scaled by ``correction``
(plain aggregation under-corrects: interpolation by constants has too much
energy; an over-correction of about 1.5-2 is the classic remedy, Blaheta
1986, Vanek et al. 1996).  Each level's error compounds in a V-cycle of
plain aggregation, so its iterations grow with the number of levels (Notay
2010 accelerates the coarse levels for this reason); the W-cycle solves each
cell level's coarse problem with two cycles, which keeps the iteration
count nearly flat in N at the cost of the coarser levels only.  The cycle is a fixed linear operator, so it can
precondition BiCGSTAB (right preconditioning: ``A M^-1 y = b``,
``x = M^-1 y``).

The whole cycle is one kernel launch (at 10k particles launches, not
arithmetic, dominate).  On level 0 the pre-smoothing from zero, the residual
and the restriction are one gather loop over cells (a cell's particles are
listed contiguously); the prolongation and the first post-smoothing sweep
are another.  So a cycle costs ``1 + post`` passes over the pairs plus the
cell levels (a few percent of that with the largest support's cells, about
as much again with a quarter of the median support's).  The first cell level
and, from ``SERIAL_MAX_N`` particles on, the next ones with at least
``PARALLEL_MIN_NNZ`` entries run as parallel loops in a static schedule; the
rest in one serial loop driven as a state machine (kernels cannot recurse).  The
Galerkin operators are formed once per matrix, in kernels; on the host each
level is a :class:`Level` (its :class:`CellMatrix` and aggregation map; scipy
is not a run-time dependency).

Bordered systems (:class:`~taichi_hh.poisson.matrix.PoissonMatrix` with
``bordered=True``): the border unknown is treated by Jacobi alone.

The modules: :mod:`.preconditioner` (options, the one set-up, ``apply``),
:mod:`.levels` (the two aggregations, each giving the same record of
Galerkin operators), :mod:`.galerkin` (the set-up's kernels), :mod:`.cycle`
(the cycle kernel and its records of named arrays).
"""
from .cycle import MAX_SCHEDULE_OPS, PARALLEL_MIN_NNZ, CellLevels, CycleShape, FineLevel, Work
from .galerkin import GALERKIN_CHUNK_ROWS, GALERKIN_MAX_CHUNKS
from .levels import COARSEST, CellMatrix, grid_level_dims
from .preconditioner import SERIAL_MAX_N, Level, MultilevelPreconditioner

__all__ = ["MultilevelPreconditioner", "Level", "CellMatrix", "FineLevel", "CellLevels", "Work",
           "CycleShape", "grid_level_dims", "COARSEST", "SERIAL_MAX_N", "MAX_SCHEDULE_OPS",
           "PARALLEL_MIN_NNZ", "GALERKIN_CHUNK_ROWS", "GALERKIN_MAX_CHUNKS"]
