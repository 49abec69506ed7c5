"""The conformal map that carries a regional decomposition on the sphere to
the plane: the stereographic projection centred on the data.

On a conformal map with map factor m (map length / length on the sphere) the
sphere's operators are the plane's scaled:

    grad_s f = m grad f,   div_s w = m^2 div(w / m),   curl_s w = m^2 curl(w / m),
    lap_s f  = m^2 lap f

(grad, div, curl, lap in the map's coordinates; vectors in the local
orthonormal frame aligned with the map's axes).  So the split of a wind u on
the sphere,

    u = grad_s chi + k x grad_s psi + h,

is, divided by m, the plane's split of F = u / m in the map,

    F = grad chi + k x grad psi + h / m,

with the same potentials chi and psi (lap chi = div F is lap_s chi = div_s u
over m^2), h / m harmonic on the plane exactly when h is on the sphere, and
the boundary conditions unchanged (a normal derivative is m times the map's,
a value is a value).  The stereographic projection centred at (lon0, lat0) on
a sphere of radius R (Snyder 1987, Map projections: a working manual, Eqs.
21-2 to 21-4):

    k = 2 / (1 + cos c),   cos c = sin lat0 sin lat + cos lat0 cos lat cos(lon - lon0),
    x = R k cos lat sin(lon - lon0),
    y = R k (cos lat0 sin lat - sin lat0 cos lat cos(lon - lon0)),

m = k, c the great-circle distance from the centre: m = 1.02 at 16 degrees
from the centre, 1.1 at 35, 2 at 90 (a hemisphere), infinite at the
antipode.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["Stereographic", "centre_of", "unwrap_longitudes", "MAX_DISTANCE"]

#: the largest great-circle distance (degrees) from the map's centre a point
#: may lie at: a hemisphere (m = 2 there)
MAX_DISTANCE = 90.0


@dataclass(frozen=True)
class Stereographic:
    """The stereographic projection centred at ``(lon0, lat0)`` (degrees) of
    the sphere of radius ``radius``."""
    lon0: float
    lat0: float
    radius: float

    def distance(self, lon, lat) -> np.ndarray:
        """Great-circle distance from the centre, degrees."""
        return np.degrees(np.arccos(np.clip(self._cos_c(lon, lat), -1.0, 1.0)))

    def _cos_c(self, lon, lat):
        phi, phi0 = np.radians(lat), np.radians(self.lat0)
        dlam = np.radians(np.asarray(lon, dtype=np.float64) - self.lon0)
        return np.sin(phi0) * np.sin(phi) + np.cos(phi0) * np.cos(phi) * np.cos(dlam)

    def forward(self, lon, lat) -> tuple:
        """``(points, m, east)``: map coordinates (..., 2) in the radius'
        units, the map factor (...), and the unit vector (..., 2) along which
        the local east points on the map (north is east turned a quarter
        counter-clockwise: the map is conformal and keeps orientation).
        East is undefined at a pole: there it is the limit along the
        meridian ``lon``."""
        lon = np.asarray(lon, dtype=np.float64)
        lat = np.asarray(lat, dtype=np.float64)
        phi, phi0 = np.radians(lat), np.radians(self.lat0)
        dlam = np.radians(lon - self.lon0)
        sp, cp = np.sin(phi), np.cos(phi)
        s0, c0 = np.sin(phi0), np.cos(phi0)
        sl, cl = np.sin(dlam), np.cos(dlam)
        cos_c = s0 * sp + c0 * cp * cl
        k = 2.0 / (1.0 + cos_c)
        R = self.radius
        points = np.stack([R * k * cp * sl, R * k * (c0 * sp - s0 * cp * cl)], axis=-1)
        # d(x, y)/d lon / (R cos lat) = the image of the east unit vector (length k);
        # written without the 1 / cos lat, which cancels: east / k
        dk = 0.5 * k * k * c0 * sl            # (d k / d lon) / cos lat
        ex = dk * cp * sl + k * cl
        ey = dk * (c0 * sp - s0 * cp * cl) + k * s0 * sl
        norm = np.hypot(ex, ey)
        east = np.stack([ex / norm, ey / norm], axis=-1)
        return points, k, east

    def to_map(self, u, v, east) -> np.ndarray:
        """Eastward ``u``, northward ``v`` as (..., 2) components along the
        map's axes."""
        ex, ey = east[..., 0], east[..., 1]
        return np.stack([u * ex - v * ey, u * ey + v * ex], axis=-1)

    @staticmethod
    def from_map(w, east) -> tuple:
        """Components (..., 2) along the map's axes as ``(eastward, northward)``."""
        ex, ey = east[..., 0], east[..., 1]
        return w[..., 0] * ex + w[..., 1] * ey, -w[..., 0] * ey + w[..., 1] * ex


def unwrap_longitudes(lon) -> np.ndarray:
    """Longitudes (degrees) shifted by multiples of 360 to lie within 180 of
    the circular mean of the points (a region across the dateline, 170E to
    170W, becomes 170 to 190)."""
    lon = np.asarray(lon, dtype=np.float64)
    rad = np.radians(lon)
    mean = np.degrees(np.arctan2(np.nanmean(np.sin(rad)), np.nanmean(np.cos(rad))))
    return mean + (lon - mean + 180.0) % 360.0 - 180.0


def centre_of(lon, lat) -> tuple:
    """``(lon0, lat0, farthest)``: the centre of the points on the sphere (the
    normalised mean of their unit vectors: the same for the points turned
    about the axis, symmetric for a symmetric region) and the great-circle distance in degrees of the
    farthest point from it.  Points of a whole hemisphere or more are
    refused: the map's factor grows without bound (no regional map holds
    them).  lon, lat: 1-D arrays of finite degrees."""
    phi, lam = np.radians(lat), np.radians(lon)
    xyz = np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], -1)
    mean = xyz.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm < 1e-6:
        raise InputError("the points surround the sphere (their mean direction is zero): "
                         "a regional decomposition needs them within a hemisphere; use a "
                         "global (spherical-harmonic) method for global fields")
    c = mean / norm
    farthest = float(np.degrees(np.arccos(np.clip((xyz @ c).min(), -1.0, 1.0))))
    lat0 = float(np.degrees(np.arcsin(np.clip(c[2], -1.0, 1.0))))
    lon0 = float(np.degrees(np.arctan2(c[1], c[0])))
    return lon0, lat0, farthest
