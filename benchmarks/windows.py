"""Windows cut from a larger flow (issue 28): the split each boundary condition
gives against the one a scientist expects (sources inside in d, vortices
inside in r, everything from outside and the stream in h;
:mod:`taichi_hh.validation.windows`).

    python benchmarks/windows.py [--sizes 5000,15000,100000] [--grid 161x81]

Cases: uniformly random points in the 2 x 1 window; a PIV-like grid with 2%
noise (of max |v|, per component) and 4% NaN dropouts (``decompose_grid``);
the same grid with a masked round obstacle away from the cores; and, for the
default's other branch, closed containers (15k random points in the closed
2 x 1 box, v.n = 0 on the walls: a circulation, and one with sources,
:func:`closed_container`; expected h = 0).  Per case
and condition (``neumann``, ``normal-parallel``, ``natural`` and the
default): mean errors of d, r, h over mean |v| on the decomposed points
(against the noise-free expected split), the critical points found against
the cores inside (matched within two core radii), the whole call's seconds
after a warm-up call.  Writes ``outputs/benchmarks/windows.csv``.
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import _common

_common.add_repo_to_path()

CONDITIONS = ("default", "neumann", "normal-parallel", "no-flux", "natural")


def _errors(np, got, ex, where):
    vm = np.linalg.norm(ex.v[where], axis=1).mean()
    return [float(np.linalg.norm(a[where] - b[where], axis=1).mean() / vm)
            for a, b in zip(got, (ex.d, ex.r, ex.h))]


def _critical(np, found, wanted, core):
    """(matched, spurious): cores inside found within 2 core radii with the
    right kind, and points found that match none."""
    matched, used = 0, set()
    for x, y, kind in wanted:
        for k, c in enumerate(found):
            if k not in used and c.kind == kind and np.hypot(c.x - x, c.y - y) < 2 * core:
                matched += 1
                used.add(k)
                break
    return matched, len(found) - len(used)


def closed_container(np, pts, sources: bool):
    """A flow in the closed 2 x 1 box (v.n = 0 on its walls) and its expected
    split: a cavity-like circulation r = J grad psi with psi = 0 on the walls,
    and with ``sources`` a source-sink pair d = grad phi with d.n = 0 on the
    walls (phi's normal derivative zero); h = 0."""
    from taichi_hh.validation.fields import Components
    x, y = pts[:, 0], pts[:, 1]
    a, b = np.pi / 2, np.pi
    psi = 0.1 * np.sin(a * x) * np.sin(b * y)
    grad_psi = 0.1 * np.c_[a * np.cos(a * x) * np.sin(b * y), b * np.sin(a * x) * np.cos(b * y)]
    r = np.c_[grad_psi[:, 1], -grad_psi[:, 0]]             # J(a, b) = (b, -a)
    phi = 0.05 * np.cos(2 * a * x) * np.cos(b * y) * sources
    d = 0.05 * sources * np.c_[-2 * a * np.sin(2 * a * x) * np.cos(b * y),
                               -b * np.cos(2 * a * x) * np.sin(b * y)]
    return Components(v=d + r, d=d, r=r, h=np.zeros_like(r), phi=phi, psi=psi)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="5000,15000,100000")
    ap.add_argument("--grid", default="161x81", help="nx x ny of the PIV-like grid")
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.validation.windows import window_field
    warnings.simplefilter("ignore")
    W = window_field(seed=args.seed)
    core = W.cores[0].core
    wanted = W.critical_points()
    conditions = args.conditions.split(",")
    rng = np.random.default_rng(args.seed + 1)
    cases = []
    for n in _common.parse_list(args.sizes, int):
        pts = rng.random((n, 2)) * [2.0, 1.0]
        cases.append((f"random {n}", "points", pts, None))
    nx, ny = (int(s) for s in args.grid.lower().split("x"))
    x, y = np.linspace(0, 2, nx), np.linspace(0, 1, ny)
    X, Y = np.meshgrid(x, y)
    gpts = np.c_[X.ravel(), Y.ravel()]
    dropout = rng.random(X.shape) < 0.04
    cases.append((f"PIV grid {nx}x{ny}, 2% noise, 4% NaN", "grid", gpts, dropout))
    # an obstacle away from every core (the expected split holds outside it)
    centres = np.array([c.centre for c in W.cores])
    cand = np.c_[rng.uniform(0.3, 1.7, 400), rng.uniform(0.25, 0.75, 400)]
    far = np.min(np.linalg.norm(cand[:, None] - centres[None], axis=2), axis=1)
    oc = cand[np.argmax(far)]
    obstacle = (X - oc[0]) ** 2 + (Y - oc[1]) ** 2 < 0.1 ** 2
    cases.append((f"PIV grid {nx}x{ny}, noise, NaN, obstacle", "grid", gpts, dropout | obstacle))
    closed_n = 15000
    closed_pts = rng.random((closed_n, 2)) * [2.0, 1.0]
    cases.append((f"closed box {closed_n}, circulation", "closed", closed_pts, False))
    cases.append((f"closed box {closed_n}, circulation + sources", "closed", closed_pts, True))
    rows = []
    for name, kind, pts, invalid in cases:
        ex = closed_container(np, pts, invalid) if kind == "closed" else W.evaluate(pts)
        vmax = float(np.abs(ex.v).max())
        for condition in conditions:
            opts = {} if condition == "default" else {"boundary_condition": condition}
            if kind in ("points", "closed"):
                def call():
                    return thh.decompose(pts, ex.v, W.domain, **opts)
            else:
                noise = 0.02 * vmax * np.random.default_rng(7).standard_normal(ex.v.shape)
                u = (ex.v[:, 0] + noise[:, 0]).reshape(X.shape)
                v = (ex.v[:, 1] + noise[:, 1]).reshape(X.shape)
                u = np.where(invalid, np.nan, u)

                def call():
                    return thh.decompose_grid(x, y, u, v, **opts)
            try:
                call()                                   # compile and warm up
                t = time.perf_counter()
                res = call()
                seconds = time.perf_counter() - t
            except thh.TaichiHHError as exc:
                rows.append({"case": name, "condition": condition, "n": len(pts),
                             "err_d": float("nan"), "err_r": float("nan"),
                             "err_h": float("nan"), "matched": 0, "spurious": 0,
                             "seconds": float("nan"), "error": str(exc)[:80]})
                print(rows[-1], flush=True)
                continue
            if kind in ("points", "closed"):
                got, where = (res.curl_free, res.div_free, res.harmonic), np.ones(len(pts), bool)
                chosen = res.stats.get("boundary_condition", res.options.boundary_condition)
            else:
                where = res.used.ravel()
                got = tuple(a.reshape(-1, 2) for a in (res.curl_free, res.div_free, res.harmonic))
                chosen = res.scattered.stats.get("boundary_condition",
                                                 res.scattered.options.boundary_condition)
            err = _errors(np, got, ex, where)
            matched, spurious = ((0, 0) if kind == "closed"
                                 else _critical(np, res.critical_points(), wanted, core))
            rows.append({"case": name, "condition": condition if condition != "default"
                         else f"default ({chosen})", "n": int(where.sum()),
                         "err_d": err[0], "err_r": err[1], "err_h": err[2],
                         "matched": matched, "spurious": spurious, "seconds": seconds,
                         "error": ""})
            print(rows[-1], flush=True)
    _common.report_rows(rows, args.out_dir, "windows.csv", "ll" + "r" * 8 + "l")
    print(f"cores inside: {len(wanted)} (matched within {2 * core:g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
