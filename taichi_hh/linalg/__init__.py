"""Linear-algebra layer, generic (it knows nothing of particles): matrix-free
Krylov solvers in Taichi (:mod:`.krylov`: the methods and their one driver;
:mod:`.stopping`: one right-hand side's state, stopping tests and result;
:mod:`.krylov_kernels`: their kernels), CSR matrices (:mod:`.csr`), and kernels
over several right-hand sides at once (:mod:`.columns`).  The SPH Poisson rows
and the multilevel preconditioner are the layer above: :mod:`taichi_hh.poisson`."""
