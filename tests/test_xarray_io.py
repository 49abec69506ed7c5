"""xarray Datasets in and out (taichi_hh.app.xarray_io): every snapshot
the decomposition of its grid, coordinates and units kept, CF attributes,
a netCDF round trip."""
import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import InputError

xr = pytest.importorskip("xarray")


def _dataset(times=3):
    x = np.linspace(0.0, 2000.0, 33)                 # metres
    y = np.linspace(0.0, 1000.0, 17)
    X, Y = np.meshgrid(x, y)
    u = np.empty((times, len(y), len(x)))
    v = np.empty_like(u)
    for t in range(times):                           # a drifting vortex and a stream
        cx, cy = 700.0 + 200.0 * t, 500.0
        r2 = ((X - cx) ** 2 + (Y - cy) ** 2) / 200.0 ** 2
        swirl = np.exp(-r2)
        u[t] = -(Y - cy) / 200.0 * swirl + 0.3
        v[t] = (X - cx) / 200.0 * swirl
    u[min(1, times - 1), 5, 7] = np.nan                 # a dropout
    ds = xr.Dataset({"u": (("time", "y", "x"), u, {"units": "m/s"}),
                     "v": (("time", "y", "x"), v, {"units": "m/s"})},
                    coords={"time": np.arange(times) * 60.0, "x": ("x", x, {"units": "m"}),
                            "y": ("y", y, {"units": "m"})})
    return ds


def test_every_snapshot_is_its_grid_decomposition():
    ds = _dataset()
    out = thh.decompose_dataset(ds)
    assert out["d_u"].dims == ("time", "y", "x")
    assert np.array_equal(out["x"].values, ds["x"].values)
    for t in range(ds.sizes["time"]):
        ref = thh.decompose_grid(ds["x"].values, ds["y"].values, ds["u"].values[t],
                                 ds["v"].values[t])
        np.testing.assert_array_equal(out["r_u"].values[t], ref.div_free[..., 0])
        np.testing.assert_array_equal(out["phi"].values[t], ref.phi)
        np.testing.assert_array_equal(out["curl"].values[t], ref.curl)
        assert out["boundary_condition"].values[t] == ref.stats["boundary_condition"]
    assert np.isnan(out["h_v"].values[1, 5, 7])           # the dropout stays missing
    # the parts add up to the field where it is valid
    total = out["d_u"] + out["r_u"] + out["h_u"]
    ok = np.isfinite(ds["u"].values)
    assert np.allclose(total.values[ok], ds["u"].values[ok])
    assert out["psi"].attrs["units"] == "m2 s-1" and out["curl"].attrs["units"] == "s-1"
    assert out["d_u"].attrs["units"] == "m/s" and "long_name" in out["phi"].attrs


def test_other_dimension_orders_and_names():
    ds = _dataset(2).rename({"x": "east", "y": "north"}).transpose("east", "time", "north")
    ds["east"].attrs["axis"] = "X"
    out = ds.hhd.decompose(y="north")                     # x found by its axis attribute
    assert out["r_v"].dims == ("time", "north", "east")
    ref = thh.decompose_dataset(_dataset(2))
    np.testing.assert_array_equal(out["r_v"].values, ref["r_v"].values)


def test_netcdf_round_trip(tmp_path):
    pytest.importorskip("scipy")
    out = thh.decompose_dataset(_dataset(2), boundary_condition="natural")
    path = tmp_path / "split.nc"
    out.to_netcdf(path, engine="scipy")
    back = xr.load_dataset(path, engine="scipy")
    for name in ("d_u", "psi", "curl", "energy_ratio"):
        np.testing.assert_array_equal(back[name].values, out[name].values)
        assert back[name].attrs == out[name].attrs
    assert back.attrs["taichi_hh_options"] == "{'boundary_condition': 'natural'}"
    np.testing.assert_array_equal(back["time"].values, out["time"].values)


def test_bad_datasets_are_named():
    ds = _dataset(1)
    with pytest.raises(InputError, match="no variable 'w'"):
        thh.decompose_dataset(ds, u="w")
    with pytest.raises(InputError, match="cannot tell the field's x dimension"):
        thh.decompose_dataset(ds.rename({"x": "col"}))
    lonlat = ds.rename({"x": "lon", "y": "lat"})
    lonlat["lon"].attrs["units"] = "degrees_east"
    with pytest.raises(InputError, match="degrees.*sphere"):
        thh.decompose_dataset(lonlat)
    with pytest.raises(InputError, match="takes an xarray.Dataset"):
        thh.decompose_dataset(ds["u"])
