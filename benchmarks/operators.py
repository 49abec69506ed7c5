"""Benchmark of neighbour search and SPH operator applies.

    python benchmarks/operators.py [--sizes 10000,100000,1000000] [--precision f32,f64]
                                   [--repeats 7] [--quick] [--out-dir DIR] [--threads T]

Points: a lattice of m x m points in the unit square (m = round(sqrt(N)), so
N = 100000 gives 316^2 = 99856 points), every coordinate displaced by a
uniform random amount in [-0.3, 0.3] lattice spacings, then shuffled (seeded)
so that binning starts from an arbitrary order.  Support ratio and kernel are
the :class:`~taichi_hh.sph.pointset.PointSet` defaults.

Each precision runs in its own subprocess (Taichi's precision is runtime-wide).
Every number is the median of ``--repeats`` timed calls made after one
untimed warm-up call (so compilation is excluded); ``ti.sync()`` is called
before every timer stops.  Measured, per N:

setup
  ``bin_reorder``        ``bin_particles`` (CellGrid.sort + Particles.permute) on
                         particles in shuffled order; scratch buffers already
                         allocated by the warm-up call (the steady state).
  ``bin.sort``/``bin.permute``  the two halves of it, timed separately (the
                         sort includes allocating a new CellGrid, as bin_particles does).
  ``bin_reorder_cold``   the same on a freshly built particle set (what
                         PointSet pays: includes allocating the reorder scratch).
  ``rebin_sorted``       ``bin_particles`` on particles that are already binned
                         (about what a simulation step pays, where only a few
                         particles change cells).
  ``pair_build``         ``PairList.build`` (count, scan, fill), buffers reused.
  ``density``            ``Operators.compute_density``.
coefficients
  gradient ``difference``/``corrected``, Laplacian ``brookshaw``/``corrected``
  (each call allocates its coefficient arrays, as the API does).
apply
  ``Operators.gradient/divergence/curl/laplacian`` on Taichi ndarrays from the
  precomputed pair coefficients; variant ``plain`` = difference gradient +
  Brookshaw Laplacian, ``corrected`` = corrected gradient + corrected Laplacian.

``pairs_per_s`` = n_pairs / median time.  ``stream_GBps`` is the compulsory
traffic of an apply (neighbour index + coefficients per pair, per-particle
offsets, self coefficients, input and output) over the median time: a lower
bound on the memory bandwidth the apply achieved.

``--quick`` measures N = 10k only, 3 repeats (a smoke test; it writes the same
files, so give it another ``--out-dir`` to keep a full run's).  The CSV also
records the 1-minute load average, because the machine may be shared.

Writes ``outputs/benchmarks/operators.csv`` and ``operators.png`` (atomically).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (REPO_ROOT, add_repo_to_path, format_table, measure,  # noqa: E402
                     parse_list, save_figure_atomic, summary, write_csv_atomic)

DEFAULT_SIZES = (10_000, 100_000, 1_000_000)
JITTER = 0.3
SEED = 12345
TARGET_APPLY_PAIRS_PER_S = 0.4e9      # f64, 1M particles
TARGET_BIN_SECONDS = 0.1              # binning + reorder at 1M particles

GRADIENT_VARIANTS = {"plain": "difference", "corrected": "corrected"}
LAPLACIAN_VARIANTS = {"plain": "brookshaw", "corrected": "corrected"}
APPLY_OPS = ("gradient", "divergence", "curl", "laplacian")

FIELDS = ["precision", "n_requested", "n", "n_pairs", "group", "operation", "variant",
          "repeats", "median_s", "min_s", "max_s", "pairs_per_s", "stream_GBps", "threads",
          "load_avg_1min"]


# ---------------------------------------------------------------------------
# worker: one precision, every size, in this process

def _stream_bytes(op: str, n: int, n_pairs: int, real: int) -> int:
    """Compulsory memory traffic of one apply (neighbour reads assumed cached)."""
    if op == "gradient":       # f scalar -> vector; G vector
        return n_pairs * (4 + 2 * real) + n * (4 + 2 * real + real + 2 * real)
    if op in ("divergence", "curl"):   # v vector -> scalar; G vector
        return n_pairs * (4 + 2 * real) + n * (4 + 2 * real + 2 * real + real)
    return n_pairs * (4 + real) + n * (4 + real + real + real)   # laplacian


def run_worker(precision: str, sizes, repeats: int, threads: int | None, result_path: str):
    add_repo_to_path()
    import numpy as np
    import taichi_hh
    taichi_hh.init(arch="cpu", precision=precision, threads=threads)
    import taichi as ti
    from taichi_hh import runtime
    from taichi_hh.sph.neighbors import CellGrid, PairList, bin_particles
    from taichi_hh.sph.particles import FLUID, Particles
    from taichi_hh.sph.pointset import DUPLICATE_FRACTION, PointSet
    from taichi_hh.validation.layouts import jittered_lattice

    nthreads = ti.lang.impl.current_cfg().cpu_max_num_threads
    real = np.dtype(runtime.np_real()).itemsize
    rows = []

    def log(msg):
        print(f"[{precision}] {msg}", file=sys.stderr, flush=True)

    for n_req in sizes:
        pts = jittered_lattice(n_req, JITTER, SEED)
        n = pts.shape[0]
        t0 = time.perf_counter()
        ps = PointSet(pts)
        ti.sync()
        log(f"N={n}: PointSet set-up {time.perf_counter() - t0:.2f} s (first one includes compiling)")
        n_pairs = ps.pairs.n_pairs
        spec = ps.grid.spec
        mass = ps.area / n
        base = dict(precision=precision, n_requested=n_req, n=n, n_pairs=n_pairs, threads=nthreads)

        def record(group, operation, variant, times, pairs=None, nbytes=None):
            row = dict(base, group=group, operation=operation, variant=variant, **summary(times))
            med = row["median_s"]
            row["pairs_per_s"] = pairs / med if pairs else ""
            row["stream_GBps"] = nbytes / med / 1e9 if nbytes else ""
            row["load_avg_1min"] = round(os.getloadavg()[0], 2)   # the machine is shared
            rows.append(row)
            extra = f"  {row['pairs_per_s'] / 1e9:.3f} Gpairs/s" if pairs else ""
            log(f"N={n}: {group:12s} {operation:16s} {variant:10s} {med * 1e3:9.3f} ms{extra}")

        # ---- binning + physical reorder ------------------------------------------
        parts = Particles.from_numpy(pts, mass=mass, kind=FLUID)

        def restore_shuffled():
            # undo the previous binning (untimed): slot k must hold input point k again
            orig = parts.original_index.to_numpy()[:n]
            if not np.array_equal(orig, np.arange(n)):
                slot_of = np.empty(n, dtype=np.int32)
                slot_of[orig] = np.arange(n, dtype=np.int32)
                parts.permute(slot_of)

        record("setup", "bin_reorder", "", measure(
            lambda: bin_particles(parts, spec), repeats, sync=ti.sync, setup=restore_shuffled))

        grid = CellGrid(spec)
        record("setup", "bin.sort", "", measure(
            lambda: CellGrid(spec).sort(parts.position, n), repeats, sync=ti.sync,
            setup=restore_shuffled))
        state = {}

        def restore_and_sort():
            restore_shuffled()
            state["order"] = grid.sort(parts.position, n)
            # the inverse permutation, when the grid recorded one for bin_particles
            state["inverse"] = grid.rank

        def permute():
            if state["inverse"] is None:
                parts.permute(state["order"])
            else:
                parts.permute(state["order"], inverse=state["inverse"])

        record("setup", "bin.permute", "", measure(
            permute, repeats, sync=ti.sync, setup=restore_and_sort))

        def fresh_particles():
            state["fresh"] = None
            state["fresh"] = Particles.from_numpy(pts, mass=mass, kind=FLUID)
            ti.sync()

        record("setup", "bin_reorder_cold", "", measure(
            lambda: bin_particles(state["fresh"], spec), repeats, sync=ti.sync,
            setup=fresh_particles))
        state.pop("fresh", None)

        bin_particles(parts, spec)     # now binned: the simulation's steady state
        record("setup", "rebin_sorted", "", measure(
            lambda: bin_particles(parts, spec), repeats, sync=ti.sync))
        del parts, grid, state

        # ---- pair list, density ----------------------------------------------------------
        p = ps.particles
        pl = PairList()
        tol = DUPLICATE_FRACTION * ps.spacing
        record("setup", "pair_build", "", measure(
            lambda: pl.build(p.position, n, p.position, ps.grid, ps.support,
                             duplicate_tolerance=tol), repeats, sync=ti.sync), pairs=n_pairs)
        assert pl.n_pairs == n_pairs
        del pl
        record("setup", "density", "", measure(ps.ops.compute_density, repeats, sync=ti.sync),
               pairs=n_pairs)

        # ---- coefficients ------------------------------------------------------------------
        stencils = {}
        for key, variant in GRADIENT_VARIANTS.items():
            def build(variant=variant, key=key):
                stencils.pop(("g", key), None)      # free the previous one first
                stencils[("g", key)] = ps.ops.gradient_coefficients(variant)
            record("coefficients", "gradient", variant, measure(build, repeats, sync=ti.sync),
                   pairs=n_pairs)
        for key, variant in LAPLACIAN_VARIANTS.items():
            def build(variant=variant, key=key):
                stencils.pop(("l", key), None)
                stencils[("l", key)] = ps.ops.laplacian_coefficients(variant)
            record("coefficients", "laplacian", variant, measure(build, repeats, sync=ti.sync),
                   pairs=n_pairs)

        # ---- applies from precomputed pair data --------------------------------------------
        rt = runtime.real_dtype()
        xy = p.get("position")
        f_nd = ti.ndarray(rt, shape=(n,))
        f_nd.from_numpy((np.sin(2 * np.pi * xy[:, 0]) * np.cos(2 * np.pi * xy[:, 1]))
                        .astype(runtime.np_real()))
        v_nd = ti.Vector.ndarray(2, rt, shape=(n,))
        v_nd.from_numpy(np.stack([np.sin(np.pi * xy[:, 1]), np.cos(np.pi * xy[:, 0])], 1)
                        .astype(runtime.np_real()))
        out_v = ti.Vector.ndarray(2, rt, shape=(n,))
        out_s = ti.ndarray(rt, shape=(n,))
        ops = ps.ops
        for key in ("plain", "corrected"):
            g, lap = stencils[("g", key)], stencils[("l", key)]
            calls = {
                "gradient": lambda: ops.gradient(g, f_nd, out_v),
                "divergence": lambda: ops.divergence(g, v_nd, out_s),
                "curl": lambda: ops.curl(g, v_nd, out_s),
                "laplacian": lambda: ops.laplacian(lap, f_nd, out_s),
            }
            for op in APPLY_OPS:
                record("apply", op, key, measure(calls[op], repeats, sync=ti.sync),
                       pairs=n_pairs, nbytes=_stream_bytes(op, n, n_pairs, real))
        del stencils, ps, p, f_nd, v_nd, out_v, out_s, ops

    with open(result_path, "w") as fh:
        json.dump(rows, fh)


# ---------------------------------------------------------------------------
# parent: one subprocess per precision, then report

def _label(row) -> str:
    if row["group"] == "coefficients":
        return f"coef {row['operation']}"
    if row["group"] == "apply":
        return f"apply {row['operation']}"
    return row["operation"]


def print_tables(rows, file=sys.stdout) -> None:
    for prec in dict.fromkeys(r["precision"] for r in rows):
        sub = [r for r in rows if r["precision"] == prec]
        sizes = list(dict.fromkeys((r["n_requested"], r["n"], r["n_pairs"]) for r in sub))
        keys = list(dict.fromkeys((_label(r), r["variant"]) for r in sub))
        header = ["operation", "variant"]
        for _, n, _ in sizes:
            header += [f"N={n} ms", "Gpair/s"]
        table = []
        for label, variant in keys:
            line = [label, variant]
            for n_req, _, _ in sizes:
                match = [r for r in sub if r["n_requested"] == n_req
                         and (_label(r), r["variant"]) == (label, variant)]
                if match:
                    r = match[0]
                    line.append(f"{r['median_s'] * 1e3:.3f}")
                    line.append(f"{r['pairs_per_s'] / 1e9:.3f}" if r["pairs_per_s"] != "" else "")
                else:
                    line += ["", ""]
            table.append(line)
        threads = sub[0]["threads"]
        pairs = ", ".join(f"N={n}: {p} pairs ({p / n:.1f}/particle)" for _, n, p in sizes)
        loads = [r["load_avg_1min"] for r in sub]
        print(f"\n== precision {prec}, {threads} CPU threads; medians of {sub[0]['repeats']} "
              f"runs; 1-min load average {min(loads):.1f}-{max(loads):.1f} ==\n{pairs}",
              file=file)
        print(format_table(header, table, "ll" + "r" * (len(header) - 2)), file=file)


def check_targets(rows, file=sys.stdout) -> None:
    big = [r for r in rows if r["precision"] == "f64" and r["n_requested"] == 1_000_000]
    print("\n== targets (f64, N = 1M) ==", file=file)
    if not big:
        print("not measured (needs --precision with f64 and --sizes with 1000000)", file=file)
        return
    for r in big:
        if r["group"] == "apply":
            ok = r["pairs_per_s"] >= TARGET_APPLY_PAIRS_PER_S
            print(f"apply {r['operation']:10s} {r['variant']:9s} {r['pairs_per_s'] / 1e9:6.3f} "
                  f"Gpairs/s (target >= {TARGET_APPLY_PAIRS_PER_S / 1e9:.1f})  "
                  f"{'met' if ok else 'MISSED'}   [{r['stream_GBps']:.1f} GB/s streamed]",
                  file=file)
    for r in big:
        if r["operation"] in ("bin_reorder", "rebin_sorted", "bin_reorder_cold"):
            ok = r["median_s"] < TARGET_BIN_SECONDS
            print(f"{r['operation']:17s} {r['median_s']:.4f} s (target < {TARGET_BIN_SECONDS} s)  "
                  f"{'met' if ok else 'MISSED'}", file=file)


def plot(rows, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    apply_rows = [r for r in rows if r["group"] == "apply"]
    precs = list(dict.fromkeys(r["precision"] for r in apply_rows))
    fig, axes = plt.subplots(1, len(precs), figsize=(6 * len(precs), 5), squeeze=False,
                             sharey=True)
    colors = dict(zip(APPLY_OPS, ("C0", "C1", "C2", "C3")))
    for ax, prec in zip(axes[0], precs):
        for op in APPLY_OPS:
            for variant, style in (("plain", "-o"), ("corrected", "--s")):
                sel = sorted((r["n"], r["pairs_per_s"]) for r in apply_rows
                             if r["precision"] == prec and r["operation"] == op
                             and r["variant"] == variant)
                if sel:
                    ax.plot([s[0] for s in sel], [s[1] / 1e9 for s in sel], style,
                            color=colors[op], label=f"{op} ({variant})")
        ax.axhline(TARGET_APPLY_PAIRS_PER_S / 1e9, color="k", lw=0.8, ls=":",
                   label="target (f64, 1M)")
        ax.set_xscale("log")
        ax.set_xlabel("particles N")
        ax.set_title(f"operator apply from precomputed pairs, {prec}")
        ax.grid(True, which="both", alpha=0.3)
    top = max(r["pairs_per_s"] for r in apply_rows) / 1e9
    axes[0][0].set_ylim(0, 1.1 * max(top, TARGET_APPLY_PAIRS_PER_S / 1e9))
    axes[0][0].set_ylabel("G pairs / s (median)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=5, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    save_figure_atomic(fig, path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)),
                    help="comma-separated particle counts (default: %(default)s)")
    ap.add_argument("--precision", default="f32,f64", help="comma-separated: f32, f64")
    ap.add_argument("--repeats", type=int, default=7, help="timed calls per measurement")
    ap.add_argument("--quick", action="store_true", help="smoke test: N=10k, 3 repeats")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--result", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    try:
        sizes = parse_list(args.sizes, int)
    except ValueError:
        ap.error(f"--sizes must be comma-separated integers, got {args.sizes!r}")
    precisions = parse_list(args.precision, str)
    for p in precisions:
        if p not in ("f32", "f64"):
            ap.error(f"unknown precision {p!r}; use f32 and/or f64")
    repeats = args.repeats
    if args.quick:
        sizes, repeats = [10_000], 3
    if repeats < 1 or not sizes or min(sizes) < 4:
        ap.error("need repeats >= 1 and sizes >= 4")

    if args.worker:
        run_worker(precisions[0], sizes, repeats, args.threads, args.result)
        return 0

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_ops_") as tmp:
        for prec in precisions:
            result = os.path.join(tmp, f"{prec}.json")
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--precision", prec,
                   "--sizes", ",".join(map(str, sizes)), "--repeats", str(repeats),
                   "--result", result]
            if args.threads:
                cmd += ["--threads", str(args.threads)]
            print(f"running {prec} in a subprocess ...", file=sys.stderr, flush=True)
            proc = subprocess.run(cmd, stdout=sys.stderr, cwd=str(REPO_ROOT))
            if proc.returncode != 0 or not os.path.exists(result):
                print(f"error: the {prec} worker failed (exit code {proc.returncode}); "
                      "no output files written", file=sys.stderr)
                return 1
            with open(result) as fh:
                rows += json.load(fh)

    print_tables(rows)
    check_targets(rows)
    out = Path(args.out_dir)
    write_csv_atomic(out / "operators.csv", rows, FIELDS)
    plot(rows, out / "operators.png")
    print(f"\nwrote {out / 'operators.csv'} and {out / 'operators.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
