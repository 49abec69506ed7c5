"""The natural HHD side by side with its authors' library (issue 17).

    git clone https://github.com/bhatiaharsh/naturalHHD /tmp/naturalHHD
    python benchmarks/natural_peer.py --peer /tmp/naturalHHD/pynhhd-v1.1 [--sizes 1000,3300,6000]

Peer: pynhhd v1.1 (Bhatia et al. 2014, pure Python): on scattered points it
triangulates them (Delaunay, scipy), takes div v and curl v per vertex from
a field given per triangle (constant on each: we give it v at the centroids
and compare its d, r, h there), and sums the free-space Green's function over all
pairs with a dense N x N matrix (O(N^2) time and memory: 8 N^2 bytes, 1.1 GB
at 12k points, hence the default sizes).  It is run as published, with shims
for what no longer imports (``np.float``/``np.int``, removed from numpy; the
``gsw`` and ``joblib`` modules, used only by its spherical solver).

Ours: ``decompose(boundary_condition="natural")`` (particle-mesh FFT).  Same
points (blue noise), same field (``natural`` of
:mod:`taichi_hh.validation.fields`, whose natural parts are exact), same error
measure (mean |error| over mean |v| for d, r, h), wall-clock seconds of the
whole decomposition (the peer's includes its triangulation and Green's
matrix; ours its particle set and neighbours).  One warm-up of ours first.
Writes ``outputs/benchmarks/natural_peer.csv``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import types
import warnings

import _common

_common.add_repo_to_path()


def load_peer(path):
    """Import pynhhd from ``path`` with the shims named in the module doc."""
    import numpy as np
    for name, value in (("float", float), ("int", int)):
        if not hasattr(np, name):
            setattr(np, name, value)
    sys.modules.setdefault("gsw", types.ModuleType("gsw"))
    if "joblib" not in sys.modules:
        try:
            import joblib  # noqa: F401
        except ImportError:
            jl = types.ModuleType("joblib")
            jl.Parallel = lambda **kw: (lambda tasks: [f(*a, **k) for f, a, k in tasks])
            jl.delayed = lambda f: (lambda *a, **k: (f, a, k))
            sys.modules["joblib"] = jl
    sys.path.insert(0, str(path))
    import pynhhd
    return pynhhd


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", required=True, help="a pynhhd-v1.1 directory of naturalHHD")
    ap.add_argument("--sizes", default="1000,3300,6000")
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.validation import fields
    pynhhd = load_peer(args.peer)
    warnings.simplefilter("ignore")

    F = fields.get("natural")

    def errors(d, r, h, ex):
        vm = np.linalg.norm(ex.v, axis=1).mean()
        return [float(np.linalg.norm(a - b, axis=1).mean() / vm)
                for a, b in ((d, ex.d), (r, ex.r), (h, ex.h))]

    pts0 = F.sample(1000, "poisson", seed=1)
    thh.decompose(pts0, F.evaluate(pts0).v, F.domain, boundary_condition="natural")
    rows = []
    for n in _common.parse_list(args.sizes, int):
        pts = F.sample(n, "poisson", seed=1)
        ex = F.evaluate(pts)
        t = time.perf_counter()
        res = thh.decompose(pts, ex.v, F.domain, boundary_condition="natural")
        ours_s = time.perf_counter() - t
        ours = errors(res.curl_free, res.div_free, res.harmonic, ex)
        t = time.perf_counter()
        peer = pynhhd.nHHD(points=pts)
        # the peer takes v per triangle and returns d, r, h per triangle
        centroids = pts[peer.mesh.simplices].mean(axis=1)
        ex_c = F.evaluate(centroids)
        peer.decompose(ex_c.v)
        peer_s = time.perf_counter() - t
        theirs = errors(peer.d, peer.r, peer.h, ex_c)
        row = {"n": len(pts), "ours_s": ours_s, "peer_s": peer_s}
        row.update({f"ours_err_{k}": e for k, e in zip("drh", ours)})
        row.update({f"peer_err_{k}": e for k, e in zip("drh", theirs)})
        rows.append(row)
        print({k: (f"{v:.3g}" if isinstance(v, float) else v) for k, v in row.items()},
              flush=True)
    names = ["n", "ours_s", "peer_s", "ours_err_d", "ours_err_r", "ours_err_h", "peer_err_d",
             "peer_err_r", "peer_err_h"]
    print(_common.format_table(
        ["N", "ours s", "pynhhd s", "ours err d", "r", "h", "pynhhd err d", "r", "h"],
        [[str(r[k]) if k == "n" else f"{r[k]:.3g}" for k in names] for r in rows]))
    path = _common.write_rows(args.out_dir, "natural_peer.csv", rows, names)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
