"""The command line's fixed costs (issue 32, "Start-up"): ``taichi-hh decompose
FILE`` on a 4k-point file, with Taichi's offline cache warm, and 100 such files
in one call.

Two measurements, each in fresh processes (the CLI as users run it):

* **wall**: ``python -m taichi_hh decompose FILE -o DIR -q`` timed from the
  outside (process start to exit), the median of ``--repeats`` runs after one
  warm-up run that fills the offline cache; the same for the 100-file series
  (``--series``, fewer repeats).  Targets: <= 1.5 s and <= 15 s.  With its
  CPU seconds (all threads: the load of a shared machine stretches the wall
  time, not these).  Also one **cold** run per field, in a fresh empty
  offline cache (every kernel compiled), and with ``--without-figures`` the
  call with ``--no-figures`` (what the two PNG figures cost).
* **breakdown**: the same command in a probe process (this file run with
  ``--probe``) that timestamps the CLI's own stages, times every Taichi
  kernel's Python-to-IR transform (``Kernel.materialize``, paid in every
  process: the offline cache keeps the compiled code, not the transform) and
  its first launch (the cache's load, or a compile), and with
  ``python -X importtime`` the imports of the heavy packages.

With ``--worker``, the same calls also through a persistent worker
(``taichi-hh worker start``, app/worker.py): its start-up (with its warm-up)
once, then each call's wall time from the outside and its CPU seconds (the
client's and the worker's together, from the worker's status).

Fields: ``scattered`` (4000 uniformly random points in the unit square: the
scattered path) and ``grid`` (64 x 64 nodes: the grid path).  Writes
``outputs/benchmarks/cli_startup.csv`` (wall times), ``outputs/benchmarks/cli_startup_breakdown.csv``
(stages and kernels) and prints both tables.

    python benchmarks/cli_startup.py                      # both fields, 5 repeats, 100-file series
    python benchmarks/cli_startup.py --fields scattered --repeats 3 --series 0
    python benchmarks/cli_startup.py --fields scattered --worker --no-breakdown
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import REPO_ROOT, format_table, write_csv_atomic  # noqa: E402

N_POINTS = 4000
HEAVY = ("taichi", "matplotlib", "scipy", "xarray", "numpy", "h5py", "netCDF4", "pandas",
         "taichi_hh.app.cli", "taichi_hh")


# --------------------------------------------------------------------------- inputs
def write_fields(directory: Path, kind: str, count: int = 1) -> list[Path]:
    """``count`` snapshot files of a drifting flow on the same points
    (a vortex, a source and a stream), npz."""
    import numpy as np
    rng = np.random.default_rng(0)
    if kind == "scattered":
        pts = rng.uniform(0.0, 1.0, (N_POINTS, 2))
    elif kind == "grid":
        side = int(round(N_POINTS ** 0.5))
        xs = np.linspace(0.0, 1.0, side)
        X, Y = np.meshgrid(xs, xs)
        pts = np.c_[X.ravel(), Y.ravel()]
    else:
        raise ValueError(kind)
    out = []
    for t in range(count):
        cx, cy = 0.4 + 0.002 * t, 0.5
        dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
        g = np.exp(-(dx ** 2 + dy ** 2) / 0.02)
        sx, sy = pts[:, 0] - 0.7, pts[:, 1] - 0.4
        s = np.exp(-(sx ** 2 + sy ** 2) / 0.01)
        u = -dy * g + sx * s + 0.3
        v = dx * g + sy * s + 0.1
        path = directory / f"{kind}_{t:03d}.npz"
        np.savez(path, points=pts, vectors=np.c_[u, v])
        out.append(path)
    return out


def cli_command(files, out_dir, extra=()) -> list[str]:
    return [sys.executable, "-m", "taichi_hh", "decompose", *map(str, files), "-o", str(out_dir),
            "-q", *extra]


def child_env(cache: Path, root: Path = REPO_ROOT) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root) + os.pathsep + env.get("PYTHONPATH", "")
    env["TAICHI_HH_CACHE"] = str(cache)
    return env


def worker_cpu(env) -> float:
    """The running worker's CPU seconds so far (0 where none runs)."""
    done = subprocess.run([sys.executable, "-c", "import json; from taichi_hh.app import "
                           "worker_client as w; print(json.dumps(w.request('status')))"],
                          env=env, stdout=subprocess.PIPE, text=True)
    got = json.loads(done.stdout or "null")
    return got["cpu_seconds"] if got else 0.0


def timed_run(cmd, env, through_worker: bool = False) -> tuple:
    """(wall seconds, CPU seconds) of one run of ``cmd`` (and of the worker's
    share where it ran there)."""
    cpu0 = worker_cpu(env) if through_worker else 0.0
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True)
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    if through_worker:
        cpu += worker_cpu(env) - cpu0
    return dt, cpu


# --------------------------------------------------------------------------- probe
def probe(argv: list[str], report: str) -> int:
    """Run the CLI in this process with timers around its stages and Taichi's
    kernel materialisation and first launches; write JSON to ``report``."""
    t_start = time.perf_counter()
    stages = []
    kernels = {}

    from taichi_hh.app import cli
    t_cli = time.perf_counter()

    class StageClock:
        """stderr, with the time each of the CLI's stage messages came"""

        def __init__(self, stream):
            self.stream = stream

        def write(self, text):
            if text.startswith("taichi-hh ") and "] " in text:
                stages.append((text.split("] ", 1)[1].strip(), time.perf_counter() - t_start))
            return self.stream.write(text)

        def __getattr__(self, name):
            return getattr(self.stream, name)

    sys.stderr = StageClock(sys.stderr)

    def patch_taichi():
        from taichi.lang import kernel_impl
        materialize, launch = kernel_impl.Kernel.materialize, kernel_impl.Kernel.launch_kernel
        seen = set()

        def timed_materialize(self, key=None, args=None, arg_features=None):
            k = kernels.setdefault(self.func.__qualname__, dict(
                module=self.func.__module__, materialize=0.0, n_materialize=0,
                first_launch=0.0, launches=0, launch_s=0.0))
            before = len(self.compiled_kernels)
            t0 = time.perf_counter()
            try:
                return materialize(self, key, args, arg_features)
            finally:
                if len(self.compiled_kernels) > before:
                    k["materialize"] += time.perf_counter() - t0
                    k["n_materialize"] += 1

        def timed_launch(self, t_kernel, *args):
            k = kernels.setdefault(self.func.__qualname__, dict(
                module=self.func.__module__, materialize=0.0, n_materialize=0,
                first_launch=0.0, launches=0, launch_s=0.0))
            t0 = time.perf_counter()
            try:
                return launch(self, t_kernel, *args)
            finally:
                dt = time.perf_counter() - t0
                k["launches"] += 1
                k["launch_s"] += dt
                if id(t_kernel) not in seen:
                    seen.add(id(t_kernel))
                    k["first_launch"] += dt

        kernel_impl.Kernel.materialize = timed_materialize
        kernel_impl.Kernel.launch_kernel = timed_launch

    from taichi_hh import runtime
    init = runtime.init

    def patched_init(*a, **kw):
        t0 = time.perf_counter()
        import taichi  # noqa: F401
        stages.append(("(import taichi)", time.perf_counter() - t_start, time.perf_counter() - t0))
        patch_taichi()
        return init(*a, **kw)

    runtime.init = patched_init
    try:
        code = cli.main(argv)
    finally:
        end = time.perf_counter() - t_start
        Path(report).write_text(json.dumps(dict(
            import_cli=t_cli - t_start, stages=stages, end=end, kernels=kernels,
            modules=sorted({m.split(".")[0] for m in sys.modules if m.split(".")[0] in
                            ("matplotlib", "scipy", "xarray", "h5py", "pandas", "netCDF4")}))))
    return code


def import_times(stderr: str) -> dict:
    """Cumulative import seconds of the HEAVY packages from ``-X importtime``."""
    out = {}
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        parts = line.split("|")
        try:
            cum = int(parts[1]) * 1e-6
        except ValueError:
            continue
        name = parts[2].strip()
        if name in HEAVY:
            out[name] = max(out.get(name, 0.0), cum)
    return out


def breakdown(files, out_dir, env) -> dict:
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
        report = fh.name
    cmd = [sys.executable, "-X", "importtime", str(Path(__file__).resolve()), "--probe", report,
           "--", "decompose", *map(str, files), "-o", str(out_dir)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"probe failed:\n{done.stderr[-3000:]}")
    got = json.loads(Path(report).read_text())
    os.remove(report)
    got["wall"] = wall
    got["imports"] = import_times(done.stderr)
    return got


def stage_rows(field: str, got: dict) -> list[dict]:
    """Consecutive stages: (name, seconds) from the probe's timestamps."""
    rows = [dict(field=field, stage="interpreter start", seconds=got["wall"] - got["end"])]
    rows.append(dict(field=field, stage="import taichi_hh.app.cli", seconds=got["import_cli"]))
    prev_name, prev_t = "parse arguments, checks", got["import_cli"]
    for entry in got["stages"]:
        name, t = entry[0], entry[1]
        if name.startswith("(import taichi)"):
            continue
        rows.append(dict(field=field, stage=prev_name, seconds=t - prev_t))
        prev_name, prev_t = name, t
    rows.append(dict(field=field, stage=prev_name + " (to exit)", seconds=got["end"] - prev_t))
    k = got["kernels"]
    rows.append(dict(field=field, stage=f"of which: {sum(v['n_materialize'] for v in k.values())} "
                     f"kernels' Python->IR transforms", seconds=sum(v["materialize"] for v in k.values())))
    rows.append(dict(field=field, stage="of which: first launches (cache load / compile + run)",
                     seconds=sum(v["first_launch"] for v in k.values())))
    rows.append(dict(field=field, stage=f"of which: {sum(v['launches'] for v in k.values())} "
                     "launches in all", seconds=sum(v["launch_s"] for v in k.values())))
    for name, sec in sorted(got["imports"].items(), key=lambda kv: -kv[1]):
        rows.append(dict(field=field, stage=f"import {name} (-X importtime, cumulative)",
                         seconds=sec))
    rows.append(dict(field=field, stage="wall (probe, -X importtime)", seconds=got["wall"]))
    rows.append(dict(field=field, stage="heavy packages loaded: " + (", ".join(got["modules"]) or
                                                                     "none"), seconds=0.0))
    return rows


def start_worker(env, walls) -> None:
    """``taichi-hh worker start`` (kept when already running): its wall time
    with the warm-up, as a row."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "taichi_hh", "worker", "start"], env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise SystemExit(f"worker start failed:\n{done.stderr[-3000:]}")
    if "already" not in done.stdout:
        dt = time.perf_counter() - t0
        walls.append(wall_row("worker start (with its warm-up), once", 0, "this, worker",
                              [(dt, worker_cpu(env))], float("nan")))
        print(f"worker start: {dt:.2f} s", flush=True)


def wall_row(case, files, version, runs, target) -> dict:
    walls = [w for w, _ in runs]
    cpus = [c for _, c in runs]
    return dict(case=case, version=version, files=files, median_s=statistics.median(walls),
                min_s=min(walls), max_s=max(walls), cpu_median_s=statistics.median(cpus),
                runs=len(runs), target_s=target)


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--probe":
        rest = sys.argv[3:]
        if rest and rest[0] == "--":
            rest = rest[1:]
        sys.path.insert(0, str(REPO_ROOT))
        return probe(rest, sys.argv[2])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fields", default="scattered,grid", help="scattered,grid")
    ap.add_argument("--repeats", type=int, default=5, help="runs per wall time (median)")
    ap.add_argument("--series", type=int, default=100, help="files in the series call (0: none)")
    ap.add_argument("--series-repeats", type=int, default=2)
    ap.add_argument("--kernels", type=int, default=12, help="kernels listed (slowest first)")
    ap.add_argument("--baseline", metavar="DIR", default=None,
                    help="a checkout of the reference version (e.g. a git worktree of main): "
                         "its CLI timed in the same run, runs interleaved with this one's")
    ap.add_argument("--no-breakdown", action="store_true", help="wall times only")
    ap.add_argument("--worker", action="store_true",
                    help="also time the calls through a persistent worker (taichi-hh worker)")
    ap.add_argument("--without-figures", action="store_true",
                    help="also time the call with --no-figures (what the figures cost)")
    ap.add_argument("--out", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    walls, stages, kernel_rows = [], [], []
    with tempfile.TemporaryDirectory(prefix="cli_startup_") as tmp:
        tmp = Path(tmp)
        versions = {"this": child_env(tmp / "cache", REPO_ROOT)}
        if args.baseline:
            versions["baseline"] = child_env(tmp / "cache_baseline", Path(args.baseline).resolve())
        if args.worker:                  # its own socket directory, the same kernel cache
            versions["this, worker"] = dict(versions["this"],
                                            TAICHI_HH_WORKER_DIR=str(tmp / "worker"))
        for v in versions:               # only "this, worker" may find a worker
            versions[v].setdefault("TAICHI_HH_WORKER_DIR", str(tmp / f"none_{len(v)}"))
        env = versions["this"]
        try:
            for field in [f.strip() for f in args.fields.split(",") if f.strip()]:
                one = write_fields(tmp, field, 1)
                cases = {"1 file": ()}
                if args.without_figures:
                    cases["1 file, --no-figures"] = ("--no-figures",)
                for case, extra in cases.items():
                    cmds = {v: cli_command(one, tmp / f"out_{field}_{v}", extra) for v in versions}
                    runs = {v: [] for v in versions}
                    cold = {}
                    for v in versions:
                        if v.endswith("worker"):
                            start_worker(versions[v], walls)
                            continue
                        if not extra:
                            # the cold start: a fresh, empty offline cache of its own
                            fresh = dict(versions[v], TAICHI_HH_CACHE=str(tmp / f"cold_{field}_{v}"))
                            cold[v] = timed_run(cmds[v], fresh)
                        timed_run(cmds[v], versions[v])              # fills the offline cache
                    for _ in range(args.repeats):
                        for v in versions:                           # interleaved
                            runs[v].append(timed_run(cmds[v], versions[v], v.endswith("worker")))
                    for v in versions:
                        if v in cold:
                            walls.append(wall_row(f"{field}: {case}, cold cache", 1, v, [cold[v]],
                                                  float("nan")))
                        walls.append(wall_row(f"{field}: {case}", 1, v, runs[v], 1.5))
                        w = walls[-1]
                        said = f"cold cache {cold[v][0]:.2f} s wall {cold[v][1]:.2f} s CPU; " \
                            if v in cold else ""
                        print(f"{field}: {case} ({v}), {said}warm median {w['median_s']:.2f} s "
                              f"wall, {w['cpu_median_s']:.2f} s CPU", flush=True)
                if not args.no_breakdown:
                    got = breakdown(one, tmp / f"probe_{field}", env)
                    stages += stage_rows(field, got)
                    for name, v in sorted(got["kernels"].items(),
                                          key=lambda kv: -(kv[1]["materialize"] + kv[1]["first_launch"])
                                          )[:args.kernels]:
                        kernel_rows.append(dict(field=field, kernel=name, module=v["module"],
                                                transform_s=v["materialize"],
                                                first_launch_s=v["first_launch"],
                                                launches=v["launches"], launch_s=v["launch_s"]))
                if args.series:
                    many = write_fields(tmp, field, args.series)
                    cmds = {v: cli_command(many, tmp / f"series_{field}_{v}") for v in versions}
                    runs = {v: [] for v in versions}
                    for v in versions:      # the series path's own kernels into the cache, untimed
                        if not v.endswith("worker"):    # (the worker's warm-up has a series)
                            timed_run(cli_command(many[:2], tmp / f"fill_{field}_{v}"), versions[v])
                    for _ in range(args.series_repeats):
                        for v in versions:
                            runs[v].append(timed_run(cmds[v], versions[v], v.endswith("worker")))
                    for v in versions:
                        walls.append(wall_row(f"{field}: {args.series} files", args.series, v,
                                              runs[v], 15.0))
                        w = walls[-1]
                        print(f"{field}: {args.series} files ({v}), median {w['median_s']:.2f} s "
                              f"wall, {w['cpu_median_s']:.2f} s CPU", flush=True)
                    for p in many[1:]:
                        p.unlink()
        finally:            # the worker's socket is in tmp: stop it before tmp goes
            for v, venv in versions.items():
                if v.endswith("worker"):
                    subprocess.run([sys.executable, "-m", "taichi_hh", "worker", "stop"],
                                   env=venv, stdout=subprocess.PIPE)

    print()
    print(format_table(["case", "version", "median s", "min s", "max s", "CPU s", "runs",
                        "target s"],
                       [[w["case"], w["version"], f"{w['median_s']:.2f}", f"{w['min_s']:.2f}",
                         f"{w['max_s']:.2f}", f"{w['cpu_median_s']:.2f}", w["runs"],
                         f"{w['target_s']:g}"] for w in walls], align="llrrrrrr"))
    if stages:
        print()
        print(format_table(["field", "stage", "s"], [[r["field"], r["stage"], f"{r['seconds']:.3f}"]
                                                      for r in stages], align="llr"))
        print()
        print(format_table(["field", "kernel", "module", "transform s", "first launch s",
                            "launches"],
                           [[r["field"], r["kernel"], r["module"].replace("taichi_hh.", ""),
                             f"{r['transform_s']:.3f}", f"{r['first_launch_s']:.3f}", r["launches"]]
                            for r in kernel_rows], align="lllrrr"))
        write_csv_atomic(out / "cli_startup_breakdown.csv",
                         stages + [dict(field=r["field"], stage=f"kernel {r['kernel']} transform",
                                        seconds=r["transform_s"]) for r in kernel_rows] +
                         [dict(field=r["field"], stage=f"kernel {r['kernel']} first launch",
                               seconds=r["first_launch_s"]) for r in kernel_rows],
                         ["field", "stage", "seconds"])
    write_csv_atomic(out / "cli_startup.csv", walls, list(walls[0]))
    print(f"\nwrote {out / 'cli_startup.csv'}" +
          ("" if not stages else f" and {out / 'cli_startup_breakdown.csv'}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
