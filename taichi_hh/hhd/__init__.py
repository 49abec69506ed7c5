"""Decomposition layer: the SPH Helmholtz-Hodge decomposition
(:mod:`.decompose`, its options and bundles in :mod:`.options`, the natural
boundary condition's free-space potentials in :mod:`.natural`), the
null-divergence projection (:mod:`.project`) and critical points
(:mod:`.critical`); input checks (:mod:`.inputs`), boundary particles
(:mod:`.boundary`) and the rotation J (:mod:`.rotation`) shared by them."""
