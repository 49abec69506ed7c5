"""Dropped Taichi ndarrays are given back (taichi_hh.ndarray_release).

Taichi 1.7 keeps two kinds of dropped ndarray for the life of the process:
vector and matrix ndarrays on every arch (no ``__del__``), and on the SPIR-V
archs (Vulkan) any ndarray a launch used since the last synchronisation
(``Program.delete_ndarray`` refuses it and nobody asks again).  Runs on the
CPU and, in ``.ci/vulkan``, on lavapipe, where the second leak was found."""
import gc
import os

import numpy as np
import pytest

from taichi_hh import ndarray_release, runtime

STATUS = "/proc/self/status"


def rss_mb() -> float:
    with open(STATUS) as fh:
        return next(int(l.split()[1]) for l in fh if l.startswith("VmRSS")) / 1024


def _fill():
    import taichi as ti

    @ti.kernel
    def fill(a: ti.types.ndarray(), v: float):
        for i in range(a.shape[0]):
            a[i] = v

    @ti.kernel
    def fill_vectors(a: ti.types.ndarray(), v: float):
        for i in range(a.shape[0]):
            a[i] = ti.Vector([v, -v])

    return fill, fill_vectors


@pytest.mark.skipif(not os.path.exists(STATUS), reason="needs /proc for the resident set")
def test_ndarrays_dropped_after_a_launch_are_freed():
    """64 scalar and 64 vector ndarrays of 8 MB each, each written by a kernel
    and dropped before any synchronisation: 1 GB if kept (Vulkan kept them
    all), at most DEFER_BYTES waiting to be freed here."""
    fill, fill_vectors = _fill()
    runtime.ensure_init()
    a = runtime.array(None, 1_000_000)          # compile, and touch the allocator, first
    fill(a, 1.0)
    b = runtime.array(None, 500_000, vector=2)
    fill_vectors(b, 1.0)
    del a, b
    gc.collect()
    ndarray_release.release_deferred()
    before = rss_mb()
    for k in range(64):
        a = runtime.array(None, 1_000_000)
        fill(a, float(k))
        b = runtime.array(None, 500_000, vector=2)
        fill_vectors(b, float(k))
        del a, b
    grown = rss_mb() - before
    assert grown < ndarray_release.DEFER_BYTES / 2**20 + 64, f"{grown:.0f} MB kept"
    ndarray_release.release_deferred()
    assert ndarray_release.deferred() == 0


def test_waiting_arrays_are_freed_on_request_and_keep_their_values_until_then():
    """On a SPIR-V arch a dropped array waits (the launch that wrote it may
    still run) until release_deferred; arrays still held are not touched; on
    the CPU nothing waits."""
    fill, _ = _fill()
    kept = runtime.array(None, 1000)
    fill(kept, 3.0)
    ndarray_release.release_deferred()
    for _ in range(5):
        a = runtime.array(None, 1000)
        fill(a, 1.0)
        del a
    waiting = ndarray_release.deferred()
    spirv = runtime.state().arch == "vulkan"
    assert waiting == (5 if spirv else 0)
    assert ndarray_release.release_deferred() == waiting
    assert ndarray_release.deferred() == 0
    np.testing.assert_array_equal(kept.to_numpy(), 3.0)
