"""Flow layer: two-phase incompressible SPH by projection.

:mod:`.twophase` the time stepping (:class:`TwoPhaseFlow`), :mod:`.operators` the
operators of one step (one record, built in one place), :mod:`.params` its
settings, :mod:`.walls` the wall-particle conditions, :mod:`.shifting` particle
shifting, :mod:`.buffers` the per-step work arrays, :mod:`.clock` the stage timing.
"""
from .clock import STAGES, StageClock
from .params import WALL_CONDITIONS, FlowParams, WallVelocity
from .operators import StepOperators
from .twophase import STEP_EVENTS, BlowUpError, TwoPhaseFlow

__all__ = ["TwoPhaseFlow", "FlowParams", "BlowUpError", "StageClock", "STAGES",
           "WALL_CONDITIONS", "WallVelocity", "StepOperators", "STEP_EVENTS"]
