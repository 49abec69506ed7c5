"""Taichi runtime ownership: the only module that calls ``ti.init``.

Nothing in :mod:`taichi_hh` initialises Taichi at import time.  The first call
that needs Taichi runs :func:`ensure_init`, which initialises the CPU arch in
double precision unless :func:`init` was called before with other settings.

Precision is a runtime-wide choice (Taichi's ``default_fp``): every ``float``
inside a kernel and every real-valued array this package allocates follows it.
Re-initialising with other settings invalidates every Taichi array made before
(Taichi frees them); objects of this package remember the runtime generation
they were made in and refuse to run on a later one instead of crashing.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import numpy as np

_ARCHES = ("cpu", "gpu", "auto")
_PRECISIONS = {"f32": np.float32, "f64": np.float64}


@dataclass
class RuntimeState:
    initialized: bool = False
    arch: str = ""           # "cpu" or "gpu": what Taichi actually runs on
    requested_arch: str = ""
    precision: str = ""
    generation: int = 0      # bumped on every (re)initialisation


_state = RuntimeState()


def _taichi():
    import taichi as ti  # imported lazily: importing taichi prints a banner
    _free_vector_ndarrays()
    return ti


_vector_free_done = False


def _free_vector_ndarrays() -> None:
    """Make Taichi free vector and matrix ndarrays when Python collects them.

    Taichi 1.7 frees the memory of a ``ScalarNdarray`` in its ``__del__`` but
    ``VectorNdarray`` and ``MatrixNdarray`` have none, so every vector ndarray
    made and dropped stays allocated (taichi-dev/taichi issue #8763; the fix,
    PR #8764, moves ``__del__`` to the base class).  The flow keeps every
    array it uses across steps and needs none of this (its memory is flat
    without it: benchmarks/flow_memory.py); the one-shot calls
    (``decompose``, ``project``, :class:`~taichi_hh.sph.pointset.PointSet`)
    make vector ndarrays per call, which would otherwise never be freed
    (docs/notes/flow.md).  Same deletion as the scalar class; done once (a
    later removal, as the benchmark's ``--without-vector-free`` does,
    sticks), and only where the class lacks its
    own ``__del__``.
    """
    global _vector_free_done
    if _vector_free_done:
        return
    _vector_free_done = True
    try:
        from taichi.lang import _ndarray, matrix
    except ImportError:          # another Taichi layout: leave it alone
        return
    free = getattr(_ndarray.ScalarNdarray, "__del__", None)
    if free is None:
        return
    for cls in (getattr(matrix, "VectorNdarray", None), getattr(matrix, "MatrixNdarray", None)):
        if cls is not None and "__del__" not in vars(cls):
            cls.__del__ = free


def init(arch: str = "cpu", precision: str = "f64", *, offline_cache_dir: str | None = None,
         threads: int | None = None, debug: bool = False, verbose: bool = True) -> RuntimeState:
    """Initialise Taichi for this package.

    arch: ``"cpu"``, ``"gpu"`` (falls back to CPU with one message when no GPU
    is found) or ``"auto"`` (GPU when present, CPU silently otherwise).
    precision: ``"f32"`` or ``"f64"``; the default floating type of every kernel.
    offline_cache_dir: where Taichi keeps compiled kernels between runs
    (default: Taichi's own, or ``$TAICHI_HH_CACHE`` when set).
    threads: CPU worker threads (default: all cores).
    """
    if arch not in _ARCHES:
        raise ValueError(f"arch must be one of {_ARCHES}, got {arch!r}")
    if precision not in _PRECISIONS:
        raise ValueError(f"precision must be one of {tuple(_PRECISIONS)}, got {precision!r}")
    ti = _taichi()
    if _state.initialized:
        if (_state.requested_arch, _state.precision) == (arch, precision):
            return _state
        ti.reset()
    kwargs = dict(default_fp=ti.f64 if precision == "f64" else ti.f32, default_ip=ti.i32,
                  offline_cache=True, debug=debug, log_level=ti.WARN)
    cache = offline_cache_dir or os.environ.get("TAICHI_HH_CACHE")
    if cache:
        os.makedirs(cache, exist_ok=True)
        kwargs["offline_cache_file_path"] = cache
    if threads:
        kwargs["cpu_max_num_threads"] = int(threads)
    actual = "cpu"
    if arch != "cpu":
        # Try the GPU backends one by one rather than ti.gpu: its OpenGL probe
        # segfaults on machines without a display (seen on the CPU-only CI boxes),
        # while CUDA and Vulkan fall back to the CPU cleanly when absent.
        for backend in _gpu_backends(ti):
            ti.init(arch=backend, **kwargs)
            if ti.lang.impl.current_cfg().arch != ti.cpu:
                actual = "gpu"
                break
            ti.reset()
    if actual == "cpu":
        ti.init(arch=ti.cpu, **kwargs)
    if arch == "gpu" and actual == "cpu" and verbose:
        print("taichi_hh: no usable GPU found; running on the CPU instead.", file=sys.stderr)
    _state.initialized = True
    _state.arch = actual
    _state.requested_arch = arch
    _state.precision = precision
    _state.generation += 1
    return _state


def _gpu_backends(ti):
    backends = [ti.cuda, ti.vulkan]
    if sys.platform == "darwin":
        backends.insert(0, ti.metal)
    return backends


def ensure_init() -> RuntimeState:
    """Initialise lazily (CPU, f64) unless already initialised."""
    if not _state.initialized:
        init()
    return _state


def state() -> RuntimeState:
    return _state


def real_dtype():
    """The Taichi real type of the current runtime (f32 or f64)."""
    ti = _taichi()
    ensure_init()
    return ti.f64 if _state.precision == "f64" else ti.f32


def np_real():
    """The numpy real type matching :func:`real_dtype`."""
    ensure_init()
    return _PRECISIONS[_state.precision]


def generation() -> int:
    return _state.generation


def check_generation(made_in: int, what: str = "object") -> None:
    """Refuse to use Taichi arrays from an earlier runtime (they were freed)."""
    if made_in != _state.generation:
        raise RuntimeError(
            f"this {what} was created before taichi_hh.init() re-initialised Taichi; "
            "its arrays are gone. Create it again.")
