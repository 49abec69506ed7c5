"""One Taichi runtime for the whole test session (f64; the CPU arch unless
``$TAICHI_HH_ARCH`` names another: ``vulkan`` in CI's Vulkan run).

Re-initialising Taichi frees every array made before, so tests never call
``ti.init``/``ti.reset`` themselves; a test that re-initialised Taichi on
another arch would leave every later test there, so each test is followed by
a check that Taichi still runs on the session's arch.  The offline kernel
cache lives inside the workspace so that repeated runs (and CI re-runs in the
same clone) reuse it.
"""
import importlib.util
import os
import pathlib

import pytest

import taichi_hh
from taichi_hh import runtime

ROOT = pathlib.Path(__file__).resolve().parent.parent
CACHE = ROOT / ".taichi_cache"
#: the arch the session asks for
ARCH = os.environ.get("TAICHI_HH_ARCH", "cpu")


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    return taichi_hh.init(arch=ARCH, precision="f64", offline_cache_dir=str(CACHE))


@pytest.fixture(autouse=True)
def _session_arch_kept(taichi_runtime):
    """After each test: Taichi still on the session's arch (not re-initialised
    elsewhere by the test)."""
    arch = taichi_runtime.arch
    yield
    assert runtime.taichi_arch() == arch, \
        f"the test left Taichi on {runtime.taichi_arch()}, the session runs on {arch}"


def pytest_report_header(config):
    return f"taichi_hh arch requested: {ARCH} (TAICHI_HH_ARCH)"


@pytest.fixture(scope="session")
def scene_module():
    """Loads a scene script ``scenes/<name>.py`` as a module (its ``SCENE``,
    ``build``, ``add_arguments``, ...): the scenes are scripts, not a package."""
    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"scene_{name}",
                                                      ROOT / "scenes" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    return load
