"""Rayleigh-Taylor early growth of one mode against viscous linear theory.

For a single mode y = y0 + a0 cos(k x) of small amplitude, linear theory with
equal kinematic viscosity nu in both fluids gives a(t) = a0 cosh(s t) (the
interface starts at rest) with s = sqrt(A g k + nu^2 k^4) - nu k^2,
A = (rho_h - rho_l) / (rho_h + rho_l) (Chandrasekhar 1961; Duff, Harlow & Hirt
1962).  :func:`run_case` runs the two-phase flow on that setting (box 1 x 2,
one wavelength wide, g = 1) and fits s: the flow's accuracy against an exact
growth rate, used by ``benchmarks/rt_growth.py``, the speed-accuracy sweep and
the stability map.

Seeding: the mode is put in by displacing a lattice with the divergence-free
field xi = grad(a0/k e^{-k|y - y0|} cos k x), so that amplitudes below the
particle spacing are represented; the amplitude is the cos(k x) coefficient of
the vertical position of the particles that started in the two lattice rows
next to the interface.  Walls: free-slip side walls at x = 0 and one wavelength
leave the cos(k x) mode exactly as in a periodic box, so ``walls="free-slip"``
is the theory's setting; no-slip walls add viscous boundary layers that slow
the growth.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..flow.twophase import FlowParams, TwoPhaseFlow
from .layouts import lattice_in_box

WIDTH, HEIGHT, WAVELENGTH, GRAVITY = 1.0, 2.0, 1.0, 1.0
A0 = 0.01 * WAVELENGTH          # initial amplitude: 1% of the wavelength
LINEAR_LIMIT = 0.05             # the fit uses a < LINEAR_LIMIT wavelengths


def theory(ratio: float, g: float, k: float, nu: float) -> tuple[float, float]:
    """(growth rate s, Atwood number A) of viscous linear theory (module doc)."""
    A = (ratio - 1.0) / (ratio + 1.0)
    return math.sqrt(A * g * k + nu ** 2 * k ** 4) - nu * k ** 2, A


def fit_rate(t, a, a0) -> float:
    """s minimising sum (ln a - ln(a0 cosh(s t)))^2 (golden-section search on
    [0, 10])."""
    la = np.log(np.abs(a))

    def cost(s):
        return float(((la - np.log(a0 * np.cosh(s * t))) ** 2).sum())

    lo, hi = 0.0, 10.0
    phi = (math.sqrt(5) - 1) / 2
    for _ in range(80):
        m1, m2 = hi - phi * (hi - lo), lo + phi * (hi - lo)
        if cost(m1) < cost(m2):
            hi = m2
        else:
            lo = m1
    return 0.5 * (lo + hi)


class SingleMode:
    """The flow of one Rayleigh-Taylor case, built (``flow``) but not yet run.

    ratio: heavy / light density; n: particles; ``params``: FlowParams fields
    that override the case's own (e.g. ``solver_tol``, ``cfl``, ``walls``)."""

    def __init__(self, ratio: float, n: int, *, viscosity: float = 2e-3,
                 shifting: float = 2.0, walls: str = "no-slip", params: dict | None = None):
        self.ratio, self.nu = ratio, viscosity
        box = (0.0, 0.0, WIDTH, HEIGHT)
        pts, dx = lattice_in_box(n, box)
        self.k = 2 * math.pi / WAVELENGTH
        self.y0 = 0.5 * HEIGHT
        k, y0 = self.k, self.y0
        phases = np.where(pts[:, 1] > y0, 1, 0)
        decay = A0 * np.exp(-k * np.abs(pts[:, 1] - y0))
        # the two lattice rows next to the interface, chosen before the displacement
        # (which reaches 0.8 spacings at 12800 particles and would bias the choice)
        self.interface = np.flatnonzero(np.abs(pts[:, 1] - y0) < dx)   # ids, as fluid_state orders
        pts = pts + np.c_[np.sign(pts[:, 1] - y0) * decay * np.sin(k * pts[:, 0]),
                          decay * np.cos(k * pts[:, 0])]
        options = dict(box=box, gravity=(0.0, -GRAVITY), nu=viscosity, densities=(1.0, ratio),
                       shifting=shifting, walls=walls)
        options.update(params or {})
        self.walls = options["walls"]
        self.flow = TwoPhaseFlow(pts, phases, dx, FlowParams(**options))

    def amplitude(self) -> float:
        """The mode's amplitude now (module doc)."""
        p = self.flow.fluid_state()[0][self.interface]
        return 2.0 * np.mean((p[:, 1] - self.y0) * np.cos(self.k * p[:, 0]))

    def run(self, max_time: float = 6.0, on_step=None):
        """Step until the amplitude has grown to about 5 a0 by theory (or
        ``max_time``) and fit the growth rate.  ``on_step(info)`` sees every
        step's diagnostics.  Returns (row of measures, (times, amplitudes))."""
        flow = self.flow
        s_th, A = theory(self.ratio, GRAVITY, self.k, self.nu)
        t_end = min(max_time, math.acosh(5.0) / s_th)
        ts = [0.0]
        amps = [self.amplitude()]
        t0 = time.perf_counter()
        while flow.time < t_end:
            info = flow.step()
            if on_step is not None:
                on_step(info)
            ts.append(flow.time)
            amps.append(self.amplitude())
        wall = time.perf_counter() - t0
        ts, amps = np.array(ts), np.array(amps)
        keep = np.abs(amps) < LINEAR_LIMIT * WAVELENGTH
        s_fit = fit_rate(ts[keep], amps[keep], amps[0])
        return {"density_ratio": self.ratio, "walls": self.walls, "atwood": A,
                "particles": flow.n_fluid, "spacing": flow.dx,
                "a0_measured": amps[0], "s_theory": s_th, "s_measured": s_fit,
                "relative_error": s_fit / s_th - 1.0, "steps": flow.step_count,
                "t_end": flow.time, "wall_seconds": wall,
                "sim_time_per_wall_second": flow.time / wall}, (ts, amps)


def run_case(ratio: float, n: int, *, viscosity: float = 2e-3, shifting: float = 2.0,
             max_time: float = 6.0, walls: str = "no-slip", params: dict | None = None,
             on_step=None):
    """Build and run one case (:class:`SingleMode`); returns (row, (times, amplitudes))."""
    case = SingleMode(ratio, n, viscosity=viscosity, shifting=shifting, walls=walls,
                      params=params)
    return case.run(max_time, on_step)
