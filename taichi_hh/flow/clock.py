"""Wall time of the flow's time steps, split into stages (:class:`StageClock`)."""
import time

import taichi as ti

from .. import runtime

#: The stages of a time step whose wall time :attr:`TwoPhaseFlow.timings` accumulates.
STAGES = ("neighbours", "operators", "solve", "other")


class StageClock:
    """Wall time of a time step split into stages, accumulated over steps.

    Lap timing: :meth:`lap` charges the time since the previous lap (or since
    :meth:`start`) to a stage, so the stages of a step add up to its wall time
    exactly; :meth:`stop` charges what is left to ``"other"``.  ``detail`` keys
    name finer parts of a stage (e.g. ``"bin"`` and ``"pairs"`` of
    ``"neighbours"``).  Outside a step (between :meth:`stop` and :meth:`start`)
    laps are ignored.  Taichi kernels run synchronously on the CPU; on a GPU
    every lap calls ``ti.sync()`` first so that a stage is charged with the
    kernels it launched.
    """

    def __init__(self):
        self.totals = dict.fromkeys(STAGES, 0.0)
        self.detail = {}
        self.steps = 0
        self.last_step = dict.fromkeys(STAGES, 0.0)
        self._t = None
        self._sync = runtime.state().arch not in ("", "cpu")

    def _now(self) -> float:
        if self._sync:
            ti.sync()
        return time.perf_counter()

    def start(self) -> None:
        self.last_step = dict.fromkeys(STAGES, 0.0)
        self._t = self._now()

    def lap(self, stage: str, detail: str | None = None) -> None:
        if self._t is None:
            return
        now = self._now()
        dt, self._t = now - self._t, now
        self.last_step[stage] += dt
        self.totals[stage] += dt
        key = f"{stage}.{detail or stage}"
        self.detail[key] = self.detail.get(key, 0.0) + dt

    def stop(self) -> dict:
        """End the step; returns its stage seconds (and ``"total"``)."""
        self.lap("other", "other")
        self._t = None
        self.steps += 1
        return {**self.last_step, "total": sum(self.last_step.values())}

    def abort(self) -> None:
        """A step that raised: charge its time so far to ``"other"`` and stop."""
        if self._t is not None:
            self.lap("other", "aborted")
            self._t = None

    def reset(self) -> None:
        self.totals = dict.fromkeys(STAGES, 0.0)
        self.detail = {}
        self.steps = 0
