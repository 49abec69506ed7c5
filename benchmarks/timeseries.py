"""Many snapshots on the same points (issue 32): taichi_hh.Decomposer against
one warm decompose() call per snapshot, in the same run.

    python benchmarks/timeseries.py [--layouts grid13k,random100k] [--snapshots 10]
                                    [--conditions auto,neumann,normal-parallel,no-flux]
                                    [--one-off 3] [--batch B] [--interleave]
                                    [--direct] [--dask]
                                    [--out-dir DIR]

The flow: a vortex and a source drifting across a uniform stream (the flow
crosses the window's edges, so ``auto`` chooses ``natural``), T snapshots
on fixed points: ``grid13k`` a 115 x 115 grid on the unit square (13225
points, through the scattered Decomposer as decompose() takes them),
``random100k`` 100k uniformly random points.  Per layout and condition:

* ``one_off_s``: the median of ``--one-off`` warm ``decompose()`` calls
  (after one untimed call that compiles);
* ``setup_s``: the Decomposer's set-up (points, systems, preconditioners, the
  natural set-up, auto's band of points next to the boundary, the natural
  condition's reach check: ``Decomposer.seconds``),
  in a process that made one before (its kernels loaded, as the one-off
  call's are); ``setup_cold_s``: the first one's, kernels loaded;
  ``amortised_s``: (set-up + the stream over T snapshots) / T, after an
  untimed warm-up batch (the joint solve's column width compiles once per
  width); ``per_snapshot_s``: the stream alone over T;
* ``ratio``: amortised_s / one_off_s (the target: <= 0.1 at 13k);
  ``median_snapshot_s``: the median over the stream's batches of a
  snapshot's seconds (the field's making not counted up to ``--hold``
  snapshots), ``snapshot_ratio`` that over one_off_s; the same in CPU
  seconds of the process (all threads): ``one_off_cpu_s``,
  ``median_snapshot_cpu_s``, ``cpu_ratio`` (on a shared, loaded machine the
  CPU seconds move less than the wall time);
  a condition written ``neumann+lu`` runs the Decomposer with
  ``factorize=True`` (each system factorised once by SuperLU, its set-up
  seconds counted in ``setup_s``);
* ``rss_first_mb``, ``rss_last_mb``, ``rss_peak_mb``: the process's resident
  memory after the stream's first and last batch, and its peak (flat: the
  last close to the first; the stream holds one batch, whatever T);
* ``max_rel_diff``: the largest difference of d, r, h against the one-off
  calls' (over their max |.|), on the snapshots both computed;
* with ``--interleave``, a warm one-off call before each batch (the second
  of two in a row), outside the stream's time, and the ratios paired batch by batch (the machine's speed
  drifts by tens of percent within a run, so the one-off calls timed before
  the stream can be on another machine's speed): ``interleaved_one_off_s``,
  ``paired_snapshot_ratio``, ``paired_ratio`` (:func:`paired_ratios`).

``--direct`` adds, per condition with Poisson rows, the sparse direct
alternative for repeated solves: scipy's SuperLU (splu) of the assembled
matrix, its factorisation seconds and seconds per right-hand side, against
the joint Krylov solve's seconds per column (the same matrix, the same
columns, the preconditioner built already).  ``--dask`` adds the
in-process run against a 2-worker ``distributed.LocalCluster`` (one
Decomposer per worker; :func:`taichi_hh.app.dask_series.decompose_dask`).

Writes ``outputs/benchmarks/timeseries.csv`` (and ``timeseries_direct.csv``).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings

import _common

_common.add_repo_to_path()

import numpy as np  # noqa: E402

LAYOUTS = {"grid13k": ("grid", 115), "random100k": ("random", 100_000),
           "grid4k": ("grid", 64), "random13k": ("random", 13_225),
           "random1m": ("random", 1_000_000)}


def layout_points(name: str) -> np.ndarray:
    kind, size = LAYOUTS[name]
    if kind == "grid":
        x = np.linspace(0.0, 1.0, size)
        X, Y = np.meshgrid(x, x)
        return np.c_[X.ravel(), Y.ravel()]
    return np.random.default_rng(0).random((size, 2))


def drifting_flow(points: np.ndarray, t: float) -> np.ndarray:
    """Snapshot at phase t in [0, 1]: a vortex and a source drifting left to
    right through a stream, their strength varying."""
    cx, cy = 0.25 + 0.5 * t, 0.5 + 0.1 * np.sin(2 * np.pi * t)
    dx, dy = points[:, 0] - cx, points[:, 1] - cy
    g = np.exp(-(dx * dx + dy * dy) / 0.02)
    s = 1.0 + 0.5 * np.cos(2 * np.pi * t)
    return np.c_[0.4 - s * dy * g + 0.6 * dx * g, s * dx * g + 0.6 * dy * g]


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def peak_mb() -> float:
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_condition(thh, layout: str, points, condition: str, args) -> dict:
    T = args.snapshots
    phases = np.linspace(0.0, 1.0, T)
    # "neumann+lu": the Decomposer with factorize=True (SuperLU once per system)
    factorize = condition.endswith("+lu")
    base = condition[:-3] if factorize else condition
    options = {} if base == "auto" else {"boundary_condition": base}
    thh.decompose(points, drifting_flow(points, 0.0), **options)          # compile
    k = min(args.one_off, T)
    one_off, one_off_cpu, refs = [], [], []
    for t in phases[:k]:
        t0, c0 = time.perf_counter(), time.process_time()
        refs.append(thh.decompose(points, drifting_flow(points, t), **options))
        one_off.append(time.perf_counter() - t0)
        one_off_cpu.append(time.process_time() - c0)

    def made():
        t0 = time.perf_counter()
        dec = thh.Decomposer(points, batch=args.batch, factorize=factorize, **options)
        construct = time.perf_counter() - t0
        # the first batch builds the systems (timed into the set-up) and
        # compiles the joint solve's width (once per machine's cache)
        t0 = time.perf_counter()
        list(dec.stream(drifting_flow(points, t) for t in phases[:dec.batch]))
        first = time.perf_counter() - t0
        setup = construct + sum(t for c, t in dec.seconds.items() if c != "last_batch")
        return dec, setup, first
    # the first Decomposer in the process also loads its kernels (as the
    # one-off's untimed call does its own): the set-up compared is the second's
    _, setup_cold, _ = made()
    dec, setup, first_batch = made()
    rss, diffs, conditions = [], [], {}
    snaps = [drifting_flow(points, t) for t in phases] if T <= args.hold else None
    # a warm one-off call before each batch, outside the stream's time: each
    # batch's snapshot against the call timed next to it (the machine's
    # speed drifts by tens of percent within a run); two calls, the second
    # timed, as a caller's loop of one-off calls runs them (the caches theirs)
    interleaved, paired = [], []

    def one_off_now(t):
        s0 = time.perf_counter()
        fld = drifting_flow(points, t)
        thh.decompose(points, fld, **options)
        s1 = time.perf_counter()
        thh.decompose(points, fld, **options)
        interleaved.append(time.perf_counter() - s1)
        return time.perf_counter() - s0
    if args.interleave:
        one_off_now(phases[0])
    outside = 0.0                       # the stream's seconds spent on one-off calls
    batches, last = [], (time.perf_counter(), time.process_time(), 0)
    t0, c0 = time.perf_counter(), time.process_time()
    for i, res in enumerate(dec.stream(snaps if snaps is not None else
                                       (drifting_flow(points, t) for t in phases))):
        conditions[res.stats["boundary_condition"]] = \
            conditions.get(res.stats["boundary_condition"], 0) + 1
        if i < k:
            ref = refs[i]
            for name in ("curl_free", "div_free", "harmonic"):
                a, b = getattr(res, name), getattr(ref, name)
                diffs.append(float(np.abs(a - b).max() / np.abs(b).max()))
        if (i + 1) % dec.batch == 0 or i + 1 == T:
            rss.append(rss_mb())
            now = (time.perf_counter(), time.process_time(), i + 1)
            batches.append(((now[0] - last[0]) / (now[2] - last[2]),
                            (now[1] - last[1]) / (now[2] - last[2])))
            if args.interleave:
                # (the batch's seconds, its snapshots, the one-off timed before it)
                paired.append((now[0] - last[0], now[2] - last[2], interleaved[-1]))
                if i + 1 < T:
                    c1 = time.process_time()
                    outside += one_off_now(phases[i + 1])
                    c0 += time.process_time() - c1
                    now = (time.perf_counter(), time.process_time(), i + 1)
            last = now
    stream, stream_cpu = time.perf_counter() - t0 - outside, time.process_time() - c0
    median = statistics.median(one_off)
    median_cpu = statistics.median(one_off_cpu)
    amortised = (setup + stream) / T
    batch_wall = statistics.median(b[0] for b in batches)
    batch_cpu = statistics.median(b[1] for b in batches)
    return {"layout": layout, "n_points": len(points), "condition": condition,
            "chosen": "+".join(f"{c}:{n}" for c, n in sorted(conditions.items())),
            "snapshots": T, "batch": dec.batch, "one_off_s": median,
            "setup_s": setup, "setup_cold_s": setup_cold, "first_batch_s": first_batch, "per_snapshot_s": stream / T,
            "amortised_s": amortised, "ratio": amortised / median,
            "median_snapshot_s": batch_wall, "snapshot_ratio": batch_wall / median,
            "one_off_cpu_s": median_cpu, "per_snapshot_cpu_s": stream_cpu / T,
            "median_snapshot_cpu_s": batch_cpu, "cpu_ratio": batch_cpu / median_cpu,
            "rss_first_mb": rss[0], "rss_last_mb": rss[-1], "rss_peak_mb": peak_mb(),
            "max_rel_diff": max(diffs) if diffs else float("nan"),
            **paired_ratios(paired, interleaved, setup, T)}


def paired_ratios(paired: list, interleaved: list, setup: float, T: int) -> dict:
    """``--interleave``'s figures: ``interleaved_one_off_s`` the median of the
    one-off calls timed between the batches; ``paired_snapshot_ratio`` the
    median over batches of a snapshot's seconds over the one-off call timed
    just before its batch; ``paired_ratio`` the amortised ratio so paired:
    the sum over batches of (the batch's seconds / its one-off call) plus
    the set-up over the median one-off call, over T (a short last batch
    counted as it is)."""
    if not paired:
        return {"interleaved_one_off_s": float("nan"), "paired_snapshot_ratio": float("nan"),
                "paired_ratio": float("nan")}
    median = statistics.median(interleaved)
    return {"interleaved_one_off_s": median,
            "paired_snapshot_ratio": statistics.median(s / n / o for s, n, o in paired),
            "paired_ratio": (sum(s / o for s, n, o in paired) + setup / median) / T}


def run_direct(thh, layout: str, points, condition: str, args) -> dict | None:
    """SuperLU of the assembled matrix against the joint Krylov solve."""
    import scipy.sparse.linalg as sla
    from taichi_hh.hhd.decompose import options_for
    from taichi_hh.hhd.inputs import prepare_data
    from taichi_hh.hhd.poisson_setup import right_hand_sides, unit_setup
    if condition in ("auto", "no-flux", "natural") or condition.endswith("+lu"):
        return None
    opts = options_for(boundary_condition=condition)
    data = prepare_data(points, drifting_flow(points, 0.0), None)
    setup = unit_setup(data.unit_points, data.unit_domain, opts, None, data)
    A = setup.A
    cols = 2 * (args.batch or 8)
    rhs = [right_hand_sides(setup, drifting_flow(points, t)) for t in np.linspace(0.0, 1.0,
                                                                                  cols // 2)]
    B = np.stack([r[name] for r in rhs for name in ("phi", "psi")], axis=1)
    kw = dict(tol=opts.tol, preconditioner=opts.preconditioner,
              multilevel_options=dict(opts.multilevel_options))
    from taichi_hh.hhd.operator_split import MAX_COLUMNS
    A.solve_columns(B[:, :MAX_COLUMNS], **kw)            # compile and preconditioner
    t0 = time.perf_counter()
    # the Decomposer's joint solves: MAX_COLUMNS columns at a time
    krylov = [r for a in range(0, cols, MAX_COLUMNS)
              for r in A.solve_columns(B[:, a:a + MAX_COLUMNS], **kw)]
    krylov_s = (time.perf_counter() - t0) / cols
    S = A.to_scipy().tocsc()
    if A.bordered:
        Bd = np.vstack([B, np.zeros((1, cols))])
    else:
        Bd = B
    t0 = time.perf_counter()
    lu = sla.splu(S)
    factor_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    X = lu.solve(Bd)
    solve_s = (time.perf_counter() - t0) / cols
    diff = max(float(np.abs(X[:A.n_particles, c] - krylov[c].x).max()
                     / max(np.abs(krylov[c].x).max(), 1e-300)) for c in range(cols))
    return {"layout": layout, "n_points": len(points), "condition": condition,
            "columns": cols, "krylov_per_column_s": krylov_s,
            "krylov_iterations": statistics.median(r.iterations for r in krylov),
            "splu_factor_s": factor_s, "splu_per_column_s": solve_s,
            "splu_fill_nnz": int(lu.L.nnz + lu.U.nnz), "matrix_nnz": int(S.nnz),
            "break_even_columns": factor_s / max(krylov_s - solve_s, 1e-12)
            if krylov_s > solve_s else float("inf"),
            "max_rel_diff": diff}


def run_dask(thh, layout: str, points, args) -> dict:
    from taichi_hh.app.dask_series import decompose_dask
    from distributed import Client, LocalCluster
    T = args.snapshots
    V = np.stack([drifting_flow(points, t) for t in np.linspace(0.0, 1.0, T)])
    t0 = time.perf_counter()
    local = thh.Decomposer(points, batch=args.batch).decompose(V)
    in_process = time.perf_counter() - t0
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster, \
            Client(cluster) as client:
        decompose_dask(points, V[:2], client=client)        # workers compile
        t0 = time.perf_counter()
        remote = decompose_dask(points, V, client=client)
        dask_s = time.perf_counter() - t0
    diff = float(np.abs(remote.curl_free - local.curl_free).max()
                 / np.abs(local.curl_free).max())
    return {"layout": layout, "n_points": len(points), "condition": "auto (dask)",
            "snapshots": T, "in_process_s": in_process, "dask_2_workers_s": dask_s,
            "speedup": in_process / dask_s, "max_rel_diff": diff}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--layouts", default="grid13k,random100k")
    ap.add_argument("--snapshots", type=int, default=10)
    ap.add_argument("--conditions", default="auto,neumann,normal-parallel,no-flux")
    ap.add_argument("--one-off", type=int, default=3)
    ap.add_argument("--batch", type=int, default=None)
    ap.add_argument("--hold", type=int, default=200,
                    help="series of at most this many snapshots made before the stream "
                         "(longer ones made as it reads them: memory flat)")
    ap.add_argument("--interleave", action="store_true",
                    help="a warm one-off call before each batch (not in the stream's "
                         "time): the ratios paired batch by batch")
    ap.add_argument("--direct", action="store_true")
    ap.add_argument("--dask", action="store_true")
    ap.add_argument("--out-dir", default=str(_common.REPO_ROOT / "outputs" / "benchmarks"))
    args = ap.parse_args(argv)
    import taichi_hh as thh
    thh.init(arch="cpu", precision="f64")
    warnings.simplefilter("ignore")
    os.makedirs(args.out_dir, exist_ok=True)
    rows, direct, dask_rows = [], [], []
    for layout in _common.parse_list(args.layouts, str):
        points = layout_points(layout)
        for condition in _common.parse_list(args.conditions, str):
            row = run_condition(thh, layout, points, condition, args)
            rows.append(row)
            print(f"{layout:>10} {condition:>15} [{row['chosen']}] T={row['snapshots']} "
                  f"batch={row['batch']}: one-off {row['one_off_s']:.3f} s, set-up "
                  f"{row['setup_s']:.2f} s (first in the process {row['setup_cold_s']:.2f} s), per snapshot {row['per_snapshot_s']:.3f} s, "
                  f"amortised {row['amortised_s']:.3f} s = {row['ratio']:.2f}x; a snapshot "
                  f"(median of batches) {row['median_snapshot_s']:.4f} s = "
                  f"{row['snapshot_ratio']:.2f}x, CPU {row['median_snapshot_cpu_s']:.4f} s "
                  f"against {row['one_off_cpu_s']:.3f} s = {row['cpu_ratio']:.2f}x; rss "
                  f"{row['rss_first_mb']:.0f} -> {row['rss_last_mb']:.0f} MB (peak "
                  f"{row['rss_peak_mb']:.0f}); diff {row['max_rel_diff']:.1e}"
                  + (f"; paired with {row['interleaved_one_off_s']:.3f} s one-off calls "
                     f"between batches: a snapshot {row['paired_snapshot_ratio']:.3f}x, "
                     f"amortised {row['paired_ratio']:.3f}x" if args.interleave else ""),
                  flush=True)
            if args.direct:
                d = run_direct(thh, layout, points, condition, args)
                if d is not None:
                    direct.append(d)
                    print(f"{'':>10} {'direct':>15}: Krylov {d['krylov_per_column_s'] * 1e3:.1f}"
                          f" ms/column ({d['krylov_iterations']} it), splu factor "
                          f"{d['splu_factor_s']:.2f} s + {d['splu_per_column_s'] * 1e3:.1f} ms"
                          f"/column (fill {d['splu_fill_nnz'] / d['matrix_nnz']:.1f}x), "
                          f"break-even {d['break_even_columns']:.0f} columns, diff "
                          f"{d['max_rel_diff']:.1e}", flush=True)
        if args.dask:
            d = run_dask(thh, layout, points, args)
            dask_rows.append(d)
            print(f"{layout:>10} {'dask':>15}: in-process {d['in_process_s']:.2f} s, 2 workers "
                  f"{d['dask_2_workers_s']:.2f} s ({d['speedup']:.2f}x), diff "
                  f"{d['max_rel_diff']:.1e}", flush=True)
    if rows:
        _common.write_csv_atomic(os.path.join(args.out_dir, "timeseries.csv"), rows,
                                 list(rows[0]))
    if direct:
        _common.write_csv_atomic(os.path.join(args.out_dir, "timeseries_direct.csv"), direct,
                                 list(direct[0]))
    if dask_rows:
        _common.write_csv_atomic(os.path.join(args.out_dir, "timeseries_dask.csv"), dask_rows,
                                 list(dask_rows[0]))


if __name__ == "__main__":
    main()
