"""Per-step profile of the two-phase flow (the rising droplet at its defaults)
and the step's distance from a modelled lower bound (issue 16).

    python benchmarks/flow_profile.py [--particles 10000] [--warmup 8] [--steps 20]
                                      [--threads N] [--out-dir outputs/benchmarks]

Builds scenes/rising_droplet.py's flow (its own set-up, through the library; no
frames), runs ``--warmup`` steps (compilation, the start-up transient), then
profiles ``--steps`` steps, each instrumented:

* time per phase: the flow's own stage clock (``flow.clock.detail``), median
  ms per step;
* kernel launches: every Taichi kernel call is counted and timed (wall and
  process CPU time, both cores summed), by kernel; a kernel whose CPU/wall is
  near 1 ran on one thread (serial loops: ``ti.loop_config(serialize=True)``,
  the multilevel cycle under ``SERIAL_MAX_N``, the Krylov vector kernels under
  ``PARALLEL_MIN_SIZE``);
* host round trips: ``to_numpy``/``from_numpy`` calls on Taichi ndarrays and the
  bytes they move, per step;
* the loop's CPU time over its wall time.

Lower bound model.  The step's unavoidable work is its passes over the pair
list: every pass reads, per pair, a neighbour index (4 B) and at least one
coefficient (8 B) and gathers the neighbour's value.  The passes per step are
counted from the algorithm (``PASSES_OUTSIDE_SOLVE`` plus, per BiCGSTAB
iteration, 2 operator applies and 2 V-cycles of 1 + post = 3 particle-level
pair passes each, plus 2 applies per solve: the initial residual and the one
confirming convergence), times the pair count.  The
bound is those pair evaluations over the measured throughput of one operator
apply ``A x`` (the Poisson matrix, both cores available) net of the launch
cost of an empty kernel, which also bounds the bytes (the apply streams the
same index and coefficient per pair).  The benchmark prints the step over that
bound, and over the bound plus a launch floor (launches per step times the
empty kernel's launch).

Writes OUT/flow_profile.csv (one row per particle count: the phase, kernel and
copy figures) and OUT/flow_profile_kernels.csv (per kernel).
"""
import argparse
import inspect
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import (REPO_ROOT, add_repo_to_path, format_table, parse_list,  # noqa: E402
                     scene_module, write_csv_atomic)

add_repo_to_path()

import taichi as ti  # noqa: E402
from taichi_hh.app.scene import SOLVER_TOL  # noqa: E402

#: the scenes' pressure-solver tolerance in f64, the default here
SCENE_SOLVER_TOL = SOLVER_TOL["f64"]


@ti.kernel
def _trivial(a: ti.types.ndarray(), b: ti.types.ndarray()):
    for i in range(1):
        b[i] = a[i]

#: pair passes of a step outside the pressure solve (counted in twophase._step
#: with the defaults: nu > 0, corrected operators, shifting on):
#: neighbour search 1, wall velocity (viscous) 1, the coefficient kernel 3 (its
#: three pair loops build the corrected Laplacian, the corrected gradient, both
#: density-weighted copies and the concentration gradient), viscous apply 1,
#: Poisson assembly 1, the right-hand side 3 (wall velocity, divergence, wall
#: rows), pressure-gradient correction 1, measured divergence 2 (the multilevel
#: hierarchy's level-1 stencil, one more, is left out as before)
PASSES_OUTSIDE_SOLVE = 13
#: per solve: the initial residual's apply and the apply confirming convergence
PASSES_PER_SOLVE = 2
#: per BiCGSTAB iteration: 2 applies + 2 V-cycles x (1 + post 2) passes
PASSES_PER_ITERATION = 2 + 2 * 3


class KernelMeter:
    """Counts and times every Taichi kernel call (wall and process CPU seconds)
    and every ndarray host copy while active."""

    def __init__(self):
        self.calls, self.wall, self.cpu = {}, {}, {}
        self.copies = {"to_numpy": 0, "from_numpy": 0}
        self.copy_bytes = {"to_numpy": 0, "from_numpy": 0}
        self.serial_flag = {}

    def __enter__(self):
        from taichi.lang import kernel_impl
        from taichi.lang._ndarray import Ndarray
        self._kernel_cls = kernel_impl.Kernel
        self._orig_call = self._kernel_cls.__call__
        meter = self
        orig_call = self._orig_call

        def call(kernel, *args, **kwargs):
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                return orig_call(kernel, *args, **kwargs)
            finally:
                w, c = time.perf_counter() - t0, time.process_time() - c0
                name = _kernel_name(kernel)
                meter.calls[name] = meter.calls.get(name, 0) + 1
                meter.wall[name] = meter.wall.get(name, 0.0) + w
                meter.cpu[name] = meter.cpu.get(name, 0.0) + c
                if name not in meter.serial_flag:
                    meter.serial_flag[name] = _serial_loops(kernel, args)

        self._kernel_cls.__call__ = call
        self._nd = Ndarray
        self._orig_nd = {}
        for attr, kind in (("_ndarray_to_numpy", "to_numpy"),
                           ("_ndarray_matrix_to_numpy", "to_numpy"),
                           ("_ndarray_from_numpy", "from_numpy"),
                           ("_ndarray_matrix_from_numpy", "from_numpy")):
            orig = getattr(Ndarray, attr)
            self._orig_nd[attr] = orig

            def wrapped(arr, *a, _orig=orig, _kind=kind, **k):
                meter.copies[_kind] += 1
                meter.copy_bytes[_kind] += _nbytes(arr)
                return _orig(arr, *a, **k)
            setattr(Ndarray, attr, wrapped)
        return self

    def __exit__(self, *exc):
        self._kernel_cls.__call__ = self._orig_call
        for attr, orig in self._orig_nd.items():
            setattr(self._nd, attr, orig)

    def reset(self):
        self.__init__()


def _kernel_name(kernel) -> str:
    f = getattr(kernel, "func", None)
    mod = getattr(f, "__module__", "?").replace("taichi_hh.", "")
    return f"{mod}.{getattr(f, '__name__', '?')}"


def _serial_loops(kernel, args) -> str:
    """'all' when every loop of the kernel is serialized for these arguments,
    'some' when some loop is, '' otherwise (from its source and, for the kernels
    that take the choice as an argument or closure variable, its value)."""
    f = getattr(kernel, "func", None)
    try:
        src = inspect.getsource(f)
    except (OSError, TypeError):
        return "?"
    if "serialize=serial" in src:
        serial = None
        closure = inspect.getclosurevars(f).nonlocals
        if "serial" in closure:
            serial = bool(closure["serial"])
        elif args and isinstance(args[0], bool):
            serial = args[0]
        if serial:
            return "all"
        return "some" if "serialize=True" in src else ""
    return "some" if "serialize=True" in src else ""


def _nbytes(arr) -> int:
    try:
        import numpy as np
        n = int(np.prod(arr.shape))
        width = getattr(arr, "n", 1) * getattr(arr, "m", 1) if hasattr(arr, "n") else 1
        return n * width * 8
    except Exception:
        return 0


def build_flow(particles: int, solver_tol: float | None = None, **params_changes):
    import dataclasses
    from taichi_hh.flow.twophase import TwoPhaseFlow
    scene = scene_module("rising_droplet")
    ap = argparse.ArgumentParser()
    ap.add_argument("--particles", type=int)
    scene.SCENE.add_arguments(ap)
    args = ap.parse_args(["--particles", str(particles)])
    pts, phases, dx, params = scene.SCENE.build(args)
    if solver_tol is None:
        solver_tol = SCENE_SOLVER_TOL
    params = dataclasses.replace(params, solver_tol=solver_tol,   # default: the scene's (f64)
                                 **params_changes)
    return TwoPhaseFlow(pts, phases, dx, params)


def launch_cost(repeats: int = 300) -> float:
    """Median wall seconds of launching a kernel that does (almost) nothing: two
    ndarray arguments, one parallel loop of one iteration."""
    import taichi as ti
    from taichi_hh import runtime
    a = ti.ndarray(runtime.real_dtype(), shape=(4,))
    b = ti.ndarray(runtime.real_dtype(), shape=(4,))
    _trivial(a, b)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        _trivial(a, b)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def apply_throughput(flow, repeats: int = 30) -> dict:
    """Pairs per second of one Poisson-matrix apply on the flow's current pairs."""
    import numpy as np
    import taichi as ti
    from taichi_hh import runtime
    from taichi_hh.flow.twophase import FLUID
    ops = flow.ops
    st = ops.laplacian_coefficients(flow.params.viscous_laplacian, row_kinds=(FLUID,))
    from taichi_hh.poisson.matrix import PoissonMatrix
    A = PoissonMatrix(ops, laplacian=ops.density_weighted(st), gradient=ops.gradient_coefficients(
        flow.params.gradient, row_kinds=(FLUID,)), kappa=0.0, bordered=True)
    x = ti.ndarray(runtime.real_dtype(), shape=(A.n,))
    y = ti.ndarray(runtime.real_dtype(), shape=(A.n,))
    x.from_numpy(np.random.default_rng(0).standard_normal(A.n))
    A.apply(x, y)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        A.apply(x, y)
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    return {"apply_s": t, "pairs": flow.pairs.n_pairs, "pairs_per_s": flow.pairs.n_pairs / t}


def profile(particles: int, warmup: int, steps: int,
            solver_tol: float | None = None, **params_changes) -> tuple[dict, list[dict]]:
    flow = build_flow(particles, solver_tol, **params_changes)
    for _ in range(warmup):
        flow.step()
    flow.reset_timings()
    per_step, details, iters, cpu_wall, cpu_step = [], [], [], [], []
    with KernelMeter() as meter:
        t_loop, c_loop = time.perf_counter(), time.process_time()
        for _ in range(steps):
            before = dict(flow.clock.detail)
            t0, c0 = time.perf_counter(), time.process_time()
            info = flow.step()
            w, c = time.perf_counter() - t0, time.process_time() - c0
            per_step.append(w)
            cpu_wall.append(c / w)
            cpu_step.append(c)
            iters.append(info["iterations"])
            details.append({k: v - before.get(k, 0.0) for k, v in flow.clock.detail.items()})
        loop_wall, loop_cpu = time.perf_counter() - t_loop, time.process_time() - c_loop
    thr = apply_throughput(flow)
    launch = launch_cost()
    n_pairs = flow.pairs.n_pairs
    med_it = statistics.median(iters)
    passes = PASSES_OUTSIDE_SOLVE + PASSES_PER_SOLVE + PASSES_PER_ITERATION * med_it
    # the apply's own launch cost taken out: pairs per second of the loop itself
    net_rate = n_pairs / max(thr["apply_s"] - launch, 0.1 * thr["apply_s"])
    bound = passes * n_pairs / net_rate
    launch_floor = sum(meter.calls.values()) / steps * launch
    step = statistics.median(per_step)
    row = {"fluid_particles": flow.n_fluid, "all_particles": flow.particles.n,
           "solver_tol": flow.params.solver_tol, "warm_start": getattr(flow.params, "warm_start", "previous"),
           "pairs": n_pairs, "steps": steps, "ms_per_step": 1e3 * step,
           "particle_steps_per_s": flow.n_fluid / step,
           # process CPU ms per step (both cores summed): steadier than wall time on a
           # shared machine while the step runs on one core
           "cpu_ms_per_step": 1e3 * statistics.median(cpu_step),
           "mean_iterations": statistics.fmean(iters),
           "median_iterations": med_it, "cpu_over_wall": loop_cpu / loop_wall,
           "kernel_launches_per_step": sum(meter.calls.values()) / steps,
           "to_numpy_per_step": meter.copies["to_numpy"] / steps,
           "from_numpy_per_step": meter.copies["from_numpy"] / steps,
           "host_mb_per_step": sum(meter.copy_bytes.values()) / steps / 1e6,
           "kernel_ms_per_step": 1e3 * sum(meter.wall.values()) / steps,
           "serial_kernel_ms_per_step": 1e3 * sum(
               w for k, w in meter.wall.items() if meter.serial_flag.get(k) == "all") / steps,
           "apply_ms": 1e3 * thr["apply_s"], "apply_gpairs_per_s": thr["pairs_per_s"] / 1e9,
           "pair_passes_per_step": passes,
           "launch_us": 1e6 * launch, "net_gpairs_per_s": net_rate / 1e9,
           "bound_ms_per_step": 1e3 * bound, "step_over_bound": step / bound,
           "launch_floor_ms_per_step": 1e3 * launch_floor,
           "step_over_bound_and_launches": step / (bound + launch_floor),
           "bytes_per_step_mb": passes * n_pairs * 12 / 1e6}
    keys = sorted({k for d in details for k in d})
    for k in keys:
        row[f"phase.{k}_ms"] = 1e3 * statistics.median(d.get(k, 0.0) for d in details)
    kernels = []
    for name in sorted(meter.calls, key=lambda k: -meter.wall[k]):
        kernels.append({"fluid_particles": flow.n_fluid, "kernel": name,
                        "launches_per_step": meter.calls[name] / steps,
                        "ms_per_step": 1e3 * meter.wall[name] / steps,
                        "cpu_over_wall": meter.cpu[name] / max(meter.wall[name], 1e-12),
                        "serial_loops": meter.serial_flag.get(name, "")})
    return row, kernels


def ab(particles: int, warmup: int, steps: int, field: str, value: str) -> dict:
    """Two flows, the default and one with ``field = value``, stepped in turn
    (so that both see the same machine load): median step seconds, CPU seconds
    and iterations of each."""
    from taichi_hh.flow.twophase import FlowParams
    kind = type(getattr(FlowParams(), field))
    flows = {"default": build_flow(particles),
             f"{field}={value}": build_flow(particles, **{field: kind(value)})}
    for f in flows.values():
        for _ in range(warmup):
            f.step()
    wall = {k: [] for k in flows}
    cpu = {k: [] for k in flows}
    its = {k: [] for k in flows}
    for _ in range(steps):
        for k, f in flows.items():
            t0, c0 = time.perf_counter(), time.process_time()
            info = f.step()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
            its[k].append(info["iterations"])
    out = {}
    for k in flows:
        out[k] = {"ms_per_step": 1e3 * statistics.median(wall[k]),
                  "cpu_ms_per_step": 1e3 * statistics.median(cpu[k]),
                  "mean_iterations": statistics.fmean(its[k])}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--particles", default="10000", help="comma-separated fluid particle counts")
    ap.add_argument("--warmup", type=int, default=8, help="steps before profiling")
    ap.add_argument("--steps", type=int, default=20, help="profiled steps")
    ap.add_argument("--solver-tol", type=float, default=None,
                    help=f"pressure solver tolerance (default: the scene's, {SCENE_SOLVER_TOL:g})")
    ap.add_argument("--warm-start", default=None,
                    help="FlowParams.warm_start (default: the flow's)")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    ap.add_argument("--arch", default=None,
                    help="Taichi arch (default: $TAICHI_HH_ARCH, else cpu; docs/arch.md)")
    ap.add_argument("--top", type=int, default=25, help="kernels listed")
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    ap.add_argument("--ab", default=None, metavar="FIELD=VALUE",
                    help="instead of the profile: step the default flow and one with this "
                         "FlowParams change in turn and compare their step times")
    args = ap.parse_args(argv)
    import taichi_hh
    taichi_hh.init(arch=args.arch, precision="f64", threads=args.threads, verbose=False)
    if args.ab:
        field, value = args.ab.split("=", 1)
        for n in parse_list(args.particles, int):
            res = ab(n, args.warmup, args.steps, field, value)
            (ka, a), (kb, b) = res.items()
            print(format_table(["particles", "flow", "ms/step", "CPU ms/step", "mean it."],
                               [[n, k, f"{r['ms_per_step']:.1f}", f"{r['cpu_ms_per_step']:.1f}",
                                 f"{r['mean_iterations']:.2f}"] for k, r in res.items()]))
            print(f"{ka} / {kb}: step {a['ms_per_step'] / b['ms_per_step']:.3f}, "
                  f"CPU {a['cpu_ms_per_step'] / b['cpu_ms_per_step']:.3f}, "
                  f"iterations {a['mean_iterations'] / b['mean_iterations']:.3f}")
        return 0
    rows, kernels = [], []
    for n in parse_list(args.particles, int):
        changes = {"warm_start": args.warm_start} if args.warm_start else {}
        row, ks = profile(n, args.warmup, args.steps, args.solver_tol, **changes)
        rows.append(row)
        kernels += ks
        phases = [(k[len("phase."):-3], v) for k, v in row.items() if k.startswith("phase.")]
        print(f"\n{row['fluid_particles']} fluid particles ({row['all_particles']} with walls, "
              f"{row['pairs']} pairs), median of {row['steps']} steps: "
              f"{row['ms_per_step']:.1f} ms/step ({row['cpu_ms_per_step']:.1f} CPU ms), "
              f"{row['particle_steps_per_s']:.3g} particle-steps/s, "
              f"{row['median_iterations']:.0f} BiCGSTAB iterations (mean {row['mean_iterations']:.1f}), CPU/wall {row['cpu_over_wall']:.2f}")
        print(format_table(["phase", "ms/step", "share"],
                           [[k, f"{v:.2f}", f"{100 * v / row['ms_per_step']:.0f}%"]
                            for k, v in sorted(phases, key=lambda kv: -kv[1])]))
        print(format_table(["kernel", "launches/step", "ms/step", "CPU/wall", "serial loops"],
                           [[k["kernel"], f"{k['launches_per_step']:.1f}", f"{k['ms_per_step']:.2f}",
                             f"{k['cpu_over_wall']:.2f}", k["serial_loops"]]
                            for k in ks[: args.top]]))
        print(f"kernel launches/step {row['kernel_launches_per_step']:.0f} "
              f"({row['kernel_ms_per_step']:.1f} ms inside kernels, "
              f"{row['serial_kernel_ms_per_step']:.1f} ms in all-serial kernels); host copies/step: "
              f"{row['to_numpy_per_step']:.0f} to_numpy + {row['from_numpy_per_step']:.0f} from_numpy, "
              f"{row['host_mb_per_step']:.1f} MB")
        print(f"lower bound: {row['pair_passes_per_step']:.0f} pair passes x {row['pairs']} pairs "
              f"({row['bytes_per_step_mb']:.0f} MB of indices and coefficients) at the apply's "
              f"throughput net of its launch, {row['net_gpairs_per_s']:.2f} G pairs/s "
              f"({row['apply_ms']:.2f} ms per apply, {row['apply_gpairs_per_s']:.2f} G pairs/s "
              f"with the launch) = {row['bound_ms_per_step']:.1f} ms; step / bound = "
              f"{row['step_over_bound']:.1f}")
        print(f"launch floor: {row['kernel_launches_per_step']:.0f} launches x "
              f"{row['launch_us']:.0f} us (an empty kernel's launch) = "
              f"{row['launch_floor_ms_per_step']:.1f} ms; step / (bound + launch floor) = "
              f"{row['step_over_bound_and_launches']:.1f}")
    out = Path(args.out_dir)
    fields = []
    for r in rows:
        fields += [k for k in r if k not in fields]
    write_csv_atomic(out / "flow_profile.csv", rows, fields)
    write_csv_atomic(out / "flow_profile_kernels.csv", kernels, list(kernels[0]))
    print(f"wrote {out / 'flow_profile.csv'} and {out / 'flow_profile_kernels.csv'}",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
