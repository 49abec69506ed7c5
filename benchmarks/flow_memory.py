"""Resident memory of the flow over many steps: does a step leak?

Runs the rising-droplet scene (built as ``scenes/rising_droplet.py`` builds it,
2.5k particles by default) for ``--steps`` steps and records the process's
resident set size (VmRSS of /proc/self/status) every ``--every`` steps, then
prints the growth from step 100 (after the kernels compiled and the buffers
grew to size) to the end.  A step allocates its coefficient and matrix arrays
in the library (:class:`~taichi_hh.sph.operators.Operators`,
:class:`~taichi_hh.poisson.matrix.PoissonMatrix`, the Krylov solvers); Taichi 1.7
frees dropped vector ndarrays only with the ``__del__`` :mod:`taichi_hh.runtime`
adds (taichi-dev/taichi#8763).  ``--without-vector-free`` removes it for the run
to show the leak it prevents.

    python benchmarks/flow_memory.py [--particles 2500] [--steps 600] [--every 50]
        [--without-vector-free] [--out outputs/benchmarks/flow_memory.csv]
"""
import argparse
import gc
import sys
import time

from _common import add_repo_to_path, scene_module, write_csv_atomic

add_repo_to_path()


def rss_mb() -> float:
    """The process's resident set size in MB (VmRSS of /proc/self/status)."""
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS")) / 1024


def drop_vector_free() -> None:
    """Undo the runtime's fix: Taichi's own classes again, without ``__del__``."""
    from taichi.lang import matrix
    for cls in (matrix.VectorNdarray, matrix.MatrixNdarray):
        if "__del__" in vars(cls):
            delattr(cls, "__del__")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=2500)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--every", type=int, default=50, help="record the RSS every this many steps")
    ap.add_argument("--from-step", type=int, default=100,
                    help="the growth is measured from this step to the end")
    ap.add_argument("--without-vector-free", action="store_true",
                    help="remove taichi_hh.runtime's VectorNdarray.__del__ for this run")
    ap.add_argument("--out", default="outputs/benchmarks/flow_memory.csv")
    args = ap.parse_args(argv)

    from taichi_hh import runtime
    from taichi_hh.flow import TwoPhaseFlow
    runtime.ensure_init()
    if args.without_vector_free:
        drop_vector_free()
    scene = scene_module("rising_droplet")
    sp = argparse.ArgumentParser()
    scene.add_arguments(sp)
    scene_args = sp.parse_args([])
    scene_args.particles = args.particles
    pts, phases, dx, params = scene.build(scene_args)
    flow = TwoPhaseFlow(pts, phases, dx, params)

    rows = [{"step": 0, "time": 0.0, "rss_mb": round(rss_mb(), 2), "seconds": 0.0}]
    print(f"{flow.n_fluid} fluid + {flow.particles.n - flow.n_fluid} wall particles, "
          f"{args.steps} steps{' WITHOUT the vector-ndarray free' if args.without_vector_free else ''}")
    print(f"{'step':>6} {'t':>8} {'RSS MB':>9}")
    print(f"{0:6d} {0.0:8.4f} {rows[0]['rss_mb']:9.1f}")
    t0 = time.perf_counter()
    for step in range(1, args.steps + 1):
        flow.step()
        if step % args.every == 0 or step == args.steps:
            gc.collect()
            rows.append({"step": step, "time": round(flow.time, 6), "rss_mb": round(rss_mb(), 2),
                         "seconds": round(time.perf_counter() - t0, 2)})
            print(f"{step:6d} {flow.time:8.4f} {rows[-1]['rss_mb']:9.1f}")
    start = next((r for r in rows if r["step"] >= args.from_step), rows[0])
    growth = rows[-1]["rss_mb"] - start["rss_mb"]
    steps = rows[-1]["step"] - start["step"]
    print(f"growth from step {start['step']} to {rows[-1]['step']}: {growth:+.1f} MB"
          + (f" ({1024 * growth / steps:+.1f} kB per step)" if steps else ""))
    write_csv_atomic(args.out, rows, ["step", "time", "rss_mb", "seconds"])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
