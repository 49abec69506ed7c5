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
    allowed = os.sched_getaffinity(int(name))
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
def test_workers_are_bound_one_to_a_core():
    cpus = sorted(os.sched_getaffinity(0))
    got = _probe()
    if len(cpus) < 2:
        assert got["pinned"] == [] and got["single"] == []
        return
    # every worker bound, to the usable cores in turn; the caller left free
    assert len(got["pinned"]) == got["workers"]
    assert set(got["pinned"]) == set(cpus[:got["workers"]])
    assert got["single"] == sorted(got["pinned"])
    assert got["main"] == cpus


@needs_affinity
def test_binding_can_be_turned_off():
    for got in (_probe(env={"TAICHI_HH_PIN_THREADS": "0"}), _probe("{'pin_threads': False}")):
        assert got["pinned"] == [] and got["single"] == []


@needs_affinity
def test_one_thread_is_left_unbound():
    got = _probe("{'threads': 1}")
    assert got["workers"] == 1
    assert got["pinned"] == [] and got["single"] == []
