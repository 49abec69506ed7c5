"""Frame cost by style: the smooth interpolated field against the disc raster.

The droplet scene's frame at its defaults (10 368 particles in the 1 x 2 box,
800 px wide), particles on the lattice with a 15% jitter (what a frame shows
after the first steps).  Styles are timed interleaved, after compilation, as
medians of ``--repeat`` rounds: the draw alone, and the whole frame (draw,
labels, PNG bytes).  Prints a table and writes outputs/benchmarks/render.csv.

    python benchmarks/render.py [--repeat 15] [--width 800] [--particles 10500]
"""
import argparse
import time

import numpy as np
from _common import REPO_ROOT, add_repo_to_path, write_csv_atomic

add_repo_to_path()

import taichi_hh as thh
from taichi_hh.app import render
from taichi_hh.app.overlay import FrameLabels, label_frame
from taichi_hh.app.scene import lattice_in_box

OUT = REPO_ROOT / "outputs" / "benchmarks"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--particles", type=int, default=10500)
    args = ap.parse_args()
    thh.init(arch="cpu", precision="f64")
    pts, dx = lattice_in_box(args.particles, (0.0, 0.0, 1.0, 2.0))
    pts = pts + np.random.default_rng(0).normal(0.0, 0.15 * dx, pts.shape)
    phase = (np.linalg.norm(pts - [0.5, 0.5], axis=1) >= 0.25).astype(np.int32)
    renderers = {s: render.FrameRenderer(args.width, None, (0, 0), (1, 2), style=s)
                 for s in render.STYLES}
    legend = FrameLabels(legend=[("droplet", render.PHASE_PALETTE[0]),
                                 ("surrounding fluid", render.PHASE_PALETTE[1])])
    times = {(s, part): [] for s in render.STYLES for part in ("draw", "frame")}
    for r in renderers.values():                      # compile
        r.draw(pts, phase=phase)
    for _ in range(args.repeat):
        for style, r in renderers.items():
            t0 = time.perf_counter()
            image = r.draw(pts, phase=phase)
            t1 = time.perf_counter()
            render.png_bytes(label_frame(image, 1.0, legend))
            t2 = time.perf_counter()
            times[(style, "draw")].append(t1 - t0)
            times[(style, "frame")].append(t2 - t0)
    rows = []
    base = {part: np.median(times[("discs", part)]) for part in ("draw", "frame")}
    print(f"{len(pts)} particles, {args.width} px wide, median of {args.repeat} interleaved rounds")
    print(f"{'style':8s} {'draw ms':>8s} {'frame ms':>9s} {'draw / discs':>13s} {'frame / discs':>14s}")
    for style in render.STYLES:
        d, f = (np.median(times[(style, p)]) for p in ("draw", "frame"))
        row = {"style": style, "particles": len(pts), "width": args.width,
               "draw_ms": 1e3 * d, "frame_ms": 1e3 * f,
               "draw_ratio": d / base["draw"], "frame_ratio": f / base["frame"]}
        rows.append(row)
        print(f"{style:8s} {row['draw_ms']:8.1f} {row['frame_ms']:9.1f} {row['draw_ratio']:13.2f} "
              f"{row['frame_ratio']:14.2f}")
    path = OUT / "render.csv"
    write_csv_atomic(path, rows, list(rows[0]))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
