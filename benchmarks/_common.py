"""Small helpers shared by the benchmark scripts: timing, CSV, tables.

Nothing here imports Taichi; the caller passes its ``ti.sync`` so that a timer
stops only after the asynchronous kernels it launched have finished.
"""
from __future__ import annotations

import csv
import io
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def add_repo_to_path() -> None:
    """Make ``import taichi_hh`` work from a checkout without installing it."""
    root = str(REPO_ROOT)
    if root not in sys.path:
        sys.path.insert(0, root)


def measure(fn, repeats: int, *, sync=None, setup=None, warmup: int = 1) -> list[float]:
    """Wall-clock seconds of ``repeats`` calls of ``fn()`` (after ``warmup`` calls).

    ``setup()`` runs untimed before every call (warm-up included); ``sync()``
    runs before starting and before stopping each timer.
    """
    sync = sync or (lambda: None)
    for _ in range(warmup):
        if setup:
            setup()
        fn()
        sync()
    times = []
    for _ in range(repeats):
        if setup:
            setup()
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return times


def summary(times: list[float]) -> dict:
    return {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
            "repeats": len(times)}


def _atomic_write(path: Path, write) -> None:
    """Write through a temporary file in the same directory, then rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)      # mkstemp makes it private; use normal permissions
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_csv_atomic(path, rows: list[dict], fieldnames: list[str]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fieldnames, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(row)
    data = buf.getvalue().encode()
    _atomic_write(path, lambda fh: fh.write(data))


def save_figure_atomic(fig, path, **kwargs) -> None:
    fmt = Path(path).suffix.lstrip(".") or "png"
    _atomic_write(path, lambda fh: fig.savefig(fh, format=fmt, **kwargs))


def format_table(header: list[str], rows: list[list[str]], align: str | None = None) -> str:
    """Plain-text table; ``align`` is one character per column, 'l' or 'r'."""
    align = align or "l" + "r" * (len(header) - 1)
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]

    def line(cells):
        return "  ".join(str(c).ljust(w) if a == "l" else str(c).rjust(w)
                         for c, w, a in zip(cells, widths, align))

    out = [line(header), "  ".join("-" * w for w in widths)]
    out += [line(r) for r in rows]
    return "\n".join(out)


def scene_module(name: str):
    """The module of the scene script ``scenes/<name>.py`` (its ``SCENE``,
    ``build``, ``add_arguments``, ...), loaded from its file."""
    import importlib.util
    spec = importlib.util.spec_from_file_location(f"scene_{name}", REPO_ROOT / "scenes" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
