"""Winds on a longitude-latitude grid held by xarray (ERA5, CF model output):
streamfunction and velocity potential as a Dataset.

    import taichi_hh
    out = taichi_hh.decompose_lonlat_dataset(era5, u="u", v="v")   # or ds.hhd.decompose_lonlat()
    out.to_netcdf("sfvp.nc")

The horizontal dimensions are found by name (``longitude``/``latitude``,
``lon``/``lat``), by CF ``units`` (``degrees_east``, ``degrees_north``) or
``standard_name``, or given (``lon="x"``, ``lat="y"``); every other dimension
(time, level) is one snapshot each, decomposed by
:func:`~taichi_hh.hhd.lonlat.decompose_lonlat` with NaN as missing (land).
The result keeps the other dimensions and the horizontal coordinates (of
``region`` when one is cut) and holds, with CF names and units (m/s winds on
the earth: potentials in m2 s-1):

=====================  ==========================================  ================
variable               standard_name                               part
=====================  ==========================================  ================
``streamfunction``     atmosphere_horizontal_streamfunction        psi
``velocity_potential`` atmosphere_horizontal_velocity_potential    chi
``u_chi``, ``v_chi``   (long_name: divergent wind)                 grad chi
``u_psi``, ``v_psi``   (long_name: rotational wind)                k x grad psi
``u_harmonic`` ...     (long_name: harmonic wind)                  the rest
``divergence``         divergence_of_wind                          div u
``vorticity``          atmosphere_relative_vorticity               curl u
=====================  ==========================================  ================
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .xarray_io import vector_variables

__all__ = ["decompose_lonlat_dataset", "lonlat_dims", "VARIABLES"]

#: output variable -> (LonLatResult attribute, component or None, CF standard name,
#: long name, units kind: "potential" | "wind" | "rate")
VARIABLES = {
    "streamfunction": ("streamfunction", None, "atmosphere_horizontal_streamfunction",
                       "streamfunction psi (rotational wind = k x grad psi)", "potential"),
    "velocity_potential": ("velocity_potential", None,
                           "atmosphere_horizontal_velocity_potential",
                           "velocity potential chi (divergent wind = grad chi)", "potential"),
    "u_chi": ("curl_free", 0, None, "eastward divergent wind", "wind"),
    "v_chi": ("curl_free", 1, None, "northward divergent wind", "wind"),
    "u_psi": ("div_free", 0, None, "eastward rotational wind", "wind"),
    "v_psi": ("div_free", 1, None, "northward rotational wind", "wind"),
    "u_harmonic": ("harmonic", 0, None, "eastward harmonic wind (neither potential's)",
                   "wind"),
    "v_harmonic": ("harmonic", 1, None, "northward harmonic wind (neither potential's)",
                   "wind"),
    "divergence": ("divergence", None, "divergence_of_wind", "divergence of the wind",
                   "rate"),
    "vorticity": ("vorticity", None, "atmosphere_relative_vorticity",
                  "relative vorticity of the wind", "rate"),
}
_LON_NAMES = ("longitude", "lon")
_LAT_NAMES = ("latitude", "lat")
_LON_UNITS = ("degrees_east", "degree_east", "degrees_e", "degreese")
_LAT_UNITS = ("degrees_north", "degree_north", "degrees_n", "degreesn")
_SI_SPEED = ("m/s", "m s-1", "m.s-1", "m s**-1")


def lonlat_dims(ds, da=None, lon: str | None = None, lat: str | None = None):
    """``(lon_dim, lat_dim)`` of ``da`` (default: any of ``ds``'s
    dimensions), or None when none looks like longitude and latitude."""
    dims = list(da.dims if da is not None else ds.dims)

    def find(given, names, units, standard):
        if given is not None:
            if given not in dims:
                raise InputError(f"{given!r} is not a dimension of the field {tuple(dims)}")
            return given
        for d in dims:
            if str(d).lower() in names:
                return d
        for d in dims:
            c = ds.coords.get(d)
            if c is None:
                continue
            unit = str(c.attrs.get("units", "")).strip().lower()
            if unit in units or str(c.attrs.get("standard_name", "")).lower() == standard:
                return d
        return None
    x = find(lon, _LON_NAMES, _LON_UNITS, "longitude")
    y = find(lat, _LAT_NAMES, _LAT_UNITS, "latitude")
    if x is None or y is None or x == y:
        return None
    return x, y


def decompose_lonlat_dataset(ds, u: str = "u", v: str = "v", *, lon: str | None = None,
                             lat: str | None = None, radius: float | None = None,
                             region=None, **options):
    """The decomposition of the winds ``ds[u]`` (eastward), ``ds[v]``
    (northward) on the sphere (module doc); ``radius`` default the earth's
    (metres); ``region``, ``options`` as
    :func:`~taichi_hh.hhd.lonlat.decompose_lonlat` takes them.  Returns an
    ``xarray.Dataset``."""
    try:
        import xarray as xr
    except ImportError:
        raise InputError("decompose_lonlat_dataset needs xarray: pip install xarray") from None
    from ..hhd.lonlat import EARTH_RADIUS, decompose_lonlat
    U, V = vector_variables(ds, u, v, "decompose_lonlat_dataset", "wind components")
    found = lonlat_dims(ds, U, lon, lat)
    if found is None:
        raise InputError(f"cannot tell the longitude and latitude dimensions among {U.dims}: "
                         "name them longitude/latitude or lon/lat, give their coordinates "
                         "units degrees_east/degrees_north, or pass lon=..., lat=...")
    xdim, ydim = found
    others = [d for d in U.dims if d not in (xdim, ydim)]
    order = others + [ydim, xdim]
    U, V = U.transpose(*order), V.transpose(*order)
    lon_axis = _coordinate(ds, xdim)
    lat_axis = _coordinate(ds, ydim)
    res = decompose_lonlat(lon_axis, lat_axis, np.asarray(U.values, dtype=np.float64),
                           np.asarray(V.values, dtype=np.float64),
                           EARTH_RADIUS if radius is None else radius, region=region, **options)
    coords = {c: ds.coords[c] for c in ds.coords
              if set(ds.coords[c].dims) <= set(others)}
    coords[xdim] = (xdim, res.lon, dict(ds.coords[xdim].attrs))
    coords[ydim] = (ydim, res.lat, dict(ds.coords[ydim].attrs))
    out = xr.Dataset(coords=coords)
    units = _units(U, radius)
    for name, (attr, k, standard, long_name, kind) in VARIABLES.items():
        value = getattr(res, attr)
        attrs = {"long_name": long_name}
        if standard:
            attrs["standard_name"] = standard
        if units[kind]:
            attrs["units"] = units[kind]
        out[name] = (order, value if k is None else value[..., k], attrs)
    stats = res.stats.get("snapshots", [res.stats])
    conditions = np.array([s.get("boundary_condition", "") for s in stats], dtype=str)
    out["boundary_condition"] = (others, conditions.reshape([ds.sizes[d] for d in others]),
                                 {"long_name": "boundary condition of the decomposition"})
    out.attrs.update({
        "title": f"streamfunction and velocity potential of ({u}, {v}) over a region",
        "source": "taichi_hh.decompose_lonlat_dataset (stereographic map centred at "
                  f"{res.projection.lon0:.3f}E, {res.projection.lat0:.3f}N)",
        "Conventions": "CF-1.8",
        "taichi_hh_options": repr(dict(sorted(options.items()))),
    })
    return out


def _coordinate(ds, dim) -> np.ndarray:
    if dim not in ds.coords:
        raise InputError(f"the dimension {dim!r} has no coordinate: longitude and latitude "
                         "values in degrees are needed")
    values = np.asarray(ds.coords[dim].values)
    if values.dtype.kind not in "iuf":
        raise InputError(f"the coordinate {dim!r} must be numeric degrees, got {values.dtype}")
    return values.astype(np.float64)


def _units(U, radius) -> dict:
    """Units of the outputs from the wind's (SI winds on the earth in metres:
    m2 s-1 and s-1)."""
    speed = str(U.attrs.get("units", "")).strip()
    si = speed in _SI_SPEED and radius is None
    if si:
        return {"potential": "m2 s-1", "wind": speed, "rate": "s-1"}
    return {"potential": f"({speed}) (radius unit)" if speed else "",
            "wind": speed, "rate": f"({speed}) / (radius unit)" if speed else ""}


# --------------------------------------------------------------------------- files

#: names of the eastward and northward components tried in a file, in order
#: (ERA5's u, v and u10, v10; CF standard names are tried after these)
WIND_NAMES = (("u", "v"), ("u10", "v10"), ("uo", "vo"), ("ugos", "vgos"), ("U", "V"))
_STANDARD = (("eastward_wind", "northward_wind"),
             ("eastward_sea_water_velocity", "northward_sea_water_velocity"))


def is_lonlat_file(path) -> bool:
    """Whether ``path`` is a netCDF file whose variables lie on longitude and
    latitude (by name or CF units): what ``taichi-hh decompose FILE.nc`` sends
    to :func:`decompose_lonlat_file` without ``--lonlat``."""
    if not str(path).lower().endswith((".nc", ".nc4", ".netcdf")):
        return False
    try:
        import xarray as xr
        with xr.open_dataset(path) as ds:
            return lonlat_dims(ds) is not None
    except Exception:          # unreadable here: the ordinary readers say why
        return False


def wind_names(ds) -> tuple:
    """``(u, v)``: the dataset's eastward and northward components."""
    for u, v in WIND_NAMES:
        if u in ds.data_vars and v in ds.data_vars:
            return u, v
    for east, north in _STANDARD:
        found = [next((n for n in ds.data_vars if ds[n].attrs.get("standard_name") == s), None)
                 for s in (east, north)]
        if None not in found:
            return tuple(found)
    raise InputError(f"cannot tell the eastward and northward components among "
                     f"{', '.join(map(str, ds.data_vars)) or 'no variables'}: name them u and v "
                     "(or u10/v10, uo/vo), or give them CF standard names eastward_wind and "
                     "northward_wind")


def decompose_lonlat_file(path, out_dir: str, *, figures: bool = True, **options) -> tuple:
    """``taichi-hh decompose FILE.nc --lonlat``: the winds of a netCDF file
    on longitude and latitude decomposed on the sphere
    (:func:`decompose_lonlat_dataset`), written to ``out_dir/lonlat.nc`` and,
    with ``figures``, ``out_dir/lonlat.png`` (streamfunction and velocity
    potential of the first snapshot).  Returns ``(written paths, summary)``."""
    import os
    try:
        import xarray as xr
    except ImportError:
        raise InputError("netCDF files need xarray: pip install 'taichi-hh[xarray]'") from None
    from . import io
    try:
        ds = xr.open_dataset(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read it as netCDF ({exc})") from None
    with ds:
        u, v = wind_names(ds)
        out = decompose_lonlat_dataset(ds.load(), u, v, **options)
    target = os.path.join(out_dir, "lonlat.nc")
    with io.atomic_path(target, ".nc") as tmp:
        out.to_netcdf(tmp)
    written = [target]
    if figures:
        from .lonlat_figure import streamfunction_figure
        written.append(streamfunction_figure(out, os.path.join(out_dir, "lonlat.png")))
    sf = out["streamfunction"]
    first = {d: 0 for d in sf.dims[:-2]}
    conditions = sorted(set(np.asarray(out["boundary_condition"].values).ravel().tolist()))
    summary = (f"Decomposed ({u}, {v}) of {path} on the sphere: {sf.shape[-1]} x "
               f"{sf.shape[-2]} longitudes x latitudes, {int(np.prod(sf.shape[:-2]))} "
               f"snapshot(s), condition {', '.join(conditions)}; streamfunction "
               f"{float(sf.isel(first).min()):.3g} to {float(sf.isel(first).max()):.3g} "
               f"{sf.attrs.get('units', '')}. Wrote {', '.join(written)}.")
    return written, summary
