"""project() with its default options on the point sets users have (issue 29).

For each point layout and size: one default call ``project(points, v, box)``
(one pass, neumann scheme) on the `gaussian` field of
taichi_hh.validation.fields on the unit square, timed after compilation:
success or the error, max |div| before and after (the scheme's own measure),
the solver iterations (Poisson step / orthogonal step), seconds, the mean
distance of the result from the field's exact divergence-free part r + h
(percent of mean |v|), the support the call used (fixed or adaptive) and the
layout's irregularity (the coefficient of variation of the nearest-neighbour
distances, :func:`taichi_hh.hhd.project.layout_irregularity`, by which the
default chooses it).  Prints a table and writes outputs/projection_defaults.csv.

    python benchmarks/projection_defaults.py [--n 1000,4000,16000]
        [--layouts lattice,jitter0.5,jitter1.0,poisson,random,clusters,gradient] [--seed 1]
        [--options '{"adaptive_support": false}'] [--out outputs/projection_defaults.csv]

Layouts (:func:`taichi_hh.validation.layouts.sample`): ``lattice``,
``jitterX`` (a lattice, each point moved uniformly within a square of side X
spacings: 0.5 moves it by up to +-0.25 spacings, 1.0 by up to +-0.5),
``poisson`` (blue noise), ``random`` (uniformly random), ``clusters`` (half
uniformly random, half a mixture of four Gaussians of width 0.05 clipped to
the box), ``gradient`` (uniformly random, density rising 1:10
across x).  ``--options '{"adaptive_support": false}'`` forces the fixed
support on every layout (the default before issue 29).
"""
import argparse
import json
import math
import time

import numpy as np
from _common import REPO_ROOT, add_repo_to_path, format_table, write_csv_atomic

add_repo_to_path()

import taichi_hh as thh  # noqa: E402
from taichi_hh.errors import TaichiHHError  # noqa: E402
from taichi_hh.hhd.project import layout_irregularity  # noqa: E402
from taichi_hh.validation import fields, layouts  # noqa: E402

OUT = REPO_ROOT / "outputs" / "projection_defaults.csv"
LAYOUTS = ("lattice", "jitter0.5", "jitter1.0", "poisson", "random", "clusters", "gradient")
FIELDS = ["layout", "n", "irregularity", "support", "chosen_by", "status", "max_div_in",
          "max_div_out", "reduction", "err_rh_pct", "iterations_poisson",
          "iterations_orthogonal", "seconds", "error"]


def run(layout: str, n: int, seed: int, options: dict) -> dict:
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, n, layout, seed=seed)
    ex = F.evaluate(pts)
    row = {"layout": layout, "n": len(pts), "irregularity": layout_irregularity(pts)}
    t = time.perf_counter()
    try:
        res = thh.project(pts, ex.v, F.domain, **options)
    except TaichiHHError as exc:
        row["seconds"] = time.perf_counter() - t
        row["status"] = type(exc).__name__
        row["error"] = " ".join(str(exc).split())[:160]
        return row
    row["seconds"] = time.perf_counter() - t
    st = res.stats
    row["status"] = "ok"
    row["support"], row["chosen_by"] = st["support_choice"], st["support_chosen_by"]
    row["max_div_in"], row["max_div_out"] = (float(x) for x in res.max_divergence[:2])
    row["reduction"] = row["max_div_out"] / row["max_div_in"]
    scale = np.linalg.norm(ex.v, axis=1).mean()
    row["err_rh_pct"] = 100 * np.linalg.norm(res.vectors - ex.r - ex.h, axis=1).mean() / scale
    counts = st["stage_iterations"][0]
    row["iterations_poisson"], row["iterations_orthogonal"] = counts
    return row


def fmt(x, spec=".2e"):
    return "" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", default="1000,4000,16000")
    ap.add_argument("--layouts", default=",".join(LAYOUTS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--options", default="{}", help="project() options as JSON")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args()
    options = json.loads(args.options)
    chosen = args.layouts.split(",")
    thh.init(arch="cpu", precision="f64")
    # compile both supports' kernels (and the serial and parallel multilevel
    # cycles) before timing anything; failures are part of the measurement
    F = fields.get("gaussian")
    for layout in ("lattice", "random"):
        for n_warm in (1000, 5000):
            pts = layouts.sample(F.domain, n_warm, layout, seed=0)
            for extra in ({"adaptive_support": False}, {"adaptive_support": True,
                                                         "support_ratio": 3.5,
                                                         "divergence": "cubic"}):
                try:
                    thh.project(pts, F.evaluate(pts).v, F.domain, **extra)
                except TaichiHHError:
                    pass
    rows = []
    for n in [int(x) for x in args.n.split(",")]:
        for layout in chosen:
            row = run(layout, n, args.seed, options)
            rows.append(row)
            print(f"{layout:10s} {row['n']:6d} {row['status']:12s} "
                  f"{row.get('support', ''):8s} {row['seconds']:7.2f} s "
                  f"{fmt(row.get('max_div_out'))} {row.get('error', '')}", flush=True)
    header = ["layout", "N", "irreg.", "support", "result", "max|div| in", "max|div| out",
              "out/in", "|w-(r+h)| %", "its P/O", "s"]
    table = [[r["layout"], str(r["n"]), f"{r['irregularity']:.3f}", r.get("support", ""),
              r["status"] if r["status"] == "ok" else f"{r['status']}: {r['error'][:60]}",
              fmt(r.get("max_div_in"), ".3g"), fmt(r.get("max_div_out")),
              fmt(r.get("reduction"), ".1e"), fmt(r.get("err_rh_pct"), ".2f"),
              (f"{r['iterations_poisson']}/{r['iterations_orthogonal']}"
               if "iterations_poisson" in r else ""), f"{r['seconds']:.2f}"]
             for r in rows]
    print()
    print(f"project(points, v, box) {args.options if options else '(defaults)'}, gaussian "
          "field, one pass")
    print(format_table(header, table, align="lrrllrrrrrr"))
    write_csv_atomic(args.out, rows, FIELDS)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
