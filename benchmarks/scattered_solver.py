"""Multilevel-preconditioned BiCGSTAB on the default decomposition's rows (issue 13).

    nice python benchmarks/scattered_solver.py [--sizes 13000,53000,200000]
                                               [--layouts poisson,jitter0.3,random]
                                               [--max-iterations 1000] [--out-dir DIR]

The systems are those :func:`taichi_hh.hhd.decompose.decompose` assembles with
the default options (corrected Laplacian on the data points, quadratic-gradient
Neumann rows on boundary particles, bordered) for the ``gaussian`` field on the
unit square, sampled as blue noise (``poisson``), a 30%-jittered lattice and
uniformly random points (support 4 spacings there: 2.5 leaves isolated
points).  Both potentials are solved to 1e-8 from zero with each set of
``multilevel_options``: ``old`` (the cycle's own defaults: Jacobi smoothing,
one post-sweep, omega 0.7) and ``new`` (the default's
``HHDOptions.multilevel_options``: l1 smoothing, two post-sweeps, omega 0.85).
``setup_s`` is the hierarchy's construction, ``solve_s`` both solves
(compilation excluded: a warm-up solve on a small system runs first).
Prints a table; writes ``scattered_solver.csv`` to ``--out-dir`` (default
outputs/benchmarks).  Iteration counts are deterministic; seconds are wall
clock on a shared machine.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from _common import REPO_ROOT, add_repo_to_path, parse_list, write_csv_atomic

add_repo_to_path()

import taichi_hh as thh  # noqa: E402
from taichi_hh.errors import SolverError  # noqa: E402
from taichi_hh.hhd.decompose import poisson_problems  # noqa: E402
from taichi_hh.hhd.options import HHDOptions  # noqa: E402
from taichi_hh.validation import fields, layouts  # noqa: E402

SUPPORT = {"random": 4.0}          # other layouts: the default 2.5
OPTION_SETS = {"old": {}, "new": dict(HHDOptions().multilevel_options)}
FIELDS = ["layout", "n", "support_ratio", "options", "iterations_phi", "iterations_psi",
          "setup_s", "solve_s", "status"]


def run(layout: str, n: int, max_iterations: int) -> list[dict]:
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, n, layout, seed=1)
    ratio = SUPPORT.get(layout, 2.5)
    P = poisson_problems(pts, F.evaluate(pts).v, F.domain, support_ratio=ratio,
                         boundary_condition="neumann")
    rows = []
    for name, opts in OPTION_SETS.items():
        t = time.perf_counter()
        P.A.multilevel(**opts)
        setup = time.perf_counter() - t
        its, status = [], "ok"
        t = time.perf_counter()
        for pot in ("phi", "psi"):
            try:
                res = P.A.solve(P.rhs[pot], tol=1e-8, max_iterations=max_iterations,
                                preconditioner="multilevel", multilevel_options=opts)
                its.append(res.iterations)
            except SolverError as e:
                its.append(-1)
                status = str(e).split(":")[0]
        rows.append({"layout": layout, "n": len(pts), "support_ratio": ratio, "options": name,
                     "iterations_phi": its[0], "iterations_psi": its[1],
                     "setup_s": round(setup, 3), "solve_s": round(time.perf_counter() - t, 3),
                     "status": status})
        print(f"{layout:10s} {len(pts):8d} {ratio:4.1f} {name:4s} "
              f"{its[0]:5d} {its[1]:5d} {setup:7.2f} {rows[-1]['solve_s']:8.2f} {status}",
              flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="13000,53000,200000")
    ap.add_argument("--layouts", default="poisson,jitter0.3,random")
    ap.add_argument("--max-iterations", type=int, default=1000)
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    args = ap.parse_args()
    thh.init(arch="cpu", precision="f64")
    run("poisson", 2000, 100)                  # warm-up: compile both cycles
    print(f"{'layout':10s} {'N':>8s} {'supp':>4s} opts {'phi':>5s} {'psi':>5s} "
          f"{'setup':>7s} {'solve_s':>8s}")
    rows = []
    for n in parse_list(args.sizes, int):
        for layout in parse_list(args.layouts, str):
            rows += run(layout, n, args.max_iterations)
            from pathlib import Path
            out = Path(args.out_dir)
            out.mkdir(parents=True, exist_ok=True)
            write_csv_atomic(out / "scattered_solver.csv", rows, FIELDS)


if __name__ == "__main__":
    main()
