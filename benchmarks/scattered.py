"""decompose() on the point sets users have (issue 13).

For each point layout and size: the default decompose() of an analytic field
with an exact decomposition (the `gaussian` field of
taichi_hh.validation.fields on the unit square), as a whole call after
compilation: mean error of d, r, h (percent of mean |v|), BiCGSTAB iterations
per potential, seconds by stage; and in the same run the SuperLU solve of the
same two assembled systems (scipy) as the time reference, up to --superlu-max
points.  Prints a table, writes outputs/benchmarks/scattered.csv and a chart.

    python benchmarks/scattered.py [--n 3000,13000,53000] [--layouts poisson,jitter0.6,random,gradient,clusters,partial]
                                   [--options '{"support_ratio": 3}'] [--superlu-max 200000]
"""
import argparse
import json
import time

import numpy as np
from _common import REPO_ROOT, add_repo_to_path, write_csv_atomic

add_repo_to_path()

import taichi_hh as thh
from taichi_hh.errors import TaichiHHError
from taichi_hh.hhd.decompose import poisson_problems
from taichi_hh.poisson import multilevel
from taichi_hh.validation import fields, layouts

OUT = REPO_ROOT / "outputs" / "benchmarks"
LAYOUTS = ("poisson", "jitter0.6", "random", "gradient", "clusters", "partial")
#: ``partial``: data covering part of the domain, uniformly random points in the
#: unit square's inner [m, 1 - m]^2 decomposed on the domain they draw (their alpha
#: shape). The gaussian field's bumps lie 0.22 from that edge, where their normal
#: derivative is below 4e-4 of the peak slope, so the unit square's exact parts
#: stay the exact answer there.
PARTIAL_MARGIN = 0.05


def points_and_domain(layout: str, n: int, F):
    """The points of ``layout`` and the domain they are decomposed on."""
    if layout == "partial":
        from taichi_hh.geometry.domain import Box
        inner = Box((PARTIAL_MARGIN,) * 2, (1 - PARTIAL_MARGIN,) * 2)
        return layouts.sample(inner, n, "random", seed=1), "alpha"
    return layouts.sample(F.domain, n, layout, seed=1), F.domain


def superlu_seconds(pts, v, domain, options) -> float:
    import scipy.sparse.linalg as spla
    # the Neumann system: the one a sparse factorization would replace
    P = poisson_problems(pts, v, domain, **{"boundary_condition": "neumann", **options})
    A = P.A.to_scipy().tocsc()
    t = time.perf_counter()
    lu = spla.splu(A)
    for name in ("phi", "psi"):
        b = np.zeros(A.shape[0])
        b[: len(P.rhs[name])] = P.rhs[name]
        lu.solve(b)
    return time.perf_counter() - t


def run(layout: str, n: int, options: dict, superlu_max: int) -> dict:
    F = fields.get("gaussian")
    pts, domain = points_and_domain(layout, n, F)
    ex = F.evaluate(pts)
    scale = np.linalg.norm(ex.v, axis=1).mean()
    row = {"layout": layout, "n": len(pts)}
    t = time.perf_counter()
    try:
        res = thh.decompose(pts, ex.v, domain, **options)
    except TaichiHHError as exc:
        row["failure"] = f"{type(exc).__name__}: {str(exc)[:120]}"
        return row
    row["seconds"] = time.perf_counter() - t
    for name, got, want in (("d", res.curl_free, ex.d), ("r", res.div_free, ex.r),
                            ("h", res.harmonic, ex.h)):
        row[f"err_{name}_pct"] = 100 * np.linalg.norm(got - want, axis=1).mean() / scale
    st = res.stats
    row["iterations_phi"] = st["iterations_phi"]
    row["iterations_psi"] = st["iterations_psi"]
    row["mean_neighbours"] = st["mean_neighbours"]
    for stage, sec in st["seconds"].items():
        if stage != "total":
            row[f"s_{stage}"] = sec
    if len(pts) <= superlu_max:
        row["superlu_seconds"] = superlu_seconds(pts, ex.v, domain, options)
        solve = st["seconds"]["preconditioner"] + st["seconds"]["solve"]
        row["solve_over_superlu"] = solve / row["superlu_seconds"]
        row["call_over_superlu"] = row["seconds"] / row["superlu_seconds"]
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", default="3000,13000,53000")
    ap.add_argument("--layouts", default=",".join(LAYOUTS))
    ap.add_argument("--options", default='{"boundary_condition": "neumann"}',
                    help="decompose() options as JSON (default: the Neumann system, whose "
                         "iterations and SuperLU comparison this measures; the default "
                         "condition, auto, is measured by benchmarks/windows.py)")
    ap.add_argument("--superlu-max", type=int, default=200_000)
    ap.add_argument("--out", default=str(OUT / "scattered.csv"))
    ap.add_argument("--repeat", type=int, default=1,
                    help="calls per point set; the row of the median call is kept")
    args = ap.parse_args()
    options = json.loads(args.options)
    thh.init(arch="cpu", precision="f64")
    F = fields.get("gaussian")
    # compile every kernel the layouts use: below multilevel.SERIAL_MAX_N points
    # the cycle is one serial loop, above it a parallel schedule (a kernel of
    # its own); a larger N may add parallel levels, compiled on its first call
    for n_warm in sorted({2000, multilevel.SERIAL_MAX_N + 1000}):
        for layout in args.layouts.split(","):
            pts, domain = points_and_domain(layout, n_warm, F)
            try:
                thh.decompose(pts, F.evaluate(pts).v, domain, **options)
            except TaichiHHError:
                pass
    rows = []
    head = (f"{'layout':10s} {'n':>8s} {'err d/r/h %':>20s} {'its':>9s} {'nbrs':>5s} "
            f"{'seconds':>8s} {'superlu s':>9s} {'call/slu':>8s}")
    print(head)
    for n in [int(x) for x in args.n.split(",")]:
        for layout in args.layouts.split(","):
            runs = [run(layout, n, options, args.superlu_max if k == 0 else 0)
                    for k in range(max(1, args.repeat))]
            ok = sorted((r for r in runs if "failure" not in r), key=lambda r: r["seconds"])
            row = ok[(len(ok) - 1) // 2] if len(ok) == len(runs) else runs[0]
            if "superlu_seconds" in runs[0] and row is not runs[0]:   # SuperLU once
                slu = row["superlu_seconds"] = runs[0]["superlu_seconds"]
                row["solve_over_superlu"] = (row["s_preconditioner"] + row["s_solve"]) / slu
                row["call_over_superlu"] = row["seconds"] / slu
            rows.append(row)
            if "failure" in row:
                print(f"{layout:10s} {row['n']:8d} FAILED {row['failure']}", flush=True)
                continue
            errs = f"{row['err_d_pct']:.3f}/{row['err_r_pct']:.3f}/{row['err_h_pct']:.3f}"
            slu = row.get("superlu_seconds", float("nan"))
            print(f"{layout:10s} {row['n']:8d} {errs:>20s} "
                  f"{row['iterations_phi']:4d}/{row['iterations_psi']:<4d} "
                  f"{row['mean_neighbours']:5.1f} {row['seconds']:8.3f} {slu:9.3f} "
                  f"{row.get('call_over_superlu', float('nan')):8.2f}", flush=True)
            print("    stages s: " + ", ".join(f"{k[2:]} {v:.3f}" for k, v in row.items()
                                              if k.startswith("s_")), flush=True)
    keys = sorted({k for r in rows for k in r}, key=lambda k: (k not in ("layout", "n"), k))
    write_csv_atomic(args.out, rows, keys)
    chart = args.out.rsplit(".", 1)[0] + ".png"
    plot(rows, chart)
    print(f"wrote {args.out} and {chart}")


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from _common import save_figure_atomic
    fig, (ax_err, ax_its, ax_time) = plt.subplots(1, 3, figsize=(13, 4))
    for layout in dict.fromkeys(r["layout"] for r in rows):
        ok = [r for r in rows if r["layout"] == layout and "failure" not in r]
        if not ok:
            continue
        n = [r["n"] for r in ok]
        ax_err.loglog(n, [max(r["err_d_pct"], r["err_r_pct"]) for r in ok], "o-", label=layout)
        ax_its.semilogx(n, [max(r["iterations_phi"], r["iterations_psi"]) for r in ok], "o-",
                        label=layout)
        ax_time.loglog(n, [r["seconds"] for r in ok], "o-", label=layout)
    ax_err.set(xlabel="points", ylabel="max(err d, err r) [% of mean |v|]",
               title="accuracy")
    ax_its.set(xlabel="points", ylabel="BiCGSTAB iterations (worse potential)",
               title="iterations")
    ax_time.set(xlabel="points", ylabel="seconds (whole decompose call)", title="time")
    ax_err.legend(fontsize=8)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
