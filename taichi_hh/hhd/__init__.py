"""Decomposition layer: the SPH Helmholtz-Hodge decomposition
(:mod:`.decompose`), the null-divergence projection (:mod:`.project`) and
critical points (:mod:`.critical`)."""
