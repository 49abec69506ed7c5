"""Linear-algebra layer: matrix-free Krylov solvers and CSR matrices in Taichi
(:mod:`.krylov`), the Poisson rows of the decomposition and the flow
(:mod:`.poisson`), the multilevel preconditioner (:mod:`.multilevel`), and
kernels over several right-hand sides at once (:mod:`.columns`)."""
