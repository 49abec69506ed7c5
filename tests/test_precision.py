"""Single precision: every public call runs in f32 with its defaults.

The f32 runtime runs in its own interpreter (one precision per process), on
the session's arch (``$TAICHI_HH_ARCH``: the subprocess inherits it, so CI's
Vulkan run checks f32 on Vulkan).  The solver's default tolerance (1e-8) is
below what an f32 residual attains; the Poisson solves reach it by
refinement with the residual in f64 (poisson/matrix.py), so the defaults
are the same in both precisions.  test_units.py checks f32's accuracy under
every placement; here every call and boundary condition, and the answers
against f64's (this process).
"""
import json
import os
import pathlib
import subprocess
import sys
import warnings

import numpy as np

import taichi_hh as thh
from taichi_hh import runtime

ROOT = pathlib.Path(__file__).resolve().parent.parent
CONDITIONS = ("auto", "neumann", "normal-parallel", "no-flux", "natural")

CALLS = r"""
import json, sys, warnings
import numpy as np
import taichi_hh as thh
from taichi_hh import runtime
sys.path.insert(0, "tests")
from test_precision import CONDITIONS, calls
thh.init(precision="f32")
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    out = calls()
out["arch"] = runtime.taichi_arch()
print(json.dumps(out))
"""


def calls() -> dict:
    """Every public call on the trig field (1200 random points; a 33 x 25
    grid): its outputs as lists."""
    from taichi_hh.validation import fields
    field = fields.trig()
    p = field.sample(1200, kind="random", seed=4)
    v = field.evaluate(p).v
    exact = field.evaluate(p)
    out = {"exact_d": exact.d.tolist()}
    for condition in CONDITIONS:
        res = thh.decompose(p, v, domain=field.domain, boundary_condition=condition)
        out[condition] = {"d": res.curl_free.tolist(), "r": res.div_free.tolist(),
                          "condition": res.stats["boundary_condition"],
                          "critical": len(res.critical_points()),
                          "precision": res.stats["precision"]}
    proj = thh.project(p, v, domain=field.domain)
    out["project"] = {"w": proj.vectors.tolist(),
                      "max_divergence": float(proj.max_divergence[-1])}
    x, y = np.linspace(0, 1, 33), np.linspace(0, 1, 25)
    X, Y = np.meshgrid(x, y)
    g = field.evaluate(np.c_[X.ravel(), Y.ravel()]).v
    grid = thh.decompose_grid(x, y, g[:, 0].reshape(X.shape), g[:, 1].reshape(X.shape))
    out["grid"] = {"d": np.nan_to_num(grid.curl_free).tolist()}
    return out


def test_every_public_call_runs_in_single_precision_with_its_defaults():
    proc = subprocess.run([sys.executable, "-c", CALLS], capture_output=True, text=True,
                          cwd=ROOT, env=dict(os.environ), timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    single = json.loads(proc.stdout.strip().splitlines()[-1])
    assert single["arch"] == runtime.taichi_arch()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        double = calls()
    scale = np.abs(np.array(double["neumann"]["d"])).max()
    # f32 costs no accuracy that matters: its difference from f64 stays below a
    # tenth of f64's own error against the exact split (the trig field's parts
    # are exact under Neumann): measured 1.0e-4 of the field (Vulkan) against 1.3e-3
    bound = 0.1 * np.abs(np.array(double["neumann"]["d"]) - np.array(double["exact_d"])).max()
    for condition in CONDITIONS:
        s, d = single[condition], double[condition]
        assert s["precision"] == "f32" and s["condition"] == d["condition"], condition
        assert s["critical"] == d["critical"], condition
        for part in ("d", "r"):
            err = np.abs(np.array(s[part]) - np.array(d[part])).max()
            assert err < bound, (condition, part, err / scale, bound / scale)
    # the projection stops at its rounding floor, |D w| <= 1e3 eps |w|_2 / spacing
    # (project(): f32's 1e-4 of the field's own divergence scale), so w may
    # move by up to 1e3 eps |w|_2 from f64's (measured: 1.0e-3 against 2.8e-3)
    w = np.array(double["project"]["w"])
    err = np.abs(np.array(single["project"]["w"]) - w).max()
    assert err < 1e3 * np.finfo(np.float32).eps * np.linalg.norm(w)
    assert np.abs(np.array(single["grid"]["d"]) - np.array(double["grid"]["d"])).max() < bound
