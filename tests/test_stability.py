"""Representative failures, provoked through the public API, are reported (an
error naming the cause, or a flagged result) and never returned as garbage.
benchmarks/stability_map.py maps the same edges over many more cells."""
import math

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.validation import fields
from taichi_hh.flow.twophase import BlowUpError, FlowParams, TwoPhaseFlow
from taichi_hh.errors import BlowUp, TaichiHHError
from taichi_hh.hhd.decompose import options_for

SOLVER_REASONS = {"breakdown", "stagnation", "divergence", "max_iterations", "non-finite"}


@pytest.fixture(scope="module")
def trig():
    F = fields.get("trig")
    pts = F.sample(900, "poisson", seed=3)
    return F, pts, F.evaluate(pts)


def _finite(res):
    return all(np.isfinite(a).all() for a in (res.curl_free, res.div_free, res.harmonic,
                                              res.phi, res.psi))


@pytest.mark.parametrize("ratio", [0.8, 1.0])
def test_too_few_neighbours_isolated_points(trig, ratio):
    F, pts, ex = trig
    with pytest.raises(thh.NeighbourError, match=r"no neighbour within the kernel support.*"
                                                 r"Increase support_ratio"):
        thh.decompose(pts, ex.v, F.domain, support_ratio=ratio)


def test_too_few_neighbours_singular_correction(trig):
    """Every point has a neighbour but some correction matrix is singular."""
    F, pts, ex = trig
    with pytest.raises(thh.NeighbourError, match=r"singular.*neighbours.*support_ratio"):
        # the corrected Laplacian's matrices (the Neumann system's rows)
        thh.decompose(pts, ex.v, F.domain, support_ratio=1.5, boundary_condition="neumann")


def test_too_few_neighbours_projection(trig):
    F, pts, ex = trig
    with pytest.raises(thh.NeighbourError, match="support"):
        thh.project(pts, ex.v, F.domain, support_ratio=1.0)


@pytest.mark.parametrize("method,options", [
    ("petronetto2010", {"kappa": 0.0}),                       # published, ridge removed
    pytest.param("default", {"kappa": 0.0, "bordered": False,    # pure Neumann, singular
                             "boundary_condition": "neumann"},
                 marks=pytest.mark.slow),            # about 13 s
])
def test_kappa_zero_pure_neumann_without_bordering_is_reported(method, options):
    """Pure Neumann without the ridge term or the compatibility unknown: the
    matrix is singular and the discrete right-hand side is not exactly in its
    range.  Either the solver reports its failure, or the result is flagged by
    its residual and is finite."""
    F = fields.get("gaussian")
    pts = F.sample(1640, "poisson", seed=3)
    ex = F.evaluate(pts)
    opts = options_for(method, **options)
    try:
        res = thh.decompose(pts, ex.v, F.domain, method=method, **options)
    except thh.SolverError as exc:
        assert exc.reason in SOLVER_REASONS
        assert exc.reason in str(exc) and math.isfinite(exc.iteration)
        return
    assert _finite(res)
    assert res.stats["residual_phi"] <= opts.tol and res.stats["residual_psi"] <= opts.tol


def test_bordered_kappa_zero_is_fine(trig):
    """The default's answer to the pure-Neumann problem: kappa 0 converges."""
    F, pts, ex = trig
    res = thh.decompose(pts, ex.v, F.domain, kappa=0.0, boundary_condition="neumann")
    vmean = np.linalg.norm(ex.v, axis=1).mean()
    assert _finite(res)
    assert np.linalg.norm(res.curl_free - ex.d, axis=1).mean() / vmean < 0.03


def test_iteration_cap_is_reported_not_returned(trig):
    F, pts, ex = trig
    with pytest.raises(thh.SolverError) as info:
        thh.decompose(pts, ex.v, F.domain, max_iterations=3, preconditioner="jacobi",
                      boundary_condition="neumann")
    assert info.value.reason == "max_iterations"
    assert "iteration cap" in str(info.value)


@pytest.mark.parametrize("where", ["vectors", "points"])
def test_nan_input_is_refused(trig, where):
    F, pts, ex = trig
    pts, v = pts.copy(), ex.v.copy()
    (v if where == "vectors" else pts)[17, 1] = np.nan
    # a NaN row is missing data: left out, NaN in the result (tests/test_missing.py)
    res = thh.decompose(pts, v, F.domain)
    assert res.stats["n_invalid"] == 1 and np.isnan(res.curl_free[17]).all()
    assert np.isfinite(np.delete(res.curl_free, 17, axis=0)).all()
    with pytest.raises(thh.InputError, match="1 of .* rows are missing .* first row 17"):
        thh.decompose(pts, v, F.domain, invalid="error")
    with pytest.raises(thh.InputError, match="first row 17; a projection needs a velocity"):
        thh.project(pts, v, F.domain)


def test_nan_flow_particles_refused():
    from taichi_hh.validation.layouts import lattice_in_box
    pts, dx = lattice_in_box(200, (0.0, 0.0, 1.0, 2.0))
    pts[5, 0] = np.nan
    with pytest.raises(thh.InputError):
        TwoPhaseFlow(pts, np.zeros(len(pts), dtype=int), dx, FlowParams())


def _rt_flow(n, **params):
    """The Rayleigh-Taylor set-up of benchmarks/rt_growth.py (heavy over light,
    one mode of amplitude 1% of the wavelength)."""
    from taichi_hh.validation.layouts import lattice_in_box
    box = (0.0, 0.0, 1.0, 2.0)
    pts, dx = lattice_in_box(n, box)
    k, y0, a0 = 2 * math.pi, 1.0, 0.01
    phases = np.where(pts[:, 1] > y0, 1, 0)
    decay = a0 * np.exp(-k * np.abs(pts[:, 1] - y0))
    pts = pts + np.c_[np.sign(pts[:, 1] - y0) * decay * np.sin(k * pts[:, 0]),
                      decay * np.cos(k * pts[:, 0])]
    p = FlowParams(box=box, gravity=(0.0, -1.0), **params)
    return TwoPhaseFlow(pts, phases, dx, p)


def _run_until_blowup(flow, steps, dt=None):
    """Step; return the BlowUpError raised, or None.  Every step that returns
    must leave finite state inside the box with a bounded speed (no garbage)."""
    x0, y0, x1, y1 = flow.params.box
    for _ in range(steps):
        try:
            info = flow.step(dt)
        except BlowUpError as exc:
            return exc
        pos, vel, _, _ = flow.fluid_state()
        assert np.isfinite(pos).all() and np.isfinite(vel).all()
        assert ((pos > [x0, y0]) & (pos < [x1, y1])).all()
        assert info["max_speed"] < 10.0, info       # free fall over the box: speed 2
    return None


def test_flow_time_step_far_past_the_limit_is_reported():
    f = 64
    d = FlowParams()                    # every step limit 64x its default
    flow = _rt_flow(800, densities=(1.0, 2.0), cfl=d.cfl * f, viscous_cfl=d.viscous_cfl * f,
                    force_cfl=d.force_cfl * f, dt_max=d.dt_max * f)
    exc = _run_until_blowup(flow, 40)
    assert exc is not None, "a time step 64x past the stable limit ran on silently"
    assert isinstance(exc, BlowUp) and exc.cause in BlowUp.CAUSES
    assert isinstance(exc, TaichiHHError)                  # caught with the package's errors
    assert f"t={flow.time:.4g}" in str(exc)


def test_flow_explicit_huge_dt_is_reported():
    flow = _rt_flow(800, densities=(1.0, 2.0))
    exc = _run_until_blowup(flow, 20, dt=2.0)
    assert exc is not None and exc.cause in BlowUp.CAUSES


def test_flow_density_ratio_1000_reported_or_sane():
    """Large density ratios: either the run stays sane or it is stopped with a
    named cause."""
    flow = _rt_flow(800, densities=(1.0, 1000.0))
    exc = _run_until_blowup(flow, 25)
    if exc is not None:
        assert exc.cause in BlowUp.CAUSES and str(exc)


def test_stability_map_classification():
    from taichi_hh.validation.stability import classify
    ok = {"status": "ok", "task": "hhd", "finite": True, "err": 0.01, "max_abs_ratio": 1.2}
    assert classify(ok, 0.01)[0] == "ok"
    assert classify({**ok, "err": 0.3}, 0.01)[0] == "inaccurate"
    assert classify({**ok, "err": 0.05}, 0.01)[0] == "inaccurate"       # 5x its reference
    assert classify({**ok, "finite": False, "err": math.nan}, 0.01)[0] == "garbage"
    assert classify({**ok, "max_abs_ratio": 1e4}, 0.01)[0] == "garbage"
    err = {"status": "error", "error": "SolverError", "reason": "stagnation", "task": "hhd"}
    assert classify(err, 0.01) == ("error", "SolverError: stagnation")
    assert classify({**err, "error": "ZeroDivisionError"}, 0.01)[0] == "crash"
    rt = {"status": "ok", "task": "rt", "finite": True, "err": 0.05, "max_speed": 50.0}
    assert classify(rt, 0.05)[0] == "garbage"


# Silent garbage found by benchmarks/stability_map.py, now detected and reported:
# a diverging projection raises, an inconsistent decomposition is flagged.

@pytest.mark.slow
def test_colin2006_projection_never_returns_garbage():
    F = fields.get("trig")
    pts = F.domain.sample_interior(1600, kind="poisson", seed=3)
    v = F.evaluate(pts).v
    # measured: max|div| 31.7 -> 1.3e3 at pass 2 (then 4.2e6 by pass 5, |w| ~ 1e5 |v|)
    with pytest.raises(thh.SolverError, match="projection diverged at pass 2") as exc:
        thh.project(pts, v, F.domain, iterations=5, method="colin2006")
    assert exc.value.reason == "divergence"


def test_symmetric_gradient_on_random_points_never_returns_garbage():
    F = fields.get("trig")
    pts = F.domain.sample_interior(1600, kind="random", seed=3)
    v = F.evaluate(pts).v
    # the solve converges (residual 1e-9) to components ~1000 x |v| that cancel:
    # flagged by the energy check (measured ratio 4.8e4)
    with pytest.warns(thh.AccuracyWarning, match="times the field's energy"):
        # (at the fixed support of 2.5 spacings, where it was measured)
        res = thh.decompose(pts, v, F.domain, divergence="symmetric", gradient="symmetric",
                            neumann_gradient="symmetric", adaptive_support=False,
                            support_ratio=2.5, boundary_condition="neumann")
    assert res.stats["energy_ratio"] > 100 and res.stats["flags"]
    # the default method on blue noise is consistent and not flagged
    blue = F.domain.sample_interior(1600, kind="poisson", seed=3)
    good = thh.decompose(blue, F.evaluate(blue).v, F.domain, boundary_condition="neumann")
    assert good.stats["energy_ratio"] < 1.1 and not good.stats["flags"]
