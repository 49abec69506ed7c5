"""The gridded natural HHD side by side with its authors' library (issue 28).

    git clone https://github.com/bhatiaharsh/naturalHHD /tmp/naturalHHD
    python benchmarks/grid_peer.py [--peer /tmp/naturalHHD/pynhhd-v1.1] [--sizes 161x81,321x161]

The field: the window of :func:`taichi_hh.validation.windows.window_field`
(Gaussian-core sources and vortices inside and outside a 2 x 1 window, a
stream) sampled on an nx x ny grid of the window, whose expected split is
exact (what the sources inside induce is d, the vortices inside r, the rest
h).  Error: mean |error| over mean |v| over every node, for d, r, h.

Ours: ``taichi_hh.decompose_grid(x, y, u, v)`` with its defaults (the whole
call: input checks, the domain from the valid nodes, the default condition's
boundary-flux measure, which picks ``natural`` here, the decomposition, the
energy and harmonicity checks), on the grid-native path
(:mod:`taichi_hh.hhd.natural_grid`), and the same call through the
scattered machinery (``_path="scattered"``: neighbour search, MLS stencils,
cut-cell coverage, the particle-mesh FFT of :mod:`taichi_hh.hhd.natural`).
``decompose_grid`` keeps the last layouts (the outline, the auto flux's band:
``GridLayout.of``), which a field decomposed again or a run of frames with
the same invalid nodes reuses; the row "ours (new layout each call)" drops
them before each call (``forget_layouts``): a grid's first call after
compilation, or frames whose mask changes.

Peer (``--peer``): pynhhd v1.1's grid path, ``nHHD(grid=(ny, nx),
spacings=(dy, dx))`` then ``decompose(vfield)`` (second-order differences
by numpy.gradient, the Green's function convolution by
scipy.signal.fftconvolve), timed whole (its Green's function grid made in
the constructor) and the ``decompose`` call alone; loaded with the shims of
benchmarks/natural_peer.py.

Timing: each timed call repeated ``--repeats`` times after a warm-up, the
variants interleaved round by round on the same machine (each round in a
random order: a call right after another library's can find Taichi's worker
threads asleep and the other's threads still spinning, which a busy
machine makes costly), the median (and
the minimum) reported, and each median over pynhhd's whole call's median
(``ratio``; the machine's load average printed with it).  Writes
``outputs/benchmarks/grid_peer.csv``.
"""
from __future__ import annotations

import argparse
import math
import os
import random
import statistics
import time
import warnings

import _common

_common.add_repo_to_path()


def parse_sizes(text: str) -> list:
    out = []
    for part in text.split(","):
        nx, ny = part.lower().split("x")
        out.append((int(nx), int(ny)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", default=None, help="a pynhhd-v1.1 directory of naturalHHD")
    ap.add_argument("--sizes", default="161x81,321x161")
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--scattered-repeats", type=int, default=3)
    ap.add_argument("--no-scattered", action="store_true",
                    help="leave out the scattered path (slow)")
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.hhd.grid import forget_layouts
    from taichi_hh.validation.windows import window_field
    pynhhd = None
    if args.peer:
        from natural_peer import load_peer
        pynhhd = load_peer(args.peer)
    warnings.simplefilter("ignore")
    W = window_field()

    def errors(d, r, h, ex):
        vm = np.linalg.norm(ex.v, axis=1).mean()
        return [float(np.linalg.norm(np.reshape(a, (-1, 2)) - b, axis=1).mean() / vm)
                for a, b in ((d, ex.d), (r, ex.r), (h, ex.h))]

    rows = []
    for nx, ny in parse_sizes(args.sizes):
        x, y = np.linspace(0.0, 2.0, nx), np.linspace(0.0, 1.0, ny)
        X, Y = np.meshgrid(x, y)
        ex = W.evaluate(np.c_[X.ravel(), Y.ravel()])
        u = ex.v[:, 0].reshape(X.shape).copy()
        v = ex.v[:, 1].reshape(X.shape).copy()
        vfield = ex.v.reshape(ny, nx, 2).copy()
        def ours_new_layout():
            forget_layouts()
            return thh.decompose_grid(x, y, u, v)
        calls = {"ours": lambda: thh.decompose_grid(x, y, u, v), "ours_new": ours_new_layout}
        if pynhhd is not None:
            def peer_whole():
                p = pynhhd.nHHD(grid=(ny, nx), spacings=(y[1] - y[0], x[1] - x[0]))
                p.decompose(vfield)
                return p
            peer_made = pynhhd.nHHD(grid=(ny, nx), spacings=(y[1] - y[0], x[1] - x[0]))

            def peer_decompose():
                peer_made.decompose(vfield)
                return peer_made
            calls["pynhhd"] = peer_whole
            calls["pynhhd_decompose"] = peer_decompose
        results = {name: fn() for name, fn in calls.items()}          # warm-up
        times = {name: [] for name in calls}
        order, shuffle = list(calls), random.Random(0).shuffle
        for _ in range(args.repeats):                    # interleaved rounds, order shuffled
            shuffle(order)
            for name in order:
                t = time.perf_counter()
                calls[name]()
                times[name].append(time.perf_counter() - t)
        if not args.no_scattered:
            call = lambda: thh.decompose_grid(x, y, u, v, _path="scattered")  # noqa: E731
            results["scattered"] = call()
            times["scattered"] = []
            for _ in range(args.scattered_repeats):
                t = time.perf_counter()
                call()
                times["scattered"].append(time.perf_counter() - t)
        for name, res in results.items():
            if name.startswith("pynhhd"):
                err = errors(res.d, res.r, res.h, ex)
                label = ("pynhhd (whole)" if name == "pynhhd" else "pynhhd (decompose only)")
            else:
                err = errors(res.curl_free, res.div_free, res.harmonic, ex)
                label = {"ours": "ours (grid-native)",
                         "ours_new": "ours (new layout each call)"}.get(name,
                                                                        "ours (scattered path)")
                if name == "ours" and not res.stats.get("grid_native"):
                    label = "ours (took the scattered path)"
            median = statistics.median(times[name])
            peer = statistics.median(times["pynhhd"]) if "pynhhd" in times else math.nan
            row = {"grid": f"{nx}x{ny}", "method": label, "median_s": median,
                   "min_s": min(times[name]), "ratio": median / peer,
                   "repeats": len(times[name]), "err_d": err[0], "err_r": err[1],
                   "err_h": err[2], "load": os.getloadavg()[0]}
            rows.append(row)
            print({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()},
                  flush=True)
    names = ["grid", "method", "median_s", "min_s", "ratio", "repeats", "err_d", "err_r",
             "err_h", "load"]
    print(_common.format_table(
        ["grid", "method", "median ms", "min ms", "/ pynhhd", "err d %", "err r %", "err h %",
         "load"],
        [[r["grid"], r["method"], f"{1e3 * r['median_s']:.1f}", f"{1e3 * r['min_s']:.1f}",
          f"{r['ratio']:.2f}", f"{100 * r['err_d']:.4f}", f"{100 * r['err_r']:.4f}",
          f"{100 * r['err_h']:.4f}", f"{r['load']:.1f}"] for r in rows]))
    path = _common.write_rows(args.out_dir, "grid_peer.csv", rows, names)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
