"""The same cases on each available Taichi arch: time, and the largest
difference from the CPU's result.

    python benchmarks/arch.py [--arches cpu,vulkan] [--sizes 2000,10000]
                              [--steps 5] [--repeats 3] [--out-dir outputs/benchmarks]

Cases, at each size N:

``decompose``  ``thh.decompose`` of the trig field at N uniformly random
               points with the Neumann condition (the default options
               otherwise): curl-free and divergence-free parts.
``natural``    the same with ``boundary_condition="natural"`` (the natural
               HHD's grid convolution and spline interpolation).
``project``    ``thh.project`` of the same field: the projected velocities.
``flow``       the rising droplet (scenes/rising_droplet.py's set-up) at N
               particles, ``--steps`` steps: positions and velocities.

Each arch runs in its own interpreter (Taichi runs one arch per process).
Per case: ``first_s``, the first call (kernel compilation or loading from
the offline cache included); ``median_s``, the median of ``--repeats``
further calls (for ``flow`` a fresh flow each time, set-up excluded:
seconds per step); ``max_diff``, the largest absolute difference from the
CPU's output over the largest |output| (0 for the CPU itself); ``speed``,
the CPU's median over this arch's.  An arch that cannot start (no device) is
reported with its error instead.  ``vulkan`` on a machine without a GPU is
Mesa's lavapipe: a correctness check of the GPU code path, not a speed one.

Writes OUT/arch.csv atomically; prints a table.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (REPO_ROOT, add_repo_to_path, format_table, measure, parse_list,  # noqa: E402
                     scene_module, summary, write_csv_atomic)

CASES = ("decompose", "natural", "project", "flow")
COLUMNS = ["case", "n", "arch", "device", "first_s", "median_s", "max_diff", "speed", "error"]


def _field(n: int):
    import numpy as np
    from taichi_hh.validation import fields
    field = fields.trig()
    p = field.sample(n, kind="random", seed=7)
    return p, field.evaluate(p).v, field.domain, np


def _flow(n: int, steps: int):
    import dataclasses
    from taichi_hh.flow.twophase import TwoPhaseFlow
    scene = scene_module("rising_droplet")
    ap = argparse.ArgumentParser()
    ap.add_argument("--particles", type=int)
    scene.SCENE.add_arguments(ap)
    pts, phases, dx, params = scene.SCENE.build(ap.parse_args(["--particles", str(n)]))
    params = dataclasses.replace(params, solver_tol=1e-6)

    held = {}

    def setup():
        held["flow"] = TwoPhaseFlow(pts, phases, dx, params)

    def run():
        flow = held["flow"]
        for _ in range(steps):
            flow.step()
        pos, vel, _, _ = flow.fluid_state()
        return {"positions": pos, "velocities": vel}
    return setup, run


def _case(case: str, n: int, steps: int):
    """(set-up, run): ``run()`` runs the case once and returns its outputs
    (arrays); ``set-up()``, untimed, comes before every run."""
    import warnings
    import taichi_hh as thh
    if case == "flow":
        return _flow(n, steps)
    p, v, domain, np = _field(n)

    def run():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if case == "project":
                return {"vectors": thh.project(p, v, domain=domain).vectors}
            res = thh.decompose(p, v, domain=domain, boundary_condition=(
                "natural" if case == "natural" else "neumann"))
            return {"curl_free": res.curl_free, "div_free": res.div_free}
    return (lambda: None), run


def worker(arch: str, cases: list, sizes: list, steps: int, repeats: int, out: str) -> None:
    """One arch, every case: times into OUT.json, outputs into OUT_<case>_<n>.npz."""
    add_repo_to_path()
    import numpy as np
    import taichi as ti
    import taichi_hh as thh
    from taichi_hh import runtime
    rows = []
    try:
        state = thh.init(arch=arch, precision="f64")
    except thh.TaichiHHError as exc:
        Path(out + ".json").write_text(json.dumps({"error": str(exc)}))
        return
    for case in cases:
        for n in sizes:
            row = {"case": case, "n": n, "arch": state.arch, "device": state.device or state.arch}
            try:
                setup, fn = _case(case, n, steps)
                first = measure(fn, 1, sync=ti.sync, setup=setup, warmup=0)[0]
                times = measure(fn, repeats, sync=ti.sync, setup=setup, warmup=0)
                setup()
                outputs = fn()
                np.savez(f"{out}_{case}_{n}.npz", **outputs)
                per = steps if case == "flow" else 1
                row.update(first_s=first, median_s=summary(times)["median_s"] / per)
            except Exception as exc:                  # reported, the other cases go on
                row["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0][:200]}"
            rows.append(row)
            print(json.dumps(row), flush=True)
    assert runtime.taichi_arch() == state.arch
    Path(out + ".json").write_text(json.dumps({"rows": rows}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arches", default="cpu,vulkan")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--sizes", default="2000,10000")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    ap.add_argument("--worker", help=argparse.SUPPRESS)    # ARCH:OUT, internal
    args = ap.parse_args(argv)
    cases = parse_list(args.cases, str)
    sizes = parse_list(args.sizes, int)
    if args.worker:
        arch, out = args.worker.split(":", 1)
        worker(arch, cases, sizes, args.steps, args.repeats, out)
        return 0
    arches = parse_list(args.arches, str)
    if "cpu" not in arches:
        arches.insert(0, "cpu")                       # the reference
    import numpy as np
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for arch in arches:
            out = os.path.join(tmp, arch)
            cmd = [sys.executable, __file__, "--worker", f"{arch}:{out}", "--cases", args.cases,
                   "--sizes", args.sizes, "--steps", str(args.steps),
                   "--repeats", str(args.repeats)]
            print(f"arch {arch} ...", file=sys.stderr, flush=True)
            proc = subprocess.run(cmd, text=True, stdout=subprocess.PIPE)
            try:
                report = json.loads(Path(out + ".json").read_text())
            except OSError:
                report = {"error": f"the {arch} worker ended with status {proc.returncode}"}
            results[arch] = report
            for row in report.get("rows", []):
                row["outputs"] = f"{out}_{row['case']}_{row['n']}.npz"
                if not row.get("error"):
                    row["data"] = dict(np.load(row["outputs"]))
        rows = []
        reference = {(r["case"], r["n"]): r for r in results["cpu"].get("rows", [])}
        for arch in arches:
            if "error" in results[arch]:
                rows.append({"case": "-", "n": "-", "arch": arch, "error": results[arch]["error"]})
                continue
            for row in results[arch]["rows"]:
                ref = reference.get((row["case"], row["n"]))
                if row.get("data") is not None and ref is not None and ref.get("data") is not None:
                    scale = max(np.abs(a).max() for a in ref["data"].values())
                    row["max_diff"] = max(np.abs(row["data"][k] - ref["data"][k]).max()
                                          for k in ref["data"]) / scale
                    row["speed"] = ref["median_s"] / row["median_s"]
                rows.append(row)
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_csv_atomic(out_dir / "arch.csv", rows, COLUMNS)

    def cell(row, key, fmt):
        value = row.get(key)
        return "" if value is None or value == "" else format(value, fmt)
    table = [[str(r["case"]), str(r["n"]), str(r.get("device") or r["arch"]),
              cell(r, "first_s", ".2f"), cell(r, "median_s", ".3f"), cell(r, "max_diff", ".1e"),
              cell(r, "speed", ".2f"), r.get("error", "")] for r in rows]
    print(format_table(["case", "N", "arch", "first s", "median s", "max diff", "speed", "error"],
                       table, "lrlrrrrl"))
    print(f"wrote {out_dir / 'arch.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
