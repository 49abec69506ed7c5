"""Winds on the sphere over a limited area (issue 33): decompose_lonlat
against the exact split and against a spherical-harmonic peer.

For regions from 10 x 10 to 80 x 60 degrees (longitude x latitude, centred
at 70W, 42.5N): winds whose streamfunction and velocity potential are
compactly supported bumps inside the region (the exact split under every
boundary condition; taichi_hh/validation/sphere.py), sampled

* on a 0.25 degree grid with NaN land (blobs over calm air, 15% of the
  nodes: the exact split stays the field's);
* at 15 000 scattered points (uniform on the sphere's area): without land
  (the points' box is the domain), and with the grid's land blobs (the
  points over them dropped; the domain the coast given as rings in degrees,
  or the points' alpha shape at 2 and 3 (the default) local spacings).

The bumps' radii are 0.28-0.4 of the region's smaller side, at most 8
degrees, more bumps in larger regions (each 0.7-1 times that): a 10 x 10
region's 2.0-2.6 degree bumps span 8-10 grid steps of radius, a 60 x 35
region's 5.9-6.8 degree ones 24-27.  Where that resolution, or the
scattered points' spacing (0.5 degrees at 15 000 over 80 x 60), limits the
error, the refinement rows show it: the 10 x 10 grid at 0.25, 0.125 and
0.0625 degrees, the 80 x 60 region at 15 000 to 120 000 points.

The same field plus a stream through the region (curl-free and
divergence-free on the sphere: harmonic_stream) is a window of a larger flow:
the default condition chooses natural, whose exact answer it still is (the
stream all harmonic); on the calm-edged field alone it chooses natural too
(no flow next to the edges, across them or along them: no wall in the data;
it chose no-flux before, whose solve errs 4-5 times more on random points).

Errors: mean |part - exact| over the mean |exact part| of each wind (the
rotational k x grad psi and the divergent grad chi), and the same over the
mean |u|; against the peer likewise.  The peer: skyborn.windspharm (a
compiled port of windspharm, spherical harmonics on the whole globe) on the
global 0.25 degree grid of the same field (its vorticity and divergence lie
inside the region), compared on the region's nodes.  Also: the plane's
decomposition of the same grid with degrees as x and y (what a user without
the sphere gets), and the timing target: a 1440 x 721 global grid restricted
to a 90 x 60 degree region (default options; a jet and vortices crossing the
region's edges), median of 3 calls after a warm-up.

    python benchmarks/lonlat.py                     # all regions, CSV to outputs/benchmarks/
    python benchmarks/lonlat.py --regions 60x35 --no-peer
    python benchmarks/lonlat.py --regions "" --no-timing   # the refinement rows only
    python benchmarks/lonlat.py --figure            # also docs/figures/lonlat.png (README's)
"""
from __future__ import annotations

import argparse
import time
import warnings

import _common

_common.add_repo_to_path()

import numpy as np  # noqa: E402

OUT = _common.REPO_ROOT / "outputs" / "benchmarks"
CENTRE = (-70.0, 42.5)
FIELDS = ["region", "layout", "n", "condition", "chosen", "rot_err", "div_err", "rot_err_v",
          "div_err_v", "rot_vs_peer", "div_vs_peer", "peer_rot_err", "peer_div_err",
          "max_map_factor", "seconds"]


def region_bounds(size: str) -> tuple:
    w, h = (float(s) for s in size.split("x"))
    return CENTRE[0] - w / 2, CENTRE[0] + w / 2, CENTRE[1] - h / 2, CENTRE[1] + h / 2


def errors(got, exact, scale_v) -> tuple:
    ok = np.isfinite(got).all(axis=-1)
    diff = np.linalg.norm(got[ok] - exact[ok], axis=-1).mean()
    return diff / np.linalg.norm(exact[ok], axis=-1).mean(), diff / scale_v


def scattered_row(size, n: int, condition: str, s, seconds: float, exact, scale_v) -> dict:
    """A scattered case's row (errors of the rotational and divergent winds
    against ``exact``'s, over their own mean and over ``scale_v``), printed."""
    row = dict(region=size, layout="scattered", n=n, condition=condition,
               chosen=s.stats.get("boundary_condition"), seconds=seconds,
               max_map_factor=s.stats["max_map_factor"])
    row["rot_err"], row["rot_err_v"] = errors(s.div_free, np.c_[exact["u_psi"], exact["v_psi"]],
                                              scale_v)
    row["div_err"], row["div_err_v"] = errors(s.curl_free, np.c_[exact["u_chi"], exact["v_chi"]],
                                              scale_v)
    print(f"  {size} scattered {condition}: rot {row['rot_err']:.2e} "
          f"div {row['div_err']:.2e} ({row['chosen']}, {seconds:.2f} s)")
    return row


def peer_split(field, step: float):
    """The peer's (rotational, divergent) winds on the global grid and the grid."""
    from skyborn.windspharm.standard import VectorWind
    lon = np.arange(0.0, 360.0, step)
    lat = np.linspace(90.0, -90.0, int(round(180.0 / step)) + 1)
    w = field.evaluate(*np.meshgrid(lon, lat))
    vw = VectorWind(w["u"], w["v"], rsphere=field.radius)
    up, vp = vw.nondivergentcomponent()
    uc, vc = vw.irrotationalcomponent()
    return lon, lat, np.stack([up, vp], -1), np.stack([uc, vc], -1)


def on_peer_grid(peer, lon, lat):
    """The peer's parts at the nodes (lon, lat) of its grid."""
    plon, plat, rot, div = peer
    ii = np.rint(((np.asarray(lon) % 360.0) / (plon[1] - plon[0]))).astype(int) % len(plon)
    jj = np.rint((90.0 - np.asarray(lat)) / (plat[0] - plat[1])).astype(int)
    return rot[jj][:, ii], div[jj][:, ii]


def run_region(size, args, rows):
    from taichi_hh.hhd.lonlat import decompose_lonlat
    from taichi_hh.validation.sphere import harmonic_stream, land_mask, regional_field
    lo0, lo1, la0, la1 = region_bounds(size)
    field = regional_field(lo0, lo1, la0, la1, seed=11, max_width=8.0)
    step = 0.25
    lon = np.arange(lo0, lo1 + 1e-9, step)
    lat = np.arange(la1, la0 - 1e-9, -step)
    LON, LAT = np.meshgrid(lon, lat)
    w = field.evaluate(LON, LAT)
    land = land_mask(lon, lat, field, seed=5, fraction=0.15)
    exact_rot = np.stack([w["u_psi"], w["v_psi"]], -1)
    exact_div = np.stack([w["u_chi"], w["v_chi"]], -1)
    scale = np.hypot(w["u"], w["v"])[~land].mean()
    peer = None
    if not args.no_peer:
        t = time.perf_counter()
        peer = peer_split(field, step)
        peer_seconds = time.perf_counter() - t
        p_rot, p_div = on_peer_grid(peer, lon, lat)
        p_rot[land] = np.nan
        p_div[land] = np.nan
        rows.append(dict(region=size, layout="grid 0.25", n=int((~land).sum()),
                         condition="peer (skyborn.windspharm, global)", chosen="",
                         rot_err=errors(p_rot, exact_rot, scale)[0],
                         div_err=errors(p_div, exact_div, scale)[0],
                         rot_err_v=errors(p_rot, exact_rot, scale)[1],
                         div_err_v=errors(p_div, exact_div, scale)[1],
                         seconds=peer_seconds))
        print(f"  {size} peer: {peer_seconds:.2f} s")
    u = np.where(land, np.nan, w["u"])
    v = np.where(land, np.nan, w["v"])
    for condition in args.conditions:
        opts = {} if condition == "default" else {"boundary_condition": condition}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            decompose_lonlat(lon, lat, u, v, **opts)         # warm-up (compiles)
            t = time.perf_counter()
            g = decompose_lonlat(lon, lat, u, v, **opts)
            seconds = time.perf_counter() - t
        row = dict(region=size, layout="grid 0.25", n=int(g.used.sum()), condition=condition,
                   chosen=g.stats.get("boundary_condition"), seconds=seconds,
                   max_map_factor=g.stats["max_map_factor"])
        row["rot_err"], row["rot_err_v"] = errors(g.div_free, exact_rot, scale)
        row["div_err"], row["div_err_v"] = errors(g.curl_free, exact_div, scale)
        if peer is not None:
            row["rot_vs_peer"] = errors(g.div_free, p_rot, scale)[0]
            row["div_vs_peer"] = errors(g.curl_free, p_div, scale)[0]
            row["peer_rot_err"] = errors(p_rot, exact_rot, scale)[0]
            row["peer_div_err"] = errors(p_div, exact_div, scale)[0]
        rows.append(row)
        print(f"  {size} grid {condition}: rot {row['rot_err']:.2e} div {row['div_err']:.2e} "
              f"({row['chosen']}, {seconds:.2f} s)")
    # the same without land: what the land's gaps cost the grid (natural)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        g = decompose_lonlat(lon, lat, w["u"], w["v"], boundary_condition="natural")
        seconds = time.perf_counter() - t
    row = dict(region=size, layout="grid 0.25, no land", n=int(g.used.sum()),
               condition="natural", chosen="natural", seconds=seconds,
               max_map_factor=g.stats["max_map_factor"])
    row["rot_err"], row["rot_err_v"] = errors(g.div_free, exact_rot, scale)
    row["div_err"], row["div_err_v"] = errors(g.curl_free, exact_div, scale)
    rows.append(row)
    print(f"  {size} grid without land: rot {row['rot_err']:.2e} div {row['div_err']:.2e}")
    # a window: the same with a stream through the region (harmonic on the sphere),
    # which the default condition sees crossing the edges and splits naturally
    su, sv = harmonic_stream(LON, LAT, CENTRE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        g = decompose_lonlat(lon, lat, np.where(land, np.nan, w["u"] + su),
                             np.where(land, np.nan, w["v"] + sv))
        seconds = time.perf_counter() - t
    row = dict(region=size, layout="grid 0.25", n=int(g.used.sum()),
               condition="default, window (+ a stream)", chosen=g.stats.get("boundary_condition"),
               seconds=seconds, max_map_factor=g.stats["max_map_factor"])
    row["rot_err"], row["rot_err_v"] = errors(g.div_free, exact_rot, scale)
    row["div_err"], row["div_err_v"] = errors(g.curl_free, exact_div, scale)
    rows.append(row)
    print(f"  {size} grid window: rot {row['rot_err']:.2e} div {row['div_err']:.2e} "
          f"({row['chosen']}, {seconds:.2f} s)")
    if size == "60x35":
        # the plane's decomposition with degrees as x and y: the metric ignored
        import taichi_hh as thh
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = time.perf_counter()
            naive = thh.decompose_grid(lon, lat, u, v, boundary_condition="natural")
            seconds = time.perf_counter() - t
        row = dict(region=size, layout="grid 0.25", n=int(naive.used.sum()),
                   condition="plane, degrees as x, y (natural)", chosen="natural",
                   seconds=seconds)
        row["rot_err"], row["rot_err_v"] = errors(naive.div_free, exact_rot, scale)
        row["div_err"], row["div_err_v"] = errors(naive.curl_free, exact_div, scale)
        rows.append(row)
        print(f"  {size} plane in degrees: rot {row['rot_err']:.2e} div {row['div_err']:.2e}")
    # scattered: uniform on the sphere's area
    rng = np.random.default_rng(3)
    n = args.points
    plon = rng.uniform(lo0, lo1, n)
    plat = np.degrees(np.arcsin(rng.uniform(np.sin(np.radians(la0)), np.sin(np.radians(la1)),
                                            n)))
    pw = field.evaluate(plon, plat)
    pscale = np.hypot(pw["u"], pw["v"]).mean()
    for condition in args.conditions:
        opts = {} if condition == "default" else {"boundary_condition": condition}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = time.perf_counter()
            s = decompose_lonlat(plon, plat, pw["u"], pw["v"], **opts)
            seconds = time.perf_counter() - t
        rows.append(scattered_row(size, len(plon), condition, s, seconds, pw, pscale))
    # scattered with land: the points over the grid's land blobs dropped, the
    # domain the coast given (the sea nodes' outline in degrees, its land
    # holes) or left to the points' alpha shape
    from taichi_hh.errors import InputError
    from taichi_hh.geometry.polygon import Polygon
    from taichi_hh.geometry.raster import cell_outlines
    outer, holes = cell_outlines(lon, lat[::-1], ~land[::-1])[0]
    # (the points within 0.01 degrees of the coast left out too: the map's
    # chords of the outline's edges depart from them by up to 0.025 spacings)
    sea = Polygon(outer, holes).signed_distance(np.c_[plon, plat]) < -0.01
    lw = field.evaluate(plon[sea], plat[sea])
    lscale = np.hypot(lw["u"], lw["v"]).mean()
    for label, dom in (("default, land, the coast given", [outer, *holes]),
                       ("default, land, alpha shape (2 spacings)", ("alpha", 2.0)),
                       ("default, land, alpha shape (3 spacings, the default)", "alpha")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = time.perf_counter()
            try:
                s = decompose_lonlat(plon[sea], plat[sea], lw["u"], lw["v"], domain=dom)
            except InputError as exc:       # the alpha shape's outline can cross land bays
                rows.append(dict(region=size, layout="scattered", n=int(sea.sum()),
                                 condition=label, chosen="refused",
                                 seconds=time.perf_counter() - t))
                print(f"  {size} scattered {label}: refused ({exc})")
                continue
            seconds = time.perf_counter() - t
        rows.append(scattered_row(size, int(sea.sum()), label, s, seconds, lw, lscale))
    su, sv = harmonic_stream(plon, plat, CENTRE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        s = decompose_lonlat(plon, plat, pw["u"] + su, pw["v"] + sv)
        seconds = time.perf_counter() - t
    row = dict(region=size, layout="scattered", n=len(plon),
               condition="default, window (+ a stream)", chosen=s.stats.get("boundary_condition"),
               seconds=seconds, max_map_factor=s.stats["max_map_factor"])
    row["rot_err"], row["rot_err_v"] = errors(s.div_free, np.c_[pw["u_psi"], pw["v_psi"]], pscale)
    row["div_err"], row["div_err_v"] = errors(s.curl_free, np.c_[pw["u_chi"], pw["v_chi"]], pscale)
    rows.append(row)
    print(f"  {size} scattered window: rot {row['rot_err']:.2e} div {row['div_err']:.2e} "
          f"({row['chosen']}, {seconds:.2f} s)")


def run_refinement(rows, args):
    """Where a region misses 1% by resolution: the same field refined.  The
    10 x 10 region's 0.25 degree grid (its bumps 8-10 grid steps of radius)
    at 0.25, 0.125 and 0.0625 degrees, with the land blobs (the same shapes
    at each step) and without; the 80 x 60 region's scattered points (0.5
    degrees apart at 15 000) at 15 000 to 120 000.  Default condition; the
    order printed is log2 of the error's ratio per halving of the step
    (per quadrupling of the points)."""
    from taichi_hh.hhd.lonlat import decompose_lonlat
    from taichi_hh.validation.sphere import land_mask, regional_field

    def add(size, layout, n, got_rot, exact_rot, got_div, exact_div, scale, chosen, seconds):
        row = dict(region=size, layout=layout, n=n, condition="default, refinement",
                   chosen=chosen, seconds=seconds)
        row["rot_err"], row["rot_err_v"] = errors(got_rot, exact_rot, scale)
        row["div_err"], row["div_err_v"] = errors(got_div, exact_div, scale)
        rows.append(row)
        print(f"  {size} {layout} (n {n}): rot {row['rot_err']:.2e} div {row['div_err']:.2e} "
              f"({chosen}, {seconds:.2f} s)")
        return row["rot_err"], row["div_err"]

    size = "10x10"
    lo0, lo1, la0, la1 = region_bounds(size)
    field = regional_field(lo0, lo1, la0, la1, seed=11, max_width=8.0)
    for with_land in (True, False):
        errs = []
        for step in args.refine_steps:
            lon = np.arange(lo0, lo1 + 1e-9, step)
            lat = np.arange(la1, la0 - 1e-9, -step)
            w = field.evaluate(*np.meshgrid(lon, lat))
            land = land_mask(lon, lat, field, seed=5, fraction=0.15) if with_land \
                else np.zeros(w["u"].shape, dtype=bool)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t = time.perf_counter()
                g = decompose_lonlat(lon, lat, np.where(land, np.nan, w["u"]),
                                     np.where(land, np.nan, w["v"]))
                seconds = time.perf_counter() - t
            errs.append(add(size, f"grid {step:g}" + ("" if with_land else ", no land"),
                            int(g.used.sum()), g.div_free,
                            np.stack([w["u_psi"], w["v_psi"]], -1), g.curl_free,
                            np.stack([w["u_chi"], w["v_chi"]], -1),
                            np.hypot(w["u"], w["v"])[~land].mean(),
                            g.stats.get("boundary_condition"), seconds))
        _say_orders(f"{size} grid{'' if with_land else ', no land'}", args.refine_steps, errs,
                    halving=True)
    size = "80x60"
    lo0, lo1, la0, la1 = region_bounds(size)
    field = regional_field(lo0, lo1, la0, la1, seed=11, max_width=8.0)
    errs = []
    for n in args.refine_points:
        rng = np.random.default_rng(3)
        plon = rng.uniform(lo0, lo1, n)
        plat = np.degrees(np.arcsin(rng.uniform(np.sin(np.radians(la0)),
                                                np.sin(np.radians(la1)), n)))
        pw = field.evaluate(plon, plat)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = time.perf_counter()
            s = decompose_lonlat(plon, plat, pw["u"], pw["v"])
            seconds = time.perf_counter() - t
        errs.append(add(size, "scattered", n, s.div_free, np.c_[pw["u_psi"], pw["v_psi"]],
                        s.curl_free, np.c_[pw["u_chi"], pw["v_chi"]],
                        np.hypot(pw["u"], pw["v"]).mean(), s.stats.get("boundary_condition"),
                        seconds))
    _say_orders(f"{size} scattered", args.refine_points, errs, halving=False)


def _say_orders(label, sizes, errs, *, halving: bool):
    """The observed orders between successive refinements: per halving of the
    step, or in the spacing (N^-1/2) for points."""
    for (a, ea), (b, eb) in zip(zip(sizes, errs), zip(sizes[1:], errs[1:])):
        ratio = a / b if halving else np.sqrt(b / a)
        orders = [np.log(x / y) / np.log(ratio) for x, y in zip(ea, eb)]
        print(f"  {label} {a:g} -> {b:g}: order rot {orders[0]:.2f} div {orders[1]:.2f}")


def run_timing(rows, repeats: int):
    """The 5 s target: a 1440 x 721 global grid, a 90 x 60 region cut by region=."""
    from taichi_hh.hhd.lonlat import decompose_lonlat
    from taichi_hh.validation.sphere import regional_field
    region = (-115.0, -25.0, 10.0, 70.0)
    field = regional_field(*region, seed=2)
    lon = np.arange(0.0, 360.0, 0.25)
    lat = np.linspace(90.0, -90.0, 721)
    LON, LAT = np.meshgrid(lon, lat)
    w = field.evaluate(LON, LAT)
    u = w["u"] + 25.0 * np.exp(-((LAT - 45.0) / 8.0) ** 2)        # a jet across the region
    v = w["v"] + 3.0 * np.sin(np.radians(3 * LON)) * np.cos(np.radians(LAT))
    calls = []

    def call():
        calls.append(decompose_lonlat(lon, lat, u, v, region=region))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        times = _common.measure(call, repeats)
    g = calls[-1]
    med = float(np.median(times))
    rows.append(dict(region="90x60 of 1440x721", layout="grid 0.25", n=int(g.used.sum()),
                     condition="default", chosen=g.stats.get("boundary_condition"),
                     max_map_factor=g.stats["max_map_factor"], seconds=med))
    print(f"  1440 x 721 global, 90 x 60 region: median {med:.2f} s of {repeats} "
          f"({', '.join(f'{t:.2f}' for t in times)}), {g.stats.get('boundary_condition')}")


def write_figure():
    """docs/figures/lonlat.png: the README's example."""
    import xarray as xr
    import taichi_hh as thh
    from taichi_hh.app.lonlat_figure import streamfunction_figure
    from taichi_hh.validation.sphere import era5_like_winds
    lon = np.arange(-100.0, -39.9, 0.25)
    lat = np.arange(60.0, 24.9, -0.25)
    u, v = era5_like_winds(lon, lat)
    ds = xr.Dataset({"u": (("latitude", "longitude"), u, {"units": "m s-1"}),
                     "v": (("latitude", "longitude"), v, {"units": "m s-1"})},
                    coords={"latitude": ("latitude", lat, {"units": "degrees_north"}),
                            "longitude": ("longitude", lon, {"units": "degrees_east"})})
    out = thh.decompose_lonlat_dataset(ds)
    target = _common.REPO_ROOT / "docs" / "figures" / "lonlat.png"
    tmp = OUT / "lonlat_figure.png"
    OUT.mkdir(parents=True, exist_ok=True)
    streamfunction_figure(out, str(tmp))
    _common.write_bytes_atomic(target, tmp.read_bytes())
    print(f"wrote {target}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--regions", default="10x10,20x15,40x25,60x35,80x60",
                    help="lon x lat sizes in degrees, comma-separated")
    ap.add_argument("--conditions", default="default,natural,neumann",
                    help="on the calm-edged field (each condition's exact answer); the window "
                         "with a stream runs with the default only")
    ap.add_argument("--points", type=int, default=15000, help="scattered points per region")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls of the 5 s target")
    ap.add_argument("--no-peer", action="store_true", help="skip skyborn.windspharm")
    ap.add_argument("--no-timing", action="store_true", help="skip the 1440 x 721 target")
    ap.add_argument("--no-refinement", action="store_true",
                    help="skip the refinement rows (10 x 10 grids, 80 x 60 points)")
    ap.add_argument("--refine-steps", default="0.25,0.125,0.0625",
                    help="grid steps of the 10 x 10 refinement, degrees")
    ap.add_argument("--refine-points", default="15000,30000,60000,120000",
                    help="scattered points of the 80 x 60 refinement")
    ap.add_argument("--figure", action="store_true",
                    help="also write docs/figures/lonlat.png (the README's)")
    args = ap.parse_args(argv)
    args.conditions = _common.parse_list(args.conditions, str)
    args.refine_steps = _common.parse_list(args.refine_steps, float)
    args.refine_points = _common.parse_list(args.refine_points, int)
    import taichi_hh as thh
    thh.init(arch="cpu", precision="f64")
    if not args.no_peer:
        try:
            import skyborn.windspharm.standard  # noqa: F401
        except ImportError as exc:
            print(f"peer unavailable ({exc}): pip install -e '.[bench]' installs skyborn")
            args.no_peer = True
    rows = []
    for size in _common.parse_list(args.regions, str):
        run_region(size, args, rows)
    if not args.no_refinement:
        run_refinement(rows, args)
    if not args.no_timing:
        run_timing(rows, args.repeats)
    OUT.mkdir(parents=True, exist_ok=True)
    _common.write_csv_atomic(OUT / "lonlat.csv", rows, FIELDS)

    def pct(x):
        return "" if x is None or not np.isfinite(x) else f"{100 * x:.3g}%"
    table = [[r["region"], r["layout"], str(r["n"]), r["condition"], str(r.get("chosen") or ""),
              pct(r.get("rot_err")), pct(r.get("div_err")), pct(r.get("rot_vs_peer")),
              pct(r.get("div_vs_peer")), f"{r['seconds']:.2f}"] for r in rows]
    print(_common.format_table(["region", "layout", "n", "condition", "chosen", "rot err",
                                "div err", "rot vs peer", "div vs peer", "s"], table))
    print(f"wrote {OUT / 'lonlat.csv'}")
    if args.figure:
        write_figure()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
