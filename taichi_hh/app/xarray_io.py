"""Gridded fields held by xarray (netCDF, zarr, model output, pivpy): the
decomposition as a Dataset in, a Dataset out.

    import taichi_hh
    out = taichi_hh.decompose_dataset(ds, u="u", v="v")     # or ds.hhd.decompose(...)
    out.to_netcdf("split.nc")

``ds`` holds ``u`` and ``v`` on a rectilinear ``x``, ``y`` grid and any
other dimensions (time, depth, ensemble member): every combination of the
other dimensions is one snapshot, decomposed as
:func:`~taichi_hh.hhd.grid.decompose_grid` does it with NaN as missing,
through one :class:`~taichi_hh.hhd.decomposer.GridDecomposer` (what
depends on the grid made once, snapshots solved together).  The result
keeps the input's dimensions, coordinates and order, and holds ``d_u``,
``d_v`` (the curl-free part), ``r_u``, ``r_v`` (the divergence-free part),
``h_u``, ``h_v`` (the harmonic part), ``phi``, ``psi``, ``divergence`` and
``curl``, with CF attributes (``long_name``, ``units`` derived from the
input's: potentials in velocity x length, derivatives in velocity per
length), per snapshot the condition used and the energy ratio, and the
options as attributes.

The spatial dimensions are found by name (``x``/``y``), by a coordinate's
CF ``axis`` attribute (``X``/``Y``), or given (``x="east"``, ``y="north"``).
Longitude and latitude (degrees) are refused: the plane's operators are not
the sphere's (issue 33).  xarray is an optional dependency: ``pip install
xarray`` (netCDF files need one of its engines: netCDF4, h5netcdf or scipy).
"""
from __future__ import annotations

import itertools
import warnings

import numpy as np

from ..errors import InputError

__all__ = ["decompose_dataset", "COMPONENTS"]

#: output variable -> (GridResult attribute, component index or None, long name)
COMPONENTS = {
    "d_u": ("curl_free", 0, "curl-free part d = grad phi, x component"),
    "d_v": ("curl_free", 1, "curl-free part d = grad phi, y component"),
    "r_u": ("div_free", 0, "divergence-free part r = J grad psi, x component"),
    "r_v": ("div_free", 1, "divergence-free part r = J grad psi, y component"),
    "h_u": ("harmonic", 0, "harmonic part h = v - d - r, x component"),
    "h_v": ("harmonic", 1, "harmonic part h = v - d - r, y component"),
    "phi": ("phi", None, "scalar potential phi (velocity potential), d = grad phi"),
    "psi": ("psi", None, "stream function psi, r = (d psi/dy, -d psi/dx)"),
    "divergence": ("divergence", None, "divergence of the field"),
    "curl": ("curl", None, "curl (vorticity) of the field"),
}
_DEGREES = ("degrees_east", "degree_east", "degrees_e", "degreese", "degrees_north",
            "degree_north", "degrees_n", "degreesn", "degrees", "degree", "deg")
_LONLAT = ("lon", "longitude", "lat", "latitude")


def _xarray():
    try:
        import xarray
    except ImportError:
        raise InputError("decompose_dataset needs xarray: pip install xarray") from None
    return xarray


def decompose_dataset(ds, u: str = "u", v: str = "v", *, x: str | None = None,
                      y: str | None = None, **options):
    """The Helmholtz-Hodge decomposition of ``ds[u]``, ``ds[v]`` (module
    doc); ``options`` as :func:`~taichi_hh.hhd.grid.decompose_grid` takes
    them.  Returns an ``xarray.Dataset``."""
    xr = _xarray()
    U, V = vector_variables(ds, u, v, "decompose_dataset", "components")
    xdim, ydim = _spatial_dims(ds, U, x, y)
    for dim in (xdim, ydim):
        _refuse_degrees(ds, dim)
    others = [d for d in U.dims if d not in (xdim, ydim)]
    order = others + [ydim, xdim]
    U, V = U.transpose(*order), V.transpose(*order)
    xs = _axis(ds, xdim)
    ys = _axis(ds, ydim)
    from ..hhd.decomposer import GridDecomposer
    shape = tuple(ds.sizes[d] for d in others)
    arrays = {name: np.full(shape + (len(ys), len(xs)), np.nan) for name in COMPONENTS}
    conditions = np.empty(shape, dtype=object)
    energy = np.full(shape, np.nan)
    u_values = np.asarray(U.values, dtype=np.float64)
    v_values = np.asarray(V.values, dtype=np.float64)
    # every snapshot on the same grid: what depends on the grid and the missing
    # nodes made once, the snapshots solved together (each as decompose_grid's)
    indices = list(itertools.product(*(range(n) for n in shape)))
    snapshots = GridDecomposer(xs, ys, **options).stream(
        (u_values[index], v_values[index]) for index in indices)
    for index, res in zip(indices, snapshots):
        for name, (attr, k, _) in COMPONENTS.items():
            value = getattr(res, attr)
            arrays[name][index] = value if k is None else value[..., k]
        conditions[index] = res.stats.get("boundary_condition", "")
        energy[index] = res.stats.get("energy_ratio", np.nan)
    units = _units(U, ds, xdim)
    out = xr.Dataset(coords={c: ds.coords[c] for c in ds.coords
                             if set(ds.coords[c].dims) <= set(order)})
    for name, (_, _, long_name) in COMPONENTS.items():
        out[name] = (order, arrays[name], {"long_name": long_name,
                                           **({"units": units[name]} if units[name] else {})})
    out["boundary_condition"] = (others, conditions.astype(str),
                                 {"long_name": "boundary condition of the decomposition"})
    out["energy_ratio"] = (others, energy, {
        "long_name": "(|d|^2 + |r|^2 + |h|^2) / |v|^2 over the decomposed nodes",
        "units": "1"})
    out.attrs.update({
        "title": f"Helmholtz-Hodge decomposition of ({u}, {v})",
        "source": "taichi_hh.decompose_dataset",
        "Conventions": "CF-1.8",
        "taichi_hh_options": repr(dict(sorted(options.items()))),
    })
    return out


def vector_variables(ds, u: str, v: str, caller: str, what: str) -> tuple:
    """``(U, V)``: the Dataset ``ds``'s variables ``u`` and ``v`` (the vector's
    ``what``, named in the messages), checked: a Dataset, both present, the
    same dimensions (InputError naming ``caller``)."""
    xr = _xarray()
    if not isinstance(ds, xr.Dataset):
        raise InputError(f"{caller} takes an xarray.Dataset, got {type(ds).__name__}")
    for name in (u, v):
        if name not in ds.data_vars:
            raise InputError(f"the dataset has no variable {name!r} (its variables: "
                             f"{', '.join(map(str, ds.data_vars)) or 'none'}); name the "
                             f"{what} with u=..., v=...")
    U, V = ds[u], ds[v]
    if U.dims != V.dims:
        raise InputError(f"{u!r} and {v!r} have different dimensions: {U.dims} and {V.dims}")
    return U, V


def _spatial_dims(ds, da, x, y) -> tuple:
    def find(given, name, axis):
        if given is not None:
            if given not in da.dims:
                raise InputError(f"{given!r} is not a dimension of the field {da.dims}")
            return given
        if name in da.dims:
            return name
        for d in da.dims:
            if d in ds.coords and str(ds.coords[d].attrs.get("axis", "")).upper() == axis:
                return d
        for d in da.dims:
            if str(d).lower() in (_LONLAT[:2] if axis == "X" else _LONLAT[2:]):
                return d
        raise InputError(f"cannot tell the field's {name} dimension among {da.dims}: name it "
                         f"{name}, give its coordinate axis='{axis}', or pass {name}=...")
    xdim, ydim = find(x, "x", "X"), find(y, "y", "Y")
    if xdim == ydim:
        raise InputError(f"x and y are the same dimension {xdim!r}")
    return xdim, ydim


def _refuse_degrees(ds, dim) -> None:
    coord = ds.coords.get(dim)
    unit = str(coord.attrs.get("units", "")).strip().lower() if coord is not None else ""
    if unit in _DEGREES or (not unit and str(dim).lower() in _LONLAT):
        raise InputError(f"the dimension {dim!r} is in degrees (longitude or latitude): the "
                         "plane's decomposition would ignore the sphere's metric (cos(latitude), "
                         "the earth's radius; 17% error on a 60 x 35 degree region); use "
                         "decompose_lonlat_dataset (ds.hhd.decompose_lonlat) or give "
                         "projected coordinates in length units")


def _axis(ds, dim) -> np.ndarray:
    if dim not in ds.coords:
        return np.arange(ds.sizes[dim], dtype=np.float64)
    values = np.asarray(ds.coords[dim].values)
    if values.dtype.kind not in "iuf":
        raise InputError(f"the coordinate {dim!r} must be numeric, got {values.dtype}")
    return values.astype(np.float64)


def _units(U, ds, xdim) -> dict:
    """Units of each output variable from the velocity's and the length's."""
    velocity = str(U.attrs.get("units", "")).strip()
    coord = ds.coords.get(xdim)
    length = str(coord.attrs.get("units", "")).strip() if coord is not None else ""
    si = velocity in ("m/s", "m s-1", "m.s-1") and length in ("m", "meter", "metre", "meters",
                                                              "metres")
    potential = "m2 s-1" if si else (f"({velocity}) ({length})" if velocity and length else "")
    derivative = "s-1" if si else (f"({velocity}) / ({length})" if velocity and length else "")
    out = {}
    for name in COMPONENTS:
        if name in ("phi", "psi"):
            out[name] = potential
        elif name in ("divergence", "curl"):
            out[name] = derivative
        else:
            out[name] = velocity
    return out


def _register_accessor() -> None:
    """``ds.hhd.decompose(u="u", v="v", **options)`` once xarray is imported
    with this module."""
    try:
        import xarray as xr
    except ImportError:
        return

    class HHDAccessor:
        def __init__(self, ds):
            self._ds = ds

        def decompose(self, u: str = "u", v: str = "v", **kwargs):
            return decompose_dataset(self._ds, u, v, **kwargs)

        def decompose_lonlat(self, u: str = "u", v: str = "v", **kwargs):
            from .xarray_lonlat import decompose_lonlat_dataset
            return decompose_lonlat_dataset(self._ds, u, v, **kwargs)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # re-registration on a module reload
        xr.register_dataset_accessor("hhd")(HHDAccessor)


_register_accessor()
