"""A light circular droplet rising in a fluid twice as dense, in a closed box
(Petronetto et al. 2010, Fig. 18: 10500 particles, frames at t = 0, 2, 4, 6).

Physics used: gravity, viscosity (equal kinematic viscosity in both fluids),
incompressibility by the density-weighted SPH projection, no-slip walls.  No
surface tension.  Units are nondimensional: box 1 x 2, droplet radius 0.25
centred at (0.5, 0.5), g = 1, densities 1 (droplet) and 2 (surroundings),
nu = 2e-3 (Reynolds number sqrt(A g R) R / nu about 36 with A = 1/3).

    python scenes/rising_droplet.py [--particles 10500] [--end-time 6] [--out outputs/rising_droplet]
    taichi-hh scene rising-droplet [the same options]

Writes OUT/frame_NNNNN.png, OUT/diagnostics.csv (with the droplet's centroid
and rise speed) and OUT/checkpoint.npz (for --resume).
"""
import sys

import numpy as np

from ...flow.twophase import FlowParams
from ...checks import nonnegative_float, positive_float
from ..scene import Scene, lattice_in_box, main

LIGHT, HEAVY = 0, 1


def add_arguments(ap):
    ap.add_argument("--radius", type=positive_float, default=0.25, help="droplet radius")
    ap.add_argument("--density-ratio", type=positive_float, default=2.0,
                    help="surrounding density / droplet density")
    ap.add_argument("--gravity", type=nonnegative_float, default=1.0, help="gravity magnitude")
    ap.add_argument("--viscosity", type=nonnegative_float, default=2e-3, help="kinematic viscosity")
    ap.add_argument("--width", type=positive_float, default=1.0, help="box width")
    ap.add_argument("--height", type=positive_float, default=2.0, help="box height")
    ap.add_argument("--shifting", type=nonnegative_float, default=2.0,
                    help="particle-shifting coefficient (0 = off; without it the particles "
                         "line up in streaks behind the interface: docs/notes/flow.md)")


def build(args):
    box = (0.0, 0.0, args.width, args.height)
    pts, dx = lattice_in_box(args.particles, box)
    centre = np.array([0.5 * args.width, 0.25 * args.height])
    if not 0 < args.radius < min(0.5 * args.width, 0.25 * args.height):
        raise ValueError(f"--radius {args.radius:g} does not fit: the droplet, centred at "
                         f"({centre[0]:g}, {centre[1]:g}), needs a radius below "
                         f"{min(0.5 * args.width, 0.25 * args.height):g} in this box")
    phases = np.where(np.linalg.norm(pts - centre, axis=1) < args.radius, LIGHT, HEAVY)
    if not (phases == LIGHT).any() or not (phases == HEAVY).any():
        raise ValueError(f"{len(pts)} particles resolve no droplet of radius {args.radius:g} "
                         f"(spacing {dx:.3g}): use more --particles or a larger --radius")
    params = FlowParams(box=box, gravity=(0.0, -args.gravity), nu=args.viscosity,
                        densities=(1.0, args.density_ratio), shifting=args.shifting)
    return pts, phases, dx, params


def measures(flow):
    pos, vel, ph, _ = flow.fluid_state()
    drop = ph == LIGHT
    return {"centroid_x": pos[drop, 0].mean(), "centroid_y": pos[drop, 1].mean(),
            "rise_speed": vel[drop, 1].mean()}


SCENE = Scene(
    name="rising_droplet",
    description="Light droplet rising in a denser fluid (two-phase projection SPH), "
                "headless PNG frames.",
    defaults={"particles": 10500, "end_time": 6.0, "out": "outputs/rising_droplet",
              "output_interval": 0.1, "montage": "0,2,4,6"},
    add_arguments=add_arguments, build=build, measures=measures, phase_names=("droplet", "surrounding fluid"),
    measure_columns=["centroid_x", "centroid_y", "rise_speed"],
    terms="gravity, viscosity, density-weighted pressure projection, no-slip walls, "
          "particle shifting (--shifting 0 turns it off)")

if __name__ == "__main__":
    sys.exit(main(SCENE))
