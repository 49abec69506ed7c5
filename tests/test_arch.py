"""The Taichi arch: the session really runs on the arch it asked for
(``$TAICHI_HH_ARCH``, conftest), results say which arch made them, a GPU
request that no device serves is an error rather than a silent CPU run, and
the session's arch gives the CPU's answers.

Cases that start Taichi otherwise than the session run in a fresh interpreter:
re-initialising the session's runtime would free every array of the other
tests.
"""
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh import runtime
from taichi_hh.errors import InputError

from conftest import ARCH

ROOT = pathlib.Path(__file__).resolve().parent.parent
#: a Vulkan loader environment with no driver at all: no Vulkan device
NO_VULKAN = {"VK_ICD_FILENAMES": "/nonexistent/no_icd.json",
             "VK_DRIVER_FILES": "/nonexistent/no_icd.json"}


def _python(code: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=600, cwd=ROOT)


def test_the_session_runs_on_the_requested_arch():
    """The arch Taichi itself reports is the one asked for: a silent fallback
    (Taichi starts the CPU when the asked backend fails) fails here."""
    import taichi as ti
    state = runtime.state()
    assert state.requested_arch == ARCH
    assert state.arch == runtime.taichi_arch()
    if ARCH in ("cpu", "cuda", "vulkan"):
        assert state.arch == ARCH
        assert ti.lang.impl.current_cfg().arch == (ti.cpu if ARCH == "cpu" else getattr(ti, ARCH))
    if state.arch == "vulkan":
        assert state.device                  # the device's name, e.g. llvmpipe (lavapipe)


def _field(n=600, seed=3):
    """The ``trig`` field (Neumann-exact) at n uniformly random points."""
    from taichi_hh.validation import fields
    field = fields.trig()
    p = field.sample(n, kind="random", seed=seed)
    return p, field.evaluate(p).v


#: the solves' tolerance of the comparison with the CPU
TOL = 1e-12

CPU_REFERENCE = r"""
import json, sys, numpy as np, taichi_hh as thh
sys.path.insert(0, "tests")
from test_arch import _field, TOL
thh.init(arch="cpu", precision="f64")
p, v = _field()
dom = thh.Box((0, 0), (1, 1))
res = thh.decompose(p, v, domain=dom, boundary_condition="neumann", tol=TOL)
out = thh.project(p, v, domain=dom, tol=TOL)
print(json.dumps({"d": res.curl_free.tolist(), "r": res.div_free.tolist(),
                  "w": out.vectors.tolist(), "arch": res.stats["arch"]}))
"""


def test_the_session_arch_gives_the_cpus_answers():
    """A decomposition and a projection on the session's arch against the
    same calls on the CPU in a fresh interpreter; the results name the arch
    that made them.  Solved to TOL: the iterates of two archs part at
    rounding, so that each stops at its own point within the solver's
    tolerance (5e-9 apart at the default 1e-8)."""
    p, v = _field()
    dom = thh.Box((0, 0), (1, 1))
    res = thh.decompose(p, v, domain=dom, boundary_condition="neumann", tol=TOL)
    out = thh.project(p, v, domain=dom, tol=TOL)
    assert res.stats["arch"] == out.stats["arch"] == runtime.taichi_arch()
    assert res.stats["precision"] == out.stats["precision"] == "f64"
    proc = _python(CPU_REFERENCE)
    assert proc.returncode == 0, proc.stderr[-3000:]
    cpu = json.loads(proc.stdout.strip().splitlines()[-1])
    assert cpu["arch"] == "cpu"
    scale = np.abs(v).max()
    for name, mine in (("d", res.curl_free), ("r", res.div_free), ("w", out.vectors)):
        assert np.abs(mine - np.array(cpu[name])).max() < 1e-10 * scale, name


MISSING_GPU = r"""
import json, taichi_hh as thh
from taichi_hh import runtime
from taichi_hh.errors import InputError
out = {}
try:
    thh.init(arch="vulkan")
    out["vulkan"] = "started on " + runtime.state().arch
except InputError as exc:
    out["vulkan"] = str(exc)
st = thh.init(arch="auto")
out["auto"] = [st.arch, runtime.taichi_arch()]
print(json.dumps(out))
"""


def test_a_vulkan_request_without_vulkan_is_an_error_not_a_cpu_run():
    """With no Vulkan driver, ``arch="vulkan"`` raises InputError naming the
    backend (Taichi alone would run on the CPU and say so only in a log
    line); ``"auto"`` then takes what there is, and says which."""
    proc = _python(MISSING_GPU, NO_VULKAN)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "arch='vulkan' asks for a GPU backend" in out["vulkan"], out
    assert "no usable vulkan device" in out["vulkan"], out
    arch, reported = out["auto"]
    assert arch == reported and arch in ("cpu", "cuda"), out


def test_the_command_line_refuses_a_missing_gpu_and_names_the_device():
    """``taichi-hh info --arch vulkan`` without Vulkan: status 2 and the
    message; with the session's arch, the arch in use is printed."""
    cmd = [sys.executable, "-m", "taichi_hh", "info", "--arch", "vulkan"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT,
                          env={**os.environ, **NO_VULKAN})
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert "no usable vulkan device" in proc.stderr
    if ARCH in ("cpu", "cuda", "vulkan"):
        cmd[-1] = ARCH
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert f"Taichi arch={ARCH} (requested {ARCH}" in proc.stdout


def test_an_unknown_arch_is_refused_by_name():
    with pytest.raises(InputError, match="arch must be one of .*'vulkan'.*got 'tpu'"):
        thh.init(arch="tpu")


def test_the_direct_sums_logarithm_from_the_bits_is_numpys():
    """The natural decomposition's direct sum takes ln |x|^2 from the float's
    bits on the SPIR-V archs (no f64 log there): on any arch, the same sum
    as numpy's log gives, to round-off."""
    from taichi_hh.geometry.box import Box
    from taichi_hh.hhd import free_space
    grid = free_space.Grid(Box((0.0, 0.0), (1.0, 1.0)), 1 / 24)
    density = np.random.default_rng(5).standard_normal(grid.shape)
    bits = free_space.convolve_direct(grid, density, bitwise_log=True).ravel()
    c = grid.centres()
    q = density.ravel() * grid.hx * grid.hy
    r2 = ((c[:, None, :] - c[None, :, :]) ** 2).sum(axis=2)
    np.fill_diagonal(r2, 1.0)
    weight = np.log(r2) / (4 * np.pi)
    # the cells within EXACT_CELLS: the kernel's exact cell integrals
    E = free_space.EXACT_CELLS
    i = np.rint((c[:, None, 0] - c[None, :, 0]) / grid.hx).astype(int)
    j = np.rint((c[:, None, 1] - c[None, :, 1]) / grid.hy).astype(int)
    near = (np.abs(i) <= E) & (np.abs(j) <= E)
    weight[near] = (grid.near_kernel() / (grid.hx * grid.hy))[i[near] + E, j[near] + E]
    want = weight @ q
    assert np.abs(bits - want).max() < 1e-13 * np.abs(want).max()


def test_a_low_mapping_limit_is_named_before_lavapipe_crashes(tmp_path):
    """lavapipe keeps a memory mapping per kernel launch and segfaults at the
    kernel's limit (docs/arch.md): a low vm.max_map_count is named, with the
    fix; a raised one, or none to read, says nothing."""
    import warnings
    low, high = tmp_path / "low", tmp_path / "high"
    low.write_text("65530\n")
    high.write_text(f"{runtime.LAVAPIPE_MAPPINGS}\n")
    with pytest.warns(RuntimeWarning, match=r"vm\.max_map_count = 65530.*sysctl"):
        assert runtime.check_mapping_limit(str(low)) == 65530
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert runtime.check_mapping_limit(str(high)) == runtime.LAVAPIPE_MAPPINGS
        assert runtime.check_mapping_limit(str(tmp_path / "absent")) is None
