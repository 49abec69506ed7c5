"""Demo: plain versus corrected SPH operators under refinement (headless PNG).

Samples cos(pi x) cos(pi y) on 30%-jittered lattices of increasing size, applies
the plain (Petronetto Eq. 8 / Eq. 10) and corrected (Bonet-Lok / renormalised)
gradient and Laplacian, and plots the interior mean relative error against the
particle spacing.  Writes OUT/operator_convergence.png and .csv.

    python scenes/operator_convergence.py [--sizes 24,48,96,192] [--out outputs/operator_convergence] [--docs]
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="24,48,96,192", help="lattice sizes m (m x m points)")
    ap.add_argument("--jitter", type=float, default=0.3, help="jitter, in spacings")
    ap.add_argument("--out", default="outputs/operator_convergence", help="output directory")
    ap.add_argument("--arch", default="cpu", choices=("cpu", "gpu", "auto"))
    ap.add_argument("--docs", action="store_true",
                    help="also refresh docs/figures/operator_convergence.png (the README's figure)")
    args = ap.parse_args(argv)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import taichi_hh as thh
    from taichi_hh.app.io import atomic_write_csv, atomic_savefig

    thh.init(arch=args.arch)
    rng = np.random.default_rng(0)
    rows = []
    for m in (int(s) for s in args.sizes.split(",")):
        dx = 1.0 / m
        g = (np.arange(m) + 0.5) * dx
        pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
        pts += rng.uniform(-args.jitter, args.jitter, pts.shape) * dx
        x, y = pts.T
        f = np.cos(np.pi * x) * np.cos(np.pi * y)
        grad = np.c_[-np.pi * np.sin(np.pi * x) * np.cos(np.pi * y),
                     -np.pi * np.cos(np.pi * x) * np.sin(np.pi * y)]
        lap = -2 * np.pi ** 2 * f
        inner = (np.abs(x - 0.5) < 0.3) & (np.abs(y - 0.5) < 0.3)
        ps = thh.PointSet(pts, area=1.0)
        row = {"n": len(pts), "dx": dx}
        for v in ("difference", "corrected"):
            e = np.linalg.norm(ps.gradient(f, v) - grad, axis=1)[inner].mean()
            row[f"gradient_{v}"] = e / np.linalg.norm(grad[inner], axis=1).mean()
        for v in ("brookshaw", "corrected"):
            e = np.abs(ps.laplacian(f, v) - lap)[inner].mean()
            row[f"laplacian_{v}"] = e / np.abs(lap[inner]).mean()
        rows.append(row)
        print(" ".join(f"{k}={val:.4g}" for k, val in row.items()), flush=True)

    os.makedirs(args.out, exist_ok=True)
    atomic_write_csv(os.path.join(args.out, "operator_convergence.csv"), rows)
    fig, ax = plt.subplots(figsize=(5.5, 4))
    dxs = [r["dx"] for r in rows]
    styles = {"gradient_difference": ("C0", "--o", "gradient, difference (Petronetto Eq. 8)"),
              "gradient_corrected": ("C0", "-o", "gradient, corrected (Bonet-Lok)"),
              "laplacian_brookshaw": ("C3", "--s", "Laplacian, Brookshaw (Petronetto Eq. 10)"),
              "laplacian_corrected": ("C3", "-s", "Laplacian, corrected")}
    for key, (col, st, label) in styles.items():
        ax.loglog(dxs, [r[key] for r in rows], st, color=col, label=label)
    ax.set_xlabel("particle spacing dx")
    ax.set_ylabel("mean relative error (interior)")
    ax.set_title(f"cos(pi x) cos(pi y), {int(args.jitter * 100)}% jittered particles")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path = os.path.join(args.out, "operator_convergence.png")
    atomic_savefig(fig, path, dpi=110)
    print("wrote", path)
    if args.docs:
        docs = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "figures",
                            "operator_convergence.png")
        atomic_savefig(fig, docs, dpi=110)
        print("wrote", docs)


if __name__ == "__main__":
    main()
