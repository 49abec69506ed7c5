"""SPH layer: particle storage, kernels, the neighbour grid, operator
coefficients and :class:`PointSet` (the operators on numpy arrays)."""
