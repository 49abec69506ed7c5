"""Performance of the two scenes end to end: where the wall time goes.

    python benchmarks/scenes.py [--duration 0.5] [--full] [--cases droplet,rt,rt_grenier]
                                [--out-dir outputs/benchmarks] [--no-warmup]

Cases (each runs the scene script's own set-up through the library,
:func:`taichi_hh.app.scene.run_scene`, frames, diagnostics and checkpoints included,
writing into OUT/scenes_runs/<case>/):

``droplet``      scenes/rising_droplet.py at its defaults (10500 particles).
``rt``           scenes/rayleigh_taylor.py at its defaults (12500 particles, 1.2 : 1).
``rt_grenier``   the common SPH Rayleigh-Taylor benchmark (Grenier et al. 2009;
                 PySPH ``examples/rayleigh_taylor.py``; REFERENCE.md): box 1 x 2,
                 1.8 : 1, amplitude 0.15, Re = 420 (nu = 2/420), 10000 fluid
                 particles requested (a 71 x 142 lattice: 10082).  Its simulated
                 time per wall second is compared with the weakly compressible
                 reference, PySPH's TVF scheme with OpenMP on 2 threads, which
                 manages about 7e-4 (its step is capped by the sound speed);
                 the target is at least 150x that (issue 16).

Every case runs ``--duration`` simulated seconds (default 0.5) from t = 0.
Before the timed runs a small warm-up run of each scene (1250 particles, so the
multilevel preconditioner path is compiled too) compiles the kernels, so the
timed runs measure the steady state; ``compile_s`` reports the warm-up.

Reported per case: steps, the time loop's wall seconds and the
``particle-steps/s`` (fluid particles x steps / loop seconds), simulated time
per wall second, the median solver iterations per step, and the loop's time
split into ``neighbours`` (binning, reorder, pair list), ``operators``
(coefficient builds, Poisson assembly, viscous predictor, divergence and wall
rows, pressure-gradient correction, particle shifting), ``solve`` (the pressure
solve; ``precond_setup_s`` is the part of it that builds the multilevel
preconditioner), ``rendering`` (the loop's side of the frames and particle
files: with the scenes' output worker, the default, the host copies handed
over and any wait for the worker; with ``--output-workers 0`` the drawing and
writing too) and ``other`` (the flow's bookkeeping, diagnostics rows,
checkpoints, the loop itself).  ``worker_s`` / ``worker_cpu_s``: the output
worker's own wall and CPU seconds, beside the loop; ``cpu_over_wall``: the CPU
seconds of the loop (every thread of the main process, plus the worker's) over
its wall seconds: 1 means one core busy, 2 both.  ``--output-workers 0``
passes that option to every case.

Full droplet run: the wall time of the whole 6 s run is extrapolated from the
measured droplet case two ways: (a) by simulated time (loop seconds x 6 /
duration; optimistic, since the droplet speeds up and dt shrinks), and (b) by
steps, when a previous full-length run's diagnostics.csv at the same
resolution is found (``--steps-from``, default the droplet resolution study's
10.5k run), as its step count x the measured seconds per step.  ``--full``
runs the real thing (6 s, frames at every 0.1 s) and reports it as case
``droplet_full``.  Targets (issue 16): the loop in at most 50 s, at least
1.3e5 particle-steps/s, CPU time at least 1.6x the loop's wall time.

Writes OUT/scenes.csv and OUT/scenes.png (stacked bars of seconds per step by
part) atomically.  The machine may be shared: the CSV records the load average.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import (REPO_ROOT, add_repo_to_path, format_table, parse_list,  # noqa: E402
                     save_figure_atomic, scene_module, write_csv_atomic)

add_repo_to_path()

WCSPH_RATE = 7e-4          # simulated time units per wall second, PySPH TVF, 2 threads
RATE_TARGET = 150.0        # x WCSPH_RATE
FULL_END = 6.0             # the droplet's whole run
FULL_TARGET_S = 50.0       # the whole run's loop, seconds
STEPS_TARGET = 1.3e5       # particle-steps/s in the whole run
CPU_TARGET = 1.6           # CPU seconds over the loop's wall seconds

CASES = {
    "droplet": ("rising_droplet", []),
    "rt": ("rayleigh_taylor", []),
    "rt_grenier": ("rayleigh_taylor", ["--particles", "10000", "--density-ratio", "1.8",
                                       "--amplitude", "0.15", "--viscosity", repr(2.0 / 420)]),
}
PARTS = ("neighbours", "operators", "solve", "rendering", "other")
COLORS = {"neighbours": "#4c72b0", "operators": "#55a868", "solve": "#c44e52",
          "rendering": "#8172b2", "other": "#bbbbbb"}


class PrecondSetupTimer:
    """Seconds spent building the multilevel preconditioner (part of ``solve``):
    wraps ``PoissonMatrix.multilevel`` while active, if the library has it."""

    def __init__(self):
        self.seconds = 0.0
        self._orig = None

    def __enter__(self):
        from taichi_hh.poisson.matrix import PoissonMatrix
        self._cls = PoissonMatrix
        self._orig = getattr(self._cls, "multilevel", None)
        if self._orig is not None:
            orig, outer = self._orig, self

            def timed(matrix, *a, **k):
                t0 = time.perf_counter()
                try:
                    return orig(matrix, *a, **k)
                finally:
                    outer.seconds += time.perf_counter() - t0
            self._cls.multilevel = timed
        return self

    def __exit__(self, *exc):
        if self._orig is not None:
            self._cls.multilevel = self._orig


def run_case(case: str, end: float, out_dir: Path, frame_width: int, quiet: bool,
             extra=(), output_workers: int = 1) -> dict:
    from taichi_hh.app.scene import run_scene
    scene_name, options = CASES[case.replace("_full", "")]
    scene = scene_module(scene_name).SCENE
    out = out_dir / "scenes_runs" / case
    argv = list(options) + ["--end-time", repr(end), "--out", str(out), "--montage", "",
                            "--frame-width", str(frame_width),
                            "--output-workers", str(output_workers)] + list(extra)
    if quiet:
        argv.append("--quiet")
    with PrecondSetupTimer() as pre:
        res = run_scene(scene, argv)
    s = res.seconds
    parts = {"neighbours": s["neighbours"], "operators": s["operators"], "solve": s["solve"],
             "rendering": s["render"] + s["output_wait"],
             "other": s["other"] + s["diagnostics"] + s["checkpoint"] + s["driver"]}
    flow = res.flow
    n = flow.n_fluid
    steps = max(res.steps, 1)
    sim = flow.time
    row = {"case": case, "scene": scene_name, "options": " ".join(options),
           "fluid_particles": n, "all_particles": flow.particles.n, "end_time": round(sim, 6),
           "steps": res.steps, "frames": res.frames, "loop_s": res.loop, "wall_s": res.wall,
           "s_per_step": res.loop / steps,
           "particle_steps_per_s": n * res.steps / res.loop,
           "sim_per_wall_s": sim / res.loop,
           "sim_per_wall_physics": sim / max(sum(s[k] for k in ("neighbours", "operators",
                                                                 "solve", "other")), 1e-12),
           "median_iterations": statistics.median(res.iterations) if res.iterations else 0,
           "mean_iterations": statistics.fmean(res.iterations) if res.iterations else 0,
           "median_dt": statistics.median(res.dts) if res.dts else 0,
           "precond_setup_s": pre.seconds,
           # the loop's CPU time (every thread, and the output worker's) over its
           # wall time: 1 means one core busy, 2 both
           "cpu_over_wall": res.loop_cpu / max(res.loop, 1e-12),
           "output_workers": output_workers, "worker_s": res.worker_seconds,
           "worker_cpu_s": res.worker_cpu, "output_wait_s": s["output_wait"],
           "load_avg": os.getloadavg()[0]}
    row.update({f"{k}_s": v for k, v in parts.items()})
    row.update({f"detail.{k}": v for k, v in sorted(flow.clock.detail.items())})
    row["detail.diagnostics"] = s["diagnostics"]
    row["detail.checkpoint"] = s["checkpoint"]
    row["detail.driver"] = s["driver"]
    return row


def steps_in(path: Path, end: float):
    """Steps a previous run took to reach ``end`` (its diagnostics.csv), or None."""
    try:
        with open(path) as fh:
            rows = list(csv.DictReader(fh))
    except OSError:
        return None
    done = [r for r in rows if r.get("step") and float(r["time"]) >= end - 1e-9]
    return int(done[0]["step"]) if done else None


def chart(rows, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8.5, 4.2))
    labels = [f"{r['case']}\n{r['fluid_particles']} p, {r['steps']} steps" for r in rows]
    bottom = [0.0] * len(rows)
    for part in PARTS:
        vals = [1e3 * r[f"{part}_s"] / max(r["steps"], 1) for r in rows]
        ax.bar(labels, vals, bottom=bottom, label=part, color=COLORS[part])
        bottom = [b + v for b, v in zip(bottom, vals)]
    for x, (b, r) in enumerate(zip(bottom, rows)):
        ax.text(x, b, f"{b:.0f} ms\n{r['median_iterations']:.0f} it", ha="center", va="bottom",
                fontsize=8)
    ax.set_ylabel("wall ms per time step")
    ax.set_ylim(0, 1.2 * max(bottom))
    ax.set_title("Scene time per step by part (2-core CPU, frames included)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)


def scaling(counts, steps: int, out_dir: Path) -> None:
    """Step time of the droplet at each particle count (how the cost grows with N)."""
    from flow_profile import profile
    rows = []
    for n in counts:
        print(f"scaling: droplet at {n} particles ...", file=sys.stderr, flush=True)
        row, _ = profile(n, 4, steps)
        rows.append({k: row[k] for k in ("fluid_particles", "all_particles", "pairs",
                                         "ms_per_step", "cpu_ms_per_step", "particle_steps_per_s",
                                         "median_iterations", "cpu_over_wall",
                                         "step_over_bound")})
    for a, b in zip(rows, rows[1:]):
        b["growth_exponent"] = math.log(b["ms_per_step"] / a["ms_per_step"]) / math.log(
            b["fluid_particles"] / a["fluid_particles"])
    print(format_table(["particles", "pairs", "ms/step", "CPU ms/step", "p-steps/s", "med. it",
                        "CPU/wall",
                        "step/bound", "ms ~ N^"],
                       [[r["fluid_particles"], r["pairs"], f"{r['ms_per_step']:.1f}",
                         f"{r['cpu_ms_per_step']:.1f}",
                         f"{r['particle_steps_per_s']:.3g}", f"{r['median_iterations']:.0f}",
                         f"{r['cpu_over_wall']:.2f}", f"{r['step_over_bound']:.1f}",
                         f"{r['growth_exponent']:.2f}" if "growth_exponent" in r else ""]
                        for r in rows]))
    fields = []
    for r in rows:
        fields += [k for k in r if k not in fields]
    write_csv_atomic(out_dir / "scenes_scaling.csv", rows, fields)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--duration", type=float, default=0.5, help="simulated seconds per case")
    ap.add_argument("--cases", default="droplet,rt,rt_grenier",
                    help=f"comma-separated, from {', '.join(CASES)}")
    ap.add_argument("--full", action="store_true",
                    help=f"also run the whole droplet ({FULL_END:g} s) as case droplet_full")
    ap.add_argument("--full-only", action="store_true", help="run only the whole droplet")
    ap.add_argument("--steps-from", default=None,
                    help="a full-length droplet run's diagnostics.csv to take the step count "
                         "from (default: the resolution study's 10.5k run, when present)")
    ap.add_argument("--frame-width", type=int, default=800, help="frame width (scene default)")
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    ap.add_argument("--no-warmup", action="store_true", help="include compilation in the timings")
    ap.add_argument("--progress", action="store_true", help="show the scenes' progress bars")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    ap.add_argument("--output-workers", type=int, choices=(0, 1), default=1,
                    help="the scenes' output worker processes (0: outputs in the loop)")
    ap.add_argument("--replot", action="store_true", help="only redraw the chart from the CSV")
    ap.add_argument("--scaling", default="",
                    help="comma-separated fluid particle counts: also time the droplet's step at "
                         "each (benchmarks/flow_profile.py's profile, no frames; median of "
                         "--scaling-steps steps after 4 warm-up steps) into OUT/scenes_scaling.csv")
    ap.add_argument("--scaling-steps", type=int, default=10, help="timed steps per scaling row")
    args = ap.parse_args(argv)
    out_dir = Path(args.out_dir)
    if args.replot:
        name = "scenes_full" if args.full_only else "scenes"
        with open(out_dir / f"{name}.csv") as fh:
            rows = list(csv.DictReader(fh))
        for r in rows:
            for k in ["steps", "fluid_particles", "median_iterations"] + [f"{p}_s" for p in PARTS]:
                r[k] = float(r[k])
            r["steps"], r["fluid_particles"] = int(r["steps"]), int(r["fluid_particles"])
        chart(rows, out_dir / f"{name}.png")
        return 0

    import taichi_hh
    taichi_hh.init(arch="cpu", precision="f64", threads=args.threads, verbose=False)
    cases = [] if args.full_only else parse_list(args.cases, str)
    for c in cases:
        if c not in CASES:
            ap.error(f"unknown case {c!r}; choose from {', '.join(CASES)}")
    runs = [(c, args.duration) for c in cases]
    if args.full or args.full_only:
        runs.append(("droplet_full", FULL_END))

    compile_s = {}
    if not args.no_warmup:
        from taichi_hh.app.scene import run_scene
        for name in sorted({CASES[c.replace("_full", "")][0] for c, _ in runs}):
            t0 = time.perf_counter()
            run_scene(scene_module(name).SCENE, ["--particles", "1250", "--end-time", "0.06",
                                         "--output-interval", "0.03", "--montage", "",
                                         "--frame-width", "200", "--quiet", "--out",
                                         str(out_dir / "scenes_runs" / f"warmup_{name}")])
            compile_s[name] = time.perf_counter() - t0
            print(f"warm-up {name}: {compile_s[name]:.1f} s (compilation, 1250 particles)",
                  file=sys.stderr)

    rows = []
    for case, end in runs:
        print(f"running {case} to t = {end:g} ...", file=sys.stderr, flush=True)
        row = run_case(case, end, out_dir, args.frame_width, quiet=not args.progress,
                       output_workers=args.output_workers)
        row["compile_s"] = compile_s.get(row["scene"], "")
        rows.append(row)
        print(f"  {case}: {row['loop_s']:.1f} s loop, {row['steps']} steps, "
              f"{row['particle_steps_per_s']:.3g} particle-steps/s", file=sys.stderr, flush=True)

    header = ["case", "particles", "steps", "loop s", "ms/step", "p-steps/s", "sim/wall",
              "med. it", "CPU/wall", "worker s"] + list(PARTS)
    table = []
    for r in rows:
        tot = max(r["loop_s"], 1e-12)
        table.append([r["case"], r["fluid_particles"], r["steps"], f"{r['loop_s']:.1f}",
                      f"{1e3 * r['s_per_step']:.0f}", f"{r['particle_steps_per_s']:.3g}",
                      f"{r['sim_per_wall_s']:.3g}", f"{r['median_iterations']:.0f}",
                      f"{r['cpu_over_wall']:.2f}", f"{r['worker_s']:.1f}"]
                     + [f"{100 * r[p + '_s'] / tot:.0f}%" for p in PARTS])
    print(format_table(header, table))

    extra_lines = []
    for r in rows:
        if r["case"] == "rt_grenier":
            ratio = r["sim_per_wall_s"] / WCSPH_RATE
            extra_lines.append(
                f"Rayleigh-Taylor 1 x 2, 1.8 : 1, Re = 420, {r['fluid_particles']} fluid particles: "
                f"{r['sim_per_wall_s']:.3g} simulated time per wall second with frames "
                f"({r['sim_per_wall_physics']:.3g} physics only) = {ratio:.1f}x the weakly "
                f"compressible reference {WCSPH_RATE:g} (target {RATE_TARGET:g}x: "
                f"{'met' if ratio >= RATE_TARGET else 'not met'}); median dt {r['median_dt']:.3g}")
            r["vs_wcsph"] = ratio
        if r["case"] == "droplet":
            est_time = r["loop_s"] * FULL_END / max(r["end_time"], 1e-12)
            r["full_estimate_by_time_s"] = est_time
            line = (f"full droplet ({FULL_END:g} s, {r['fluid_particles']} particles, frames): "
                    f"extrapolated by simulated time {est_time:.0f} s ({est_time / 60:.1f} min)")
            src = Path(args.steps_from) if args.steps_from else (
                out_dir / "droplet_resolution" / f"n{r['fluid_particles']}" / "diagnostics.csv")
            full_steps = steps_in(src, FULL_END)
            if full_steps:
                est_steps = full_steps * r["s_per_step"]
                r["full_estimate_by_steps_s"] = est_steps
                r["full_steps"] = full_steps
                line += (f"; by steps ({full_steps} steps in {src}) {est_steps:.0f} s "
                         f"({est_steps / 60:.1f} min)")
            line += f"; target {FULL_TARGET_S:g} s"
            extra_lines.append(line)
        if r["case"] == "droplet_full":
            def verdict(ok):
                return "met" if ok else "not met"
            extra_lines.append(
                f"full droplet measured: loop {r['loop_s']:.1f} s ({r['steps']} steps; "
                f"{r['wall_s']:.1f} s wall) against {FULL_TARGET_S:g} s: "
                f"{verdict(r['loop_s'] <= FULL_TARGET_S)}; "
                f"{r['particle_steps_per_s']:.3g} particle-steps/s against {STEPS_TARGET:.3g}: "
                f"{verdict(r['particle_steps_per_s'] >= STEPS_TARGET)}; CPU/wall "
                f"{r['cpu_over_wall']:.2f} against {CPU_TARGET:g}: "
                f"{verdict(r['cpu_over_wall'] >= CPU_TARGET)}")
    for line in extra_lines:
        print(line)

    if args.scaling:
        scaling(parse_list(args.scaling, int), args.scaling_steps, out_dir)

    fields = []
    for r in rows:
        fields += [k for k in r if k not in fields]
    name = "scenes_full" if args.full_only else "scenes"
    write_csv_atomic(out_dir / f"{name}.csv", rows, fields)
    chart(rows, out_dir / f"{name}.png")
    print(f"wrote {out_dir / (name + '.csv')} and {out_dir / (name + '.png')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
