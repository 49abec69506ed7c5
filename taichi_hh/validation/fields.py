"""Analytic vector fields with exact Helmholtz-Hodge decompositions.

Each field is ``v = grad phi + J grad psi + h`` (Petronetto Eq. 3, with
``J(a, b) = (b, -a)``) where ``phi`` and ``psi`` satisfy the homogeneous
Neumann condition (Eq. 6) on the field's domain and ``h`` is harmonic
(divergence- and curl-free).  Solving Eq. 5 with Eq. 6 then returns exactly
``phi``, ``psi`` (up to constants) and ``h``: these are test answers.

Fields:

``trig``      unit square; phi = cos(pi x) cos(pi y) / pi,
              psi = cos(2 pi x) cos(pi y) / (2 pi), h = constant.
``gaussian``  unit square; two sources/sinks in phi and two vortices in psi,
              Gaussian bumps far enough inside that their normal derivative at
              the boundary is below 1e-5 of their peak slope, plus a constant
              harmonic part; ``critical_points`` lists the exact centres.
``hole``      unit square with a circular hole of radius 0.15 at its centre;
              Gaussian phi and psi away from every boundary and a harmonic part
              circulating around the hole, ``h = c (-(y - y0), x - x0) / r^2``
              (like Petronetto Fig. 17).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.domain import Box, Polygon
from ..hhd.rotation import J


@dataclass(frozen=True)
class Bump:
    """amplitude * exp(-|x - c|^2 / width^2) and its gradient."""
    center: tuple
    amplitude: float
    width: float

    def __call__(self, p):
        d = p - np.asarray(self.center)
        g = self.amplitude * np.exp(-(d ** 2).sum(axis=1) / self.width ** 2)
        return g, (-2.0 / self.width ** 2) * g[:, None] * d


@dataclass(frozen=True)
class Components:
    """Exact decomposition at some points."""
    v: np.ndarray
    d: np.ndarray
    r: np.ndarray
    h: np.ndarray
    phi: np.ndarray
    psi: np.ndarray


@dataclass(frozen=True)
class AnalyticField:
    name: str
    domain: object
    phi: callable
    psi: callable
    h: callable
    critical_points: tuple = field(default=())   # ((x, y, kind), ...)

    def evaluate(self, points) -> Components:
        p = np.asarray(points, dtype=np.float64)
        phi, dphi = self.phi(p)
        psi, dpsi = self.psi(p)
        d = dphi
        r = J(dpsi)
        h = self.h(p)
        return Components(v=d + r + h, d=d, r=r, h=h, phi=phi, psi=psi)

    def sample(self, n: int, kind: str = "poisson", seed: int = 0) -> np.ndarray:
        """About n points strictly inside the domain: ``poisson`` (blue noise),
        ``jittered`` (30%-jittered lattice) or ``random``."""
        kwargs = {"jitter": 0.6} if kind == "jittered" else {}   # +-30% of the step
        return self.domain.sample_interior(n, kind=kind, seed=seed, **kwargs)


def _sum(*bumps):
    def f(p):
        val = np.zeros(len(p))
        grad = np.zeros((len(p), 2))
        for b in bumps:
            v, g = b(p)
            val += v
            grad += g
        return val, grad
    return f


def _constant(c):
    c = np.asarray(c, dtype=np.float64)
    return lambda p: np.broadcast_to(c, (len(p), 2)).copy()


def trig() -> AnalyticField:
    def phi(p):
        x, y = p[:, 0], p[:, 1]
        v = np.cos(np.pi * x) * np.cos(np.pi * y) / np.pi
        return v, np.c_[-np.sin(np.pi * x) * np.cos(np.pi * y),
                        -np.cos(np.pi * x) * np.sin(np.pi * y)]

    def psi(p):
        x, y = p[:, 0], p[:, 1]
        v = np.cos(2 * np.pi * x) * np.cos(np.pi * y) / (2 * np.pi)
        return v, np.c_[-np.sin(2 * np.pi * x) * np.cos(np.pi * y),
                        -0.5 * np.cos(2 * np.pi * x) * np.sin(np.pi * y)]

    return AnalyticField("trig", Box((0.0, 0.0), (1.0, 1.0)), phi, psi, _constant((0.3, -0.2)))


GAUSS_WIDTH = 0.07


def gaussian() -> AnalyticField:
    w = GAUSS_WIDTH
    # phi minimum = source (d points away), maximum = sink; psi maximum = ccw vortex
    # (curl v = -lap psi > 0), psi minimum = clockwise vortex.
    phi = _sum(Bump((0.27, 0.3), -0.02, w), Bump((0.72, 0.7), 0.02, w))
    psi = _sum(Bump((0.3, 0.72), 0.02, w), Bump((0.7, 0.28), -0.02, w))
    cps = ((0.27, 0.3, "source"), (0.72, 0.7, "sink"),
           (0.3, 0.72, "ccw_vortex"), (0.7, 0.28, "cw_vortex"))
    return AnalyticField("gaussian", Box((0.0, 0.0), (1.0, 1.0)), phi, psi,
                         _constant((0.05, 0.02)), cps)


HOLE_CENTER = (0.5, 0.5)
HOLE_RADIUS = 0.15


def hole(n_segments: int = 96) -> AnalyticField:
    c = np.asarray(HOLE_CENTER)
    outer = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    t = np.linspace(0, 2 * np.pi, n_segments, endpoint=False)
    ring = c + HOLE_RADIUS * np.c_[np.cos(t), np.sin(t)]
    dom = Polygon(outer, holes=[ring])
    w = 0.06
    phi = _sum(Bump((0.2, 0.22), -0.015, w), Bump((0.8, 0.78), 0.015, w))
    psi = _sum(Bump((0.22, 0.78), 0.015, w), Bump((0.78, 0.22), -0.015, w))

    def h(p):
        d = p - c
        r2 = (d ** 2).sum(axis=1)
        return 0.01 * np.c_[-d[:, 1], d[:, 0]] / r2[:, None]

    cps = ((0.2, 0.22, "source"), (0.8, 0.78, "sink"),
           (0.22, 0.78, "ccw_vortex"), (0.78, 0.22, "cw_vortex"))
    return AnalyticField("hole", dom, phi, psi, h, cps)


FIELDS = {"trig": trig, "gaussian": gaussian, "hole": hole}


def get(name: str) -> AnalyticField:
    try:
        return FIELDS[name]()
    except KeyError:
        raise ValueError(f"unknown analytic field {name!r}; choose one of {tuple(FIELDS)}") from None
