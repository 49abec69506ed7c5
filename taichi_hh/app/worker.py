"""The persistent worker: ``taichi-hh decompose|project`` run in one long-lived
process (started by ``taichi-hh worker start``; the client side, what a call
loads, is :mod:`taichi_hh.app.worker_client`).

It listens on a Unix socket in the user's private runtime directory, warms up
(a small decomposition of scattered points and one of a grid, figures
included: Taichi started, the kernels transformed and loaded, matplotlib
imported), then serves one call at a time: in the caller's directory and
umask, with the caller's arguments, through :func:`taichi_hh.app.cli.main`
itself, so errors, messages, exit statuses and the files written (atomically,
by the same writers) are the command line's.  Its stdout and stderr go back
to the caller as they are written.  Ctrl-C at the caller stops the call
(status 130, as in the caller's own process).  A call is refused (the caller
then runs it itself) when the package's sources changed since the worker
started (it then exits) or the caller's ``TAICHI_HH_*`` settings differ.
The worker exits after ``--idle-timeout`` seconds without a call, on
``taichi-hh worker stop`` and on SIGTERM, removing its socket.
"""
from __future__ import annotations

import _thread
import argparse
import contextlib
import os
import signal
import socket
import sys
import tempfile
import threading
import time
import warnings

from . import worker_client as client


class _Frames:
    """A text stream whose writes go to the caller as frames of one kind."""

    def __init__(self, sock, kind: str, lock):
        self.sock, self.kind, self.lock = sock, kind, lock
        self.broken = False

    def write(self, text) -> int:
        if text and not self.broken:
            try:
                with self.lock:
                    client.send_frame(self.sock, {self.kind: str(text)})
            except OSError:
                self.broken = True       # the caller went away: the call still ends cleanly
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False

    @property
    def encoding(self) -> str:
        return "utf-8"


class FigureHelper:
    """A process beside the worker (spawned: numpy and matplotlib, no Taichi)
    that draws ``arrows.png`` while the worker draws ``magnitude.png``
    (:func:`taichi_hh.app.figures.draw_beside`): on two cores a call's
    figures take the longer one's time, not both."""

    def __init__(self):
        import multiprocessing
        ctx = multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_draw_arrows, args=(child,), daemon=True,
                                   name="taichi-hh figure helper")
        self.process.start()
        child.close()
        self.jobs = 0

    def __call__(self, job):
        if not self.process.is_alive():
            return None                  # draw both in the worker
        self.jobs += 1
        number = self.jobs
        try:
            self.conn.send((number, job))
        except OSError:
            return None

        def wait():
            interrupted, error = False, None
            while True:
                try:                     # a Ctrl-C waits for the file (no file after the call)
                    if not self.conn.poll(120.0):
                        raise OSError("the figure helper did not answer in 120 s")
                    got, error = self.conn.recv()
                except KeyboardInterrupt:
                    interrupted = True
                    continue
                except EOFError:
                    raise OSError("the figure helper stopped while drawing arrows.png") from None
                if got == number:
                    break
            if interrupted:
                raise KeyboardInterrupt
            if error:
                raise OSError(error)
        return wait

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.send(None)
        self.process.join(5.0)
        if self.process.is_alive():
            self.process.terminate()


def _draw_arrows(conn) -> None:
    """The figure helper's loop: :func:`~taichi_hh.app.figures.arrows_figure` per job."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from . import figures
    while True:
        try:
            got = conn.recv()
        except (EOFError, OSError):
            return
        if got is None:
            return
        number, job = got
        os.umask(job["umask"])
        try:
            figures.arrows_figure(job["result"], job["domain"], job["path"], job["critical"],
                                  units=job["units"])
            error = None
        except Exception as exc:         # noqa: BLE001 (sent back as the call's error)
            error = f"{type(exc).__name__}: {exc}"
        conn.send((number, error))


def _helper_cpu(helper) -> float:
    """The figure helper's CPU seconds so far (Linux's /proc; 0 elsewhere)."""
    try:
        with open(f"/proc/{helper.process.pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (AttributeError, OSError, ValueError, IndexError):
        return 0.0


class _NewCall(Warning):
    """Never raised: setting a filter for it makes Python forget the warnings
    already shown, so each call warns as a fresh process would."""


class Worker:
    def __init__(self, path: str, idle_timeout: float, arch: str | None, precision: str):
        self.path, self.idle_timeout = path, idle_timeout
        self.arch, self.precision = arch, precision
        self.calls, self.started = 0, time.time()
        self.stamp = client.source_stamp()
        self.env = client.environment()
        self.running = True
        self.helper = None

    # ------------------------------------------------------------------ life
    def listen(self):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        with contextlib.suppress(FileNotFoundError):
            os.remove(self.path)
        old = os.umask(0o177)            # the socket: this user only
        try:
            sock.bind(self.path)
        finally:
            os.umask(old)
        sock.listen(16)
        self.inode = os.stat(self.path).st_ino
        return sock

    def warm_up(self) -> None:
        """A scattered field, a grid and a series of two snapshots through the
        command line, figures included, in a temporary directory."""
        import numpy as np
        from . import cli
        from ..runtime import default_arch
        rng = np.random.default_rng(0)
        side = np.linspace(0.0, 1.0, 40)
        X, Y = np.meshgrid(side, side)
        fields = {"scattered": rng.uniform(0.0, 1.0, (1600, 2)), "grid": np.c_[X.ravel(), Y.ravel()]}
        with tempfile.TemporaryDirectory(prefix="taichi-hh-warm-") as tmp:
            calls = []
            for name, pts in fields.items():
                paths = []
                for t in range(2 if name == "scattered" else 1):
                    x, y = pts[:, 0] - 0.4 - 0.01 * t, pts[:, 1] - 0.5
                    g = np.exp(-(x ** 2 + y ** 2) / 0.02)
                    paths.append(os.path.join(tmp, f"{name}{t}.npz"))
                    np.savez(paths[-1], points=pts, vectors=np.c_[-y * g + 0.3, x * g + 0.1])
                calls.append([paths[0], "-o", os.path.join(tmp, name)])
                if len(paths) > 1:          # the series path: its set-up kept, series.nc
                    calls.append([*paths, "-o", os.path.join(tmp, name + "_series"),
                                  "--figures", "none"])
            for call in calls:
                argv = ["decompose", *call, "-q", "--arch", self.arch or default_arch(),
                        "--precision", self.precision]
                with open(os.devnull, "w") as sink, contextlib.redirect_stdout(sink), \
                        contextlib.redirect_stderr(sink):
                    code = cli.main(argv, worker=False)
                if code != 0:
                    raise RuntimeError(f"the warm-up call {argv} failed: {code}")

    def serve(self, warm_up: bool = True) -> None:
        server = self.listen()
        helper = None
        try:
            from . import figures
            helper = self.helper = FigureHelper()
            figures.draw_beside(helper)
            if warm_up:
                self.warm_up()
            else:
                from . import cli  # noqa: F401  (the imports, at least)
            server.settimeout(self.idle_timeout)
            while self.running:
                try:
                    conn, _ = server.accept()
                except socket.timeout:
                    break                # idle: exit
                with conn:
                    try:
                        self.handle(conn)
                    except (OSError, ValueError):
                        pass             # a caller that went away or sent garbage
                    except KeyboardInterrupt:
                        pass             # an interrupt that came as its call ended
        finally:
            server.close()
            with contextlib.suppress(OSError):
                if os.stat(self.path).st_ino == self.inode:    # still this worker's socket
                    os.remove(self.path)
            if helper is not None:
                helper.close()

    def status(self) -> dict:
        from .. import runtime
        st = runtime.state()
        return dict(pid=os.getpid(), arch=st.arch or self.arch or "cpu",
                    precision=st.precision or self.precision, uptime=time.time() - self.started,
                    calls=self.calls, idle_timeout=self.idle_timeout, socket=self.path,
                    cpu_seconds=time.process_time() + _helper_cpu(self.helper))

    # ------------------------------------------------------------------ a call
    def handle(self, conn) -> None:
        conn.settimeout(30.0)
        message = client.recv_frame(conn)
        if not message:
            return
        op = message.get("op")
        if op in ("status", "stop"):
            client.send_frame(conn, self.status())
            self.running = op != "stop"
            return
        if op != "run":
            return
        if message.get("stamp") != self.stamp:
            client.send_frame(conn, dict(accepted=False, reason="the sources changed"))
            self.running = False         # a stale worker: the next start makes a new one
            return
        if message.get("env") != self.env:
            client.send_frame(conn, dict(accepted=False, reason="other TAICHI_HH_ settings"))
            return
        try:
            os.chdir(message["cwd"])
        except OSError:
            client.send_frame(conn, dict(accepted=False, reason="cannot enter the directory"))
            return
        client.send_frame(conn, dict(accepted=True))
        conn.settimeout(None)
        self.calls += 1
        try:
            code = self.run(conn, list(message["argv"]), int(message.get("umask", 0o022)))
        finally:
            os.chdir("/")
        if code == 143:                  # the call ended by a SIGTERM to this worker
            self.running = False
        client.send_frame(conn, dict(exit=code))

    def run(self, conn, argv: list, umask: int) -> int:
        """``cli.main(argv)`` with stdout and stderr sent to the caller and an
        interrupt from it raised as KeyboardInterrupt here."""
        from . import cli
        lock = threading.Lock()
        state = dict(done=False)

        def watch():                     # the caller's Ctrl-C, or the caller gone
            try:
                while True:
                    frame = client.recv_frame(conn)
                    if frame is None or frame.get("op") == "interrupt":
                        break
            except (OSError, ValueError):
                pass
            with lock:
                if not state["done"]:
                    _thread.interrupt_main()

        out, err = _Frames(conn, "out", lock), _Frames(conn, "err", lock)
        old_umask = os.umask(umask)
        old_argv = sys.argv
        sys.argv = ["taichi-hh", *argv]
        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
                    warnings.catch_warnings():
                warnings.simplefilter("default", _NewCall)
                try:
                    code = cli.main(argv, worker=False)
                except SystemExit as exc:          # argparse: usage errors, --help
                    code = exc.code
                    if isinstance(code, str):
                        print(code, file=sys.stderr)
                        code = 1
                    code = 0 if code is None else int(code)
                except KeyboardInterrupt:          # between cli.main's own handlers
                    print(f"taichi-hh {argv[0]}: interrupted", file=sys.stderr)
                    code = 130
            with lock:
                state["done"] = True
        except KeyboardInterrupt:                  # after the call, before `done`
            code = 130
        finally:
            sys.argv = old_argv
            os.umask(old_umask)
        return code


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m taichi_hh.app.worker",
                                 description="the taichi-hh worker (see taichi-hh worker --help)")
    ap.add_argument("--socket", required=True)
    ap.add_argument("--idle-timeout", type=float, default=client.IDLE_TIMEOUT)
    ap.add_argument("--arch", default=None)
    ap.add_argument("--precision", default="f64", choices=("f32", "f64"))
    ap.add_argument("--no-warm-up", action="store_true")
    args = ap.parse_args(argv)
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
    os.chdir("/")

    def stop(signum, frame):
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    # a caller's Ctrl-C reaches a call through _thread.interrupt_main, which
    # does nothing where SIGINT is ignored: a worker started from a shell's
    # background job inherits that (SIGINT itself reaches the worker only
    # through its callers)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    worker = Worker(args.socket, args.idle_timeout, args.arch, args.precision)
    print(f"taichi-hh worker {os.getpid()}: listening on {args.socket}", flush=True)
    worker.serve(warm_up=not args.no_warm_up)
    print(f"taichi-hh worker {os.getpid()}: exiting after {worker.calls} calls", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
