"""The command line's side of the persistent worker (:mod:`taichi_hh.app.worker`).

A fresh ``taichi-hh decompose`` process spends seconds before its work:
importing numpy, Taichi and matplotlib, starting Taichi and transforming
every kernel's Python before the offline cache can hand back its compiled
code (docs/notes/series.md, "The command line's start-up").  A worker keeps
all of that between calls.  It is opt-in: ``taichi-hh worker start`` starts
one for this user, this Python and this copy of the package; while it runs,
``decompose`` and ``project`` send it their arguments over a Unix socket and
print what it sends back; it exits after ``--idle-timeout`` seconds without
a call, or on ``taichi-hh worker stop``.  With no worker running (or
``--no-worker``, or ``TAICHI_HH_WORKER=0``) the command runs in its own
process as before.

This module imports the standard library only (no numpy, no Taichi): it is
all a call through the worker loads.  Messages are frames: a 4-byte length
and a JSON object.
"""
from __future__ import annotations

import hashlib
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time

#: the commands a worker runs (the others always run in their own process)
WORKER_COMMANDS = ("decompose", "project")
#: ``0``/``off``/``no``: never use a worker
WORKER_VARIABLE = "TAICHI_HH_WORKER"
#: the directory of the sockets and logs (default: $XDG_RUNTIME_DIR/taichi-hh,
#: else taichi-hh-<uid> in the temporary directory)
DIR_VARIABLE = "TAICHI_HH_WORKER_DIR"
#: seconds a worker waits for a call before it exits
IDLE_TIMEOUT = 900.0
#: seconds ``worker start`` waits for the worker's warm-up
START_TIMEOUT = 300.0
_HEADER = struct.Struct(">I")


# --------------------------------------------------------------------------- frames
def send_frame(sock, message: dict) -> None:
    data = json.dumps(message).encode()
    sock.sendall(_HEADER.pack(len(data)) + data)


def _recv_exact(sock, n: int):
    chunks = []
    while n:
        chunk = sock.recv(n)
        if not chunk:
            return None
        chunks.append(chunk)
        n -= len(chunk)
    return b"".join(chunks)


def recv_frame(sock):
    """The next frame, or None when the other side closed the connection."""
    head = _recv_exact(sock, _HEADER.size)
    if head is None:
        return None
    body = _recv_exact(sock, _HEADER.unpack(head)[0])
    return None if body is None else json.loads(body)


# --------------------------------------------------------------------------- where
def package_dir() -> str:
    return os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def runtime_dir() -> str:
    """This user's directory of worker sockets, created private (0700); a
    directory that another user owns or others can enter is refused."""
    chosen = os.environ.get(DIR_VARIABLE)
    if not chosen:
        xdg = os.environ.get("XDG_RUNTIME_DIR")
        chosen = (os.path.join(xdg, "taichi-hh") if xdg and os.path.isdir(xdg) else
                  os.path.join(tempfile.gettempdir(), f"taichi-hh-{os.getuid()}"))
    os.makedirs(chosen, mode=0o700, exist_ok=True)
    st = os.stat(chosen)
    if st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise OSError(f"the worker directory {chosen} must belong to this user and be "
                      f"private (mode 0700); set ${DIR_VARIABLE} to another directory")
    return chosen


def worker_key() -> str:
    """One worker per Python interpreter and copy of the package."""
    from .. import __version__
    text = f"{sys.executable}\0{package_dir()}\0{__version__}"
    return hashlib.sha1(text.encode()).hexdigest()[:12]


def socket_path() -> str:
    path = os.path.join(runtime_dir(), f"worker-{worker_key()}.sock")
    if len(path.encode()) > 100:         # sun_path holds 108 bytes
        raise OSError(f"the worker socket's path is too long for a Unix socket: {path} "
                      f"(set ${DIR_VARIABLE} to a shorter directory)")
    return path


def source_stamp() -> list:
    """The package's Python sources as (count, total size, latest mtime): a
    worker whose sources changed since it started refuses calls and exits."""
    count = size = latest = 0
    for root, dirs, files in os.walk(package_dir()):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        for name in files:
            if name.endswith(".py"):
                st = os.stat(os.path.join(root, name))
                count += 1
                size += st.st_size
                latest = max(latest, st.st_mtime_ns)
    return [count, size, latest]


def environment() -> dict:
    """The variables that change what a call does (the package's own, but for
    the worker's): a worker started under others refuses the call."""
    return {k: v for k, v in os.environ.items()
            if k.startswith("TAICHI_HH_") and not k.startswith(WORKER_VARIABLE)}


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def connect(path: str, timeout: float | None = 5.0):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        sock.connect(path)
    except OSError:
        sock.close()
        raise
    return sock


# --------------------------------------------------------------------------- a call
def run_in_worker(argv: list) -> int | None:
    """Run ``taichi-hh ARGV`` in the worker; its exit status, or None where no
    worker serves this call (then the caller runs it itself)."""
    if os.environ.get(WORKER_VARIABLE, "").strip().lower() in ("0", "off", "no", "false"):
        return None
    if not argv or argv[0] not in WORKER_COMMANDS or "--no-worker" in argv:
        return None
    if os.environ.get("TAICHI_HH_DEBUG"):
        return None                      # tracebacks wanted: in this process
    try:
        path = socket_path()
        if not os.path.exists(path):
            return None
        sock = connect(path)
    except OSError:
        return None
    with sock:
        try:
            send_frame(sock, dict(op="run", argv=list(argv), cwd=os.getcwd(), umask=_umask(),
                                  env=environment(), stamp=source_stamp()))
            sock.settimeout(None)
            reply = recv_frame(sock)
        except OSError:
            return None
        if not reply or not reply.get("accepted"):
            return None                  # stale sources, other settings: run here
        return _relay(sock, argv[0])


def _relay(sock, command: str) -> int:
    """Print the worker's output until its exit status; Ctrl-C is passed on
    (the worker stops the call as the command line does: status 130)."""
    interrupted = False
    lost = None                          # the connection's error, if it broke
    while True:
        try:
            frame = recv_frame(sock)
        except KeyboardInterrupt:
            if interrupted:              # a second Ctrl-C: stop waiting
                print(f"taichi-hh {command}: interrupted", file=sys.stderr)
                return 130
            interrupted = True
            try:
                send_frame(sock, dict(op="interrupt"))
            except OSError:
                pass
            continue
        except OSError as exc:
            frame, lost = None, exc
        if frame is None:
            why = f": {lost}" if lost is not None else ""
            print(f"taichi-hh {command}: internal error: the worker stopped during the call"
                  f"{why} (its log: {log_path()}; please report it)", file=sys.stderr)
            return 1
        if "out" in frame:
            sys.stdout.write(frame["out"])
            sys.stdout.flush()
        elif "err" in frame:
            sys.stderr.write(frame["err"])
            sys.stderr.flush()
        elif "exit" in frame:
            return int(frame["exit"])


def log_path() -> str:
    return socket_path()[:-len(".sock")] + ".log"


# --------------------------------------------------------------------------- taichi-hh worker
def request(op: str, timeout: float = 10.0):
    """One request to this user's worker: its reply; ``{"busy": True}`` where
    one listens but is still in a call after ``timeout`` seconds; None where
    none listens."""
    try:
        sock = connect(socket_path(), timeout)
    except OSError:
        return None
    with sock:
        try:
            send_frame(sock, dict(op=op))
            return recv_frame(sock)
        except socket.timeout:
            return {"busy": True}
        except OSError:
            return None


def start(idle_timeout: float = IDLE_TIMEOUT, arch: str | None = None,
          precision: str = "f64", warm_up: bool = True, wait: float = START_TIMEOUT) -> dict:
    """Start this user's worker (one already running is kept); returns its
    status.  Waits for its warm-up (a small decomposition of each kind: its
    kernels loaded, matplotlib imported)."""
    got = request("status")
    if got:
        if got.get("busy"):
            raise OSError("a worker is running and busy with a call; try again when it is done")
        return dict(got, already=True)
    path = socket_path()
    if os.path.exists(path):
        os.remove(path)                  # a worker that died without cleaning up
    log = log_path()
    cmd = [sys.executable, "-m", "taichi_hh.app.worker", "--socket", path,
           "--idle-timeout", repr(float(idle_timeout)), "--precision", precision]
    if arch:
        cmd += ["--arch", arch]
    if not warm_up:
        cmd.append("--no-warm-up")
    env = dict(os.environ)
    here = os.path.dirname(package_dir())
    # the worker imports this copy of the package, wherever it was imported from
    env["PYTHONPATH"] = here + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    with open(log, "ab") as fh:
        child = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=fh, stderr=fh, env=env,
                                 cwd="/", start_new_session=True, close_fds=True)
    t0 = time.monotonic()
    while time.monotonic() - t0 < wait:
        if child.poll() is not None:
            raise OSError(f"the worker exited with status {child.returncode} while starting; "
                          f"its log: {log}")
        if os.path.exists(path):
            got = request("status", timeout=wait)
            if got and not got.get("busy"):
                return dict(got, already=False, start_seconds=time.monotonic() - t0)
        time.sleep(0.05)
    child.terminate()
    raise OSError(f"the worker did not answer within {wait:g} s; its log: {log}")


def worker_command(argv: list) -> int:
    """``taichi-hh worker start|stop|status [--idle-timeout S] [--arch A]``."""
    import argparse
    ap = argparse.ArgumentParser(
        prog="taichi-hh worker",
        description="A persistent worker for decompose and project: it keeps Taichi, its "
                    "loaded kernels and matplotlib between calls, so a call costs its work. "
                    "While it runs, 'taichi-hh decompose|project' use it (not with "
                    "--no-worker or TAICHI_HH_WORKER=0); it exits after --idle-timeout "
                    "seconds without a call.")
    ap.add_argument("action", choices=("start", "stop", "status"))
    ap.add_argument("--idle-timeout", type=float, default=IDLE_TIMEOUT, metavar="S",
                    help=f"seconds without a call before the worker exits (default: "
                         f"{IDLE_TIMEOUT:g})")
    ap.add_argument("--arch", default=None, help="its Taichi arch (default: $TAICHI_HH_ARCH "
                    "or cpu); a call asking for another restarts Taichi inside it")
    ap.add_argument("--precision", default="f64", choices=("f32", "f64"))
    ap.add_argument("--no-warm-up", action="store_true",
                    help="answer at once, without the warm-up decompositions")
    args = ap.parse_args(argv)
    prog = f"taichi-hh worker {args.action}"
    try:
        if args.action == "start":
            got = start(args.idle_timeout, args.arch, args.precision, not args.no_warm_up)
            said = "already running" if got.get("already") else \
                f"started in {got['start_seconds']:.1f} s"
            print(f"taichi-hh worker: {said} (pid {got['pid']}, {got['arch']}/"
                  f"{got['precision']}, idle timeout {got['idle_timeout']:g} s, socket "
                  f"{got['socket']})")
            return 0
        if args.action == "stop":
            got = request("stop", timeout=None)        # after the call it is in
            print("taichi-hh worker: " + (f"stopped (pid {got['pid']}, {got['calls']} calls)"
                                          if got else "none running"))
            return 0
        got = request("status")
        if not got:
            print("taichi-hh worker: none running")
            return 3
        if got.get("busy"):
            print("taichi-hh worker: running, busy with a call")
            return 0
        print(f"taichi-hh worker: running (pid {got['pid']}, {got['arch']}/{got['precision']}, "
              f"up {got['uptime']:.0f} s, {got['calls']} calls, idle timeout "
              f"{got['idle_timeout']:g} s, socket {got['socket']})")
        return 0
    except OSError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
