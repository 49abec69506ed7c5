"""benchmarks/speed_accuracy.py --quick runs end to end: its CSV has rows with
finite timings and errors for the configurations that ran, failures carry the
exception, and the four charts exist.  (Runs the script in a subprocess: it
starts its own worker pool, each worker with its own Taichi runtime.)"""
import csv
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "benchmarks" / "speed_accuracy.py"
CHARTS = ("pareto", "convergence", "kappa", "flow")

pytestmark = pytest.mark.slow          # about 90 s


def test_quick_sweep_writes_csv_and_charts(tmp_path):
    env = dict(os.environ)
    env.setdefault("TAICHI_HH_CACHE", str(ROOT / ".taichi_cache"))
    proc = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--no-progress",
                           "--out", str(tmp_path)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)   # ~90 s alone; a shared machine is slower
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Pareto front" in proc.stdout
    with open(tmp_path / "speed_accuracy_quick.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 20
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) >= 0.7 * len(rows)
    for r in ok:
        for key in ("total_s", "err"):
            assert math.isfinite(float(r[key])) and float(r[key]) >= 0, (r["label"], key, r[key])
        assert r["finite"] == "True", r["label"]
        if r["task"] == "hhd":
            for key in ("setup_s", "solve_s", "err_d", "err_r", "err_h"):
                assert math.isfinite(float(r[key])), (r["label"], key)
            assert float(r["setup_s"]) + float(r["solve_s"]) <= float(r["total_s"]) * 1.001
    for r in rows:
        assert r["status"] in ("ok", "error"), (r["label"], r["status"], r["message"])
        if r["status"] == "error":
            assert r["error"] and r["message"], r["label"]
            assert "benchmark script" not in r["message"], r["message"]
    groups = {r["group"] for r in ok}
    assert {"resolution", "kernel", "support", "tol", "precision", "kappa", "flow"} <= groups
    # the default is the most accurate of the quick resolution runs at its largest N
    res = [r for r in ok if r["group"] == "resolution"]
    nmax = max(int(r["n_points"]) for r in res)
    best = min((r for r in res if int(r["n_points"]) == nmax), key=lambda r: float(r["err"]))
    assert best["label"] == "default"
    assert {r["precision"] for r in ok} == {"f32", "f64"}
    for name in CHARTS:
        png = tmp_path / f"speed_accuracy_{name}_quick.png"
        assert png.exists() and png.stat().st_size > 10_000, png
