"""thh.project: the null-divergence projection against Colin et al. 2006 Table 1.

Default (neumann scheme): one pass leaves the measured (quadratic MLS)
divergence at the solver tolerance, so it beats Colin's fifth iteration on every
example; example 5 (a rigid rotation, exactly divergence-free) is untouched;
repeated passes are bounded.  colin2006: Colin's own formulation decreases the
divergence pass after pass, with values of the published order.
"""
import math

import numpy as np
import pytest

from taichi_hh.errors import SolverError

import taichi_hh as thh
from taichi_hh.validation import fields
from taichi_hh.validation.colin_examples import TABLE1, colin_divergence, example
from taichi_hh.errors import InputError
from taichi_hh.sph.pointset import PointSet
from taichi_hh.hhd.project import IRREGULARITY_THRESHOLD, SCATTERED_OPTIONS, \
    layout_irregularity, project  # also thh.project

UNIT = thh.Box((0.0, 0.0), (1.0, 1.0))


def colin_ratio(k):
    pts, _, h = example(k)
    return h * math.sqrt(len(pts))


@pytest.fixture(scope="module")
def default_runs():
    return {k: project(*example(k)[:2], UNIT, iterations=2) for k in TABLE1}


@pytest.mark.parametrize("k", sorted(TABLE1))
def test_default_one_pass_beats_colin_fifth_iteration(default_runs, k):
    res = default_runs[k]
    fifth = TABLE1[k]["max"][5]
    if k == 5:
        assert res.max_divergence[0] < 1e-12       # the quadratic divergence is exact on it
    else:
        assert res.max_divergence[0] > 1.0          # a real divergence to remove
        assert res.max_divergence[1] <= 1e-6 * res.max_divergence[0]
    assert res.max_divergence[1] <= 1e-3 * fifth
    # the measure is the documented operator: the quadratic divergence over the points
    pts = res.points
    ps = PointSet(pts, support=2.5 / math.sqrt(len(pts)), area=1.0)
    np.testing.assert_allclose(ps.divergence(res.vectors, "quadratic"), res.divergence,
                               atol=1e-9)
    assert "quadratic divergence over the data points" in res.stats["divergence_operator"]


def test_rigid_rotation_left_unchanged(default_runs):
    res = default_runs[5]
    v = res.initial
    speed = np.linalg.norm(v, axis=1).max()
    assert np.linalg.norm(res.vectors - v, axis=1).max() <= 1e-9 * speed     # target: 1%
    assert res.stats["iterations"] == [0, 0]


def test_default_passes_after_the_first_change_nothing(default_runs):
    for k in (1, 3):
        res = default_runs[k]
        assert res.stats["iterations"][0] > 0 and res.stats["iterations"][1] == 0
        assert res.max_divergence[2] <= res.max_divergence[1] * (1 + 1e-9)


@pytest.fixture(scope="module")
def blue_noise():
    f = fields.get("gaussian")
    pts = f.sample(2000, "poisson", seed=1)
    return f, pts, f.evaluate(pts)


def test_repeated_passes_stay_bounded_on_blue_noise(blue_noise):
    f, pts, c = blue_noise
    res = project(pts, c.v, f.domain, iterations=5, history=True)
    m = res.max_divergence
    assert m[1] <= 1e-6 * m[0]
    assert np.all(m[2:] <= m[1] * (1 + 1e-9))
    moved = [np.abs(h - res.history[1]).max() for h in res.history[2:]]
    assert max(moved) <= 1e-9 * np.abs(c.v).max()
    # and it is the divergence-free part r + h of the decomposition (measured 1.8%)
    err = np.linalg.norm(res.vectors - c.r - c.h, axis=1).mean()
    assert err <= 0.05 * np.linalg.norm(c.v, axis=1).mean()


def test_poisson_step_alone_is_what_diverged(blue_noise):
    """The former default (the Poisson step repeated alone) grows again after
    three passes on this input (max |div| 13.7, 2.8, 0.77, 0.26, 1.6, 43); the
    growth past the input's level is reported, not returned; the neumann scheme
    runs the same step once."""
    f, pts, c = blue_noise
    res = project(pts, c.v, f.domain, iterations=4, scheme="poisson")
    m = res.max_divergence
    assert m[1] < 0.5 * m[0]
    assert m[4] > m[3]
    with pytest.raises(SolverError, match="projection diverged at pass 5") as exc:
        project(pts, c.v, f.domain, iterations=5, scheme="poisson")
    assert exc.value.reason == "divergence"


def test_orthogonal_scheme_is_an_orthogonal_projection(blue_noise):
    f, pts, c = blue_noise
    res = project(pts, c.v, f.domain, iterations=2, scheme="orthogonal")
    ps = PointSet(pts, support=2.5 * math.sqrt(f.domain.area / len(pts)), area=f.domain.area)
    vol = ps.volume()
    energy = lambda v: float((vol * (v ** 2).sum(axis=1)).sum())     # noqa: E731
    assert res.max_divergence[1] <= 1e-6 * res.max_divergence[0]
    assert energy(res.vectors) < energy(c.v)
    # the removed part is V-orthogonal to the result (both lie in complementary spaces)
    removed = c.v - res.vectors
    inner = float((vol * (removed * res.vectors).sum(axis=1)).sum())
    assert abs(inner) <= 1e-6 * energy(c.v)


def test_colin_initial_divergence_matches_table1_example1():
    pts, v, h = example(1)
    d = colin_divergence(pts, v, h)
    assert abs(np.abs(d).max() - 5.32) <= 0.05 * 5.32          # measured 5.12
    assert abs((d ** 2).sum() - 1250.48) <= 0.05 * 1250.48     # measured 1276


@pytest.mark.parametrize("k", [2, 4])
def test_colin2006_divergence_decreases_over_passes(k):
    pts, v, h = example(k)
    res = project(pts, v, UNIT, iterations=5, method="colin2006", support_ratio=colin_ratio(k))
    m, q = res.max_divergence, res.sum_sq_divergence
    assert np.all(np.diff(m) < 0) and np.all(np.diff(q) < 0)
    # the measure is Colin's Eq. 33
    np.testing.assert_allclose(colin_divergence(pts, res.vectors, h), res.divergence, atol=1e-9)
    # values of the published order (measured within a factor 2.2 of Table 1)
    for ours, published in zip(m, TABLE1[k]["max"]):
        assert published / 3 <= ours <= 3 * published
    # and one default pass does better on the same input (each by its own measure)
    ours = project(pts, v, UNIT)
    assert ours.max_divergence[1] < 1e-3 * m[5]


def test_project_refuses_bad_input():
    pts, v, _ = example(2)
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(InputError, match="iterations"):
            project(pts, v, UNIT, iterations=bad)
    with pytest.raises(InputError, match="scheme"):
        project(pts, v, UNIT, scheme="exact")
    with pytest.raises(InputError, match="boundary"):
        project(pts, v, UNIT, scheme="orthogonal", boundary="colin")
    with pytest.raises(InputError, match="boundary"):
        project(pts, v, UNIT, method="petronetto2010")
    nan = v.copy()
    nan[7, 1] = np.nan
    with pytest.raises(InputError, match="first row 7; a projection needs a velocity on every"):
        project(pts, nan, UNIT)
    with pytest.raises(InputError, match="shape"):
        project(pts, v[:-1], UNIT)
    with pytest.raises(InputError, match="outside"):
        project(pts + 0.5, v, UNIT)
    with pytest.raises(ValueError, match="method"):
        project(pts, v, UNIT, method="stam1999")


def test_project_is_exported():
    assert thh.project is project


def _gaussian_on(layout, n, seed=1):
    from taichi_hh.validation import layouts
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, n, layout, seed=seed)
    return F, pts, F.evaluate(pts)


@pytest.mark.parametrize("layout", ["random", "clusters"])
def test_default_projects_scattered_points(layout):
    """Issue 29: with its defaults project() raised SolverError (max_iterations
    at 4235) on 4000 uniformly random points and NeighbourError on clustered
    ones; it now measures the layout, takes the adaptive support there, removes
    the divergence and keeps the divergence-free part r + h about as well as
    decompose() does on the same points (measured: random 2.6% against
    decompose's 2.9%, clusters 3.2% against 3.2%)."""
    F, pts, ex = _gaussian_on(layout, 4000)
    scale = np.linalg.norm(ex.v, axis=1).mean()
    res = project(pts, ex.v, F.domain)
    st = res.stats
    assert st["support_choice"] == "adaptive" and st["support_chosen_by"] == "layout"
    assert st["irregularity"] > 0.4                     # measured 0.51 and 0.76
    assert "cubic divergence" in st["divergence_operator"]
    assert "adaptive support 3.5 local spacings" in st["divergence_operator"]
    assert res.max_divergence[0] > 1.0
    assert res.max_divergence[1] <= 1e-6 * res.max_divergence[0]    # measured 3e-8, 6e-8
    err = np.linalg.norm(res.vectors - (ex.r + ex.h), axis=1).mean() / scale
    # against the decomposition under the projection's own condition (Neumann)
    dec = thh.decompose(pts, ex.v, F.domain, boundary_condition="neumann")
    err_dec = np.linalg.norm(ex.v - dec.curl_free - (ex.r + ex.h), axis=1).mean() / scale
    assert err <= 1.25 * err_dec, (err, err_dec)
    # the caller's own choice still wins, and a failing fixed support says what to use
    from taichi_hh.errors import NeighbourError
    if layout == "clusters":
        with pytest.raises(NeighbourError, match="adaptive_support=True"):
            project(pts, ex.v, F.domain, adaptive_support=False)


def test_default_keeps_the_fixed_support_on_lattices_and_blue_noise(default_runs, blue_noise):
    """What the default did on Colin's lattices and on blue noise is unchanged:
    the fixed support of PROJECT_OVERRIDES, bit for bit the same result as
    asking for it."""
    for k in (1, 3):
        res = default_runs[k]
        assert res.stats["support_choice"] == "fixed"
        assert res.stats["support_chosen_by"] == "layout"
        assert res.stats["irregularity"] < 1e-6
    pts, v, _ = example(3)
    fixed = project(pts, v, UNIT, iterations=2, adaptive_support=False)
    np.testing.assert_array_equal(fixed.vectors, default_runs[3].vectors)
    assert fixed.stats["support_chosen_by"] == "caller"
    f, pts, c = blue_noise
    res = project(pts, c.v, f.domain)
    assert res.stats["support_choice"] == "fixed"
    assert res.stats["irregularity"] < 0.1                 # measured 0.07
    np.testing.assert_array_equal(
        res.vectors, project(pts, c.v, f.domain, adaptive_support=False).vectors)
    # an explicit adaptive support on blue noise is taken as asked
    res = project(pts, c.v, f.domain, **SCATTERED_OPTIONS)
    assert res.stats["support_choice"] == "adaptive" and res.stats["irregularity"] is None


def test_layout_irregularity_separates_the_layouts():
    """The measure behind the choice: the spread of nearest-neighbour distances
    (measured: lattice 0, blue noise 0.07, jitter0.3 0.083, jitter0.5 0.15,
    random 0.51-0.54, clusters 0.76; the same within 0.01 from 1k to 16k)."""
    from taichi_hh.validation import layouts
    F = fields.get("gaussian")

    def irregularity(kind, n=2000):
        return layout_irregularity(layouts.sample(F.domain, n, kind, seed=3))

    assert irregularity("lattice") < 1e-6
    assert irregularity("poisson") < 0.1
    assert irregularity("jitter0.3") < IRREGULARITY_THRESHOLD < irregularity("jitter0.5")
    assert 0.47 < irregularity("random") < 0.58           # Rayleigh: sqrt(4/pi - 1) = 0.52
    assert irregularity("clusters") > 0.6
    # scale-free
    pts = layouts.sample(F.domain, 2000, "random", seed=3)
    assert layout_irregularity(2.0 + 1e-3 * pts) == pytest.approx(layout_irregularity(pts),
                                                                  rel=1e-6)


def test_fixed_support_failing_at_set_up_falls_back_to_the_adaptive_one():
    """A lattice with one point left alone in a hole 3 spacings wide looks
    regular (irregularity 0.07) but that point has no neighbour within the fixed
    support: the default then takes the adaptive support instead of failing."""
    from taichi_hh.errors import NeighbourError
    m = 30
    g = (np.arange(m) + 0.5) / m
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    centre = np.array([g[15], g[15]])
    far = np.abs(pts - centre).max(axis=1)
    pts = pts[(far > 2.5 / m) | (far < 0.5 / m)]
    F = fields.get("gaussian")
    v = F.evaluate(pts).v
    assert layout_irregularity(pts) < IRREGULARITY_THRESHOLD
    with pytest.raises(NeighbourError, match="no neighbour"):
        project(pts, v, UNIT, adaptive_support=False)
    res = project(pts, v, UNIT)
    assert res.stats["support_choice"] == "adaptive"
    assert res.stats["support_chosen_by"] == "fallback"
    assert "no neighbour" in res.stats["fixed_support_error"]
    assert res.max_divergence[1] <= 1e-6 * res.max_divergence[0]
