"""The command-line driver shared by the scene scripts in ``scenes/``.

A scene supplies its initial particles, its parameters and its own measures;
this module parses the common options, runs the time loop with progress,
frames, diagnostics and checkpoints (:mod:`taichi_hh.app.runloop`), and resumes.
"""
import argparse
import os
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .. import runtime
from ..checks import positive_float
from ..flow.twophase import BlowUpError, FlowParams, TwoPhaseFlow
from ..validation.layouts import lattice_in_box  # noqa: F401  (the scenes' initial lattice)
from .config import config_tokens, write_config
from .io import remove_stale_temp_files
from .outputs import OutputError, OutputSpec, Outputs
from .render import COLORMAPS, STYLES, frame_colouring, frame_path, write_movie, write_png
from .runloop import Checkpoint, DiagnosticsWriter, HelpFormatter, add_common_arguments, run

#: the checkout this module runs from (``--docs`` writes the README's figures there)
REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

BASE_COLUMNS = ["time", "step", "dt", "solver_iterations", "cleanup_iterations", "max_div",
                "max_div_before",
                "volume_error_mean", "volume_error_max", "kinetic_energy"]


@dataclass
class Scene:
    name: str
    description: str
    defaults: dict                       # overrides of the common options
    add_arguments: callable              # (parser) -> None: scene options
    build: callable                      # (args) -> (points, phases, spacing, FlowParams)
    measures: callable                   # (flow) -> dict of scene measures
    measure_columns: list = field(default_factory=list)
    terms: str = ""                      # which physical terms the scene uses
    phase_names: tuple = ()              # legend labels of phases 0, 1, ... in the frames


def _montage(args, name: str) -> None:
    import imageio.v3 as iio
    times = [float(t) for t in args.montage.split(",") if t.strip()]
    paths = [frame_path(args.out, int(round(t / args.output_interval))) for t in times]
    missing = [p for p in paths if not os.path.exists(p)]
    if missing:
        print(f"montage skipped: no frame {missing[0]}", file=sys.stderr)
        return
    frames = [iio.imread(p)[..., :3] for p in paths]
    gap = np.full((frames[0].shape[0], 8, 3), 255, dtype=np.uint8)
    row = np.concatenate(sum(([f, gap] for f in frames), [])[:-1], axis=1)
    stride = max(1, int(np.ceil(row.shape[1] / 1200)))      # keep the figure small
    row = np.ascontiguousarray(row[::stride, ::stride])
    write_png(os.path.join(args.out, "montage.png"), row)
    if args.docs:
        docs = os.path.join(REPO_ROOT, "docs", "figures", f"{name}.png")
        write_png(docs, row)


@dataclass
class SceneRun:
    """What :func:`run_scene` did: the flow at the end, the parsed options,
    the wall seconds of the whole run (``wall``) and of the time loop alone
    (``loop``), the seconds of the loop by part (``seconds``: the flow's stages
    ``neighbours``, ``operators``, ``solve``, ``other`` (see
    :attr:`~taichi_hh.flow.twophase.TwoPhaseFlow.timings`), then ``render`` (the
    frames and particle files: with an output worker the hand-off only, the
    host copies and the frame's colouring; without one the drawing and writing
    too), ``diagnostics`` (the CSV row's measures), ``checkpoint`` (likewise:
    the state's copy, plus its writing without a worker), ``output_wait``
    (waiting for the output worker: a full queue, the drain at the end) and
    ``driver`` (the loop's own overhead: progress bar, time-step choice)),
    the output worker's own wall and CPU seconds on the outputs
    (``worker_seconds``, ``worker_cpu``: beside the loop, not part of it), the
    CPU seconds of the loop (``loop_cpu``: this process's threads plus the
    worker's), the solver iterations and dt of every step, and the steps taken."""
    flow: object
    args: argparse.Namespace
    wall: float = 0.0
    loop: float = 0.0
    seconds: dict = field(default_factory=dict)
    worker_seconds: float = 0.0
    worker_cpu: float = 0.0
    loop_cpu: float = 0.0
    iterations: list = field(default_factory=list)
    dts: list = field(default_factory=list)
    steps: int = 0
    frames: int = 0


def _config_argument(argv: list) -> str | None:
    """The value of ``--config`` in ``argv`` (the last one), else None."""
    path = None
    for k, token in enumerate(argv):
        if token == "--config" and k + 1 < len(argv):
            path = argv[k + 1]
        elif token.startswith("--config="):
            path = token.split("=", 1)[1]
    return path


#: options a --resume may change: when and how the run is watched, the time step
#: (the blow-up message's advice) and the pressure solver's tolerance; every
#: other option comes from the checkpoint (a different value is refused)
RESUME_MAY_CHANGE = frozenset({"end_time", "out", "resume", "quiet", "arch", "movie", "fps",
                               "montage", "docs", "config", "cfl", "dt_max", "solver_tol",
                               "output_workers"})

#: the pressure solver's relative tolerance when --solver-tol is not given: f32
#: cannot reach f64's (stagnation near 2e-4 on the droplet: docs/notes/app.md)
SOLVER_TOL = {"f64": 1e-4, "f32": 1e-3}


def main(scene: Scene, argv=None) -> int:
    """Run a scene from the command line (``argv``); returns the exit status.
    Bad input and failed writes end in one line and status 2; an unexpected
    error in one line plus the path of a file with the full report."""
    from .errors_report import run_reporting
    def job():
        run_scene(scene, argv)
        return 0
    return run_reporting(f"{scene.name}.py", job)


def _given_options(ap: argparse.ArgumentParser, argv: list) -> set:
    """The dests of the options ``argv`` gives explicitly (not by default)."""
    saved = [(a, a.default) for a in ap._actions]
    for a, _ in saved:
        a.default = argparse.SUPPRESS
    try:
        return set(vars(ap.parse_args(argv)))
    finally:
        for a, d in saved:
            a.default = d


def _check_out_dir(ap, path: str) -> None:
    """--out must be a directory this process can create and write to."""
    if os.path.exists(path) and not os.path.isdir(path):
        ap.error(f"--out {path}: is a file, not a directory")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as exc:
        ap.error(f"--out {path}: cannot create the directory ({exc.strerror or exc})")
    if not os.access(path, os.W_OK | os.X_OK):
        ap.error(f"--out {path}: the directory is not writable")


def owned_files(out: str, scene_name: str) -> list:
    """The files a run of ``scene_name`` writes into ``out`` (that exist)."""
    import glob
    names = ["diagnostics.csv", "checkpoint.npz", "particles.pvd", "montage.png",
             "config.toml", f"{scene_name}.gif", f"{scene_name}.mp4"]
    found = [os.path.join(out, n) for n in names if os.path.isfile(os.path.join(out, n))]
    found += glob.glob(os.path.join(out, "frame_[0-9]*.png"))
    found += glob.glob(os.path.join(out, "particles", "particles_[0-9]*.npz"))
    found += glob.glob(os.path.join(out, "particles", "particles_[0-9]*.vtu"))
    return sorted(found)


def _clear_previous_run(out: str, scene_name: str, quiet: bool) -> None:
    """A fresh run removes what an earlier run wrote into ``out`` (frames,
    particles, diagnostics, checkpoint, movie), so nothing of it mixes into
    this one's files or movie; other files are left alone."""
    old = owned_files(out, scene_name)
    for path in old:
        os.remove(path)
    if old and not quiet:
        print(f"fresh run: removed {len(old)} files of an earlier run in {out} "
              "(--resume continues a run instead)", file=sys.stderr)


def _resume_options(ap, scene, args, given: set, state: dict) -> None:
    """Take the checkpoint's options for those not given; refuse given ones
    that differ (only :data:`RESUME_MAY_CHANGE` may)."""
    import json
    name = state.pop("run_scene", None)
    stored = state.pop("run_options", None)
    if name is not None and name != scene.name:
        ap.error(f"--resume: {args.out} holds a {name} run, not {scene.name}: choose another "
                 "--out or run that scene")
    if stored is None:             # an older checkpoint: its options were not recorded
        return
    stored = json.loads(stored)
    conflicts = [k for k, v in stored.items() if k in given and k not in RESUME_MAY_CHANGE
                 and getattr(args, k, v) != v]
    if conflicts:
        ap.error("--resume keeps the checkpoint's options; "
                 + ", ".join(f"--{k.replace('_', '-')} {getattr(args, k)} differs from its "
                             f"{v}" for k, v in ((k, stored[k]) for k in conflicts))
                 + " (drop the option, or start afresh without --resume)")
    for k, v in stored.items():
        if k not in given and k not in RESUME_MAY_CHANGE and hasattr(args, k):
            setattr(args, k, v)


def _recorded_options(args) -> str:
    import json
    return json.dumps({k: v for k, v in sorted(vars(args).items())
                       if k not in RESUME_MAY_CHANGE and k != "func"
                       and (v is None or isinstance(v, (bool, int, float, str)))})


def run_scene(scene: Scene, argv=None) -> SceneRun:
    """Parse ``argv`` like the scene script, run it and return a :class:`SceneRun`
    (blow-ups and Ctrl-C raise ``SystemExit`` as described in
    :mod:`taichi_hh.app.runloop`)."""
    wall0 = time.perf_counter()
    ap = argparse.ArgumentParser(prog=f"{scene.name}.py", description=scene.description,
                                 formatter_class=HelpFormatter)
    common = {k: v for k, v in scene.defaults.items() if k not in ("output_interval", "montage")}
    add_common_arguments(ap, common)
    ap.add_argument("--output-interval", type=positive_float, default=scene.defaults.get("output_interval", 0.1),
                    help="simulated time between frames and diagnostics rows")
    ap.add_argument("--montage", default=scene.defaults.get("montage", ""),
                    help="comma-separated output times whose frames are put side by side "
                         "into OUT/montage.png at the end (empty: none)")
    ap.add_argument("--style", choices=STYLES, default=scene.defaults.get("style", "smooth"),
                    help="frames: 'smooth' draws the interpolated colour field (no gaps between "
                         "particles), 'discs' one disc per particle")
    ap.add_argument("--vtk", action=argparse.BooleanOptionalAction, default=True,
                    help="with every frame write the particles as VTU (ParaView) too, listed "
                         "in OUT/particles.pvd; their .npz twins are always written to "
                         "OUT/particles/")
    ap.add_argument("--output-workers", type=int, choices=(0, 1), default=1, metavar="{0,1}",
                    help="1: draw the frames and write the particle files and checkpoints in a "
                         "worker process beside the time loop (the second core); 0: in the "
                         "time loop's own process (the same files, byte for byte)")
    ap.add_argument("--docs", action="store_true",
                    help="also copy the montage to docs/figures/<scene>.png (the README's figure)")
    ap.add_argument("--exact-projection", action="store_true",
                    help="follow each step's pressure projection by the orthogonal clean-up "
                         "that takes max |div v| to the solver tolerance (FlowParams."
                         "exact_projection; many times the cost of a step, hence off: "
                         "docs/notes/flow.md)")
    ap.add_argument("--cleanup-tol", type=float, default=None, metavar="TOL",
                    help="with --exact-projection: stop the clean-up at ||div v|| <= TOL "
                         "||div v*|| (default: the pressure solver's tolerance; a looser one "
                         "is cheaper)")
    ap.add_argument("--cfl", type=positive_float, default=None,
                    help="advective time-step limit dt <= CFL dx / max|v| (default: "
                         f"{FlowParams.cfl}; accurate up to 0.5: docs/notes/app.md)")
    ap.add_argument("--dt-max", type=positive_float, default=None, metavar="DT",
                    help=f"largest time step (default: {FlowParams.dt_max})")
    ap.add_argument("--solver-tol", type=positive_float, default=None, metavar="TOL",
                    help="relative residual of the pressure solve (default: "
                         f"{SOLVER_TOL['f64']:g} with --precision f64, {SOLVER_TOL['f32']:g} "
                         "with f32, whose rounding stops the solve near 2e-4)")
    scene.add_arguments(ap)
    ap.add_argument("--config", metavar="FILE.toml",
                    help="read options from a TOML file (option = value, named as here without "
                         "the dashes); options given on the command line win. Every run "
                         "writes its options to OUT/config.toml, so --config OUT/config.toml "
                         "repeats it")
    argv = list(sys.argv[1:] if argv is None else argv)
    config_path = _config_argument(argv)
    if config_path is not None:
        try:
            argv = config_tokens(ap, config_path) + argv
        except ValueError as exc:
            ap.error(str(exc))
    args = ap.parse_args(argv)
    given = _given_options(ap, argv)
    if args.cleanup_tol is not None and not args.exact_projection:
        ap.error("--cleanup-tol needs --exact-projection")
    _check_out_dir(ap, args.out)
    ckpt_path = os.path.join(args.out, "checkpoint.npz")
    state = None
    if args.resume:
        if not os.path.exists(ckpt_path):
            ap.error(f"--resume: no checkpoint in {args.out}: nothing to resume "
                     "(run without --resume)")
        try:
            state = Checkpoint.load(ckpt_path)
        except (ValueError, OSError) as exc:
            ap.error(f"--resume: {exc}")
        _resume_options(ap, scene, args, given, state)
    else:
        _clear_previous_run(args.out, scene.name, args.quiet)
    for folder in (args.out, os.path.join(args.out, "particles")):
        remove_stale_temp_files(folder)
    try:
        points, phases, spacing, params = scene.build(args)
    except ValueError as exc:          # a set-up the options cannot make: one line, status 2
        ap.error(str(exc))
    if args.exact_projection:
        params = replace(params, exact_projection=True, cleanup_tol=args.cleanup_tol)
    steps = {k: getattr(args, k) for k in ("cfl", "dt_max") if getattr(args, k) is not None}
    params = replace(params, solver_tol=args.solver_tol or SOLVER_TOL[args.precision], **steps)
    runtime.init(arch=args.arch, precision=args.precision)
    write_config(os.path.join(args.out, "config.toml"), ap, args,
                 header=f"{scene.name}: the options of this run; "
                        f"python scenes/{scene.name}.py --config this-file repeats it")
    if state is not None:
        try:
            flow = TwoPhaseFlow.from_state(state, params)
        except (KeyError, ValueError) as exc:
            ap.error(f"--resume: {ckpt_path} does not hold a {scene.name} state ({exc})")
    else:
        flow = TwoPhaseFlow(points, phases, spacing, params)
    recorded = {"run_scene": scene.name, "run_options": _recorded_options(args)}
    x0, y0, x1, y1 = params.box
    wall_px = max(2, args.frame_width // 200)       # the walls' grey frame around the box
    spec = OutputSpec(args.out, max(args.frame_width - 2 * wall_px, 1), (x0, y0), (x1, y1),
                      style=args.style, colormap=COLORMAPS[args.color], wall_px=wall_px,
                      phase_names=tuple(scene.phase_names), vtk=args.vtk,
                      resume_time=flow.time if args.resume else None)
    columns = BASE_COLUMNS + list(scene.measure_columns)
    writer = DiagnosticsWriter(os.path.join(args.out, "diagnostics.csv"), columns,
                               resume_time=flow.time if args.resume else None)
    result = SceneRun(flow=flow, args=args)
    spent = dict.fromkeys(("render", "diagnostics", "checkpoint"), 0.0)
    if not args.quiet:
        print(f"{scene.name} on {runtime.state().arch}/{runtime.state().precision}: "
              f"{flow.n_fluid} fluid particles, spacing {flow.dx:.4g}, "
              f"support {flow.support:.4g}, until t={args.end_time}; terms: {scene.terms}; "
              f"projection: {'exact (orthogonal clean-up)' if params.exact_projection else 'approximate'}; "
              f"writing to {args.out}", file=sys.stderr)
    try:
        outputs = Outputs(spec, workers=args.output_workers)
    except BaseException:
        writer.close()
        raise

    def step_fn(t_stop):
        dt = min(flow.suggested_dt(), t_stop - flow.time)
        info = flow.step(dt)
        result.iterations.append(info["iterations"])
        result.dts.append(dt)
        return flow.time, dt, info

    def on_output(t, step, info):
        t0, waited0 = time.perf_counter(), outputs.waited
        data = flow.particle_data()
        position = data.pop("position")
        colouring = frame_colouring(
            args.color, data["velocity"],
            vorticity=flow.vorticity() if args.color == "vorticity" else None)
        outputs.frame(int(round(t / args.output_interval)), t, position, data, colouring)
        result.frames += 1
        t1 = time.perf_counter()
        spent["render"] += t1 - t0 - (outputs.waited - waited0)
        vmean, vmax = flow.volume_error()
        row = {"time": t, "step": step, "dt": info.get("dt", ""),
               "solver_iterations": info.get("iterations", ""),
               "cleanup_iterations": info.get("cleanup_iterations", ""),
               "max_div": info.get("max_div", ""),
               "max_div_before": info.get("max_div_before", ""), "volume_error_mean": vmean,
               "volume_error_max": vmax, "kinetic_energy": flow.kinetic_energy()}
        row.update(scene.measures(flow))
        writer.write(row)
        spent["diagnostics"] += time.perf_counter() - t1

    def checkpoint_fn():
        t0, waited0 = time.perf_counter(), outputs.waited
        path = outputs.checkpoint(ckpt_path, {**flow.state_dict(), **recorded})
        spent["checkpoint"] += time.perf_counter() - t0 - (outputs.waited - waited0)
        return path

    def advice(t, step, cause):
        if cause == "solver":
            tol = params.solver_tol
            return (f"'--resume --solver-tol {10 * tol:.0e}' continues from it with a looser "
                    f"pressure-solver tolerance (now {tol:.0e})")
        dt = result.dts[-1] if result.dts else flow.suggested_dt()
        return (f"'--resume --dt-max {0.5 * dt:.3g}' continues from it with half the last "
                f"time step ({dt:.3g}); --cfl lowers the velocity limit")

    flow.reset_timings()
    loop0, cpu0 = time.perf_counter(), time.process_time()
    failure = None
    try:
        run(step_fn, t0=flow.time, t_end=args.end_time, output_interval=args.output_interval,
            on_output=on_output, checkpoint_fn=checkpoint_fn, flush_fn=outputs.drain,
            progress=not args.quiet, step0=flow.step_count, output_at_start=not args.resume,
            blowup_types=(BlowUpError,), blowup_advice=advice)
    except BaseException as exc:
        failure = exc
        raise
    finally:
        writer.close()
        _close_outputs(outputs, failure, scene.name)
        result.loop = time.perf_counter() - loop0
        result.worker_seconds, result.worker_cpu = outputs.worker_seconds, outputs.worker_cpu
        result.loop_cpu = time.process_time() - cpu0 + outputs.worker_cpu
        result.steps = len(result.iterations)
        result.seconds = {k: v for k, v in flow.timings.items() if k not in ("total", "steps")}
        result.seconds.update(spent)
        result.seconds["output_wait"] = outputs.waited
        result.seconds["driver"] = max(result.loop - sum(result.seconds.values()), 0.0)
    if not args.quiet:
        print(timing_summary(result), file=sys.stderr)
    if args.montage:
        _montage(args, scene.name)
    if args.movie != "none":
        path = write_movie(os.path.join(args.out, "frame_*.png"),
                           os.path.join(args.out, f"{scene.name}.{args.movie}"), fps=args.fps)
        print(f"movie: {path}", file=sys.stderr)
    result.wall = time.perf_counter() - wall0
    return result


def _close_outputs(outputs: Outputs, failure, prog: str) -> None:
    """Stop the output worker at the end of the loop: after writing what was
    handed over (the loop drained it already unless it failed), or at once
    when a Ctrl-C interrupted the loop's drain (a KeyboardInterrupt got
    through; the worker's temporary files go with the next run).  An output error is raised, unless another error
    ends the run already: then it is reported in one more line."""
    try:
        outputs.close(drain=not isinstance(failure, KeyboardInterrupt))
    except OutputError as exc:
        if failure is None:
            raise
        print(f"{prog}.py: error: {exc}", file=sys.stderr)


def timing_summary(result: SceneRun) -> str:
    """The time loop's wall seconds and their split by part, then the output
    worker's own seconds (beside the loop) and the loop's CPU / wall."""
    total = max(result.loop, 1e-12)
    parts = ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f}%)" for k, v in result.seconds.items())
    n = result.steps
    line = (f"time loop {result.loop:.1f} s for {n} steps "
            f"({n * result.flow.n_fluid / total:.3g} particle-steps/s): {parts}")
    if result.args.output_workers:
        line += (f"; outputs in the worker {result.worker_seconds:.1f} s "
                 f"(CPU {result.worker_cpu:.1f} s) beside the loop")
    return line + f"; CPU / wall of the loop {result.loop_cpu / total:.2f}"
