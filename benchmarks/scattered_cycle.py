"""Cost of the decomposition's multilevel preconditioner: setup, one cycle,
one operator apply, iterations per potential (issue 13).

    python benchmarks/scattered_cycle.py --n 13000 --layouts random,poisson
"""
import argparse
import time

import numpy as np
import taichi as ti

import taichi_hh as thh
from taichi_hh.hhd.decompose import poisson_problems
from taichi_hh.hhd.options import HHDOptions
from taichi_hh.poisson.multilevel import MultilevelPreconditioner
from taichi_hh.validation import fields, layouts


def median_time(f, repeat):
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        ti.sync()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=13000)
    ap.add_argument("--layouts", default="random")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--solve", action="store_true", help="also solve both potentials")
    args = ap.parse_args()
    thh.init(arch="cpu", precision="f64")
    F = fields.get("gaussian")
    opts = dict(HHDOptions().multilevel_options)
    for layout in args.layouts.split(","):
        pts = layouts.sample(F.domain, args.n, layout, seed=1)
        P = poisson_problems(pts, F.evaluate(pts).v, F.domain, boundary_condition="neumann")
        A = P.A
        MultilevelPreconditioner(A, **opts)
        reps = max(1, min(5, args.repeat // 4))
        t_setup = median_time(lambda: MultilevelPreconditioner(A, **opts), reps)
        M = MultilevelPreconditioner(A, **opts)
        r = ti.ndarray(ti.f64, shape=(A.n,))
        r.from_numpy(np.random.default_rng(0).standard_normal(A.n))
        z = ti.ndarray(ti.f64, shape=(A.n,))
        M.apply(r, z)
        t_cycle = median_time(lambda: M.apply(r, z), args.repeat)
        A.apply(r, z)
        t_apply = median_time(lambda: A.apply(r, z), args.repeat)
        line = (f"{layout:10s} n={args.n} setup {t_setup:.3f} s  cycle {t_cycle * 1e3:.2f} ms  "
                f"apply {t_apply * 1e3:.2f} ms  {M.describe()}  nnz "
                f"{[M.level_matrix(k).nnz for k in range(len(M.level_sizes))][:4]}")
        if args.solve:
            its = []
            for name in ("phi", "psi"):
                res = A.solve(P.rhs[name], tol=1e-8, preconditioner=M)
                its.append(res.iterations)
            line += f"  its {its}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
