"""The rising droplet against resolution: does the centroid height converge?

    python benchmarks/droplet_resolution.py [--particles 2592,10368] [--end 6]
                                            [--out-dir outputs/benchmarks] [--reuse N=DIR ...]
                                            [--report-only]

Runs scenes/rising_droplet.py (same physics: its defaults, only the particle
count changes) at each resolution to t = ``--end`` (default 6, the scene's
whole run) with frames every 0.1 s, in OUT/droplet_resolution/n<N>/ (the
scene's own outputs: frames, diagnostics.csv with the droplet centroid,
checkpoint.npz).  The lattice has a whole number of square cells in the 1 x 2
box, so 2600 and 10500 requested become 2592 (36 x 72) and 10368 (72 x 144).

Resumable: a run whose diagnostics.csv already reaches ``--end`` is not run
again; one with a checkpoint short of it continues from the checkpoint
(``--resume``).  ``--reuse N=DIR`` takes resolution N's results from another
directory's diagnostics.csv (e.g. a scene run made before) instead of running.

Compared at ``--end``: the droplet centroid height y_c per resolution and the
relative difference of each from the finest, |y_c - y_c(finest)| / y_c(finest)
(target: within 5%), and the stricter difference of the rise
(y_c(end) - y_c(0)).  Wall times of runs made in one go by this script are
recorded too (the full 10.5k run is the scene benchmark's full droplet run).

Writes OUT/droplet_resolution.csv (one row per resolution) and
OUT/droplet_resolution.png (centroid height and rise speed against time).
Long: run it niced in the background, e.g.
``nice python benchmarks/droplet_resolution.py > droplet_res.log 2>&1 &``.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import (REPO_ROOT, add_repo_to_path, format_table, parse_list,  # noqa: E402
                     save_figure_atomic, scene_module, write_csv_atomic)

add_repo_to_path()

TARGET = 0.05


def read_diagnostics(path: Path) -> list[dict]:
    try:
        with open(path) as fh:
            return [{k: float(v) for k, v in r.items() if v not in ("", None)}
                    for r in csv.DictReader(fh)]
    except OSError:
        return []


def reaches(rows, end: float) -> bool:
    return bool(rows) and rows[-1]["time"] >= end - 1e-9


def run_resolution(n: int, end: float, out: Path, frame_width: int, progress: bool) -> dict:
    """Run (or resume) the droplet at n particles to ``end``; returns timing info."""
    from taichi_hh.app.scene import run_scene
    argv = ["--particles", str(n), "--end-time", repr(end), "--out", str(out),
            "--frame-width", str(frame_width), "--montage", "0,2,4,6" if end >= 6 else ""]
    resumed = (out / "checkpoint.npz").exists() and bool(read_diagnostics(out / "diagnostics.csv"))
    if resumed:
        argv.append("--resume")
    if not progress:
        argv.append("--quiet")
    t0 = time.perf_counter()
    res = run_scene(scene_module("rising_droplet").SCENE, argv)
    info = {"wall_s": time.perf_counter() - t0, "loop_s": res.loop, "steps_run": res.steps,
            "resumed": resumed, "seconds": res.seconds,
            "median_iterations": sorted(res.iterations)[len(res.iterations) // 2]
            if res.iterations else 0}
    (out / "timing.json").write_text(json.dumps(info, indent=1))
    return info


def chart(series: dict, end: float, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.8))
    for n, rows in sorted(series.items()):
        t = [r["time"] for r in rows]
        a1.plot(t, [r["centroid_y"] for r in rows], label=f"{n} particles")
        a2.plot(t, [r["rise_speed"] for r in rows], label=f"{n} particles")
    a1.set_xlabel("t")
    a1.set_ylabel("droplet centroid height")
    a2.set_xlabel("t")
    a2.set_ylabel("mean vertical velocity of the droplet")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    a2.grid(alpha=0.3)
    fig.suptitle("Rising droplet against resolution (1 x 2 box, density ratio 2, nu = 2e-3)",
                 fontsize=10)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)


def at_time(rows, t: float):
    """The row with the given output time (or the last before it)."""
    best = None
    for r in rows:
        if r["time"] <= t + 1e-9:
            best = r
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--particles", default="2592,10368",
                    help="comma-separated particle counts (the scene's lattice rounds them)")
    ap.add_argument("--end", type=float, default=6.0, help="simulated time to compare at")
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    ap.add_argument("--reuse", action="append", default=[], metavar="N=DIR",
                    help="take resolution N from DIR/diagnostics.csv instead of running it")
    ap.add_argument("--report-only", action="store_true",
                    help="run nothing; compare what the run directories hold")
    ap.add_argument("--times", default="2,4",
                    help="earlier output times to compare the centroid heights at as well")
    ap.add_argument("--frame-width", type=int, default=800)
    ap.add_argument("--progress", action="store_true", help="show the scene's progress bar")
    args = ap.parse_args(argv)
    out_dir = Path(args.out_dir)
    counts = parse_list(args.particles, int)
    reuse = {}
    for item in args.reuse:
        n, _, d = item.partition("=")
        reuse[int(n)] = Path(d)
        if int(n) not in counts:
            counts.append(int(n))

    if not args.report_only:
        import taichi_hh
        taichi_hh.init(arch="cpu", precision="f64", verbose=False)

    series, timing, dirs = {}, {}, {}
    for n in sorted(counts):
        d = reuse.get(n, out_dir / "droplet_resolution" / f"n{n}")
        dirs[n] = d
        rows = read_diagnostics(d / "diagnostics.csv")
        if not reaches(rows, args.end) and n not in reuse and not args.report_only:
            print(f"droplet at {n} particles -> t = {args.end:g} in {d} "
                  f"({'resuming' if rows else 'starting'}) ...", file=sys.stderr, flush=True)
            info = run_resolution(n, args.end, d, args.frame_width, args.progress)
            print(f"  done: {info['wall_s']:.0f} s wall, {info['steps_run']} steps", file=sys.stderr,
                  flush=True)
            rows = read_diagnostics(d / "diagnostics.csv")
        try:
            timing[n] = json.loads((d / "timing.json").read_text())
        except (OSError, ValueError):
            timing[n] = {}
        if rows:
            series[n] = rows

    if not series:
        print("no results yet", file=sys.stderr)
        return 1
    finest = max(n for n in series if reaches(series[n], args.end)) if any(
        reaches(r, args.end) for r in series.values()) else max(series)
    t_cmp = min(args.end, min(r[-1]["time"] for r in series.values()))
    ref = at_time(series[finest], t_cmp)
    ref_rise = ref["centroid_y"] - series[finest][0]["centroid_y"]
    out_rows, table = [], []
    for n, rows in sorted(series.items()):
        r = at_time(rows, t_cmp)
        y0 = rows[0]["centroid_y"]
        rel = abs(r["centroid_y"] - ref["centroid_y"]) / abs(ref["centroid_y"])
        rise = r["centroid_y"] - y0
        rel_rise = abs(rise - ref_rise) / abs(ref_rise) if ref_rise else float("nan")
        tm = timing.get(n, {})
        one_go = bool(tm) and not tm.get("resumed") and reaches(rows, args.end)
        row = {"particles": n, "dir": str(dirs[n]), "t_compare": t_cmp,
               "reached_end": reaches(rows, args.end), "centroid_y0": y0,
               "centroid_y": r["centroid_y"], "centroid_x": r.get("centroid_x", ""),
               "rise": rise, "rise_speed": r.get("rise_speed", ""),
               "rel_diff_vs_finest": rel, "rel_rise_diff_vs_finest": rel_rise,
               "steps": int(r["step"]), "volume_error_mean": r.get("volume_error_mean", ""),
               "wall_s_one_go": tm.get("wall_s", "") if one_go else "",
               "median_iterations": tm.get("median_iterations", "")}
        out_rows.append(row)
        table.append([n, f"{t_cmp:g}", f"{y0:.4f}", f"{r['centroid_y']:.4f}", f"{rise:.4f}",
                      f"{100 * rel:.2f}%", f"{100 * rel_rise:.2f}%", int(r["step"]),
                      f"{row['wall_s_one_go']:.0f}" if row["wall_s_one_go"] != "" else "-"])
    print(format_table(["particles", "t", "y_c(0)", "y_c(t)", "rise", "diff y_c", "diff rise",
                        "steps", "wall s"], table))
    pairs = []
    for a in out_rows:
        for b in out_rows:
            if a["particles"] < b["particles"]:
                d = abs(a["centroid_y"] - b["centroid_y"]) / abs(b["centroid_y"])
                pairs.append(f"{a['particles']} vs {b['particles']}: {100 * d:.2f}%"
                             f"{'' if d <= TARGET else ' (over)'}")
    if pairs:
        print(f"pairwise at t = {t_cmp:g}: " + "; ".join(pairs))
    worst = max(r["rel_diff_vs_finest"] for r in out_rows)
    times = [t for t in parse_list(args.times) if t < t_cmp]
    for t in times:
        ref_t = at_time(series[finest], t)["centroid_y"]
        diffs = []
        for row in out_rows:
            y = at_time(series[row["particles"]], t)["centroid_y"]
            row[f"centroid_y_t{t:g}"] = y
            row[f"rel_diff_t{t:g}"] = abs(y - ref_t) / abs(ref_t)
            diffs.append(f"{row['particles']}: {y:.4f} ({100 * row[f'rel_diff_t{t:g}']:.2f}%)")
        print(f"t = {t:g}: centroid heights " + ", ".join(diffs))
    print(f"centroid heights at t = {t_cmp:g} agree within {100 * worst:.2f}% of the finest "
          f"({finest} particles); target {100 * TARGET:g}%: "
          f"{'met' if worst <= TARGET else 'not met'}"
          f"{'' if t_cmp >= args.end - 1e-9 else ' (runs incomplete: compared at the common time)'}")
    write_csv_atomic(out_dir / "droplet_resolution.csv", out_rows, list(out_rows[0]))
    chart(series, args.end, out_dir / "droplet_resolution.png")
    print(f"wrote {out_dir / 'droplet_resolution.csv'} and .png", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
