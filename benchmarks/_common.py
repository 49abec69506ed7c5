"""Command-line glue shared by the benchmark scripts: timing, option lists,
atomic CSV and figure files, tables, loading a scene script.

Nothing here imports Taichi; the caller passes its ``ti.sync`` so that a timer
stops only after the asynchronous kernels it launched have finished.  What the
benchmarks measure lives in :mod:`taichi_hh.validation`.
"""
from __future__ import annotations

import csv
import io
import statistics
import sys
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


def write_bytes_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    from taichi_hh.app.io import atomic_path
    with atomic_path(str(path)) as tmp:
        Path(tmp).write_bytes(data)


def write_csv_atomic(path, rows: list[dict], fieldnames: list[str]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fieldnames, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(row)
    write_bytes_atomic(path, buf.getvalue().encode())


def write_rows(out_dir, name: str, rows: list[dict], fields: list[str] | None = None) -> str:
    """Write ``rows`` (columns ``fields``, default the first row's keys) to
    ``out_dir/name`` as CSV, atomically, the folder made if need be; returns
    the path."""
    import os
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, name)
    write_csv_atomic(path, rows, list(rows[0]) if fields is None else fields)
    return path


def report_rows(rows: list[dict], out_dir, name: str, align: str | None = None) -> str:
    """Print ``rows`` as a table (floats to 3 significant digits) and write them
    to ``out_dir/name`` (:func:`write_rows`); returns the path."""
    fields = list(rows[0])
    print(format_table(fields, [[f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k])
                                 for k in fields] for r in rows], align))
    return write_rows(out_dir, name, rows, fields)


def save_figure_atomic(fig, path, **kwargs) -> None:
    from taichi_hh.app.io import atomic_savefig
    atomic_savefig(fig, str(path), **kwargs)


def parse_list(text: str, kind=float) -> list:
    """A comma-separated option value as a list: ``"1e-8, 1e-2"`` -> [1e-08, 0.01]
    (empty items skipped; ``kind=int`` also accepts ``"4e4"``, ``kind=str``
    strips the items)."""
    convert = (lambda s: int(float(s))) if kind is int else kind
    return [convert(s.strip()) for s in str(text).split(",") if s.strip()]


def run_tasks(tasks: list[dict], workers: int, threads: int, progress: bool) -> list[dict]:
    """:func:`taichi_hh.validation.sweep.run_pool` with a progress bar."""
    from taichi_hh.app.runloop import ProgressBar
    from taichi_hh.validation.sweep import run_pool
    bar = ProgressBar(len(tasks)) if progress else None
    rows = run_pool(tasks, workers, threads,
                    on_done=(lambda done: bar.update(done, done)) if bar else None)
    if bar:
        bar.close()
    return rows


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
