"""The figure of a decomposition on the sphere: streamfunction and velocity
potential over the region, with the rotational and divergent winds as
arrows (matplotlib, Agg); coastlines when cartopy is installed."""
from __future__ import annotations

import numpy as np

__all__ = ["streamfunction_figure"]


def streamfunction_figure(ds, path: str, *, arrows: int = 18) -> str:
    """Two panels of the first snapshot of ``ds`` (from
    :func:`~taichi_hh.app.xarray_lonlat.decompose_lonlat_dataset`):
    streamfunction with the rotational wind, velocity potential with the
    divergent wind; ``arrows`` per side.  Writes ``path``; returns it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from .xarray_lonlat import lonlat_dims
    sf = ds["streamfunction"]
    xdim, ydim = lonlat_dims(ds, sf)
    first = {d: 0 for d in sf.dims if d not in (xdim, ydim)}
    lon = np.degrees(np.unwrap(np.radians(ds[xdim].values)))
    lat = ds[ydim].values
    try:
        import cartopy.crs as ccrs
        projection = ccrs.PlateCarree()
    except ImportError:
        ccrs = projection = None
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), constrained_layout=True,
                             subplot_kw={"projection": projection} if projection else {})
    panels = (("streamfunction", "u_psi", "v_psi", "streamfunction and rotational wind"),
              ("velocity_potential", "u_chi", "v_chi",
               "velocity potential and divergent wind"))
    sy = max(len(lat) // arrows, 1)
    sx = max(len(lon) // arrows, 1)
    for ax, (name, un, vn, title) in zip(axes, panels):
        field = ds[name].isel(first).transpose(ydim, xdim).values / 1e6
        extra = {"transform": ccrs.PlateCarree()} if projection else {}
        mesh = ax.contourf(lon, lat, field, levels=21, cmap="RdBu_r", **extra)
        u = ds[un].isel(first).transpose(ydim, xdim).values
        v = ds[vn].isel(first).transpose(ydim, xdim).values
        ax.quiver(lon[::sx], lat[::sy], u[::sy, ::sx], v[::sy, ::sx], **extra)
        if projection:
            ax.coastlines(linewidth=0.6)
        ax.set_title(title)
        ax.set_xlabel("longitude (degrees east)")
        ax.set_ylabel("latitude (degrees north)")
        fig.colorbar(mesh, ax=ax, shrink=0.85,
                     label=f"{name.replace('_', ' ')} (10^6 {ds[name].attrs.get('units', '')})")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
