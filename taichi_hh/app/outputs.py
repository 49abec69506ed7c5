"""The scenes' per-output files, written beside the time loop.

At every output time a scene writes a frame (drawn, labelled, PNG), the
particles (``.npz``, ``.vtu`` and the ``.pvd`` series' entry) and a checkpoint.
The time loop only takes the host copies these need and hands them over
(:meth:`Outputs.frame`, :meth:`Outputs.checkpoint`); an :class:`OutputWriter`
writes them, either in a worker process (``workers=1``, the scenes' default:
the second core draws and compresses while the first steps; Taichi's own
parallel loops gain little there) or in the calling process (``workers=0``:
the same code, hence the same bytes).

The worker process:

* is started by the ``spawn`` method (a fork after Taichi started its threads
  is unsafe) and imports no Taichi: this module and what it imports (render,
  overlay, particle_files, runloop's :class:`Checkpoint`) are numpy only, and
  the parent's ``__main__`` (a scene script, which imports Taichi) is kept
  out of it;
* ignores SIGINT: Ctrl-C goes to the time loop, which stops cleanly and then
  waits until every job handed over is written (:meth:`Outputs.drain`);
* writes the jobs in the order they were handed over, every file atomically
  (temporary name + rename), a checkpoint only after the frame before it: the
  checkpoint on disk never runs ahead of the frames and particle files, so a
  resume finds every output up to its time, even after the run was killed;
* after a failed job writes nothing more (no checkpoint past a missing frame)
  and reports the error, which the main process raises as one line
  (:class:`OutputError`) at the next hand-off or at the drain.

Bounded: at most :data:`MAX_PENDING` frames are handed over and not yet
written; the next hand-off waits for the worker (``Outputs.waited`` seconds).
"""
from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import pickle
import queue
import signal
import sys
import threading
import time
import types
from contextlib import contextmanager
from dataclasses import dataclass

from ..errors import TaichiHHError
from .errors_report import one_line
from .overlay import FrameLabels, label_frame
from .particle_files import PvdSeries, write_particles
from .render import FrameRenderer, frame_path, write_png
from .runloop import Checkpoint

#: frames handed over and not yet written, at most (each holds the particles' host copies)
MAX_PENDING = 2


class OutputError(TaichiHHError):
    """Writing an output failed (in the worker process), or the worker stopped."""


@dataclass(frozen=True)
class OutputSpec:
    """What every output of a run looks like: the output folder, the frame (the
    box drawn ``width`` pixels wide inside a grey wall frame of ``wall_px``,
    ``style``, ``colormap``, the legend's ``phase_names``), whether the
    particles go to VTU + PVD too (``vtk``), and the time up to which a resumed
    run keeps the PVD series' entries (``resume_time``; None: a fresh series)."""
    out: str
    width: int
    box_lo: tuple
    box_hi: tuple
    style: str = "smooth"
    colormap: str = "viridis"
    wall_px: int = 4
    phase_names: tuple = ()
    vtk: bool = True
    resume_time: float | None = None


class OutputWriter:
    """Writes the jobs of :class:`Outputs`, in either process: ``"frame"``
    (the frame PNG and the particle files) and ``"checkpoint"``."""

    def __init__(self, spec: OutputSpec):
        self.spec = spec
        self.renderer = FrameRenderer(spec.width, None, spec.box_lo, spec.box_hi,
                                      style=spec.style, colormap=spec.colormap)
        self.legend = [(name, self.renderer.colour_of_phase(k))
                       for k, name in enumerate(spec.phase_names)]
        self.series = PvdSeries(os.path.join(spec.out, "particles.pvd"),
                                resume_time=spec.resume_time) if spec.vtk else None

    def write(self, job: dict) -> None:
        if job["kind"] == "checkpoint":
            Checkpoint.save(job["path"], job["state"])
            return
        position, data, t = job["position"], job["data"], job["time"]
        scalar, vmin, vmax, name = job["colouring"]
        if scalar is not None:
            labels = FrameLabels(colorbar=(name, vmin, vmax, self.renderer.table_np[:256]),
                                 wall_px=self.spec.wall_px)
            image = self.renderer.draw(position, phase=data["phase"], scalar=scalar,
                                       vmin=vmin, vmax=vmax)
        else:
            labels = FrameLabels(legend=self.legend, wall_px=self.spec.wall_px)
            image = self.renderer.draw(position, phase=data["phase"])
        write_png(frame_path(self.spec.out, job["index"]), label_frame(image, t, labels))
        write_particles(os.path.join(self.spec.out, "particles"), job["index"], t, position,
                        data, vtu=self.spec.vtk, series=self.series)


def _describe(job: dict) -> str:
    if job["kind"] == "job":
        return "an output"
    if job["kind"] == "checkpoint":
        return f"the checkpoint {job['path']}"
    return f"the frame and particles at t={job['time']:.6g}"


def _failure(what: str, exc: BaseException) -> str:
    return f"writing {what} failed: {type(exc).__name__}: {one_line(exc)}"


def _worker_main(spec: OutputSpec, jobs, results) -> None:
    """The worker process: write the jobs as they come until the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})     # blocked by the parent
    _yield_to_the_loop()
    try:
        _write_jobs(spec, jobs, results)
        results.send(("bye", "taichi" in sys.modules))
    except (BrokenPipeError, EOFError):      # the main process is gone: nobody to tell
        pass


def _yield_to_the_loop() -> None:
    """Run the worker only on a core the time loop leaves idle: SCHED_IDLE (else
    the lowest nice level).  At normal priority the loop's physics ran 25-70%
    slower in 3 of 4 runs, presumably as a Taichi pool thread woke on the core
    the worker held and every parallel kernel waited for it (docs/notes/app.md)."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        try:
            os.nice(19)
        except OSError:
            pass


def _write_jobs(spec: OutputSpec, jobs, results) -> None:
    try:
        writer = OutputWriter(spec)
    except Exception as exc:
        writer = None
        results.send(("error", _failure("the first output", exc)))
    while True:
        cpu0 = time.process_time()
        try:
            raw = jobs.recv_bytes()
        except EOFError:
            return
        if writer is None:                 # after a failure: nothing more (see the module doc)
            continue
        wall0 = time.perf_counter()
        job = {"kind": "job"}
        try:
            job = pickle.loads(raw)
            writer.write(job)
        except Exception as exc:
            writer = None
            results.send(("error", _failure(_describe(job), exc)))
            continue
        results.send(("done", job["kind"], time.perf_counter() - wall0,
                      time.process_time() - cpu0))


@contextmanager
def _child_safe_start():
    """Around ``Process.start()``: SIGINT blocked, so that a Ctrl-C while the
    child starts up cannot kill it before it ignores SIGINT (the mask is
    inherited; the Ctrl-C reaches the parent once unblocked); and the parent's
    ``__main__`` hidden, which spawn's child would otherwise import again (a
    scene script: Taichi with it)."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    in_main = threading.current_thread() is threading.main_thread()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if in_main else None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        sys.modules["__main__"] = main


class Outputs:
    """Hands a run's outputs to an :class:`OutputWriter`: in a worker process
    (``workers=1``) or in this one (``workers=0``); see the module doc.

    Seconds kept: ``waited`` (this process waiting for the worker: a full
    queue or a drain), ``worker_seconds`` and ``worker_cpu`` (the worker's
    wall and CPU seconds on the jobs, receiving included)."""

    def __init__(self, spec: OutputSpec, workers: int = 1):
        if workers not in (0, 1):
            raise ValueError(f"output workers must be 0 or 1, got {workers}")
        self.workers = workers
        self.waited = self.worker_seconds = self.worker_cpu = 0.0
        self.worker_imported_taichi = None      # reported by the worker when it stops
        self._frames_pending = self._jobs_pending = 0
        self._error = None                      # the worker's failure, not yet raised
        self._raised = self._closed = False
        self._writer = self._proc = None
        if workers == 0:
            self._writer = OutputWriter(spec)
            return
        ctx = multiprocessing.get_context("spawn")
        jobs_r, self._jobs = ctx.Pipe(duplex=False)
        self._results, results_w = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_worker_main, args=(spec, jobs_r, results_w),
                                 name="taichi-hh-outputs", daemon=True)
        with _child_safe_start():
            self._proc.start()
        jobs_r.close()                 # the worker's ends: its exit then shows as EOF here
        results_w.close()
        # the sender thread writes the pickled jobs into the pipe, so that a hand-off
        # never waits for the worker to read (os.write releases the GIL)
        self._queue = queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send_loop, name="taichi-hh-outputs-sender",
                                        daemon=True)
        self._sender.start()

    @property
    def worker_pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    @property
    def worker_exitcode(self) -> int | None:
        """The worker's exit status once it stopped (0: a clean stop), else None."""
        return self._proc.exitcode if self._proc is not None else None

    @property
    def pending(self) -> int:
        """Frames handed over and not yet reported written (at most :data:`MAX_PENDING`)."""
        return self._frames_pending

    # ---- hand-offs --------------------------------------------------------------------

    def frame(self, index: int, time: float, position, data: dict, colouring=None) -> None:
        """Hand over output ``index`` at ``time``: the frame (drawn from
        ``position`` and ``data["phase"]``, coloured by ``colouring = (scalar,
        vmin, vmax, name)`` or by phase) and the particle files (``position``
        and the per-particle arrays of ``data``).  With a worker the arrays are
        copied (pickled) here, without one written at once: the caller may
        change them afterwards."""
        self._submit({"kind": "frame", "index": int(index), "time": float(time),
                      "position": position, "data": data,
                      "colouring": colouring if colouring is not None else (None, 0.0, 1.0, "")},
                     frame=True)

    def checkpoint(self, path: str, state: dict) -> str:
        """Hand over a checkpoint of ``state`` to ``path`` (written after every
        frame handed over before it); returns ``path``."""
        self._submit({"kind": "checkpoint", "path": path, "state": state}, frame=False)
        return path

    def _submit(self, job: dict, frame: bool) -> None:
        if self._closed:
            raise OutputError("outputs handed over after the writer was closed")
        if self._writer is not None:
            self._writer.write(job)
            return
        if not self._collect(block=False):
            self._gone()
        self._raise_error(again=True)
        if frame:
            self._wait(lambda: self._frames_pending < MAX_PENDING)
        data = pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
        self._frames_pending += frame
        self._jobs_pending += 1
        self._queue.put(data)

    def drain(self) -> None:
        """Wait until every job handed over is written; raise :class:`OutputError`
        if one failed."""
        if self._proc is not None and not self._closed:
            self._wait(lambda: self._jobs_pending == 0)

    def close(self, *, drain: bool = True) -> None:
        """Stop the worker: after the jobs handed over are written (``drain``),
        or at once (``drain=False``: the files a job was writing stay as
        temporary files, removed by the next run).  Raises :class:`OutputError`
        if a job failed and that was not raised yet.  Idempotent."""
        if self._closed or self._proc is None:
            self._closed = True
            return
        try:
            if drain and self._error is None:
                self.drain()
        finally:
            self._closed = True
            self._stop(drain and self._error is None)
        self._raise_error()

    # ---- the worker's side of the conversation ----------------------------------------

    def _send_loop(self) -> None:
        while True:
            data = self._queue.get()
            if data is None:
                break
            try:
                self._jobs.send_bytes(data)
            except OSError:                 # the worker is gone: _wait finds out and says so
                break
        self._jobs.close()                  # the worker's EOF: it stops after the jobs sent

    def _stop(self, graceful: bool) -> None:
        self._queue.put(None)
        if graceful:
            self._proc.join(timeout=30.0)
            self._collect(block=False)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=5.0)
        self._sender.join(timeout=5.0)
        self._results.close()

    def _handle(self, message) -> None:
        kind = message[0]
        if kind == "done":
            self._jobs_pending -= 1
            self._frames_pending -= message[1] == "frame"
            self.worker_seconds += message[2]
            self.worker_cpu += message[3]
        elif kind == "error":
            self._error = message[1]
        elif kind == "bye":
            self.worker_imported_taichi = message[1]

    def _collect(self, block: bool) -> bool:
        """Handle the worker's messages waiting (or wait for one: ``block``);
        False when the worker is gone and has nothing more to say."""
        try:
            if block:
                ready = multiprocessing.connection.wait([self._results, self._proc.sentinel])
                if self._results not in ready and not self._results.poll():
                    return False
            while self._results.poll():
                self._handle(self._results.recv())
        except (EOFError, OSError):
            return False
        return True

    def _raise_error(self, again: bool = False) -> None:
        """Raise the worker's failure: once (``close``), or every time (``again``:
        a hand-off or a drain after it, which the worker would never complete)."""
        if self._error is not None and (again or not self._raised):
            self._raised = True
            raise OutputError(self._error)

    def _gone(self) -> None:
        """The worker stopped without a word (killed, out of memory): say so once."""
        self._raise_error()
        self._proc.join(timeout=1.0)
        self._error = (f"the output worker stopped (exit code {self._proc.exitcode}) with "
                       f"{self._jobs_pending} outputs not written")
        self._raise_error()

    def _wait(self, done) -> None:
        t0 = time.perf_counter()
        try:
            while True:
                self._raise_error(again=True)
                if done():
                    return
                if not self._collect(block=True) and not done():
                    self._gone()
        finally:
            self.waited += time.perf_counter() - t0
