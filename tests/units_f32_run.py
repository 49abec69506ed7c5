"""Run by tests/test_units.py in a subprocess (Taichi runs one precision per
process): single-precision decompositions of the trig field at every
placement of test_units.PLACEMENTS; prints one JSON line per condition: the
mean errors of d and r against the exact split (over mean |v|), the largest
difference from the unit-square run (over max |v|), and any error raised."""
import json
import sys
import warnings

import numpy as np

import taichi_hh as thh
from taichi_hh.validation import fields

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from test_units import PLACEMENTS, _placed  # noqa: E402


def mean_error(got, want, v):
    return float(np.linalg.norm(got - want, axis=1).mean() / np.linalg.norm(v, axis=1).mean())


def main():
    thh.init(arch="cpu", precision="f32")
    trig = fields.get("trig")
    pts = trig.sample(1200, "random", seed=4)
    exact = trig.evaluate(pts)
    vmax = float(np.abs(exact.v).max())
    report = {}
    for condition in ("neumann", "normal-parallel", "natural"):
        rows, ref = [], None
        for scale, offset in [(1.0, (0.0, 0.0))] + PLACEMENTS:
            placed, box = _placed(pts, scale, offset)
            row = {"scale": scale, "offset": list(offset), "error": ""}
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = thh.decompose(placed, exact.v, box, boundary_condition=condition)
            except thh.TaichiHHError as exc:
                row["error"] = f"{type(exc).__name__}: {exc}"
                rows.append(row)
                continue
            if ref is None:
                ref = res
            row["err_d"] = mean_error(res.curl_free, exact.d, exact.v)
            row["err_r"] = mean_error(res.div_free, exact.r, exact.v)
            row["spread"] = float(max(np.abs(res.curl_free - ref.curl_free).max(),
                                      np.abs(res.div_free - ref.div_free).max()) / vmax)
            rows.append(row)
        report[condition] = rows
    # fields of any magnitude (f32 holds 1e-38 .. 3e38: the unit frame scales
    # the field before anything is rounded to f32) and the projection
    rows = []
    for magnitude in (1e-40, 1e30, 1e200):
        row = {"scale": 1.0, "offset": [0.0, 0.0], "magnitude": magnitude, "error": ""}
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = thh.decompose(pts, exact.v * magnitude, (0, 0, 1, 1),
                                    boundary_condition="neumann")
            ref = report["neumann"][0]
            row["err_d"] = mean_error(res.curl_free / magnitude, exact.d, exact.v)
            row["err_r"] = mean_error(res.div_free / magnitude, exact.r, exact.v)
            row["spread"] = abs(row["err_d"] - ref["err_d"]) + abs(row["err_r"] - ref["err_r"])
        except thh.TaichiHHError as exc:
            row["error"] = f"{type(exc).__name__}: {exc}"
        rows.append(row)
    report["magnitudes"] = rows
    out = thh.project(pts * 1e3 + [5e5, 5e6], exact.v * 1e-30,
                      (5e5, 5e6, 5e5 + 1e3, 5e6 + 1e3))
    report["project"] = [{"reduction": float(out.max_divergence[-1] / out.max_divergence[0]),
                          "error": ""}]
    print(json.dumps(report))


if __name__ == "__main__":
    main()
