"""Benchmark of the natural Helmholtz-Hodge decomposition (issue 17).

    python benchmarks/natural_hhd.py [--sizes 3300,13000,100000,1000000] [--direct-max 5000]
                                     [--out-dir DIR]

Field: ``natural`` of :mod:`taichi_hh.validation.fields` (Gaussian potentials
inside the unit square plus a non-constant harmonic part; its natural parts
are exact), sampled on blue noise up to 100k points and on a 30%-jittered
lattice above (Poisson-disk sampling of a million points takes longer than
the decomposition).  Per N: seconds of ``decompose(boundary_condition=
"natural")`` in all and of its stages (setup = particles and neighbours,
divergence = div v and curl v, natural = grid reconstruction, two FFT
convolutions, gradients), the grid, mean errors of d, r, h over mean |v|;
up to ``--direct-max`` points also the direct Taichi sum (same grid sum,
O(M^2)) and the largest difference from the FFT; for comparison the Neumann
decomposition's total up to 100k points.  One warm-up run at the smallest
size excludes compilation.  Writes ``outputs/benchmarks/natural_hhd.csv`` and
``natural_hhd.png`` (seconds and errors against N, log-log, with an N log N
guide).
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import _common

_common.add_repo_to_path()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="3300,13000,100000,1000000")
    ap.add_argument("--direct-max", type=int, default=5000)
    ap.add_argument("--neumann-max", type=int, default=100000)
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.validation import fields

    sizes = _common.parse_list(args.sizes, int)
    F = fields.get("natural")

    def errors(res, ex):
        vm = np.linalg.norm(ex.v, axis=1).mean()
        return [float(np.linalg.norm(a - b, axis=1).mean() / vm) for a, b in
                ((res.curl_free, ex.d), (res.div_free, ex.r), (res.harmonic, ex.h))]

    warnings.simplefilter("ignore")
    pts0 = F.sample(min(sizes), "poisson", seed=1)
    thh.decompose(pts0, F.evaluate(pts0).v, F.domain, boundary_condition="natural")  # warm-up
    rows = []
    for n in sizes:
        kind = "poisson" if n <= 100000 else "jittered"
        pts = F.sample(n, kind, seed=1)
        ex = F.evaluate(pts)
        t = time.perf_counter()
        res = thh.decompose(pts, ex.v, F.domain, boundary_condition="natural")
        total = time.perf_counter() - t
        sec = res.stats["seconds"]
        row = {"n": len(pts), "points": kind, "grid": "x".join(map(str, res.stats["natural_grid"])),
               "total_s": total, "setup_s": sec["setup"], "divergence_s": sec["divergence"],
               "natural_s": sec["natural"]}
        row.update(zip(("err_d", "err_r", "err_h"), errors(res, ex)))
        if len(pts) <= args.direct_max:
            t = time.perf_counter()
            ref = thh.decompose(pts, ex.v, F.domain, boundary_condition="natural",
                                natural_evaluation="direct")
            row["direct_natural_s"] = ref.stats["seconds"]["natural"]
            row["fft_vs_direct"] = float(np.abs(ref.curl_free - res.curl_free).max())
        if len(pts) <= args.neumann_max:
            t = time.perf_counter()
            thh.decompose(pts, ex.v, F.domain)
            row["neumann_total_s"] = time.perf_counter() - t
        rows.append(row)
        print({k: (f"{v:.3g}" if isinstance(v, float) else v) for k, v in row.items()},
              flush=True)
    names = ["n", "points", "grid", "total_s", "setup_s", "divergence_s", "natural_s", "err_d",
             "err_r", "err_h", "direct_natural_s", "fft_vs_direct", "neumann_total_s"]
    header = ["N", "points", "grid", "total s", "setup s", "div s", "natural s", "err d",
              "err r", "err h", "direct s", "fft-direct", "neumann s"]
    table = [[(f"{r[k]:.3g}" if isinstance(r.get(k), float) else str(r.get(k, "")))
              for k in names] for r in rows]
    print(_common.format_table(header, table))
    path = _common.write_rows(args.out_dir, "natural_hhd.csv", rows, names)
    print(f"wrote {path}")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = np.array([r["n"] for r in rows], dtype=float)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for key, label in (("total_s", "total"), ("natural_s", "natural step"),
                       ("setup_s", "particles and neighbours")):
        a.loglog(n, [r[key] for r in rows], "o-", label=label)
    guide = n * np.log(n)
    a.loglog(n, guide / guide[-1] * rows[-1]["total_s"], "k:", label="N log N")
    a.set_xlabel("points N")
    a.set_ylabel("seconds")
    a.legend()
    for key in ("err_d", "err_r", "err_h"):
        b.loglog(n, [r[key] for r in rows], "o-", label=key[-1])
    b.loglog(n, rows[0]["err_d"] * n[0] / n, "k:", label="second order")
    b.set_xlabel("points N")
    b.set_ylabel("mean error / mean |v|")
    b.legend()
    fig.suptitle("natural HHD (particle-mesh FFT), field 'natural'")
    png = os.path.join(args.out_dir, "natural_hhd.png")
    _common.save_figure_atomic(fig, png, dpi=120)
    print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
