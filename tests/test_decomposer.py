"""Many snapshots on the same points (taichi_hh.Decomposer): each snapshot's
answer is the one a decompose() call of its own gives, to the solver's
tolerance, under every boundary condition; snapshots solved together as
columns; missing rows per snapshot; the stream and the stacked result."""
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import InputError

FIELDS = ("curl_free", "div_free", "harmonic", "phi", "psi", "divergence", "curl")


def _points(n=700, seed=3):
    return np.random.default_rng(seed).random((n, 2))


def _window(p, t):
    """A vortex and a source drifting through a stream: the flow crosses the
    boundary (auto: natural)."""
    cx = 0.35 + 0.3 * t
    dx, dy = p[:, 0] - cx, p[:, 1] - 0.5
    g = np.exp(-(dx * dx + dy * dy) / 0.03)
    return np.c_[0.4 - dy * g + 0.5 * dx * g, dx * g + 0.5 * dy * g] * (1.0 + 3.0 * t)


def _cavity(p, t):
    """A closed container's flow (v.n = 0 on the unit square): auto's no-flux."""
    x, y = p[:, 0], p[:, 1]
    u = np.sin(np.pi * x) ** 2 * np.sin(2 * np.pi * y)
    v = -np.sin(2 * np.pi * x) * np.sin(np.pi * y) ** 2
    return np.c_[u, v] * (1.0 + t)


def _assert_same(series, t, ref, rtol):
    for name in FIELDS:
        got, want = getattr(series, name)[t], getattr(ref, name)
        assert np.array_equal(np.isnan(got), np.isnan(want)), name
        scale = np.nanmax(np.abs(want))
        err = np.nanmax(np.abs(got - want))
        assert err <= rtol * scale, (name, t, err / scale)
    assert series.stats[t]["boundary_condition"] == ref.stats["boundary_condition"]


@pytest.mark.parametrize("condition", ["neumann", "normal-parallel", "no-flux", "natural",
                                       "auto"])
def test_each_snapshot_equals_its_own_call(condition):
    pts = _points()
    V = np.stack([_window(pts, t) for t in (0.0, 0.5, 1.0)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the six columns of the three snapshots in joint solves of four (the
        # second's two padded with zero columns to the same width)
        series = thh.Decomposer(pts, boundary_condition=condition, batch=3,
                                columns=4).decompose(V)
        refs = [thh.decompose(pts, v, boundary_condition=condition) for v in V]
    assert len(series) == 3 and series.curl_free.shape == (3, len(pts), 2)
    for t, ref in enumerate(refs):
        # the Krylov solves stop at relative residual 1e-8, each column on its own
        _assert_same(series, t, ref, 1e-6)
        assert series.stats[t]["shared_setup"]
    if condition not in ("natural", "auto"):
        # every column of the joint solves stopped at the tolerance on its own
        # (the iteration counts of a long Jacobi run follow the rounding of the
        # parallel reductions, run to run)
        for t in range(3):
            for name in ("phi", "psi"):
                assert series.stats[t][f"residual_{name}"] <= 1e-8
                assert series.stats[t][f"iterations_{name}"] > 0


def test_auto_chooses_per_snapshot():
    """A window then a closed container on the same points: each snapshot gets
    its own condition, and the answers of its own call."""
    pts = _points(900, seed=5)
    V = np.stack([_window(pts, 0.2), _cavity(pts, 0.0), _window(pts, 0.8)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        series = thh.Decomposer(pts).decompose(V)
        refs = [thh.decompose(pts, v) for v in V]
    assert series.boundary_condition == [r.stats["boundary_condition"] for r in refs]
    assert series.boundary_condition == ["natural", "no-flux", "natural"]
    for t, ref in enumerate(refs):
        _assert_same(series, t, ref, 1e-6)


@pytest.mark.parametrize("method", ["petronetto2010", "default"])
def test_methods_and_operator_options(method):
    pts = _points(600, seed=7)
    V = np.stack([_window(pts, t) for t in (0.1, 0.6)])
    options = {"kernel": "quartic", "boundary_condition": "natural"} \
        if method == "default" else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        series = thh.Decomposer(pts, method=method, batch=1, **options).decompose(V)
        refs = [thh.decompose(pts, v, method=method, **options) for v in V]
    for t, ref in enumerate(refs):
        _assert_same(series, t, ref, 1e-6)


def test_missing_rows_per_snapshot():
    """The points' NaN rows are missing in every snapshot (shared set-up); a
    snapshot missing other rows is decomposed on its own (as its own call)."""
    pts = _points(600, seed=9)
    pts[[4, 50]] = np.nan
    V = np.stack([_window(np.nan_to_num(pts), t) for t in (0.0, 0.5, 1.0)])
    V[1, [7, 8, 300]] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        series = thh.Decomposer(pts, boundary_condition="neumann").decompose(V)
        refs = [thh.decompose(pts, v, boundary_condition="neumann") for v in V]
    assert [s["shared_setup"] for s in series.stats] == [True, False, True]
    for t, ref in enumerate(refs):
        _assert_same(series, t, ref, 1e-6)
    assert np.isnan(series.curl_free[:, 4]).all() and np.isnan(series.phi[1, 300])
    assert series.stats[1]["n_invalid"] == 5 and series.stats[0]["n_invalid"] == 2
    with pytest.raises(InputError, match="missing"):
        thh.Decomposer(pts, invalid="error")


def test_stream_shapes_and_snapshot_view():
    pts = _points(500, seed=11)
    dec = thh.Decomposer(pts, boundary_condition="normal-parallel", batch=1)
    gen = (_window(pts, t) for t in (0.0, 1.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        streamed = list(dec.stream(gen))
        one = dec.decompose(_window(pts, 1.0))           # (N, 2): T = 1
    assert len(one) == 1
    np.testing.assert_allclose(streamed[1].div_free, one.div_free[0], rtol=0, atol=1e-12)
    view = one[0]
    assert isinstance(view, thh.HHDResult) and view.phi.shape == (len(pts),)
    np.testing.assert_array_equal(view.harmonic, one.harmonic[0])
    assert one.energy_ratio.shape == (1,)
    assert isinstance(view.critical_points(), list)
    for bad in (np.zeros((2, len(pts) + 1, 2)), np.zeros((0, len(pts), 2)),
                np.zeros((len(pts), 3))):
        with pytest.raises(InputError, match="vectors"):
            dec.decompose(bad)
    with pytest.raises(InputError, match="batch"):
        thh.Decomposer(pts, batch=0)
    with pytest.raises(InputError, match="option"):
        thh.Decomposer(pts, bogus=1)


def _grid_snapshots(x, y, times):
    X, Y = np.meshgrid(x, y)
    pts = np.c_[X.ravel(), Y.ravel()]
    U, V = [], []
    for t in times:
        w = _window(pts, t)
        U.append(w[:, 0].reshape(X.shape))
        V.append(w[:, 1].reshape(X.shape))
    return np.array(U), np.array(V)


@pytest.mark.parametrize("options", [{}, {"boundary_condition": "normal-parallel"},
                                     {"boundary_condition": "no-flux"}])
def test_grid_snapshots_equal_decompose_grid(options):
    """The grid form: the grid-native natural path (default) and the scattered
    path through the kept systems, each snapshot as decompose_grid gives it;
    a snapshot missing other nodes gets its own layout."""
    x = np.linspace(0.0, 1.0, 26)
    y = np.linspace(0.0, 0.8, 21)
    U, V = _grid_snapshots(x, y, (0.0, 0.4, 0.8))
    U[1, 3:6, 4:7] = np.nan                      # a hole in one snapshot only
    mask = np.zeros(U.shape[1:], dtype=bool)
    mask[10, 12] = True                          # a dropout in every snapshot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        series = thh.GridDecomposer(x, y, mask, batch=2, **options).decompose(U, V)
        refs = [thh.decompose_grid(x, y, U[t], V[t], mask, **options) for t in range(3)]
    assert len(series) == 3 and series.curl_free.shape == (3, 21, 26, 2)
    assert series.boundary_condition == [r.stats["boundary_condition"] for r in refs]
    for t, ref in enumerate(refs):
        _assert_same(series, t, ref, 1e-6)
        np.testing.assert_array_equal(series.used[t], ref.used)
    assert np.isnan(series.phi[1, 4, 5]) and not np.isnan(series.phi[0, 4, 5])
    if not options:
        assert series.stats[0].get("grid_native")
    with pytest.raises(InputError, match="shape"):
        thh.GridDecomposer(x, y).decompose(U[:, :, :-1], V)


@pytest.mark.parametrize("condition", ["neumann", "normal-parallel", "no-flux"])
def test_factorised_series_equals_its_own_calls(condition):
    """factorize=True: SuperLU of each system once, triangular solves per
    snapshot; the answers of the BiCGSTAB calls to their tolerance."""
    pytest.importorskip("scipy")
    pts = _points(600, seed=13)
    V = np.stack([_window(pts, t) for t in (0.0, 0.7)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        series = thh.Decomposer(pts, boundary_condition=condition,
                                factorize=True).decompose(V)
        refs = [thh.decompose(pts, v, boundary_condition=condition) for v in V]
    for t, ref in enumerate(refs):
        _assert_same(series, t, ref, 1e-6)
        assert series.stats[t]["iterations_psi"] == 0
        assert series.stats[t]["residual_psi"] <= 1e-10
    with pytest.raises(InputError, match="least-squares"):
        thh.Decomposer(pts, method="colin2006", factorize=True).split_for("neumann")


@pytest.mark.parametrize("grid_first", [False, True])
def test_cli_series_keeps_the_points_setup(grid_first):
    """The CLI's series (app.series.FieldSeries): each file's answer that of
    decompose_field, the set-up made once for the run's points."""
    from taichi_hh.app.series import FieldSeries, decompose_field
    x = np.linspace(0.0, 1.0, 24)
    X, Y = np.meshgrid(x, x[:18])
    pts = np.c_[X.ravel(), Y.ravel()]
    kw = dict(method="default", invalid="missing", progress=None,
              overrides={"boundary_condition": "normal-parallel"}, grid_first=grid_first)
    series = FieldSeries(**kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for t in (0.0, 0.5):
            vec = _window(pts, t)
            got = series(pts, vec, None)
            want = decompose_field(pts, vec, None, **kw)
            kept = series.decomposer
            for name in FIELDS:
                a, b = getattr(got, name), getattr(want, name)
                assert np.nanmax(np.abs(a - b)) <= 1e-6 * np.nanmax(np.abs(b)), name
            assert got.stats.get("grid", None) == want.stats.get("grid", None)
        assert series.decomposer is kept              # the second file reused the first's set-up


@pytest.mark.slow
def test_timeseries_benchmark_runs(tmp_path):
    """benchmarks/timeseries.py end to end on a small grid: one row per
    condition, the Decomposer's answers those of the one-off calls."""
    import csv
    import os
    import subprocess
    import sys
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    subprocess.run([sys.executable, os.path.join(root, "benchmarks", "timeseries.py"),
                    "--layouts", "grid4k", "--snapshots", "3", "--one-off", "1", "--batch", "2",
                    "--conditions", "auto,neumann", "--out-dir", str(tmp_path)],
                   check=True, capture_output=True, timeout=900)
    rows = list(csv.DictReader(open(tmp_path / "timeseries.csv")))
    assert [r["condition"] for r in rows] == ["auto", "neumann"]
    for r in rows:
        assert float(r["max_rel_diff"]) <= 1e-6 and float(r["per_snapshot_s"]) > 0


@pytest.mark.parametrize("reuse_fits", [True, False])
def test_natural_snapshots_split_together_as_one_by_one(reuse_fits):
    """NaturalSetup.split_many (a batch's snapshots through each stage as
    columns: one gather of the fits, one FFT pass, one spline prefilter)
    gives each snapshot what its own split gives, to rounding; on a disk
    (cut cells, their near-field correction, the one-sided fits)."""
    import math

    from taichi_hh.hhd import natural
    from taichi_hh.hhd.rotation import J
    disk = thh.Polygon.circle((0.5, 0.5), 0.5, n=200)
    pts = disk.sample_interior(2000, kind="random", seed=5)
    sp = math.sqrt(disk.area / len(pts))
    setup = natural.NaturalSetup(pts, disk, sp, reuse_fits=reuse_fits)
    assert (setup.fits is not None) == reuse_fits
    V = [_window(pts, t) for t in (0.0, 0.3, 0.6, 1.0)] + \
        [np.c_[np.sin(3 * pts[:, 0]), pts[:, 0] * pts[:, 1]]]
    together = setup.split_many(V)
    assert len(together) == len(V)
    kept = [{name: getattr(a, name).copy() for name in ("phi", "d", "harmonic", "curl")}
            for a in together]
    # another batch as wide writes the setup's kept work arrays again (with
    # reuse_fits): the first batch's results are not among them
    setup.split_many([2.0 * v[::-1] for v in V])
    for a, before in zip(together, kept):
        for name, x in before.items():
            assert np.array_equal(getattr(a, name), x), name
    for v, a in zip(V, together):
        b = setup.split(v)
        for name in ("phi", "psi", "d", "grad_psi", "divergence", "curl"):
            x, y = getattr(a, name), getattr(b, name)
            assert np.abs(x - y).max() <= 1e-12 * np.abs(y).max(), name
        assert a.mean_fit_points == b.mean_fit_points
        # h = v - d - r (r = J grad psi), and its check made with the batch
        h = v - a.d - J(a.grad_psi)
        assert np.abs(a.harmonic - h).max() <= 1e-12 * np.abs(h).max()
        assert np.abs(b.harmonic - h).max() <= 1e-12 * np.abs(h).max()
        assert np.allclose(a.harmonic_ratios(), b.harmonic_ratios(), rtol=1e-12, atol=0)


def test_natural_series_results_outlive_later_batches():
    """A natural series in batches of two: every snapshot's result, kept
    while the later batches run (their work arrays the same memory), equals
    its own decompose() call."""
    pts = _points()
    V = np.stack([_window(pts, t) for t in (0.0, 0.2, 0.4, 0.7, 1.0)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        series = list(thh.Decomposer(pts, boundary_condition="natural", batch=2).stream(V))
        refs = [thh.decompose(pts, v, boundary_condition="natural") for v in V]
    for t, (got, ref) in enumerate(zip(series, refs)):
        for name in ("curl_free", "div_free", "harmonic", "phi", "psi", "divergence", "curl"):
            # in the caller's units and in the unit frame the result keeps
            for a, b in ((getattr(got, name), getattr(ref, name)),
                         (getattr(got.unit, name), getattr(ref.unit, name))):
                assert np.abs(a - b).max() <= 1e-9 * np.abs(b).max(), (t, name)


def test_one_sided_fits_kept_as_weights_equal_the_fits():
    """grid_sampling.one_sided_weights (the near-boundary fits of a series'
    set-up, one gather per batch) against one_sided_gradient (a fit per
    point and call), on a disk's cut grid with points outside it too: no fit
    (NaN there) at the same points; both give a quadratic's exact gradient
    (the fit reproduces quadratics) to 1e-8 of its scale, a constant of 25
    in the field included (both fit the values less a node's); other fields
    the same to 1e-8."""
    import math

    from taichi_hh.hhd import grid_sampling, natural
    disk = thh.Polygon.circle((0.5, 0.5), 0.5, n=200)
    pts = disk.sample_interior(1500, kind="random", seed=7)
    setup = natural.NaturalSetup(pts, disk, math.sqrt(disk.area / len(pts)))
    grid, inside = setup.cells.grid, setup.cells.inside
    probes = np.vstack([setup.binned.points[setup.near], [[-0.3, 0.5], [1.4, 1.4]]])
    weights, ok = grid_sampling.one_sided_weights(grid, inside, probes)
    c = grid.centres().reshape(grid.nx, grid.ny, 2)
    X, Y = c[..., 0], c[..., 1]
    P = probes
    quadratic = np.stack([3 + 2 * X - Y + 0.7 * X * X - 0.4 * X * Y + 1.1 * Y * Y, 25 + X * Y])
    exact = np.stack([np.c_[2 + 1.4 * P[:, 0] - 0.4 * P[:, 1], -1 - 0.4 * P[:, 0] + 2.2 * P[:, 1]],
                      np.c_[P[:, 1], P[:, 0]]], axis=1)
    smooth = np.stack([np.sin(7 * X) * np.cos(5 * Y), np.exp(-3 * X * X) + Y ** 3])
    for u in (quadratic, smooth):
        want = grid_sampling.one_sided_gradient(grid, np.moveaxis(u, 0, -1), inside, probes)
        assert np.array_equal(ok, np.isfinite(want).all(axis=(1, 2)))
        got = weights.gradients(u.reshape(2, -1).T)
        scale = np.abs(want[ok]).max()
        assert np.abs(got[ok] - want[ok]).max() <= 1e-8 * scale
        if u is quadratic:
            for g in (got, want):
                assert np.abs(g[ok] - exact[ok]).max() <= 1e-8 * np.abs(exact).max()
    assert ok.sum() > 0.9 * len(setup.near) and not ok[-2:].any()


def test_a_decomposer_pickles_with_its_setup():
    """A Decomposer that has split natural snapshots (its setup, kept fits and
    work arrays made) pickles, e.g. to go to another process, and the copy
    decomposes as the original does."""
    import pickle
    pts = _points()
    V = np.stack([_window(pts, t) for t in (0.0, 0.5)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dec = thh.Decomposer(pts, boundary_condition="natural")
        first = dec.decompose(V)
        copy = pickle.loads(pickle.dumps(dec))
        again = copy.decompose(V)
    for name in ("curl_free", "div_free", "harmonic"):
        assert np.array_equal(getattr(first, name), getattr(again, name)), name


def test_a_batchs_fields_are_checked_as_one_off_calls_check_them():
    """inputs.fields_on (a batch's fields checked in passes over their
    stack) against prepare_data (a one-off call's check) field by field:
    the same unit vectors, speed, vectors (NaN on the points' missing rows)
    and zero-row flag; None for a field missing a row the points hold (NaN
    or masked); the Data of a batch outlive its stack being reused."""
    from taichi_hh.hhd.inputs import fields_on, prepare_data
    rng = np.random.default_rng(8)
    pts = rng.random((600, 2))
    pts[[3, 40]] = np.nan                                 # missing in every snapshot
    base = prepare_data(pts, np.ones((600, 2)), None)
    fields = [rng.standard_normal((600, 2)) * s for s in (1.0, 1e-30, 7e20)]
    fields[1][[3, 40]] = np.nan                           # NaN where the points are missing
    zero = rng.standard_normal((600, 2))
    zero[100:120] = 0.0                                   # an instrument's invalid marks
    fields.append(zero)
    nan_row = rng.standard_normal((600, 2))
    nan_row[7, 1] = np.nan                                # a row the points hold
    masked = np.ma.masked_array(rng.standard_normal((600, 2)), mask=False)
    masked.mask[9] = True
    with pytest.warns(thh.AccuracyWarning, match="exactly zero"):
        got, units = fields_on(base, fields + [nan_row, masked])
    assert got[-2] is None and got[-1] is None
    assert units.shape == (4, 598, 2)
    assert all(np.shares_memory(units[j], got[j].unit_vectors)
               and np.array_equal(units[j], got[j].unit_vectors) for j in range(4))
    for vec, data in zip(fields, got):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = prepare_data(pts, vec, None)
        assert data.frame == ref.frame
        assert np.array_equal(data.unit_vectors, ref.unit_vectors)
        assert np.array_equal(data.vectors, ref.vectors, equal_nan=True)
        assert np.array_equal(data.valid, ref.valid)
        assert len(data.flags) == len(ref.flags)
    assert len(got[3].flags) == 1 and not got[0].flags
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again, _ = fields_on(base, [f * 2 for f in fields])
    assert not np.shares_memory(again[0].vectors, got[0].vectors)
