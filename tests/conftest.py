"""One Taichi runtime for the whole test session (CPU, f64).

Re-initialising Taichi frees every array made before, so tests never call
``ti.init``/``ti.reset`` themselves.  The offline kernel cache lives inside the
workspace so that repeated runs (and CI re-runs in the same clone) reuse it.
"""
import os
import pathlib

import pytest

import taichi_hh

CACHE = pathlib.Path(__file__).resolve().parent.parent / ".taichi_cache"


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    arch = os.environ.get("TAICHI_HH_TEST_ARCH", "cpu")
    return taichi_hh.init(arch=arch, precision="f64", offline_cache_dir=str(CACHE))
