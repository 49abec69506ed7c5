"""The natural potentials' gradient next to curved boundaries, by distance band (issue 28).

    python benchmarks/natural_boundary.py [--cases disk,disk_linear,annulus]
                                          [--sizes 4000,16000,64000] [--out-dir DIR]

Closed forms (``taichi_hh.hhd.natural.natural_potentials`` of a density f
on N uniformly random points, polygons of 16384 / 8192 vertices): ``disk``
f = 1 on the disk of radius 1/2 (grad u = x / 2 about its centre);
``disk_linear`` f = x - 1/2 (u = (r^3 / 8 - r / 16) cos t); ``annulus`` f = 1
between radii 0.2 and 0.5 (grad u = (r^2 - 0.04) / (2 r) radially).  Per N,
the mean error of grad u over the mean of |grad u| in bands of the distance
from the boundary in spacings sqrt(area / N), and the convergence order
between successive sizes (in the spacing: 4x points is half the spacing).
Writes ``outputs/benchmarks/natural_boundary.csv``.
"""
from __future__ import annotations

import argparse
import math
import os

import _common

_common.add_repo_to_path()

BANDS = ((0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 3.0), (3.0, 6.0), (6.0, math.inf))
CENTRE, RADIUS, HOLE = (0.5, 0.5), 0.5, 0.2


def cases():
    import numpy as np
    import taichi_hh as thh
    disk = thh.Polygon.circle(CENTRE, RADIUS, n=16384)
    annulus = thh.Polygon(disk.outer, holes=[thh.Polygon.circle(CENTRE, HOLE, n=8192).outer[::-1]])
    c = np.array(CENTRE)

    def disk_const(p):
        return np.ones(len(p)), (p - c) / 2

    def disk_linear(p):
        x, y = (p - c).T
        r2 = x * x + y * y
        return x, np.c_[r2 / 8 - RADIUS ** 2 / 4 + x * x / 4, x * y / 4]

    def annulus_const(p):
        x = p - c
        r2 = (x * x).sum(axis=1)
        return np.ones(len(p)), x * ((r2 - HOLE ** 2) / (2 * r2))[:, None]

    return {"disk": (disk, disk_const), "disk_linear": (disk, disk_linear),
            "annulus": (annulus, annulus_const)}


def band_errors(domain, exact, n: int) -> list:
    import numpy as np
    from taichi_hh.hhd import natural
    pts = domain.sample_interior(n, kind="random", seed=1)
    f, grad = exact(pts)
    spacing = math.sqrt(domain.area / n)
    got = natural.natural_potentials(pts, domain, {"u": f}, spacing)["u"][1]
    err = np.linalg.norm(got - grad, axis=1) / np.linalg.norm(grad, axis=1).mean()
    dist = -domain.signed_distance(pts) / spacing
    return [float(err[(dist >= a) & (dist < b)].mean()) for a, b in BANDS]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="disk,disk_linear,annulus")
    ap.add_argument("--sizes", default="4000,16000,64000")
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    table = cases()
    names = [f"{a:g}-{b:g}" for a, b in BANDS]
    rows, printed = [], []
    for case in _common.parse_list(args.cases, str):
        domain, exact = table[case]
        prev = None
        for n in _common.parse_list(args.sizes, int):
            errs = band_errors(domain, exact, n)
            rows.append({"case": case, "n": n, **dict(zip(names, errs))})
            printed.append([case, str(n)] + [f"{e:.2e}" for e in errs])
            print(" ".join(printed[-1]), flush=True)
            if prev is not None:
                orders = [math.log(p / e) / math.log(math.sqrt(n / prev[0]))
                          for p, e in zip(prev[1], errs)]
                printed.append(["", "order"] + [f"{o:.2f}" for o in orders])
                print(" ".join(printed[-1]), flush=True)
            prev = (n, errs)
    print()
    print(_common.format_table(["case", "N"] + names, printed))
    path = os.path.join(args.out_dir, "natural_boundary.csv")
    os.makedirs(args.out_dir, exist_ok=True)
    _common.write_csv_atomic(path, rows, ["case", "n"] + names)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
