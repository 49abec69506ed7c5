"""Warm seconds of the default decomposition of a data window at scale (issue 28).

    python benchmarks/natural_scale.py [--sizes 100000,300000,1000000] [--repeats 3]
                                       [--kernels] [--resident default|0|1|both]
                                       [--out-dir DIR]

The issue's case: ``decompose(points, vectors, domain)`` with the default
options (``boundary_condition="auto"`` chooses ``natural`` there) on N
uniformly random points in the 2 x 1 window of
:func:`taichi_hh.validation.windows.window_field` (sources and vortices
inside and outside, a stream); target 1M points in 4 s warm on a quiet
2-core machine.  Per N: the first call at that size (the first size's
includes compiling), then ``--repeats`` warm calls: their median and least
wall seconds, the process CPU seconds of the median call (both threads of
the Taichi kernels counted), the stages of ``stats["seconds"]`` (setup:
the data's reach of the boundary; divergence: div v and curl v, fitted at
the grid nodes and interpolated to the points; natural: the rest of the
natural step; checks: energy and harmonic checks; other: input checks, the
default's choice of condition, the caller's units)
and the natural step's own stages (``natural_*`` of ``stats["seconds"]``:
coverage, bins, fit (v fitted at the grid nodes), density, convolve,
interpolate, boundary_fit, divergence (div v and curl v at the points),
gather, harmonic (the harmonic check's fits of h); from
:func:`taichi_hh.hhd.natural.natural_decomposition`), the errors of d, r, h
against the expected split (% of mean |v|), and the load average when the
size started (the machines are shared: compare rows of one run, and CPU
seconds across runs).  ``--kernels`` also times every Taichi kernel launch
(wall and CPU), sums the bytes of the numpy arrays each launch takes (a GPU
arch copies them to the device and back at every launch) and prints the
largest.  ``--resident both`` times the work arrays on the device
(:func:`taichi_hh.runtime.resident`, a GPU's default) and in numpy (the
CPU's and lavapipe's) in one process, their warm calls alternating: a row each.

Writes ``outputs/benchmarks/natural_scale.csv``.
"""
from __future__ import annotations

import argparse
import collections
import os
import statistics
import time
import warnings

import _common

_common.add_repo_to_path()

NATURAL_STAGES = ("coverage", "bins", "fit", "density", "convolve", "interpolate",
                  "boundary_fit", "divergence", "gather", "harmonic")
STAGES = ("setup", "divergence", "natural", "checks")


def _kernel_timer():
    """Wrap Taichi's kernel launches: name -> [calls, wall s, CPU s, bytes of
    numpy arguments] (on a GPU arch Taichi 1.7 copies each numpy argument to
    the device before the launch and back after it)."""
    import numpy as np
    from taichi.lang import kernel_impl
    times = collections.defaultdict(lambda: [0, 0.0, 0.0, 0])
    call = kernel_impl.Kernel.__call__

    def timed(self, *args, **kwargs):
        t, c = time.perf_counter(), time.process_time()
        try:
            return call(self, *args, **kwargs)
        finally:
            entry = times[self.func.__qualname__]
            entry[0] += 1
            entry[1] += time.perf_counter() - t
            entry[2] += time.process_time() - c
            entry[3] += sum(a.nbytes for a in args if isinstance(a, np.ndarray))

    kernel_impl.Kernel.__call__ = timed
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,300000,1000000")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--kernels", action="store_true", help="time every Taichi kernel launch")
    ap.add_argument("--resident", choices=("default", "0", "1", "both"), default="default",
                    help="the work arrays on the device (1), in numpy (0), the arch's "
                         "default, or both, the warm calls alternating (an A/B in one "
                         "process; $TAICHI_HH_RESIDENT)")
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    args = ap.parse_args(argv)
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.validation.windows import window_field

    warnings.simplefilter("ignore")
    thh.init()
    kernels = _kernel_timer() if args.kernels else None
    F = window_field()
    rows = []
    for n in _common.parse_list(args.sizes, int):
        load = os.getloadavg()[0]
        pts = np.random.default_rng(args.seed).random((n, 2)) * [2.0, 1.0]
        ex = F.evaluate(pts)
        _resident("0" if args.resident == "both" else args.resident)
        t = time.perf_counter()
        res = thh.decompose(pts, ex.v, F.domain)
        first = time.perf_counter() - t
        vm = np.linalg.norm(ex.v, axis=1).mean()
        err = [100 * float(np.linalg.norm(a - b, axis=1).mean() / vm)
               for a, b in ((res.curl_free, ex.d), (res.div_free, ex.r),
                            (res.harmonic, ex.h))]
        flags = ("0", "1") if args.resident == "both" else (args.resident,)
        warm_by = {flag: [] for flag in flags}
        for flag in flags[1:]:          # each setting's own kernels compiled before timing
            _resident(flag)
            thh.decompose(pts, ex.v, F.domain)
        for r in range(max(args.repeats, 1)):
            for flag in (flags if r % 2 == 0 else flags[::-1]):
                _resident(flag)
                if kernels is not None:
                    kernels.clear()
                t, c = time.perf_counter(), time.process_time()
                res = thh.decompose(pts, ex.v, F.domain)
                wall, cpu = time.perf_counter() - t, time.process_time() - c
                kern = ({k: tuple(v) for k, v in kernels.items()} if kernels is not None
                        else {})
                sec = dict(res.stats["seconds"])
                nat = {k[len("natural_"):]: v for k, v in sec.items()
                       if k.startswith("natural_")}
                warm_by[flag].append((wall, cpu, sec, nat, kern))
        for flag, warm in warm_by.items():
            _row(rows, flag, warm, n, res, load, first, err)
    _report(args, rows, kernels is not None)
    return 0


def _resident(flag: str) -> None:
    """$TAICHI_HH_RESIDENT for the next call (``default``: unset)."""
    from taichi_hh import runtime
    if flag == "default":
        os.environ.pop(runtime.RESIDENT_VARIABLE, None)
    else:
        os.environ[runtime.RESIDENT_VARIABLE] = flag


def _row(rows: list, flag: str, warm: list, n: int, res, load: float, first: float,
         err: list) -> None:
    """The row of one size (and setting of ``--resident``) from its warm calls."""
    from taichi_hh import runtime
    warm.sort(key=lambda w: w[0])
    wall, cpu, sec, nat, kern = warm[len(warm) // 2]
    _resident(flag)
    row = {"n": n, "resident": int(runtime.resident()),
           "condition": res.stats.get("boundary_condition", ""),
           "grid": "x".join(map(str, res.stats.get("natural_grid", ()))),
           "load": load, "first_s": first,
           "warm_median_s": statistics.median(w[0] for w in warm),
           "warm_min_s": warm[0][0], "cpu_s": cpu}
    for key in STAGES:
        row[f"{key}_s"] = sec.get(key, float("nan"))
    row["other_s"] = wall - sum(sec.get(k, 0.0) for k in STAGES)
    for key in NATURAL_STAGES:
        row[f"nat_{key}_s"] = nat.get(key, float("nan"))
    if kern:
        row["kernels_s"] = sum(v[1] for v in kern.values())
        row["kernels_cpu_s"] = sum(v[2] for v in kern.values())
        row["numpy_args_mb"] = sum(v[3] for v in kern.values()) / 1e6
    row.update(zip(("err_d_pct", "err_r_pct", "err_h_pct"), err))
    rows.append(row)
    print({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()},
          flush=True)
    if kern:
        print(f"    {len(kern)} kernels, {sum(v[0] for v in kern.values())} launches, "
              f"{row['numpy_args_mb']:.0f} MB of numpy arguments")
        for name, (calls, w, c, nb) in sorted(kern.items(), key=lambda kv: -kv[1][1])[:12]:
            print(f"    {w:7.3f} s wall {c:7.3f} s cpu {calls:3d}x {nb / 1e6:6.0f} MB {name}")


def _report(args, rows: list, kernels: bool) -> None:
    """Print the tables and write the CSV."""
    names = ["n", "resident", "condition", "grid", "load", "first_s", "warm_median_s",
             "warm_min_s", "cpu_s"] \
        + [f"{k}_s" for k in STAGES] + ["other_s"] \
        + [f"nat_{k}_s" for k in NATURAL_STAGES] \
        + (["kernels_s", "kernels_cpu_s", "numpy_args_mb"] if kernels else []) \
        + ["err_d_pct", "err_r_pct", "err_h_pct"]
    header = ["N", "dev", "grid", "load", "first s", "warm s", "cpu s", "setup", "div", "natural",
              "checks", "other", "err d, r, h %"]
    table = [[str(r["n"]), str(r["resident"]), r["grid"], f"{r['load']:.1f}", f"{r['first_s']:.2f}",
              f"{r['warm_median_s']:.2f}", f"{r['cpu_s']:.2f}"]
             + [f"{r[f'{k}_s']:.2f}" for k in STAGES + ("other",)]
             + [", ".join(f"{r[k]:.2g}" for k in ("err_d_pct", "err_r_pct", "err_h_pct"))]
             for r in rows]
    print(_common.format_table(header, table))
    nat_header = ["N", "dev"] + list(NATURAL_STAGES)
    nat_table = [[str(r["n"]), str(r["resident"])] + [f"{r[f'nat_{k}_s']:.3f}" for k in NATURAL_STAGES]
                 for r in rows]
    print("natural step, seconds of the median warm call:")
    print(_common.format_table(nat_header, nat_table))
    path = _common.write_rows(args.out_dir, "natural_scale.csv", rows, names)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
