"""Linear-algebra layer: matrix-free Krylov solvers in Taichi (:mod:`.krylov`:
the methods and their one driver; :mod:`.stopping`: one right-hand side's
state, stopping tests and result; :mod:`.krylov_kernels`: their kernels), CSR
matrices (:mod:`.csr`), the Poisson rows of the decomposition and the flow
(:mod:`.poisson`), the multilevel preconditioner (:mod:`.multilevel`), and
kernels over several right-hand sides at once (:mod:`.columns`)."""
