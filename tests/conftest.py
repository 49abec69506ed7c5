"""One Taichi runtime for the whole test session (CPU, f64).

Re-initialising Taichi frees every array made before, so tests never call
``ti.init``/``ti.reset`` themselves.  The offline kernel cache lives inside the
workspace so that repeated runs (and CI re-runs in the same clone) reuse it.
"""
import importlib.util
import os
import pathlib

import pytest

import taichi_hh

ROOT = pathlib.Path(__file__).resolve().parent.parent
CACHE = ROOT / ".taichi_cache"


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    arch = os.environ.get("TAICHI_HH_TEST_ARCH", "cpu")
    return taichi_hh.init(arch=arch, precision="f64", offline_cache_dir=str(CACHE))


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
