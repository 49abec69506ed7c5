"""The runtime module: Taichi's CPU worker threads bound one to a core.

Each case runs in a fresh interpreter: the session's runtime is shared by every
other test and must not be re-initialised here.
"""
import json
import os
import subprocess
import sys

import pytest

PROBE = r"""
import json, os, threading
import taichi_hh
from taichi_hh import runtime
state = runtime.init(arch="cpu", precision="f64", verbose=False, **KWARGS)
main = threading.get_native_id()
single = []
for name in os.listdir("/proc/self/task"):
    try:
        allowed = os.sched_getaffinity(int(name))
    except ProcessLookupError:      # a thread that ended after the listing
        continue
    if int(name) != main and len(allowed) == 1:
        single.append(sorted(allowed)[0])
import taichi as ti
print(json.dumps({"pinned": list(state.pinned), "single": sorted(single),
                  "workers": int(ti.lang.impl.current_cfg().cpu_max_num_threads),
                  "main": sorted(os.sched_getaffinity(main))}))
"""


def _probe(kwargs: str = "{}", env: dict | None = None) -> dict:
    code = PROBE.replace("**KWARGS", f"**{kwargs}")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, **(env or {})}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


needs_affinity = pytest.mark.skipif(not hasattr(os, "sched_getaffinity"),
                                    reason="thread affinity is a Linux interface")


@needs_affinity
def test_workers_are_bound_one_to_a_core_or_none_is():
    """All or nothing, however busy the machine: where the probe finds every
    worker (an idle machine) each is bound to one usable core in turn and the
    caller is left free; where another process hides a worker from it
    (:func:`runtime.busy_threads` finds fewer), no thread is bound.  Which of
    the two happens depends on the load, so both are accepted; what decides
    it is checked below without threads."""
    cpus = sorted(os.sched_getaffinity(0))
    got = _probe()
    assert got["main"] == cpus
    if len(cpus) < 2 or not got["pinned"]:
        assert got["pinned"] == [] and got["single"] == []
        return
    assert len(got["pinned"]) == got["workers"]
    assert set(got["pinned"]) == set(cpus[:got["workers"]])
    assert got["single"] == sorted(got["pinned"])


def test_the_workers_are_the_threads_that_ran_the_probe():
    from taichi_hh import runtime
    # two workers ran the loops; an idle helper thread ran almost nothing
    assert runtime.busy_threads({11: 9_000_000, 12: 8_000_000, 13: 50_000}, 2) == [11, 12]
    # a worker woken late still ran more than a tenth of its share
    assert runtime.busy_threads({12: 9_000_000, 11: 1_000_000}, 2) == [11, 12]
    # a worker hidden by a busy machine: one found for two, nothing is bound
    assert runtime.busy_threads({11: 9_000_000, 12: 100_000}, 2) == [11]
    # a foreign thread busy at the same time: three found for two, nothing is bound
    assert len(runtime.busy_threads({11: 5, 12: 5, 13: 5}, 2)) == 3
    assert runtime.busy_threads({}, 2) == [] and runtime.busy_threads({11: 0}, 1) == []


@needs_affinity
def test_binding_can_be_turned_off():
    for got in (_probe(env={"TAICHI_HH_PIN_THREADS": "0"}), _probe("{'pin_threads': False}")):
        assert got["pinned"] == [] and got["single"] == []


@needs_affinity
def test_one_thread_is_left_unbound():
    got = _probe("{'threads': 1}")
    assert got["workers"] == 1
    assert got["pinned"] == [] and got["single"] == []


# ---- runtime.array: Taichi arrays without the traceback and, on request, the fill


def _fill_kernel():
    import taichi as ti

    @ti.kernel
    def fill(x: ti.types.ndarray(), y: ti.types.ndarray(), n: ti.i32):
        for i in range(n):
            x[i] = 2.0 * i
            y[i] = ti.Vector([1.0, -1.0]) * i
    return fill


def test_array_is_what_the_public_constructors_make():
    import numpy as np
    import taichi as ti
    from taichi_hh import runtime
    runtime.ensure_init()
    real = runtime.real_dtype()
    for mine, public in ((runtime.array(None, 7), ti.ndarray(real, shape=(7,))),
                         (runtime.array(real, 7, vector=2), ti.Vector.ndarray(2, real, shape=(7,))),
                         (runtime.array(ti.i32, (3, 4)), ti.ndarray(ti.i32, shape=(3, 4)))):
        assert type(mine) is type(public)
        assert mine.shape == public.shape
        assert vars(mine.get_type()) == vars(public.get_type())
        assert np.array_equal(mine.to_numpy(), public.to_numpy())     # zeroed by default
        assert not mine.to_numpy().any()
    # written by a kernel, read back; an unzeroed array is whatever the kernel wrote
    fill = _fill_kernel()
    x, y = runtime.array(None, 5, zeroed=False), runtime.array(None, 5, vector=2, zeroed=False)
    fill(x, y, 5)
    assert np.array_equal(x.to_numpy(), 2.0 * np.arange(5))
    assert np.array_equal(y.to_numpy(), np.arange(5)[:, None] * [1.0, -1.0])
    x.from_numpy(np.full(5, 3.0))
    assert np.array_equal(x.to_numpy(), np.full(5, 3.0))


def test_array_falls_back_to_the_public_constructors(monkeypatch):
    import taichi.lang.enums
    from taichi_hh import runtime
    runtime.ensure_init()
    # another Taichi layout: a name the fast path imports is gone (Taichi's own
    # classes bound it at their import and still work)
    monkeypatch.delattr(taichi.lang.enums, "Layout")
    a = runtime.array(None, 4, zeroed=False)
    b = runtime.array(None, 4, vector=2)
    monkeypatch.undo()
    assert a.shape == (4,) and b.shape == (4,) and b.n == 2
    assert not a.to_numpy().any() and not b.to_numpy().any()      # the public ones: zeroed
