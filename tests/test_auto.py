"""The default boundary condition, ``auto`` (:mod:`taichi_hh.hhd.auto`): a
window of a larger flow gets the natural HHD, a closed container the
``no-flux`` condition, each with the split its kind of data expects."""
import sys
import pathlib
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.hhd.auto import (CANCELLING_RATIO, CLOSED_FLUX, ORTHOGONAL_CONDITION, boundary_flow,
                                 boundary_flux, energy_closer, natural_cancels)
from taichi_hh.geometry.box import Box
from taichi_hh.validation.windows import window_field

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "benchmarks"))
from windows import closed_container  # noqa: E402

BOX = Box((0.0, 0.0), (2.0, 1.0))


def _errors(res, ex):
    scale = np.linalg.norm(ex.v, axis=1).mean()
    return [float(np.linalg.norm(a - b, axis=1).mean() / scale)
            for a, b in ((res.curl_free, ex.d), (res.div_free, ex.r), (res.harmonic, ex.h))]


@pytest.fixture(scope="module")
def random_points():
    return np.random.default_rng(3).random((6000, 2)) * [2.0, 1.0]


def test_boundary_flux_measures_the_normal_component():
    rng = np.random.default_rng(0)
    pts = rng.random((4000, 2))
    spacing = np.sqrt(1 / 4000)
    unit = Box((0.0, 0.0), (1.0, 1.0))
    stream = np.tile([1.0, 0.0], (len(pts), 1))
    # a uniform stream crosses two of the four walls: v.n = +-1 on half the band
    assert 0.6 < boundary_flux(pts, stream, unit, spacing) < 0.8
    x, y = pts[:, 0], pts[:, 1]
    tangent = np.c_[np.sin(np.pi * x) * np.cos(np.pi * y), -np.cos(np.pi * x) * np.sin(np.pi * y)]
    assert boundary_flux(pts, tangent, unit, spacing) < CLOSED_FLUX / 3
    assert boundary_flux(pts, 0 * stream, unit, spacing) == 0.0
    # no data next to the boundary: unknown
    inner = 0.4 + 0.2 * pts
    assert np.isnan(boundary_flux(inner, stream, unit, spacing))
    # the tangential part: the stream runs along the other two walls; the
    # cavity's flow along all four
    flux, along = boundary_flow(pts, stream, unit, spacing)
    assert flux == boundary_flux(pts, stream, unit, spacing) and 0.6 < along < 0.8
    assert boundary_flow(pts, tangent, unit, spacing)[1] > 0.9
    assert boundary_flow(pts, 0 * stream, unit, spacing) == (0.0, 0.0)


def _calm_edged(pts):
    """Compactly supported bumps of psi and of phi inside the 2 x 1 box, the
    field zero within 0.1 of its walls: every condition's exact split is
    (grad phi, J grad psi, 0)."""
    from taichi_hh.validation.fields import Components
    d, r = np.zeros_like(pts), np.zeros_like(pts)
    for (cx, cy, width, amp, which) in ((0.5, 0.5, 0.35, 1.0, r), (1.4, 0.45, 0.3, -1.0, r),
                                        (1.0, 0.55, 0.35, 0.7, d), (1.55, 0.5, 0.3, 1.0, d)):
        off = pts - (cx, cy)
        one = np.clip(1.0 - (off ** 2).sum(axis=1) / width ** 2, 0.0, None)
        grad = (-8.0 * amp / width ** 2 * one ** 3)[:, None] * off
        which += grad if which is d else np.c_[grad[:, 1], -grad[:, 0]]
    return Components(v=d + r, d=d, r=r, h=np.zeros_like(r), phi=None, psi=None)


def test_calm_edges_are_no_wall(random_points):
    """No flow next to the boundary (isolated vortices and sources, calm air at
    the edges): v.n is zero there, as in a closed container, but so is the flow
    along the walls: no wall in the data, the natural split (the field's split
    continued by zero beyond the walls).  Measured at 6k random points: natural
    0.39 / 0.51%, no-flux 1.6 / 1.7% (d / r) on the same exact answer."""
    ex = _calm_edged(random_points)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", thh.AccuracyWarning)    # the calm air's zero vectors
        res = thh.decompose(random_points, ex.v, BOX)
        closed = _errors(thh.decompose(random_points, ex.v, BOX, boundary_condition="no-flux"),
                         ex)
    assert res.stats["boundary_condition"] == "natural"
    assert res.stats["boundary_flux"] == 0.0 == res.stats["boundary_along"]
    err = _errors(res, ex)
    assert max(err) < 1e-2, err
    assert max(err[:2]) < 0.5 * min(closed[:2]), (err, closed)


@pytest.mark.parametrize("sources", [False, True])
def test_a_closed_container_gets_the_no_flux_split(random_points, sources):
    """v.n = 0 on the walls: a circulation (and a source-sink pair with d.n = 0):
    everything in d and r, h = 0, to 0.2% at 6k random points (measured
    0.07-0.09%); normal-parallel puts the sources' d into h (50%) and neumann
    the circulation's r (60%)."""
    ex = closed_container(np, random_points, sources)
    res = thh.decompose(random_points, ex.v, BOX)
    assert res.stats["boundary_condition"] == "no-flux" == res.options.boundary_condition
    assert res.stats["boundary_flux"] < CLOSED_FLUX <= res.stats["boundary_along"]
    assert max(_errors(res, ex)) < 2e-3, _errors(res, ex)
    assert not res.stats["flags"]
    assert res.stats["iterations_phi"] > 0 and res.stats["iterations_psi"] > 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        other = "normal-parallel" if sources else "neumann"
        worse = thh.decompose(random_points, ex.v, BOX, boundary_condition=other)
    assert max(_errors(worse, ex)) > 0.3


def test_no_flux_on_a_divergence_free_closed_flow_is_normal_parallel(random_points):
    """Without sources the two conditions differ only in phi's, whose right-hand
    side is then the discrete divergence of a divergence-free field
    (truncation error): r agrees to 1e-6 of max abs(v), d is below 1e-5
    (measured 2e-6)."""
    ex = closed_container(np, random_points, False)
    a = thh.decompose(random_points, ex.v, BOX, boundary_condition="no-flux")
    b = thh.decompose(random_points, ex.v, BOX, boundary_condition="normal-parallel")
    vmax = np.abs(ex.v).max()
    assert np.abs(a.div_free - b.div_free).max() < 1e-6 * vmax
    assert np.abs(a.curl_free).max() < 1e-5 * vmax
    assert np.abs(b.curl_free).max() < 1e-5 * vmax


def test_a_window_gets_the_natural_split(random_points):
    W = window_field()
    ex = W.evaluate(random_points)
    res = thh.decompose(random_points, ex.v, W.domain)
    assert res.stats["boundary_condition"] == "natural"
    assert res.stats["boundary_flux"] > 0.3
    err = _errors(res, ex)
    assert max(err) < 3e-3, err                      # measured 0.03-0.06% at 6k
    neumann = thh.decompose(random_points, ex.v, W.domain, boundary_condition="neumann")
    assert min(_errors(neumann, ex)) > 10 * max(err)


def test_the_papers_bundles_and_the_projection_keep_neumann(random_points):
    ex = closed_container(np, random_points, True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = thh.decompose(random_points[:1500], ex.v[:1500], BOX, method="petronetto2010")
    assert res.stats["boundary_condition"] == "neumann" and "boundary_flux" not in res.stats
    assert thh.project(random_points[:1500], ex.v[:1500], BOX).stats is not None
    with pytest.raises(thh.InputError, match="decomposition option"):
        thh.project(random_points[:1500], ex.v[:1500], BOX, boundary_condition="auto")


def test_no_flux_has_no_single_matrix(random_points):
    from taichi_hh.hhd.decompose import poisson_problems
    ex = closed_container(np, random_points, True)
    with pytest.raises(thh.InputError, match="two matrices"):
        poisson_problems(random_points, ex.v, BOX, boundary_condition="no-flux")
    with pytest.raises(thh.InputError, match="two matrices"):
        poisson_problems(random_points, ex.v, BOX)          # auto chose no-flux
    assert poisson_problems(random_points, ex.v, BOX,
                            boundary_condition="neumann").A is not None


def test_the_grid_path_chooses_too():
    """decompose_grid: the window's grid gets natural, a closed cavity sampled on
    a cell-centred grid (as CFD output and PIV windows are: the outline of the
    nodes' cells is the box, where v.n = 0) no-flux."""
    x, y = (np.arange(80) + 0.5) / 40, (np.arange(40) + 0.5) / 40
    X, Y = np.meshgrid(x, y)
    nodes = np.c_[X.ravel(), Y.ravel()]
    ex = closed_container(np, nodes, True)
    g = thh.decompose_grid(x, y, ex.v[:, 0].reshape(X.shape), ex.v[:, 1].reshape(X.shape))
    assert g.scattered.stats["boundary_condition"] == "no-flux"
    err = _errors(g.scattered, closed_container(np, g.scattered.points, True))
    assert max(err) < 5e-3, err
    ex = window_field().evaluate(nodes)
    g = thh.decompose_grid(x, y, ex.v[:, 0].reshape(X.shape), ex.v[:, 1].reshape(X.shape))
    assert g.scattered.stats["boundary_condition"] == "natural"


# ---- a window split whose parts cancel gives way to the orthogonal one


def _straddling_dipole(pts):
    """A vortex just inside the unit box's left wall, its opposite just
    outside (a wall's image pair), and a stream up through the top and the
    bottom: the natural split's r (the inside vortex alone, in free space) and
    h (the image and the stream) carry 2.2 times the field's energy."""
    from taichi_hh.validation.windows import Core
    inside = Core((0.05, 0.5), 1.0, 0.04, "vortex")
    outside = Core((-0.05, 0.5), -1.0, 0.04, "vortex")
    return inside.velocity(pts) + outside.velocity(pts) + np.array([0.0, 0.2])


def test_cancelling_natural_parts_give_way_to_the_orthogonal_split():
    pts = np.random.default_rng(5).random((5000, 2))
    vec = _straddling_dipole(pts)
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # the discarded attempt warns nothing
        res = thh.decompose(pts, vec, (0, 0, 1, 1))
    s = res.stats
    assert s["boundary_flux"] >= CLOSED_FLUX
    assert s["boundary_condition"] == ORTHOGONAL_CONDITION
    assert s["natural_energy_ratio"] > CANCELLING_RATIO
    assert abs(s["energy_ratio"] - 1.0) < 0.05      # orthogonal parts: no cancelling
    ref = thh.decompose(pts, vec, (0, 0, 1, 1), boundary_condition=ORTHOGONAL_CONDITION)
    for a, b in ((res.curl_free, ref.curl_free), (res.div_free, ref.div_free),
                 (res.harmonic, ref.harmonic)):
        assert np.array_equal(a, b)
    natural = thh.decompose(pts, vec, (0, 0, 1, 1), boundary_condition="natural")
    assert natural.stats["energy_ratio"] == s["natural_energy_ratio"]
    assert set(s["seconds"]["auto_attempts"]) == {"natural", "orthogonal"}


def test_a_window_whose_parts_do_not_cancel_keeps_the_natural_split(random_points):
    ex = window_field().evaluate(random_points)
    res = thh.decompose(random_points, ex.v, BOX)
    assert res.stats["boundary_condition"] == "natural"
    assert not natural_cancels(res.stats["energy_ratio"])
    assert "natural_energy_ratio" not in res.stats
    assert "auto_attempts" not in res.stats["seconds"]


def test_the_split_whose_energy_is_closer_to_the_fields_wins():
    assert energy_closer(1.1, 2.0) and not energy_closer(2.0, 1.1)
    assert energy_closer(0.8, 1.5)           # by the factor: 1.25 against 1.5
    assert not energy_closer(0.4, 2.0)       # 2.5 against 2
    assert energy_closer(3.0, float("nan")) and not energy_closer(float("inf"), 3.0)
    assert not energy_closer(0.0, 3.0)
    assert natural_cancels(CANCELLING_RATIO * 1.01) and not natural_cancels(CANCELLING_RATIO)
    assert natural_cancels(float("nan"))


def test_the_grid_path_gives_way_to_the_orthogonal_split_too():
    x = np.linspace(0.0, 1.0, 61)
    X, Y = np.meshgrid(x, x)
    vec = _straddling_dipole(np.c_[X.ravel(), Y.ravel()])
    u, v = vec[:, 0].reshape(X.shape), vec[:, 1].reshape(X.shape)
    g = thh.decompose_grid(x, x, u, v)
    s = g.stats
    assert s["boundary_condition"] == ORTHOGONAL_CONDITION
    assert s["natural_energy_ratio"] > CANCELLING_RATIO
    assert abs(s["energy_ratio"] - 1.0) < 0.05
    natural = thh.decompose_grid(x, x, u, v, boundary_condition="natural")
    assert natural.stats["energy_ratio"] == s["natural_energy_ratio"]
    ref = thh.decompose_grid(x, x, u, v, boundary_condition=ORTHOGONAL_CONDITION)
    assert np.array_equal(g.div_free, ref.div_free, equal_nan=True)
