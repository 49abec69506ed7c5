"""One right-hand side's solve in the Krylov solvers (:mod:`taichi_hh.linalg.krylov`):
its settings, its result, the monitor of its residual (divergence and
stagnation tests) and its state through the driver's rounds (running,
converged or failed; the restart it waits for), in the order the module doc
of :mod:`~taichi_hh.linalg.krylov` describes the stopping tests."""
import enum
import math
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from taichi_hh.errors import InputError

__all__ = ["SolveResult", "Settings", "checked_settings", "Monitor", "State", "Restart",
           "Column", "failure_message", "STAGNATION_WINDOW", "FAILURE_REASONS",
           "MAX_RESIDUAL_REPLACEMENTS", "MAX_BREAKDOWN_RESTARTS"]

MAX_RESIDUAL_REPLACEMENTS = 5
MAX_BREAKDOWN_RESTARTS = 10
# Jacobi-BiCGSTAB plateaus for hundreds of iterations on the SPH Neumann
# systems before converging; shorter windows called those plateaus
# stagnation (docs/notes/linalg.md).
STAGNATION_WINDOW = 400
_STAGNATION_RTOL = 1e-3
FAILURE_REASONS = ("breakdown", "stagnation", "divergence", "non-finite", "max_iterations")


@dataclass
class SolveResult:
    """Outcome of a solve.  ``reason`` is ``"converged"`` or a failure reason.
    ``x``: the solution as numpy (copied from ``x_ndarray``, the solver's own
    Taichi array, on first access: a caller that only needs the Taichi array pays
    no host copy; results of a joint solve of several columns hold ``x`` only)."""

    x_ndarray: object
    converged: bool
    reason: str
    iterations: int
    relative_residual: float          # ||b - A x|| / ||b||, recomputed from x
    history: np.ndarray               # monitored residual: initial, then one per iteration
    seconds: float
    applies: int                      # operator applies, A and A^T
    method: str
    message: str = ""
    normal_residual: Optional[float] = None   # CGNR: ||A^T (b - A x)|| / ||A^T b||
    n: int = 0                                # unknowns: x is x_ndarray[:n]
    detail: str = ""                          # the failure's cause, as in message
    _x: Optional[np.ndarray] = field(default=None, repr=False)

    @property
    def x(self) -> np.ndarray:
        if self._x is None:
            self._x = self.x_ndarray.to_numpy()[: self.n]
        return self._x

    @x.setter
    def x(self, value) -> None:
        self._x = value


@dataclass
class Settings:
    tol: float
    max_iterations: int
    stagnation_window: int
    divergence_factor: float
    callback: Optional[Callable]


@dataclass
class Monitor:
    """One column's iteration count, residual history and the divergence and
    stagnation tests."""

    settings: Settings
    iterations: int = 0
    history: list = field(default_factory=list)
    _scale: float = 1.0

    def start(self, value: float) -> None:
        self.history.append(value)
        self._scale = max(value, 1.0)

    def record(self, value: float) -> Optional[tuple[str, str]]:
        """Record one iteration's residual; returns (reason, detail) of a
        divergence or stagnation, or None."""
        self.iterations += 1
        self.history.append(value)
        if self.settings.callback is not None:
            self.settings.callback(self.iterations, value)
        s = self.settings
        if value > s.divergence_factor * self._scale:
            return ("divergence", f"residual grew above {s.divergence_factor:.0e} times "
                    f"its initial scale {self._scale:.3e}")
        # the window grows with the run (a third of it): slow solves (thousands of
        # iterations at large N) plateau for longer than fast ones
        w = max(s.stagnation_window, self.iterations // 3)
        if self.iterations >= 2 * w:
            # Window against window, not against the best ever: CG and BiCGSTAB
            # residuals are not monotone and may exceed the initial one for
            # tens of iterations before converging.
            recent = min(self.history[-w:])
            before = min(self.history[-2 * w:-w])
            if not recent < (1.0 - _STAGNATION_RTOL) * before:
                return ("stagnation", f"the last {w} iterations did not lower the residual "
                        f"below {recent:.3e}, the {w} before them reached {before:.3e}")
        return None


class State(enum.Enum):
    """Where one column's solve stands."""

    RUNNING = "running"
    CONVERGED = "converged"
    FAILED = "failed"


class Restart(enum.Enum):
    """Why a column's residual is recomputed from its iterate (``b - A x``)
    before the next step."""

    START = "start"            # the initial residual: it starts the monitor
    CLAIMED = "claimed"        # the updated residual met tol: the true one decides
    BREAKDOWN = "breakdown"    # a fresh start after a breakdown
    STOP = "stop"              # a failed column: its true residual is reported


@dataclass
class Column:
    """One right-hand side's progress through the driver's rounds (module doc of
    :mod:`taichi_hh.linalg.krylov`): its state, the restart it waits for, its
    counters and the outcome."""

    monitor: Monitor
    state: State = State.RUNNING
    restart: Optional[Restart] = Restart.START
    reason: str = "converged"
    detail: str = ""
    relres: float = math.nan
    replacements: int = 0
    breakdowns: int = 0

    def settle_by_rhs(self, bnorm: float) -> None:
        """Stop before iterating where ``||b||`` decides: NaN/inf in ``b``
        (non-finite) or ``b = 0`` (converged: x = 0, which the caller writes)."""
        if not math.isfinite(bnorm):
            self.monitor.start(math.nan)
            self.restart = None
            self.fail("non-finite", "b contains NaN or inf (found before iterating)", math.nan)
        elif bnorm == 0.0:
            self.converge(0.0, 0.0)

    def converge(self, relres: float, value: float) -> None:
        """Converged before iterating (its monitor starts at ``value``)."""
        self.monitor.start(value)
        self.restart, self.state, self.relres = None, State.CONVERGED, relres

    def fail(self, reason: str, detail: str, relres: Optional[float] = None) -> None:
        """Stop with a failure; without ``relres`` the next restart computes the
        true residual to report."""
        self.state, self.reason, self.detail = State.FAILED, reason, detail
        if relres is None:
            self.restart = Restart.STOP
        else:
            self.relres = relres

    def restarted(self, relres: float, value: float, failure: Optional[str]) -> None:
        """The outcome of a restart: ``relres`` the true relative residual,
        ``value`` the monitored one, ``failure`` a breakdown of the restart."""
        cause, self.restart = self.restart, None
        self.relres = relres
        if cause is Restart.STOP:
            return
        if cause is Restart.START:
            self.monitor.start(value)
        if not (math.isfinite(relres) and math.isfinite(value)):
            self.fail("non-finite", "the residual b - A x is not finite (NaN/inf in x0 or A)",
                      relres)
            return
        if value <= self.monitor.settings.tol:
            self.state = State.CONVERGED
            return
        if cause is Restart.CLAIMED:
            # the updated residual claimed convergence and the true one disagrees:
            # iterating goes on from the true one, a bounded number of times
            self.replacements += 1
            if self.replacements > MAX_RESIDUAL_REPLACEMENTS:
                self.fail("stagnation", f"the updated residual reached tol but the true one "
                          f"stays at {value:.3e}: tol is below the attainable accuracy", relres)
                return
        if failure:
            self.fail("breakdown", failure, relres)

    def stepped(self, relres: float, value: float, failure: Optional[str]) -> None:
        """The outcome of an iteration (arguments as :meth:`restarted`)."""
        verdict = self.monitor.record(value)
        self.relres = relres
        if not (math.isfinite(relres) and math.isfinite(value)):
            self.fail("non-finite", "NaN/inf appeared during the iteration", relres)
        elif value <= self.monitor.settings.tol:
            self.restart = Restart.CLAIMED
        elif failure:
            self.breakdowns += 1
            if self.breakdowns > MAX_BREAKDOWN_RESTARTS:
                self.fail("breakdown", f"{failure}; {self.breakdowns - 1} restarts did not "
                          "cure it")
            else:
                self.restart = Restart.BREAKDOWN
        elif verdict:
            self.fail(*verdict)


def failure_message(method: str, reason: str, iteration: int, relres: float, detail: str) -> str:
    return (f"{method} failed: {reason} at iteration {iteration} "
            f"(relative residual {relres:.3e}): {detail}")



def checked_settings(method, n, tol, max_iterations, stagnation_window, divergence_factor,
                     callback) -> Settings:
    """The settings of a solve, refused (InputError) where they make no sense."""
    if not (tol > 0.0 and math.isfinite(tol)):
        raise InputError(f"{method}: tol must be a positive finite number, got {tol!r}")
    if max_iterations is None:
        max_iterations = max(1000, n)
    if max_iterations < 0:
        raise InputError(f"{method}: max_iterations must be >= 0, got {max_iterations}")
    if stagnation_window < 1:
        raise InputError(f"{method}: stagnation_window must be >= 1, got {stagnation_window}")
    if not divergence_factor > 1.0:
        raise InputError(f"{method}: divergence_factor must be > 1, got {divergence_factor}")
    return Settings(float(tol), int(max_iterations), int(stagnation_window),
                    float(divergence_factor), callback)
