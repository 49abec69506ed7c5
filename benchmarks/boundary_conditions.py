"""Accuracy of the decomposition's boundary conditions on the analytic fields
exact for each (issue 17; the table of docs/notes/hhd.md).

    python benchmarks/boundary_conditions.py [--sizes 3300,13000] [--sampling random]

Per field and condition: mean errors of d, r, h over mean |v| on blue noise
(``seed=3``; ``--sampling random`` for uniformly random points), ``stats["h_divergence"]``, ``stats["h_curl"]``, the energy
ratio, the number of flags and the seconds.  Writes
``outputs/benchmarks/boundary_conditions.csv``.
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import _common

_common.add_repo_to_path()

CASES = [("gaussian", "neumann"), ("trig", "neumann"), ("sines", "normal-parallel"),
         ("natural", "natural"), ("gaussian", "natural"), ("rotation", "normal-parallel"),
         ("rotation", "natural"), ("hole", "neumann"), ("hole", "natural"),
         ("hole", "normal-parallel")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="3300,13000")
    ap.add_argument("--sampling", default="poisson", choices=("poisson", "jittered", "random"))
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.validation import fields
    warnings.simplefilter("ignore")
    rows = []
    for name, condition in CASES:
        F = fields.rotation(condition) if name == "rotation" else fields.get(name)
        for n in _common.parse_list(args.sizes, int):
            pts = F.sample(n, args.sampling, seed=3)
            ex = F.evaluate(pts)
            t = time.perf_counter()
            res = thh.decompose(pts, ex.v, F.domain, boundary_condition=condition)
            seconds = time.perf_counter() - t
            vm = np.linalg.norm(ex.v, axis=1).mean()
            err = [float(np.linalg.norm(a - b, axis=1).mean() / vm) for a, b in
                   ((res.curl_free, ex.d), (res.div_free, ex.r), (res.harmonic, ex.h))]
            s = res.stats
            rows.append({"field": name, "condition": condition, "sampling": args.sampling,
                         "n": len(pts),
                         "err_d": err[0], "err_r": err[1], "err_h": err[2],
                         "h_divergence": s["h_divergence"], "h_curl": s["h_curl"],
                         "energy_ratio": s["energy_ratio"], "flags": len(s["flags"]),
                         "seconds": seconds})
            print(rows[-1], flush=True)
    suffix = "" if args.sampling == "poisson" else f"_{args.sampling}"
    path = _common.report_rows(rows, args.out_dir, f"boundary_conditions{suffix}.csv",
                               "lll" + "r" * 9)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
