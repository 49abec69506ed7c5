"""How the command lines end: one line on stderr, never a traceback.

:func:`run_reporting` runs a command's body and turns what it raises into an
exit status and one line: bad input, bad numerics and failed writes
(:class:`~taichi_hh.errors.TaichiHHError`, ``ValueError``, ``OSError``) into
``PROG: error: ...`` and status 2; anything else (a bug) into ``PROG: internal
error: ...`` naming a file with the full report, status 1; Ctrl-C into status
130; SIGTERM into a normal exit (status 143) so that temporary files are
removed on the way out.  Warnings (e.g. :class:`~taichi_hh.errors.AccuracyWarning`)
print as ``PROG: warning: ...``.  ``TAICHI_HH_DEBUG=1`` lets exceptions through
with their tracebacks.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import traceback
import warnings
from contextlib import contextmanager

EXIT_ERROR, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_TERMINATED = 2, 1, 130, 143


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def write_report(prog: str, exc: BaseException) -> str:
    """Write the traceback of ``exc`` (with the command line and versions) to a
    new file in the temporary directory; returns its path."""
    import platform
    import tempfile
    from .. import __version__
    fd, path = tempfile.mkstemp(prefix="taichi-hh-error-", suffix=".txt")
    with os.fdopen(fd, "w") as fh:
        fh.write(f"{prog}: internal error\ncommand line: {' '.join(sys.argv)}\n"
                 f"taichi_hh {__version__}, Python {platform.python_version()}, "
                 f"{platform.platform()}\n\n")
        fh.write("".join(traceback.format_exception(type(exc), exc, exc.__traceback__)))
    return path


def option_rewriter(parser):
    """A function that rewrites the library's ``name='value'`` advice in a
    message into the command line's ``--name value`` for every option
    ``parser`` (an argparse parser, its subcommands included) knows, so that a
    message names the remedy in the caller's syntax; a pair
    ``name=('kind', value)`` whose kind is an option too becomes ``--name kind
    --kind value`` (``domain=('alpha', 5)``: ``--domain alpha --alpha 5``)."""
    import argparse
    import re
    flags = {}

    def collect(p):
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    collect(sub)
            elif action.option_strings:
                long = [o for o in action.option_strings if o.startswith("--")]
                if long:
                    flags.setdefault(action.dest, long[0])
    collect(parser)
    pattern = re.compile(r"\b([a-z][a-z_]*)=(?:'([^']*)'|\"([^\"]*)\"|([\w.+-]+))")
    pair = re.compile(r"\b([a-z][a-z_]*)=\(\s*['\"]([a-z_]+)['\"]\s*,\s*([\w.+-]+)\s*\)")

    def rewrite(text: str) -> str:
        def one(m):
            flag = flags.get(m.group(1))
            if flag is None:
                return m.group(0)
            value = next(g for g in m.groups()[1:] if g is not None)
            return f"{flag} {value}"

        def two(m):
            flag, second = flags.get(m.group(1)), flags.get(m.group(2))
            if flag is None or second is None:
                return m.group(0)
            return f"{flag} {m.group(2)} {second} {m.group(3)}"
        return pattern.sub(one, pair.sub(two, text))
    return rewrite


@contextmanager
def _one_line_warnings(prog: str, rewrite=None):
    old = warnings.showwarning
    rewrite = rewrite or (lambda text: text)

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{prog}: warning: {rewrite(' '.join(str(message).split()))}", file=sys.stderr)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = old


@contextmanager
def _sigterm_exits():
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise SystemExit(EXIT_TERMINATED)

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def run_reporting(prog: str, job, *, error_hint=None, rewrite=None) -> int:
    """``job()`` -> its exit status, with the module doc's endings.
    ``error_hint(exc)``: optional advice appended to an expected error's line;
    ``rewrite(text)``: applied to every error and warning line (e.g.
    :func:`option_rewriter`: the library's advice in command-line syntax)."""
    from ..errors import TaichiHHError
    debug = bool(os.environ.get("TAICHI_HH_DEBUG"))
    rewrite_line = rewrite or (lambda text: text)
    try:
        with _one_line_warnings(prog, rewrite), _sigterm_exits():
            return job()
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (TaichiHHError, ValueError, OSError) as exc:
        if debug:
            raise
        msg = rewrite_line(one_line(exc))
        if isinstance(exc, OSError) and not isinstance(exc, TaichiHHError):
            msg = f"{type(exc).__name__}: {msg}"
        hint = error_hint(exc) if error_hint else None
        print(f"{prog}: error: {msg}{' ' + hint if hint else ''}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as exc:           # a bug: one line, the traceback in a file
        if debug:
            raise
        try:
            where = f"full report in {write_report(prog, exc)}"
        except OSError as werr:
            where = f"the report could not be written: {werr}"
        print(f"{prog}: internal error: {type(exc).__name__}: {one_line(exc)} ({where}; "
              "please report it)", file=sys.stderr)
        return EXIT_INTERNAL
