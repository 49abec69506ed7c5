"""Windows cut from a larger flow, with the split a scientist expects.

A PIV window, a radar scan or a regional model domain sees part of a larger
flow: sources and vortices inside it, others outside, and a stream.  The
expected decomposition of the window (the natural HHD's, Bhatia et al. 2014):
what the sources inside induce is d, what the vortices inside induce is r,
everything from outside and the stream is h.

The sources and vortices have Gaussian cores (Lamb-Oseen): a source of
strength ``Q`` and core ``s`` at ``c`` has

    v = Q / (2 pi) (x - c) / r^2 (1 - exp(-r^2 / s^2)),   div v = Q / (pi s^2) exp(-r^2 / s^2),

the free-space field of its Gaussian divergence (a vortex: ``J`` of it, its
curl the Gaussian).  Every core sits at least ``EDGE_CORES`` core radii from
the window's edge, so the Gaussians' mass on the wrong side of the edge is
below exp(-EDGE_CORES^2) of the total: the expected split is exact to that.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.box import Box
from ..hhd.rotation import J
from .fields import Components

__all__ = ["WindowField", "window_field", "EDGE_CORES"]

#: cores at least this many core radii from the window's edge (inside or out)
EDGE_CORES = 4.0


@dataclass(frozen=True)
class Core:
    """A Gaussian-core source (``kind="source"``, strength Q > 0; a sink Q < 0)
    or vortex (``kind="vortex"``, circulation, counter-clockwise > 0)."""
    centre: tuple
    strength: float
    core: float
    kind: str

    def velocity(self, p: np.ndarray) -> np.ndarray:
        d = p - np.asarray(self.centre)
        r2 = np.maximum((d * d).sum(axis=1), 1e-300)
        radial = self.strength / (2 * np.pi) * d / r2[:, None] \
            * (-np.expm1(-r2 / self.core ** 2))[:, None]
        return radial if self.kind == "source" else -J(radial)     # J turns clockwise


@dataclass(frozen=True)
class WindowField:
    """A flow seen through ``domain``; ``evaluate`` gives v and its expected
    split (``phi``/``psi`` are not given: NaN)."""
    domain: Box
    cores: tuple
    stream: tuple

    def inside(self, core: Core) -> bool:
        return bool(self.domain.contains(np.asarray([core.centre]))[0])

    def evaluate(self, points) -> Components:
        p = np.asarray(points, dtype=np.float64)
        d = np.zeros_like(p)
        r = np.zeros_like(p)
        h = np.broadcast_to(np.asarray(self.stream, dtype=np.float64), p.shape).copy()
        for c in self.cores:
            part = c.velocity(p)
            if not self.inside(c):
                h += part
            elif c.kind == "source":
                d += part
            else:
                r += part
        nan = np.full(len(p), np.nan)
        return Components(v=d + r + h, d=d, r=r, h=h, phi=nan, psi=nan)

    def critical_points(self):
        """``[(x, y, kind)]`` of the cores inside the window."""
        kinds = {("source", True): "source", ("source", False): "sink",
                 ("vortex", True): "ccw_vortex", ("vortex", False): "cw_vortex"}
        return [(c.centre[0], c.centre[1], kinds[(c.kind, c.strength > 0)])
                for c in self.cores if self.inside(c)]


def window_field(width: float = 2.0, height: float = 1.0, core: float = 0.06,
                 seed: int = 0) -> WindowField:
    """The window ``[0, width] x [0, height]`` of a flow with two sources (one
    a sink) and two vortices (one each way) inside, as many outside within a
    window-size of the edge, and a uniform stream; core centres at least
    :data:`EDGE_CORES` cores from the edge and from each other's centres."""
    rng = np.random.default_rng(seed)
    box = Box((0.0, 0.0), (width, height))
    margin = EDGE_CORES * core
    cores: list = []

    def place(inside: bool):
        while True:
            if inside:
                c = rng.uniform([margin, margin], [width - margin, height - margin])
            else:
                c = rng.uniform([-0.5 * width, -0.5 * height], [1.5 * width, 1.5 * height])
                if box.signed_distance(c[None])[0] < margin:
                    continue
            if all(np.hypot(*(c - np.asarray(o.centre))) > 2 * margin for o in cores):
                return (float(c[0]), float(c[1]))

    for inside in (True, False):
        for kind, sign in (("source", 1.0), ("source", -1.0), ("vortex", 1.0),
                           ("vortex", -1.0)):
            strength = sign * rng.uniform(0.5, 1.0) * 0.1
            cores.append(Core(place(inside), strength, core, kind))
    return WindowField(box, tuple(cores), (0.3, 0.1))
