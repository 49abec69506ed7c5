"""Analytic vector fields with exact Helmholtz-Hodge decompositions.

Each field is ``v = grad phi + J grad psi + h`` (Petronetto Eq. 3, with
``J(a, b) = (b, -a)``) where ``h`` is harmonic (divergence- and curl-free) and
``phi`` and ``psi`` satisfy the boundary condition named by the field's
``condition``: the homogeneous Neumann condition (Eq. 6) for ``neumann``,
phi = psi = 0 on the boundary for ``normal-parallel``, and for ``natural``
potentials that vanish (below 1e-6 of their peak) on and outside the boundary,
so that the free-space convolutions of lap phi and lap psi give them back.
Solving with that condition then returns exactly ``phi``, ``psi`` (up to
constants for Neumann) and ``h``: these are test answers.  ``gaussian`` and
``hole`` satisfy both ``neumann`` and ``natural``.

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
``sines``     unit square, normal-parallel: phi = 0.1 sin(pi x) sin(pi y),
              psi = 0.05 sin(2 pi x) sin(pi y), h = 0.3 grad(x^2 - y^2) / 2.
``natural``   unit square, natural: the ``gaussian`` field's potentials with a
              non-constant harmonic part h = 0.2 grad(x^2 - y^2) / 2 + (0.05, 0.02).
``rotation``  unit square: the rigid rotation v = (0.5 - y, x - 0.5), for
              every condition but Neumann r = J grad psi with lap psi = -2
              and h harmonic; its exact parts are given for ``normal-parallel``
              (psi by its sine series) and ``natural`` (psi = -G * 2 over the
              square, in closed form); with Neumann it is all h, which is
              then not harmonic.
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
    conditions: tuple = ("neumann",)   # boundary conditions under which the parts are exact

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
                         _constant((0.05, 0.02)), cps, ("neumann", "natural"))


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
    return AnalyticField("hole", dom, phi, psi, h, cps, ("neumann", "natural"))


def _saddle(a, c=(0.0, 0.0)):
    """h = a grad(x^2 - y^2) / 2 + c: harmonic, not constant."""
    c = np.asarray(c, dtype=np.float64)
    return lambda p: a * np.c_[p[:, 0], -p[:, 1]] + c


def sines() -> AnalyticField:
    def phi(p):
        x, y = p[:, 0], p[:, 1]
        s, c = np.sin(np.pi * x), np.cos(np.pi * x)
        return 0.1 * s * np.sin(np.pi * y), 0.1 * np.pi * np.c_[c * np.sin(np.pi * y),
                                                               s * np.cos(np.pi * y)]

    def psi(p):
        x, y = p[:, 0], p[:, 1]
        s, c = np.sin(2 * np.pi * x), np.cos(2 * np.pi * x)
        return 0.05 * s * np.sin(np.pi * y), 0.05 * np.pi * np.c_[2 * c * np.sin(np.pi * y),
                                                                 s * np.cos(np.pi * y)]

    return AnalyticField("sines", Box((0.0, 0.0), (1.0, 1.0)), phi, psi, _saddle(0.3),
                         conditions=("normal-parallel",))


def natural() -> AnalyticField:
    g = gaussian()
    return AnalyticField("natural", g.domain, g.phi, g.psi, _saddle(0.2, (0.05, 0.02)),
                         g.critical_points, ("natural",))


def _rotation_psi_dirichlet(p, terms: int = 401):
    """psi with lap psi = -2 on the unit square, psi = 0 on its boundary, and its
    gradient: psi = x (1 - x) - w with w harmonic, equal to x (1 - x) on y = 0 and
    y = 1, zero on x = 0 and 1: w = sum over odd m of 8 / (pi m)^3 sin(m pi x)
    cosh(m pi (y - 1/2)) / cosh(m pi / 2) (truncation error of the gradient
    below 1e-5 of |v| on average)."""
    x, y = p[:, 0], p[:, 1]
    val = x * (1 - x)
    grad = np.c_[1 - 2 * x, np.zeros(len(p))]
    for m in range(1, terms + 1, 2):
        k = np.pi * m
        a = np.abs(k * (y - 0.5))
        # cosh(k (y - 1/2)) / cosh(k / 2) and sinh(...) / cosh(k / 2), overflow-free
        e = np.exp(a - k / 2) / (1 + np.exp(-k))
        ch = e * (1 + np.exp(-2 * a))
        sh = np.sign(y - 0.5) * e * (1 - np.exp(-2 * a))
        c = 8.0 / k ** 3
        val -= c * np.sin(k * x) * ch
        grad[:, 0] -= c * k * np.cos(k * x) * ch
        grad[:, 1] -= c * k * np.sin(k * x) * sh
    return val, grad


def _rectangle_log_potential(p, lo, hi):
    """int over the rectangle [lo, hi] of ln|p - y| / (2 pi) dy, and its gradient
    (closed form: sums over the corners of the antiderivatives of ln r)."""
    val = np.zeros(len(p))
    grad = np.zeros((len(p), 2))
    for sx_, xc in ((1, hi[0]), (-1, lo[0])):
        for sy_, yc in ((1, hi[1]), (-1, lo[1])):
            u = xc - p[:, 0]
            w = yc - p[:, 1]
            r2 = u * u + w * w
            lr = 0.5 * np.log(np.where(r2 > 0, r2, 1.0))
            at_u = np.where(u != 0, np.arctan(w / np.where(u != 0, u, 1.0)), 0.0)
            at_w = np.where(w != 0, np.arctan(u / np.where(w != 0, w, 1.0)), 0.0)
            # F(u, w) = u w ln r - 3 u w / 2 + u^2 atan(w/u) / 2 + w^2 atan(u/w) / 2
            F = u * w * lr - 1.5 * u * w + 0.5 * u * u * at_u + 0.5 * w * w * at_w
            # dF/du = w ln r - w + u atan(w/u); dF/dw alike (d/dp = -d/du)
            Fu = w * lr - w + u * at_u
            Fw = u * lr - u + w * at_w
            sgn = sx_ * sy_
            val += sgn * F
            grad[:, 0] -= sgn * Fu
            grad[:, 1] -= sgn * Fw
    return val / (2 * np.pi), grad / (2 * np.pi)


def rotation(condition: str = "normal-parallel") -> AnalyticField:
    """The rigid rotation v = (0.5 - y, x - 0.5) on the unit square with its exact
    parts under ``condition`` (normal-parallel or natural): phi = 0 and psi with
    lap psi = -2 (curl v = 2), vanishing on the boundary or the free-space potential."""
    if condition == "normal-parallel":
        psi = _rotation_psi_dirichlet
    elif condition == "natural":
        def psi(p):
            val, grad = _rectangle_log_potential(p, (0.0, 0.0), (1.0, 1.0))
            return -2.0 * val, -2.0 * grad
    else:
        raise ValueError(f"the rotation's parts are given for normal-parallel and natural, "
                         f"not {condition!r}")

    def zero(p):
        return np.zeros(len(p)), np.zeros((len(p), 2))

    def h(p):
        v = np.c_[0.5 - p[:, 1], p[:, 0] - 0.5]
        return v - J(psi(p)[1])

    return AnalyticField("rotation", Box((0.0, 0.0), (1.0, 1.0)), zero, psi, h,
                         conditions=(condition,))


FIELDS = {"trig": trig, "gaussian": gaussian, "hole": hole, "sines": sines,
          "natural": natural, "rotation": rotation}


def get(name: str) -> AnalyticField:
    try:
        return FIELDS[name]()
    except KeyError:
        raise ValueError(f"unknown analytic field {name!r}; choose one of {tuple(FIELDS)}") from None
