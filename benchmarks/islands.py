"""A coast with two islands against a box (issue 28): the same field, the same
density of uniformly random points, each boundary condition.

    python benchmarks/islands.py [--n 11500] [--seed 0]

The sea: the 2 x 1 box with a wavy coast along its top (the land above it)
and two islands (a 24-gon and a crooked heptagon).  The field: Gaussian
potentials, two sources/sinks in phi and two vortices in psi, each at least
four widths from every shore (their value and slope there below 1e-6 of
their peak: exact under every condition), plus a uniform stream (h).  The
box: the same field on the 2 x 1 box with the same density of points.  Per
domain and condition: mean errors of d, r, h over mean |v|, BiCGSTAB
iterations (phi / psi), seconds of the whole call after a warm-up call.
Writes ``outputs/benchmarks/islands.csv``.
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import _common

_common.add_repo_to_path()

CONDITIONS = ("default", "neumann", "normal-parallel", "no-flux", "natural")
WIDTH = 0.045


def coast(np):
    """The sea as a Polygon with two islands."""
    from taichi_hh.geometry.domain import Polygon
    x = np.linspace(2.0, 0.0, 41)
    top = np.c_[x, 0.85 + 0.06 * np.sin(3 * np.pi * x) + 0.03 * np.cos(7 * x)]
    outer = np.vstack([[[0.0, 0.0], [2.0, 0.0]], top])
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    round_island = np.c_[0.55 + 0.12 * np.cos(t), 0.45 + 0.09 * np.sin(t)]
    crooked = np.array([[1.35, 0.35], [1.55, 0.32], [1.62, 0.45], [1.52, 0.5], [1.56, 0.62],
                        [1.4, 0.6], [1.33, 0.48]])
    return Polygon(outer, holes=[round_island, crooked])


def field(np):
    from taichi_hh.validation.fields import Bump
    phi = (Bump((0.2, 0.2), -0.01, WIDTH), Bump((1.05, 0.62), 0.01, WIDTH))
    psi = (Bump((1.0, 0.22), 0.01, WIDTH), Bump((1.8, 0.2), -0.01, WIDTH))
    stream = np.array([0.05, 0.02])
    return phi, psi, stream


def evaluate(np, pts):
    from taichi_hh.validation.fields import Components
    phi_b, psi_b, stream = field(np)
    phi = sum(b(pts)[0] for b in phi_b)
    d = sum(b(pts)[1] for b in phi_b)
    psi = sum(b(pts)[0] for b in psi_b)
    gp = sum(b(pts)[1] for b in psi_b)
    r = np.c_[gp[:, 1], -gp[:, 0]]                      # J(a, b) = (b, -a)
    h = np.broadcast_to(stream, pts.shape).copy()
    return Components(v=d + r + h, d=d, r=r, h=h, phi=phi, psi=psi)


def shore_clearance(np, domain):
    """Smallest distance from a bump's centre to the shore, in widths."""
    phi_b, psi_b, _ = field(np)
    centres = np.array([b.center for b in phi_b + psi_b])
    return float(np.abs(domain.signed_distance(centres)).min() / WIDTH)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=11500, help="points in the sea")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.geometry.domain import Box
    warnings.simplefilter("ignore")
    sea = coast(np)
    box = Box((0.0, 0.0), (2.0, 1.0))
    print(f"bumps at least {shore_clearance(np, sea):.1f} widths from every shore")
    domains = (("coast, 2 islands", sea, args.n),
               ("box", box, int(round(args.n * box.area / sea.area))))
    rows = []
    for name, domain, n in domains:
        pts = domain.sample_interior(n, kind="random", seed=args.seed)
        ex = evaluate(np, pts)
        scale = np.linalg.norm(ex.v, axis=1).mean()
        for condition in args.conditions.split(","):
            opts = {} if condition == "default" else {"boundary_condition": condition}
            try:
                thh.decompose(pts, ex.v, domain, **opts)
                t = time.perf_counter()
                res = thh.decompose(pts, ex.v, domain, **opts)
                seconds = time.perf_counter() - t
            except thh.TaichiHHError as exc:
                rows.append({"domain": name, "condition": condition, "n": len(pts),
                             "err_d": float("nan"), "err_r": float("nan"),
                             "err_h": float("nan"), "iterations": "", "seconds": float("nan"),
                             "error": str(exc)[:80]})
                continue
            err = [float(np.linalg.norm(a - b, axis=1).mean() / scale)
                   for a, b in ((res.curl_free, ex.d), (res.div_free, ex.r),
                                (res.harmonic, ex.h))]
            s = res.stats
            its = (f"{s['iterations_phi']}/{s['iterations_psi']}" if "iterations_phi" in s
                   else "-")
            label = condition if condition != "default" else f"default ({s['boundary_condition']})"
            rows.append({"domain": name, "condition": label, "n": len(pts), "err_d": err[0],
                         "err_r": err[1], "err_h": err[2], "iterations": its,
                         "seconds": seconds, "error": ""})
            print(rows[-1], flush=True)
    _common.report_rows(rows, args.out_dir, "islands.csv", "ll" + "r" * 6 + "l")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
