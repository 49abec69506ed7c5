"""taichi_hh: meshless Helmholtz-Hodge decomposition and null-divergence SPH on Taichi.

Importing this package does not initialise Taichi; the first call that needs
it does (CPU, f64), unless :func:`init` chose otherwise.
"""
from .errors import InputError, NeighbourError, SolverError, TaichiHHError
from .runtime import init

__version__ = "0.1.0"


def __getattr__(name):
    # Heavy submodules (they import taichi) load on first use.
    if name == "PointSet":
        from .pointset import PointSet
        return PointSet
    raise AttributeError(f"module 'taichi_hh' has no attribute {name!r}")


__all__ = ["init", "PointSet", "InputError", "NeighbourError", "SolverError", "TaichiHHError"]
