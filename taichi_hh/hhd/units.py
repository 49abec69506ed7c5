"""The unit frame: every decomposition and projection runs on coordinates and
vectors of order one, whatever units the caller's data are in.

A field measured in metres over a 1000 km region, in UTM coordinates (offsets
of 5e6 m), in micrometres, or with speeds of 1e-40 in single precision is the
same problem as one on the unit square with speeds of order one.  Floating
point is not indifferent to the difference: squared distances, the moment
matrices of the MLS fits and the Krylov scalars overflow, underflow or lose
every digit to a large offset.  So the public calls map the input into the
frame

    x_unit = (x - centre) / length,    v_unit = v / speed,

(``centre`` the middle of the domain's bounds, ``length`` their larger side,
``speed`` the largest |component| of the valid vectors), run there, and map
the results back: vectors by ``speed``, potentials by ``speed * length``,
derivatives (divergence, curl) by ``speed / length``.  Every step of the
decomposition and the projection is linear in v and commutes with a
translation and a uniform scaling of the coordinates, so the answer is the
same for any units, to rounding (tests/test_units.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Frame"]


@dataclass(frozen=True)
class Frame:
    """``x_unit = (x - centre) / length``, ``v_unit = v / speed``."""
    centre: tuple
    length: float
    speed: float

    @classmethod
    def of(cls, bounds, vectors) -> "Frame":
        """The frame of a domain with ``bounds`` ``((x0, y0), (x1, y1))`` and a
        field ``vectors`` (finite (N, 2) float64 rows; the valid ones).  A
        degenerate extent or an all-zero field keeps that unit (1.0): the
        callers refuse the first and the second needs no scaling."""
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
        centre = 0.5 * lo + 0.5 * hi            # halves first: no overflow near 1e308
        length = float(np.max(hi - lo))
        if not (np.isfinite(length) and length > 0):
            length = 1.0
        return cls((float(centre[0]), float(centre[1])), length, speed_of(vectors))

    @property
    def potential(self) -> float:
        """What a potential (phi, psi) in the unit frame is multiplied by."""
        return self.speed * self.length

    @property
    def derivative(self) -> float:
        """What a derivative of the field (div v, curl v) is multiplied by."""
        return self.speed / self.length

    def points_to_unit(self, points) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.centre)) / self.length

    def points_from_unit(self, points) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) * self.length + np.asarray(self.centre)

    def domain_to_unit(self, domain):
        """A :class:`~taichi_hh.geometry.domain.Polygon` (or Box) in the unit frame."""
        return domain.rescaled(self.centre, self.length)

    def domain_from_unit(self, domain):
        """The inverse of :meth:`domain_to_unit` (to rounding)."""
        c = np.asarray(self.centre, dtype=np.float64)
        return domain.rescaled(-c / self.length, 1.0 / self.length)

    def as_dict(self) -> dict:
        return {"centre": self.centre, "length": self.length, "speed": self.speed}


def speeds_of(vectors) -> np.ndarray:
    """The unit frame's speed of each field of ``vectors`` (..., N, 2) (finite
    float64 rows): its largest |component|, 1.0 for an empty or all-zero
    field.  max(max v, -min v) is max |v| exactly, without |v|'s array."""
    v = np.asarray(vectors)
    if v.shape[-2] * v.shape[-1] == 0:
        return np.ones(v.shape[:-2])
    speed = np.maximum(v.max(axis=(-2, -1)), -v.min(axis=(-2, -1)))
    return np.where(np.isfinite(speed) & (speed > 0), speed, 1.0)


def speed_of(vectors) -> float:
    """:func:`speeds_of` of one field (N, 2)."""
    return float(speeds_of(np.asarray(vectors).reshape(-1, 2)))
