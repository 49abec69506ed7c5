"""Flow layer: two-phase incompressible SPH by projection (:mod:`.twophase`)."""
