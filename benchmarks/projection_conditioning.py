"""Why the flow's exact projection is expensive, and what would make it cheap.

    python benchmarks/projection_conditioning.py [--particles 10500] [--time 1]
                                                 [--supports 3,2.5,2] [--out-dir outputs/benchmarks]

The flow's optional clean-up (``FlowParams.exact_projection``, module doc of
:mod:`taichi_hh.flow.twophase`) solves ``S lam = D w`` with ``S = D M^-1 D^T``, ``D`` the
corrected SPH divergence of the fluid rows (walls at rest), ``w`` the velocity
the Poisson step left.  This script takes the rising-droplet scene (its
defaults) to ``--time``, then, on those very particle positions and with the
kernel support ratio of the whole flow set to each of ``--supports``, takes one
step with the clean-up on and records:

* ``taichi_cg``: the clean-up's Jacobi-CG iterations in the flow (cold start,
  tolerance ``solver_tol`` = 1e-6 of ||D w*||) and its seconds per iteration;
* ``S`` assembled with scipy from the flow's own coefficients (checked against
  the flow's ``D w``): Jacobi-CG iterations to 1e-2, 1e-4 and 1e-6 of
  ||D w*||, and the extreme eigenvalues of the Jacobi-scaled ``S`` (ARPACK,
  shift-invert for the smallest) and their ratio;
* pyamg aggregation-CG (plain aggregation on geometric cells of 3 spacings,
  then 2 x 2 cells per level, symmetric Gauss-Seidel smoothing) with two
  candidate sets: the constants alone, and the constants plus the three
  odd-even (checkerboard) carriers (-1)^i, (-1)^j, (-1)^(i+j) of the initial
  lattice indices, the null modes of an SPH gradient on a lattice;
* the droplet itself run to ``--time`` with each support ratio (clean-up off):
  its volume error (mean / max) there and its median step seconds;
* a lower bound on the clean-up with the best preconditioner: its CG
  iterations times the seconds of one clean-up iteration in the flow,
  ignoring the preconditioner's cost;
* with ``--spectrum``, the number of eigenvalues of the Jacobi-scaled ``S``
  below 1e-3 and 1e-2 of the largest (a dense eigendecomposition: about 150 s
  at 10k particles).

Writes OUT/projection_conditioning.csv (one row per support ratio).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from _common import REPO_ROOT, add_repo_to_path, format_table, parse_list, scene_module, \
    write_csv_atomic

add_repo_to_path()


def droplet_run(particles: int, t_end: float, support_ratio: float | None = None):
    """The droplet scene (defaults; optionally another kernel support ratio)
    advanced to ``t_end``: (state, params, volume error (mean, max) at the end,
    median step seconds over the steps after the first)."""
    from taichi_hh.validation.conditioning import advance
    mod = scene_module("rising_droplet")
    ap = argparse.ArgumentParser()
    mod.add_arguments(ap)
    args = ap.parse_args([])
    args.particles = particles
    pts, phases, dx, params = mod.build(args)
    if support_ratio is not None:
        params = replace(params, support_ratio=support_ratio)
    state, vol, step_s = advance(pts, phases, dx, params, t_end)
    return state, params, vol, step_s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=10500)
    ap.add_argument("--time", type=float, default=1.0, help="droplet time of the snapshot")
    ap.add_argument("--supports", default="3,2.5,2",
                    help="kernel support ratios (support / spacing) to compare")
    ap.add_argument("--spectrum", action="store_true",
                    help="also count the small eigenvalues of S (dense, slow)")
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    args = ap.parse_args(argv)
    from taichi_hh import runtime
    from taichi_hh.validation.conditioning import (aggregation_iterations, assemble,
                                                   capture_cleanup, cg_history,
                                                   eigenvalue_counts, extreme_eigenvalues,
                                                   first_below, jacobi)
    runtime.init("cpu")
    t0 = time.perf_counter()
    state, params, vol_default, step_default = droplet_run(args.particles, args.time)
    print(f"droplet at t = {state['time']:.3f} ({len(state['positions'])} fluid particles) "
          f"in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    rows = []
    for ratio in parse_list(args.supports):
        if ratio == params.support_ratio:
            vol, step_s = vol_default, step_default
        else:
            _, _, vol, step_s = droplet_run(args.particles, args.time, ratio)
        p = replace(params, support_ratio=ratio)
        seen, dx = capture_cleanup(state, p)
        D, S, pos, d = assemble(seen)
        rtol = params.solver_tol * seen["norm_before"] / np.linalg.norm(d)
        norms = cg_history(S, d, jacobi(S), rtol)
        lmin, lmax = extreme_eigenvalues(S)
        agg1 = aggregation_iterations(S, d, pos, dx, rtol, 1)
        agg4 = aggregation_iterations(S, d, pos, dx, rtol, 4)
        counts = eigenvalue_counts(S) if args.spectrum else ["", ""]
        # one clean-up CG iteration in the flow: an S apply (D^T then D) and vector work
        per_it = seen["seconds"] / max(seen["iterations"], 1)
        row = {"support_ratio": ratio, "fluid": S.shape[0], "S_nnz_per_row": S.nnz / S.shape[0],
               "taichi_cg_iterations": seen["iterations"], "taichi_cg_seconds": seen["seconds"],
               "taichi_seconds_per_iteration": per_it,
               "jacobi_cg_1e-2": first_below(norms, 1e-2 * seen["norm_before"]),
               "jacobi_cg_1e-4": first_below(norms, 1e-4 * seen["norm_before"]),
               "jacobi_cg_1e-6": first_below(norms, 1e-6 * seen["norm_before"]),
               "lambda_min": lmin, "lambda_max": lmax, "condition": lmax / lmin,
               "agg_constants_iterations": agg1[0], "agg_constants_complexity": agg1[1],
               "agg_carriers_iterations": agg4[0], "agg_carriers_complexity": agg4[1],
               "eigenvalues_below_1e-3": counts[0], "eigenvalues_below_1e-2": counts[1],
               "step_seconds": step_s, "volume_error_mean": vol[0], "volume_error_max": vol[1],
               "best_cleanup_lower_bound_seconds": (agg4[0] * per_it
                                                    if isinstance(agg4[0], int) else math.nan),
               "max_div_before_cleanup": float(np.abs(d).max()),
               "norm_div_predicted": seen["norm_before"]}
        rows.append(row)
        print(f"support {ratio}: done", file=sys.stderr)
    cols = list(rows[0])
    out = Path(args.out_dir)
    write_csv_atomic(out / "projection_conditioning.csv", rows, cols)
    table = [[f"{r['support_ratio']:g}", f"{r['S_nnz_per_row']:.0f}", r["taichi_cg_iterations"],
              f"{1e3 * r['taichi_seconds_per_iteration']:.1f}", r["jacobi_cg_1e-2"],
              r["jacobi_cg_1e-4"], r["jacobi_cg_1e-6"], f"{r['condition']:.2e}",
              r["agg_constants_iterations"], r["agg_carriers_iterations"],
              f"{r['best_cleanup_lower_bound_seconds']:.3f}", f"{r['step_seconds']:.3f}",
              f"{100 * r['volume_error_mean']:.2f}/{100 * r['volume_error_max']:.1f}"]
             for r in rows]
    print(format_table(["support/dx", "S nnz/row", "flow CG its", "ms/it", "Jacobi 1e-2",
                        "1e-4", "1e-6", "cond(S)", "agg 1 cand", "agg 4 cand",
                        "bound s/step", "step s", "vol err %"], table))
    if args.spectrum:
        for r in rows:
            print(f"support {r['support_ratio']:g}: {r['eigenvalues_below_1e-3']} / "
                  f"{r['eigenvalues_below_1e-2']} eigenvalues of {r['fluid']} below 1e-3 / 1e-2 "
                  "of the largest")
    print(f"wrote {out / 'projection_conditioning.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
