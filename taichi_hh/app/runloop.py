"""Scene-agnostic glue of the simulation scripts: the time loop and its clean
stops, a progress bar, checkpoints, the diagnostics CSV and the common options.

A scene builds its state, then::

    result = run(step_fn, t0=t, t_end=args.end_time, output_interval=dt_out,
                 on_output=write_frame_and_row, checkpoint_fn=save_state)

Stops, and what stays on disk:

* Ctrl-C: the step under way finishes (the state is never saved half-updated),
  a checkpoint of that state is saved, a message says how to continue
  (``--resume``) and the process exits with status 130.  A second Ctrl-C
  stops at once and keeps the previous checkpoint (also status 130); so does a
  ``KeyboardInterrupt`` raised from inside ``step_fn`` or ``on_output``.
* :class:`BlowUp` (or :class:`~taichi_hh.errors.SolverError`, or a type in
  ``blowup_types``) raised by ``step_fn``: nothing more is saved, the last good
  checkpoint stays, a message names the cause, exit status 2.

Every file is replaced atomically (temporary name + ``os.replace``), and the
diagnostics CSV gains whole lines only, so an interrupted run never leaves a
half-written file.  When ``on_output`` and ``checkpoint_fn`` only hand their
files over to a writer beside the loop (the scenes' output worker), ``flush_fn``
waits for it: before every stop message (the checkpoint it names is then on
disk) and at the end.  Nothing here imports Taichi.
"""

import argparse
import csv
import inspect
import io
import math
import os
import signal
import sys
import threading
import time

import numpy as np

from ..checks import positive_float, positive_int
from ..errors import BlowUp, SolverError
from ..runtime import ARCHES, default_arch
from .io import atomic_path, npz_problem


def check_finite(**arrays) -> None:
    """Raise :class:`BlowUp` (cause ``"non-finite"``) naming the first array with NaN/inf."""
    for name, a in arrays.items():
        a = np.asarray(a)
        bad = ~np.isfinite(a)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            raise BlowUp(f"non-finite values in {name}: {rows.size} entries (first at index {rows[0]})",
                         cause="non-finite")


def check_inside(positions, box_lo, box_hi, *, margin: float = 0.0, what: str = "particles") -> None:
    """Raise :class:`BlowUp` (cause ``"left-box"``) if a position lies outside
    ``[box_lo - margin, box_hi + margin]``."""
    p = np.asarray(positions, dtype=np.float64)
    lo = np.asarray(box_lo, dtype=np.float64) - margin
    hi = np.asarray(box_hi, dtype=np.float64) + margin
    out = ~np.all((p >= lo) & (p <= hi), axis=1)
    if out.any():
        i = int(np.nonzero(out)[0][0])
        raise BlowUp(f"{int(out.sum())} {what} left the box [{lo[0]:.4g}, {hi[0]:.4g}] x "
                     f"[{lo[1]:.4g}, {hi[1]:.4g}] (first: index {i} at {tuple(np.round(p[i], 6))})",
                     cause="left-box")


# ---- progress bar --------------------------------------------------------------------

def _clock(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "--:--"
    s = int(round(seconds))
    h, m = divmod(s // 60, 60)
    return f"{h}:{m:02d}:{s % 60:02d}" if h else f"{m}:{s % 60:02d}"


class ProgressBar:
    """One-line progress: simulated time / end time, steps, steps/s, ETA.

    On a terminal the line is redrawn in place at most every ``min_interval``
    seconds (default 0.2: 5 times a second); otherwise (a log file, a pipe) a
    full line is printed each time another 10% of the simulated time is done,
    and at least every ``log_interval`` wall seconds (default 30) while a slow
    stretch is under way, so a piped run never looks hung.
    The ETA is the steps left at the recent time step times the recent wall
    time per step (both over the last third of the elapsed wall time): the
    time step of a flow that speeds up shrinks, so the run's average rate
    would promise too early an end.
    """

    def __init__(self, total_time: float, stream=None, *, t_start: float = 0.0,
                 step_start: int = 0, min_interval: float = 0.2, width: int = 20,
                 log_interval: float = 30.0):
        self.stream = sys.stderr if stream is None else stream
        self.total = float(total_time)
        self.t_start, self.step_start = float(t_start), int(step_start)
        self.min_interval, self.width, self.log_interval = min_interval, width, log_interval
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty and isatty())
        self._wall0 = time.monotonic()
        self._last_draw = -math.inf
        self._last_log = self._wall0
        self._decile = int(self._fraction(self.t_start) * 10)
        self._shown = 0          # length of the line on screen (tty)
        self.t, self.step = self.t_start, self.step_start
        self._samples = [(self._wall0, self.t_start, self.step_start)]   # (wall, t, step)

    def _fraction(self, t: float) -> float:
        return min(max(t / self.total, 0.0), 1.0) if self.total > 0 else 1.0

    def line(self) -> str:
        elapsed = time.monotonic() - self._wall0
        frac = self._fraction(self.t)
        eta = self._eta()
        rate = (self.step - self.step_start) / elapsed if elapsed > 0 else 0.0
        fill = int(round(frac * self.width))
        return (f"t = {self.t:.4g} / {self.total:.4g}  [{'#' * fill}{'-' * (self.width - fill)}] "
                f"{100 * frac:3.0f}%  step {self.step}  {rate:.1f} steps/s  "
                f"elapsed {_clock(elapsed)}  ETA {_clock(max(eta, 0.0))}")

    def _eta(self) -> float:
        now, t, step = self._samples[-1]
        cut = now - (now - self._wall0) / 3.0
        last = len(self._samples) - 1
        k = min(next(i for i, s in enumerate(self._samples) if s[0] >= cut or i == last), last - 1)
        if k < 0:
            return math.inf
        wall0, t0, step0 = self._samples[k]
        steps, sim = step - step0, t - t0
        if steps <= 0 or sim <= 0:
            return math.inf
        wall_per_step = (now - wall0) / steps
        dt = sim / steps
        return (self.total - t) / dt * wall_per_step

    def update(self, t: float, step: int, *, force: bool = False) -> None:
        self.t, self.step = float(t), int(step)
        self._samples.append((time.monotonic(), self.t, self.step))
        if len(self._samples) > 4096:          # keep the memory bounded: thin the old half
            self._samples = self._samples[:2048:2] + self._samples[2048:]
        if self.tty:
            now = time.monotonic()
            if force or now - self._last_draw >= self.min_interval:
                self._last_draw = now
                text = self.line()
                pad = max(self._shown - len(text), 0)
                self.stream.write("\r" + text + " " * pad)
                self.stream.flush()
                self._shown = len(text)
        else:
            decile = int(self._fraction(self.t) * 10 + 1e-9)
            now = time.monotonic()
            if force or decile > self._decile or now - self._last_log >= self.log_interval:
                self._decile = max(decile, self._decile)
                self._last_log = now
                self.stream.write(self.line() + "\n")
                self.stream.flush()

    def clear(self) -> None:
        """End the in-place line (tty) so that a message can follow on its own line."""
        if self.tty and self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = 0

    def close(self) -> None:
        """Show the final state and end the line."""
        if self.tty:
            self.update(self.t, self.step, force=True)
        elif self._decile < 10:
            self.update(self.t, self.step, force=True)
        self.clear()


# ---- checkpoints -----------------------------------------------------------------------

class Checkpoint:
    """Checkpoints as ``.npz`` files (no pickles), written atomically.

    ``state``: a dict of numpy arrays and scalars (int, float, bool, str).
    Scalars come back from :meth:`load` as Python scalars; 0-d arrays too.
    """

    FORMAT_VERSION = 1
    #: the entry of the .npz that holds FORMAT_VERSION
    VERSION_KEY = "__taichi_hh_checkpoint_version__"

    @classmethod
    def save(cls, path: str, state: dict) -> str:
        arrays = {cls.VERSION_KEY: np.asarray(cls.FORMAT_VERSION)}
        for key, value in state.items():
            if not isinstance(key, str) or not key.isidentifier() or key.startswith("__"):
                raise ValueError(f"checkpoint keys must be identifiers not starting with '__', got {key!r}")
            a = np.asarray(value)
            if a.dtype == object:
                raise ValueError(f"checkpoint entry {key!r} is not a numeric/str array or scalar "
                                 f"(got {type(value).__name__})")
            arrays[key] = a
        with atomic_path(path, suffix=".npz") as tmp:
            with open(tmp, "wb") as fh:              # a file object: np.savez adds no suffix
                np.savez(fh, **arrays)
                fh.flush()
                os.fsync(fh.fileno())
        return path

    @classmethod
    def load(cls, path: str) -> dict:
        if not os.path.exists(path):
            raise FileNotFoundError(f"no checkpoint at {path}: nothing to resume (run without --resume)")
        problem = npz_problem(path)
        if problem:
            raise ValueError(f"{path} is not a readable checkpoint ({problem}); "
                             "start afresh without --resume")
        with np.load(path, allow_pickle=False) as data:
            if cls.VERSION_KEY not in data.files:
                raise ValueError(f"{path} is not a taichi_hh checkpoint (no format version)")
            version = int(data[cls.VERSION_KEY])
            if version != cls.FORMAT_VERSION:
                raise ValueError(f"{path} has checkpoint format {version}; this version of "
                                 f"taichi_hh reads format {cls.FORMAT_VERSION}")
            return {k: (data[k].item() if data[k].ndim == 0 else data[k])
                    for k in data.files if k != cls.VERSION_KEY}


# ---- diagnostics CSV -------------------------------------------------------------------

def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))          # shortest string that reads back exactly
    return str(value)


def _csv_line(cells) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


class DiagnosticsWriter:
    """A CSV with a header and one row per :meth:`write`, flushed at once.

    Each row goes out as one whole line in one write, then flushed.  A fresh
    writer (``resume_time=None``) replaces the file with just the header.
    With ``resume_time`` the existing file is kept up to that time: a trailing
    partial line (a crash mid-write) and every row whose ``time_column`` is
    later than ``resume_time`` are dropped (the file is rewritten atomically),
    then rows are appended, so the CSV matches the checkpoint resumed from.
    Floats are written in full precision (``repr``); missing values as ``""``.
    """

    def __init__(self, path: str, columns, *, resume_time=None, time_column: str = "time"):
        self.path = path
        self.columns = list(columns)
        if len(set(self.columns)) != len(self.columns) or not self.columns:
            raise ValueError(f"columns must be distinct and non-empty, got {self.columns}")
        if time_column not in self.columns:
            raise ValueError(f"the time column {time_column!r} is not among the columns")
        header = _csv_line(self.columns)
        lines = [header]
        self.rows_kept = 0
        if resume_time is not None and os.path.exists(path):
            lines = self._kept_lines(header, time_column, float(resume_time))
            self.rows_kept = len(lines) - 1
        with atomic_path(path, suffix=".csv") as tmp, open(tmp, "w", newline="") as fh:
            fh.writelines(lines)
        self._fh = open(path, "a", newline="")

    def _kept_lines(self, header: str, time_column: str, t_resume: float) -> list:
        with open(self.path, newline="") as fh:
            text = fh.read()
        lines = text.splitlines(keepends=True)
        if lines and not lines[-1].endswith("\n"):
            lines.pop()                                  # a partial last line
        if not lines:
            return [header]
        found = next(csv.reader([lines[0]]))
        if found != self.columns:
            raise ValueError(f"{self.path} has columns {found}, expected {self.columns}: "
                             "cannot resume into it (move it away or start afresh)")
        col = self.columns.index(time_column)
        tol = 1e-9 * max(1.0, abs(t_resume))
        kept = [header]
        for line in lines[1:]:
            cells = next(csv.reader([line]), [])
            try:
                t = float(cells[col])
            except (IndexError, ValueError):
                break
            if len(cells) != len(self.columns) or not t <= t_resume + tol:
                break
            kept.append(line)
        return kept

    def write(self, row=None, **values) -> None:
        """Append one row: a dict and/or keywords, column -> value (missing: empty)."""
        values = {**(row or {}), **values}
        unknown = [k for k in values if k not in self.columns]
        if unknown:
            raise ValueError(f"unknown diagnostics columns {unknown}; the columns are {self.columns}")
        self._fh.write(_csv_line([_cell(values.get(c)) for c in self.columns]))
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ---- the loop ------------------------------------------------------------------------------

class _DeferredInterrupt:
    """While active (main thread only), the first SIGINT only sets ``requested``;
    a second one raises KeyboardInterrupt as usual."""

    def __init__(self, say):
        self.say, self.requested, self._old = say, False, None

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        try:
            self.say("Ctrl-C: stopping after this step and saving the state "
                     "(Ctrl-C again: stop now, keep the last checkpoint)")
        except Exception:          # e.g. a re-entrant write to the stream: the message can go
            pass

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


def _takes_argument(fn) -> bool:
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)


def run(step_fn, *, t0: float, t_end: float, output_interval: float, on_output, checkpoint_fn,
        flush_fn=None, progress: bool = True, step0: int = 0, output_at_start: bool = True,
        blowup_types: tuple = (), stream=None,
        blowup_advice: str = "--resume restarts from it (e.g. with a smaller time step)"):
    """Advance ``step_fn`` from ``t0`` to ``t_end``, with outputs and checkpoints.

    step_fn() -> (t, dt, info): one time step; returns the new time, the step
    taken and a dict of step diagnostics.  If it has a positional parameter
    (``def step(t_stop)`` or ``def step(t_stop=None)``, not ``*args``) it gets
    ``t_stop``, the next output time (or ``t_end``): it should not step past it
    (clip dt), so that outputs land on the output times exactly.
    Output times are ``t0`` (if ``output_at_start``), every multiple of
    ``output_interval`` after it, and ``t_end``; an output happens at the first
    step reaching one: ``on_output(t, step, info)`` (``info == {}`` at ``t0``),
    then ``checkpoint_fn()``, which saves the state and returns its path.
    flush_fn(): if given, waits until everything ``on_output`` and
    ``checkpoint_fn`` handed over is written (they may write in the
    background); called before any stop message and at the end.
    Resuming: pass the checkpoint's time and step as ``t0``/``step0`` and
    ``output_at_start=False`` (its output was written before it was saved).

    blowup_advice: what the blow-up message suggests after naming the kept
    checkpoint: a string, or ``callable(t, step, cause) -> str``.

    Returns ``(t, step)`` at the end.  Stops (see the module docstring):
    Ctrl-C -> ``SystemExit(130)``; a blow-up -> ``SystemExit(2)``.
    """
    stream = sys.stderr if stream is None else stream
    t_end, interval = float(t_end), float(output_interval)
    if not interval > 0:
        raise ValueError(f"output_interval must be positive, got {output_interval}")
    eps = 1e-9 * interval
    t, step = float(t0), int(step0)
    bar = ProgressBar(t_end, stream, t_start=t, step_start=step) if progress else None
    saved = [None, None]                    # time and path of the last checkpoint written
    pass_target = _takes_argument(step_fn)

    def say(text):
        if bar:
            bar.clear()
        print(text, file=stream, flush=True)

    def output(info):
        on_output(t, step, info)
        saved[:] = [t, checkpoint_fn()]

    def next_output(t):
        return min((math.floor(t / interval + 1e-9) + 1) * interval, t_end)

    def flush():
        if flush_fn is not None:
            flush_fn()

    def kept():
        if saved[1] is None:
            return "no checkpoint was written by this run (a checkpoint resumed from is unchanged)"
        return f"the last saved state (t={saved[0]:.6g}) is in {saved[1]}"

    with _DeferredInterrupt(say) as sigint:
        try:
            if output_at_start:
                output({})
            target = next_output(t)
            while t < t_end - eps:
                t_new, dt, info = step_fn(target) if pass_target else step_fn()
                if not (math.isfinite(t_new) and t_new > t):
                    raise BlowUp(f"time did not advance (t={t:.6g} -> {t_new!r}, dt={dt!r})",
                                 cause="time-step")
                t, step = float(t_new), step + 1
                if bar:
                    bar.update(t, step)
                if t >= target - eps:
                    output(info)
                    target = next_output(t)
                if sigint.requested:
                    if saved[0] != t:
                        saved[:] = [t, checkpoint_fn()]
                    flush()
                    say(f"interrupted at t={t:.6g} (step {step}), state saved to {saved[1]}; "
                        "continue with --resume")
                    raise SystemExit(130)
            flush()
        except KeyboardInterrupt:
            flush()
            say(f"interrupted at t={t:.6g} (step {step}) in the middle of a step; {kept()}; "
                "continue with --resume")
            raise SystemExit(130) from None
        except (BlowUp, SolverError, *blowup_types) as exc:
            cause = getattr(exc, "cause", "solver" if isinstance(exc, SolverError) else "")
            flush()
            say(f"stopped: the simulation blew up in the step after t={t:.6g} (step {step})"
                f"{' [' + cause + ']' if cause else ''}: {exc}\n{kept()}; "
                f"{blowup_advice(t, step, cause) if callable(blowup_advice) else blowup_advice}")
            raise SystemExit(2) from None
    if bar:
        bar.close()
    return t, step


# ---- command line ------------------------------------------------------------------------

DEFAULTS = {
    "particles": 10000, "end_time": 1.0, "out": "outputs/scene", "arch": None,
    "movie": "none", "fps": 20.0, "frame_width": 800, "color": "phase", "precision": "f64",
}


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` with each option's default appended once: not where the help
    text already names it, and not for flags (whose default is off) or options
    without a default."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS) \
                or isinstance(action, argparse.BooleanOptionalAction):
            return text
        return super()._get_help_string(action)


def add_common_arguments(parser: argparse.ArgumentParser, defaults: dict | None = None):
    """Add the options every scene shares (the command line of README.md); ``defaults``
    overrides entries of :data:`DEFAULTS`.  Returns the parser."""
    d = dict(DEFAULTS)
    for key, value in (defaults or {}).items():
        if key not in d:
            raise ValueError(f"unknown default {key!r}; known: {sorted(d)}")
        d[key] = value
    dflt = " (default: %(default)s)"
    parser.add_argument("--particles", type=positive_int, default=d["particles"], metavar="N",
                        help="number of fluid particles" + dflt)
    parser.add_argument("--end-time", type=positive_float, default=d["end_time"], metavar="T",
                        help="simulated time to reach" + dflt)
    parser.add_argument("--out", default=d["out"], metavar="DIR",
                        help="output directory: frames, diagnostics.csv, checkpoint, movie; "
                             "a fresh run first removes the files an earlier run wrote there "
                             "(frames, particles, diagnostics, checkpoint, movie), other files "
                             "stay" + dflt)
    parser.add_argument("--arch", choices=ARCHES, default=d["arch"] or default_arch(),
                        help="Taichi arch: cpu, cuda, vulkan, gpu (any GPU backend; an error "
                             "where none starts) or auto (a GPU when present) (default: "
                             "$TAICHI_HH_ARCH, else cpu)")
    parser.add_argument("--resume", action="store_true",
                        help="continue from the checkpoint in --out instead of starting afresh;"
                             " the run keeps the checkpoint's options (a different value is "
                             "refused) except --end-time, --cfl, --dt-max, --solver-tol and how "
                             "it is shown (--quiet, --movie, --fps, --montage, --arch)"
                             " (default: start afresh)")
    parser.add_argument("--movie", choices=("none", "gif", "mp4"), default=d["movie"],
                        help="also write a movie of the frames (mp4 needs the mp4 extra, "
                             "else a GIF is written)" + dflt)
    parser.add_argument("--fps", type=positive_float, default=d["fps"],
                        help="movie frames per second" + dflt)
    parser.add_argument("--frame-width", type=positive_int, default=d["frame_width"], metavar="PX",
                        help="frame width in pixels; the height keeps the box's aspect ratio" + dflt)
    parser.add_argument("--color", "--color-by", choices=("phase", "speed", "vorticity"),
                        default=d["color"],
                        help="colour particles by phase, speed or vorticity (a diverging "
                             "colour bar with symmetric limits)" + dflt)
    parser.add_argument("--precision", choices=("f32", "f64"), default=d["precision"],
                        help="floating-point precision of the Taichi kernels" + dflt)
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bar (messages about stops still appear)"
                             " (default: show progress)")
    return parser
