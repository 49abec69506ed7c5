"""Rayleigh-Taylor instability: heavy fluid over light with a single-mode
interface perturbation (Petronetto et al. 2010, Fig. 19: 12500 particles,
heavy 1.2 x light).

Physics used: gravity, viscosity (equal kinematic viscosity), incompressibility
by the density-weighted SPH projection, no-slip walls (``--walls free-slip``:
the linear theory's setting, see benchmarks/rt_growth.py).  No surface tension.
Defaults: box 1 x 2, interface y = 1 + a cos(2 pi x / wavelength) with a = 0.05,
wavelength 1, densities 1 and 1.2, g = 1, nu = 2e-3.  The common SPH benchmark
(Grenier et al. 2009; PySPH): --density-ratio 1.8 --amplitude 0.15
--viscosity 0.0047619 (Re = 420; the sine profile's phase does not matter).

    python scenes/rayleigh_taylor.py [--particles 12500] [--end-time 10] [--out outputs/rayleigh_taylor]
    taichi-hh scene rayleigh-taylor [the same options]

Writes frames, OUT/diagnostics.csv (with the interface amplitude: half the
distance between the highest light and the lowest heavy particle) and a
checkpoint.
"""
import sys

import numpy as np

from ...flow.twophase import FlowParams
from ...checks import nonnegative_float, positive_float
from ..scene import Scene, lattice_in_box, main

LIGHT, HEAVY = 0, 1


def add_arguments(ap):
    ap.add_argument("--density-ratio", type=positive_float, default=1.2, help="heavy / light density")
    ap.add_argument("--amplitude", type=nonnegative_float, default=0.05, help="interface perturbation amplitude")
    ap.add_argument("--wavelength", type=positive_float, default=1.0, help="perturbation wavelength")
    ap.add_argument("--gravity", type=nonnegative_float, default=1.0, help="gravity magnitude")
    ap.add_argument("--viscosity", type=nonnegative_float, default=2e-3, help="kinematic viscosity")
    ap.add_argument("--width", type=positive_float, default=1.0, help="box width")
    ap.add_argument("--height", type=positive_float, default=2.0, help="box height")
    ap.add_argument("--walls", choices=("no-slip", "free-slip"), default="no-slip",
                    help="viscous wall condition: no-slip (the common SPH benchmark), or "
                         "free-slip (the setting of the linear theory: side walls at whole "
                         "wavelengths then act as periodic boundaries for the mode)")
    ap.add_argument("--shifting", type=nonnegative_float, default=2.0,
                    help="particle-shifting coefficient (0 = off; without it the particles "
                         "line up in streaks behind the interface: docs/notes/flow.md)")


def interface(x, args):
    return 0.5 * args.height + args.amplitude * np.cos(2 * np.pi * x / args.wavelength)


def build(args):
    box = (0.0, 0.0, args.width, args.height)
    pts, dx = lattice_in_box(args.particles, box)
    if args.amplitude >= 0.5 * args.height:
        raise ValueError(f"--amplitude {args.amplitude:g} does not fit: the interface at "
                         f"half the height {args.height:g} would leave the box")
    phases = np.where(pts[:, 1] > interface(pts[:, 0], args), HEAVY, LIGHT)
    if not (phases == LIGHT).any() or not (phases == HEAVY).any():
        raise ValueError(f"{len(pts)} particles leave one fluid empty: use more --particles")
    params = FlowParams(box=box, gravity=(0.0, -args.gravity), nu=args.viscosity,
                        densities=(1.0, args.density_ratio), shifting=args.shifting,
                        walls=args.walls)
    measures.wavelength = args.wavelength
    return pts, phases, dx, params


def mode_amplitude(pos, heavy, spacing, width, wavelength):
    """Amplitude a of the interface mode y = y0 + a cos(k x) from the heavy-fluid
    indicator: the integral of H cos(k x) over the box is -a (width / 2), and the
    particles are a quadrature of it with weights spacing^2.  Free of the particle
    spacing's quantisation that limits tip-based measures."""
    k = 2 * np.pi / wavelength
    return -2.0 / width * spacing ** 2 * np.cos(k * pos[heavy, 0]).sum()


def measures(flow, args=None):
    pos, vel, ph, _ = flow.fluid_state()
    bubble = pos[ph == LIGHT, 1].max()
    spike = pos[ph == HEAVY, 1].min()
    x0, _, x1, _ = flow.params.box
    wavelength = getattr(measures, "wavelength", x1 - x0)
    return {"bubble_tip": bubble, "spike_tip": spike, "amplitude": 0.5 * (bubble - spike),
            "mode_amplitude": mode_amplitude(pos, ph == HEAVY, flow.dx, x1 - x0, wavelength)}


SCENE = Scene(
    name="rayleigh_taylor",
    description="Rayleigh-Taylor instability (two-phase projection SPH), headless PNG frames.",
    defaults={"particles": 12500, "end_time": 10.0, "out": "outputs/rayleigh_taylor",
              "output_interval": 0.1, "montage": "0,4,8,10"},
    add_arguments=add_arguments, build=build, measures=measures, phase_names=("light fluid", "heavy fluid"),
    measure_columns=["bubble_tip", "spike_tip", "amplitude", "mode_amplitude"],
    terms="gravity, viscosity, density-weighted pressure projection, no-slip walls (--walls free-slip: free-slip), "
          "particle shifting (--shifting 0 turns it off)")

if __name__ == "__main__":
    sys.exit(main(SCENE))
