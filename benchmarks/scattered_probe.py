"""Is the default decomposition well posed on scattered points?  (issue 13)

For each point layout and support ratio: the assembled default system's row
structure (fluid rows with a positive diagonal, rows with an off-diagonal of
the diagonal's sign), its exact solve by SuperLU and the error of the
components that solve gives, and the default ``decompose()`` (iterations,
error, or the failure).  Prints a table and writes outputs/benchmarks/scattered_probe.csv.

    python benchmarks/scattered_probe.py [--n 5000,13000] [--layouts poisson,random]
                                         [--supports 2.5,4]
"""
import argparse

import numpy as np
from _common import REPO_ROOT, add_repo_to_path, write_csv_atomic

add_repo_to_path()
import scipy.sparse.linalg as spla

import taichi_hh as thh
from taichi_hh import runtime
from taichi_hh.errors import TaichiHHError
from taichi_hh.hhd.decompose import poisson_problems
from taichi_hh.sph.particles import FLUID
from taichi_hh.validation import fields

OUT = REPO_ROOT / "outputs" / "benchmarks"


def layout_points(layout: str, n: int, field) -> np.ndarray:
    if layout == "random":
        return np.random.default_rng(0).random((n, 2))
    return field.sample(n, layout, seed=1)


def probe(layout: str, n: int, support: float) -> dict:
    F = fields.get("gaussian")
    pts = layout_points(layout, n, F)
    ex = F.evaluate(pts)
    scale = np.linalg.norm(ex.v, axis=1).mean()
    row = {"layout": layout, "n": n, "support": support}
    P = poisson_problems(pts, ex.v, F.domain, support_ratio=support,
                         boundary_condition="neumann")
    A = P.A.to_scipy().tocsr()
    kind = P.kind
    fluid = np.flatnonzero(kind == FLUID)
    diag = A.diagonal()[fluid]
    Af = A[fluid]
    same_sign = 0
    for k, i in enumerate(fluid):          # per row: any off-diagonal with the diagonal's sign
        lo, hi = Af.indptr[k], Af.indptr[k + 1]
        cols, vals = Af.indices[lo:hi], Af.data[lo:hi]
        same_sign += bool(np.any((cols != i) & (vals * diag[k] > 0)))
    row["positive_diagonal_rows"] = int((diag > 0).sum())
    row["same_sign_rows_pct"] = 100.0 * same_sign / len(fluid)
    ps, ops = P.ps, P.ps.ops
    st = ops.gradient_coefficients(P.opts.gradient, row_kinds=(FLUID,))
    grads = {}
    for name in ("phi", "psi"):
        x = spla.spsolve(A.tocsc(), P.rhs[name] if len(P.rhs[name]) == A.shape[0]
                         else np.r_[P.rhs[name], np.zeros(A.shape[0] - len(P.rhs[name]))])
        x_nd = ps.new_array(1)
        buf = np.zeros(x_nd.shape[0])
        buf[: ps.n_total] = x[: ps.n_total]
        x_nd.from_numpy(buf.astype(runtime.np_real()))
        g_nd = ps.new_array(2)
        ops.gradient(st, x_nd, g_nd)
        grads[name] = ps.download(g_nd)
    d, g = grads["phi"], grads["psi"]
    r = np.c_[g[:, 1], -g[:, 0]]
    row["direct_err_d_pct"] = 100 * np.linalg.norm(d - ex.d, axis=1).mean() / scale
    row["direct_err_r_pct"] = 100 * np.linalg.norm(r - ex.r, axis=1).mean() / scale
    try:
        res = thh.decompose(pts, ex.v, F.domain, support_ratio=support,
                            boundary_condition="neumann")
        row["iterations"] = f"{res.stats['iterations_phi']}/{res.stats['iterations_psi']}"
        row["decompose_err_d_pct"] = 100 * np.linalg.norm(res.curl_free - ex.d, axis=1).mean() / scale
    except TaichiHHError as exc:
        row["iterations"] = f"failed: {type(exc).__name__}"
        row["decompose_err_d_pct"] = float("nan")
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", default="5000,13000")
    ap.add_argument("--layouts", default="poisson,random")
    ap.add_argument("--supports", default="2.5,4")
    args = ap.parse_args()
    thh.init(arch="cpu", precision="f64")
    rows = []
    for layout in args.layouts.split(","):
        for n in (int(s) for s in args.n.split(",")):
            for support in (float(s) for s in args.supports.split(",")):
                row = probe(layout, n, support)
                rows.append(row)
                print(" ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                               for k, v in row.items()), flush=True)
    path = OUT / "scattered_probe.csv"
    write_csv_atomic(path, rows, list(rows[0]))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
