"""Any units: the same decomposition and projection for coordinates in any unit
and with any origin (metres over 1000 km, UTM offsets, micrometres) and for
fields of any magnitude, in both precisions (taichi_hh.hhd.units)."""
import json
import pathlib
import subprocess
import sys
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.validation import fields

HERE = pathlib.Path(__file__).resolve().parent
TRIG = fields.get("trig")          # exact under Neumann on the unit square
#: (scale, offset): the unit square moved to micrometres ... 1e9 units, and to a
#: UTM-like origin (easting 5e5 m, northing 5e6 m) at 1 km and 1000 km sides
PLACEMENTS = [(1e-6, (0.0, 0.0)), (1e-3, (0.0, 0.0)), (1e3, (0.0, 0.0)), (1e6, (0.0, 0.0)),
              (1e9, (0.0, 0.0)), (1e3, (5e5, 5e6)), (1e6, (5e5, 5e6))]


@pytest.fixture(scope="module")
def trig_points():
    pts = TRIG.sample(1200, "random", seed=4)
    return pts, TRIG.evaluate(pts)


def _placed(pts, scale, offset):
    off = np.asarray(offset)
    return pts * scale + off, (off[0], off[1], scale + off[0], scale + off[1])


@pytest.mark.parametrize("condition", ["neumann", "normal-parallel", "natural"])
def test_decomposition_does_not_depend_on_the_units(trig_points, condition):
    pts, exact = trig_points
    ref = thh.decompose(pts, exact.v, (0, 0, 1, 1), boundary_condition=condition)
    vmax = np.abs(exact.v).max()
    for scale, offset in PLACEMENTS:
        placed, box = _placed(pts, scale, offset)
        res = thh.decompose(placed, exact.v, box, boundary_condition=condition)
        for got, want in ((res.curl_free, ref.curl_free), (res.div_free, ref.div_free),
                          (res.harmonic, ref.harmonic)):
            assert np.abs(got - want).max() <= 1e-9 * vmax, (scale, offset)
        # potentials carry the length unit, derivatives its inverse
        assert np.abs(res.phi / scale - ref.phi).max() <= 1e-9 * np.ptp(ref.phi)
        assert np.abs(res.divergence * scale - ref.divergence).max() \
            <= 1e-9 * np.abs(ref.divergence).max()
        assert res.stats["spacing"] == pytest.approx(ref.stats["spacing"] * scale, rel=1e-9)
        assert res.stats.get("iterations_phi") == ref.stats.get("iterations_phi")
        cps = res.critical_points()
        ref_cps = ref.critical_points()
        assert [c.kind for c in cps] == [c.kind for c in ref_cps]
        for c, r in zip(cps, ref_cps):
            assert np.hypot((c.x - offset[0]) / scale - r.x, (c.y - offset[1]) / scale - r.y) \
                < 1e-9


def test_decomposition_does_not_depend_on_the_fields_magnitude(trig_points):
    """Speeds of 1e-300 .. 1e300 (f64): the same components times the magnitude,
    not zeros, not "b contains NaN or inf"."""
    pts, exact = trig_points
    ref = thh.decompose(pts, exact.v, (0, 0, 1, 1))
    # 1e306: the vectors' sum (the input check's one pass for NaN) overflows
    for magnitude in (1e-300, 1e-160, 1e-40, 1e40, 1e160, 1e300, 1e306):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            res = thh.decompose(pts, exact.v * magnitude, (0, 0, 1, 1))
            series = thh.Decomposer(pts, (0, 0, 1, 1)).decompose(exact.v * magnitude)
        for got in (res, series[0]):
            assert np.abs(got.curl_free / magnitude - ref.curl_free).max() \
                <= 1e-9 * np.abs(exact.v).max(), magnitude
            assert np.abs(got.psi / magnitude - ref.psi).max() <= 1e-9 * np.ptp(ref.psi)


@pytest.mark.parametrize("condition", ["natural", "neumann"])
def test_the_unit_frame_result_is_the_callers_scaled_back(trig_points, condition):
    """``result.unit``: the valid rows in the unit frame, the caller's arrays
    over the frame's scales (a natural split's arrays are scaled to the
    caller's units in place: the unit result must not read them as they
    were), its stats' lengths in the unit frame."""
    pts, exact = trig_points
    placed, box = _placed(pts, 1e3, (5e5, 5e6))
    v = exact.v * 40.0
    v[7] = np.nan
    res = thh.decompose(placed, v, box, boundary_condition=condition)
    f, unit, ok = res.frame, res.unit, res.valid
    assert f.speed != 1.0 and f.length != 1.0 and not ok[7] and ok.sum() == len(pts) - 1
    assert np.allclose(unit.points, (placed[ok] - np.asarray(f.centre)) / f.length,
                       rtol=0, atol=1e-12)
    for name, scale in (("curl_free", f.speed), ("div_free", f.speed), ("harmonic", f.speed),
                        ("phi", f.potential), ("psi", f.potential),
                        ("divergence", f.derivative), ("curl", f.derivative)):
        got, caller = getattr(unit, name), getattr(res, name)[ok]
        assert np.abs(got * scale - caller).max() <= 1e-14 * np.abs(caller).max(), name
        assert not 0.5 < scale < 2.0 and not np.allclose(got, caller, rtol=0.1), name
    assert unit.stats["spacing"] == pytest.approx(res.stats["spacing"] / f.length, rel=1e-14)
    assert unit.domain.area == pytest.approx(res.domain.area / f.length ** 2, rel=1e-12)
    # every row valid: the natural split's arrays scaled in place, the unit
    # frame's made from them
    whole = thh.decompose(placed, exact.v * 40.0, box, boundary_condition=condition)
    again = thh.decompose(placed, exact.v * 40.0, box, boundary_condition=condition)
    assert np.abs(whole.unit.curl_free * whole.frame.speed - whole.curl_free).max() \
        <= 1e-14 * np.abs(whole.curl_free).max()
    assert np.array_equal(whole.curl_free, again.curl_free)


def test_projection_does_not_depend_on_units_or_magnitude():
    rng = np.random.default_rng(2)
    pts = rng.random((900, 2))
    v = np.c_[np.sin(3 * pts[:, 0]) + pts[:, 1], np.cos(2 * pts[:, 1]) * pts[:, 0]]
    ref = thh.project(pts, v, (0, 0, 1, 1), **thh_scattered())
    assert ref.max_divergence[-1] < 1e-6 * ref.max_divergence[0]
    for scale, offset, magnitude in ((1e-6, (0, 0), 1.0), (1e6, (5e5, 5e6), 1.0),
                                     (1.0, (0, 0), 1e-160), (1.0, (0, 0), 1e160),
                                     (1e3, (5e5, 5e6), 1e-20)):
        placed, box = _placed(pts, scale, offset)
        res = thh.project(placed, v * magnitude, box, **thh_scattered())
        # the orthogonal step's CG (about 180 iterations here) is defined to its
        # tolerance only: moving the points by 1e-3 without any scaling changes
        # w by 6e-8 too (measured), so agreement is to that level, not to 1e-9
        assert np.abs(res.vectors / magnitude - ref.vectors).max() <= 1e-6 * np.abs(v).max()
        assert res.max_divergence[-1] <= 1e-5 * res.max_divergence[0]
        assert not np.allclose(res.vectors / magnitude, v)         # it did project
        assert res.max_divergence[0] == pytest.approx(
            ref.max_divergence[0] * magnitude / scale, rel=1e-9)


def thh_scattered():
    from taichi_hh.hhd.project import SCATTERED_OPTIONS
    return SCATTERED_OPTIONS


def _mean_error(got, want, v):
    return np.linalg.norm(got - want, axis=1).mean() / np.linalg.norm(v, axis=1).mean()


def test_single_precision_in_any_units(trig_points):
    """f32 (its own process: one Taichi runtime per process): every boundary
    condition converges with the default tolerance (mixed-precision refinement,
    poisson.matrix) at every scale and offset, agrees across them, and is as
    accurate against the exact answer as f64 (this process) up to f32's
    rounding."""
    pts, exact = trig_points
    out = subprocess.run([sys.executable, str(HERE / "units_f32_run.py")], capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    report = json.loads(out.stdout.strip().splitlines()[-1])
    # fields of 1e-40 .. 1e200 in f32: the same errors as at 1 (before: d = r = 0
    # at 1e-40, "b contains NaN or inf" from 1e20)
    for row in report.pop("magnitudes"):
        assert row["error"] == "" and row["spread"] <= 1e-4, row
    # the projection in f32, metres at a UTM origin, a field of 1e-30: it runs
    # (its Poisson step refines in double; before: stagnation at 4.7e-5) and
    # stops at its rounding floor, 1e3 eps_f32 of |w| / spacing (project's
    # doc): max |div| down 160x (measured 6.2e-3; f64 reaches 1e-7)
    (proj,) = report.pop("project")
    assert proj["reduction"] < 1e-2, proj
    for condition, rows in report.items():
        f64 = thh.decompose(pts, exact.v, (0, 0, 1, 1), boundary_condition=condition)
        err_d = _mean_error(f64.curl_free, exact.d, exact.v)
        err_r = _mean_error(f64.div_free, exact.r, exact.v)
        for row in rows:
            assert row["error"] == "", (condition, row)
            assert row["spread"] <= 1e-4, (condition, row)      # any units, to f32 rounding
            assert row["err_d"] <= err_d + 1e-4, (condition, row, err_d)
            assert row["err_r"] <= err_r + 1e-4, (condition, row, err_r)


def test_subnormal_components_survive(trig_points):
    """Taichi's ti.init switches its thread to flush-to-zero; the runtime puts
    the caller's floating-point environment back, so numpy on this thread keeps
    subnormals and a field of 2**-1020 keeps its components down to 1e-8 of
    the largest (below 2.2e-308 there), not zeros."""
    from taichi_hh import runtime
    runtime.ensure_init()
    assert runtime.subnormals_kept()
    assert (np.array([1e-310]) * 1.0)[0] == 1e-310
    pts, exact = trig_points
    ref = thh.decompose(pts, exact.v, (0, 0, 1, 1))
    magnitude = 2.0 ** -1020
    res = thh.decompose(pts, exact.v * magnitude, (0, 0, 1, 1))
    for got, want in ((res.curl_free, ref.curl_free), (res.div_free, ref.div_free)):
        small = (np.abs(want) > 1e-8 * np.abs(want).max()) & (np.abs(want * magnitude) < 2.2e-308)
        assert small.any()
        assert np.allclose(got[small] / magnitude, want[small], rtol=1e-6, atol=0)
