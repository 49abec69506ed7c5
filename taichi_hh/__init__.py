"""taichi_hh: meshless Helmholtz-Hodge decomposition and null-divergence SPH on Taichi.

Importing this package does not initialise Taichi; the first call that needs
it does (CPU, f64), unless :func:`init` chose otherwise.
"""
from .errors import AccuracyWarning, InputError, NeighbourError, SolverError, TaichiHHError

__version__ = "0.1.0"


def __getattr__(name):
    # Submodules load on first use (those with taichi or numpy too: the command
    # line's client imports this package with the standard library only); the
    # name is then kept in the module, as an eager import would have (tools
    # that read the module's namespace, like pdoc, see it).
    if name in ("Box", "Polygon", "as_domain"):
        from .geometry import domain
        value = getattr(domain, name)
    elif name == "init":
        from .runtime import init as value
    elif name == "PointSet":
        from .sph.pointset import PointSet as value
    elif name in ("decompose", "HHDResult", "METHODS"):
        from .hhd import decompose as hhd
        value = getattr(hhd, name)
    elif name in ("decompose_grid", "GridResult"):
        from .hhd import grid
        value = getattr(grid, name)
    elif name in ("decompose_lonlat", "LonLatResult"):
        from .hhd import lonlat
        value = getattr(lonlat, name)
    elif name == "decompose_lonlat_dataset":
        from .app.xarray_lonlat import decompose_lonlat_dataset as value
    elif name in ("Decomposer", "SeriesResult", "GridDecomposer", "GridSeries"):
        from .hhd import decomposer
        value = getattr(decomposer, name)
    elif name == "decompose_dataset":
        from .app.xarray_io import decompose_dataset as value
    elif name in ("project", "ProjectionResult"):
        from .hhd import project as projection
        value = getattr(projection, name)
    else:
        raise AttributeError(f"module 'taichi_hh' has no attribute {name!r}")
    globals()[name] = value
    return value


__all__ = ["init", "Box", "Polygon", "as_domain", "decompose", "HHDResult", "decompose_grid", "GridResult", "decompose_lonlat", "LonLatResult", "decompose_lonlat_dataset", "Decomposer", "SeriesResult", "GridDecomposer", "GridSeries", "decompose_dataset", "project", "ProjectionResult", "PointSet", "InputError", "NeighbourError", "SolverError", "TaichiHHError", "AccuracyWarning"]
