"""Neumann rows at re-entrant corners (issue 28): per domain, the BiCGSTAB
iterations of the Neumann solve (phi / psi), the errors of d, r, h, and the
eigenvalues of the Jacobi-scaled matrix D^-1 A of the wrong sign (below
zero: the rows' sign lost; where they sit, in spacings from the nearest
re-entrant corner).

    python benchmarks/corner_rows.py [--n 11500] [--seed 0] [--domains box,notch330,...]

Domains, at the density of ``benchmarks/islands.py``'s 11.5k points in its
sea: the 2 x 1 box; the box with a triangular notch cut from its top wall
(one re-entrant corner of 250, 300 or 330 degrees at its apex); the box with
the round 24-gon island or the crooked heptagon (six corners of 230-290
degrees); the wavy coast alone, with either island, with both (the sea of
islands.py).  The field is islands.py's (exact under Neumann on all of them).
Writes ``outputs/benchmarks/corner_rows.csv``.
"""
from __future__ import annotations

import argparse
import os
import warnings

import _common
import islands

_common.add_repo_to_path()


def domains(np):
    """name -> (outer ring, holes)."""
    box = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    sea = islands.coast(np)
    coast, round_island, crooked = (np.asarray(r) for r in sea.rings)

    def notch(angle):
        beta = np.radians(360.0 - angle)              # the notch's apex angle
        depth = min(0.4, 0.25 / np.tan(beta / 2))
        half = depth * np.tan(beta / 2)
        return np.array([[0, 0], [2, 0], [2, 1], [1.5 + half, 1], [1.5, 1 - depth],
                         [1.5 - half, 1], [0, 1.0]])

    out = {"box": (box, []), "box+round": (box, [round_island]),
           "box+crooked": (box, [crooked]), "coast": (coast, []),
           "coast+round": (coast, [round_island]), "coast+crooked": (coast, [crooked]),
           "coast+both": (coast, [round_island, crooked])}
    for angle in (250, 300, 330):
        out[f"notch{angle}"] = (notch(angle), [])
    return out


def wrong_sign(np, problems, k: int = 6):
    """The eigenvalues of D^-1 A (particle rows) below -1e-9 among the ``k``
    nearest -0.3, and for each the share of its mode within 8 spacings of a
    re-entrant corner."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla
    from taichi_hh.hhd.corners import reentrant_corners
    A = problems.A
    m = A.n_particles
    S = A.to_scipy()[:m, :m].tocsc()
    B = (sp.diags(1.0 / S.diagonal()) @ S).tocsc()
    vals, vecs = sla.eigs(B, k=k, sigma=-0.3, which="LM")
    pos = problems.ps.particles.get("position")[:m]
    corners = reentrant_corners(problems.domain)
    spacing = problems.stats["spacing"]
    found = []
    for j in np.argsort(vals.real):
        if vals[j].real >= -1e-9:
            break
        share = 0.0
        if len(corners):
            dist = np.hypot(*(pos[:, None] - corners[None]).transpose(2, 0, 1)).min(axis=1)
            energy = np.abs(vecs[:, j]) ** 2
            share = float(energy[dist < 8 * spacing].sum() / energy.sum())
        found.append((float(vals[j].real), share))
    return found


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=11500, help="points in islands.py's sea")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domains", default="all")
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.geometry.domain import Polygon
    from taichi_hh.hhd.corners import reentrant_corners
    from taichi_hh.hhd.decompose import poisson_problems
    warnings.simplefilter("ignore")
    density = args.n / islands.coast(np).area
    table = domains(np)
    names = list(table) if args.domains == "all" else args.domains.split(",")
    rows = []
    for name in names:
        outer, holes = table[name]
        dom = Polygon(outer, holes=holes)
        pts = dom.sample_interior(int(round(density * dom.area)), kind="random", seed=args.seed)
        ex = islands.evaluate(np, pts)
        res = thh.decompose(pts, ex.v, dom, boundary_condition="neumann")
        scale = np.linalg.norm(ex.v, axis=1).mean()
        err = [float(np.linalg.norm(a - b, axis=1).mean() / scale)
               for a, b in ((res.curl_free, ex.d), (res.div_free, ex.r), (res.harmonic, ex.h))]
        negative = wrong_sign(np, poisson_problems(pts, ex.v, dom, boundary_condition="neumann"))
        rows.append({"domain": name, "n": len(pts), "corners": len(reentrant_corners(dom)),
                     "iterations": f"{res.stats['iterations_phi']}/{res.stats['iterations_psi']}",
                     "err_d": err[0], "err_r": err[1], "err_h": err[2],
                     "wrong_sign": " ".join(f"{v:.3g}" for v, _ in negative),
                     "near_corner": " ".join(f"{s:.2f}" for _, s in negative)})
        print(rows[-1], flush=True)
    _common.report_rows(rows, args.out_dir, "corner_rows.csv", "lrrr" + "r" * 3 + "ll")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
