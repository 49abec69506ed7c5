"""The default decomposition on the point sets users have (issue 13): blue
noise, a jittered lattice, uniformly random points, a 1:10 density gradient
and clusters, each within the issue's accuracy bound and iteration target at
13k points on a field with an exact decomposition; second-order convergence on
random points."""
import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.validation import fields, layouts

#: mean error bound of d and r (percent of mean |v|) at 13k points; h within 2x
BOUNDS = {"poisson": 0.5, "jitter0.6": 0.5, "random": 1.0, "clusters": 1.0, "gradient": 1.5}
#: BiCGSTAB iterations per potential at 13k (issue 13's target; measured 9-18:
#: docs/notes/scattered.md; iteration counts are deterministic)
MAX_ITERATIONS = 25


def errors(pts, field, boundary_condition="neumann"):
    """Mean errors of d, r, h (percent of mean abs(v)) and the result.  The
    solver's targets of issue 13 are the Neumann system's (the default chose
    it then; it chooses the natural condition on this field now, whose bounds
    test_the_default_meets_the_bounds_on_every_layout checks)."""
    ex = field.evaluate(pts)
    res = thh.decompose(pts, ex.v, field.domain, boundary_condition=boundary_condition)
    scale = np.linalg.norm(ex.v, axis=1).mean()
    err = [100 * np.linalg.norm(got - want, axis=1).mean() / scale
           for got, want in ((res.curl_free, ex.d), (res.div_free, ex.r), (res.harmonic, ex.h))]
    return err, res


@pytest.mark.parametrize("layout", list(BOUNDS))
def test_every_kind_of_point_set_decomposes_within_its_bound(layout):
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, 13000, layout, seed=1)
    (err_d, err_r, err_h), res = errors(pts, F)
    bound = BOUNDS[layout]
    assert err_d <= bound and err_r <= bound, (err_d, err_r)
    assert err_h <= 2 * bound, err_h
    assert not res.stats["flags"]
    its = (res.stats["iterations_phi"], res.stats["iterations_psi"])
    assert max(its) <= MAX_ITERATIONS, its


@pytest.mark.parametrize("layout", list(BOUNDS))
def test_the_default_meets_the_bounds_on_every_layout(layout):
    """The default condition (auto: natural here, the field's stream crosses
    the walls) within the same bounds on every layout."""
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, 13000, layout, seed=1)
    (err_d, err_r, err_h), res = errors(pts, F, boundary_condition="auto")
    assert res.stats["boundary_condition"] == "natural"
    bound = BOUNDS[layout]
    assert err_d <= bound and err_r <= bound, (err_d, err_r)
    assert err_h <= 2 * bound, err_h
    assert not res.stats["flags"]


@pytest.mark.slow
def test_second_order_convergence_on_random_points():
    F = fields.get("gaussian")
    ns = (3000, 13000, 53000)
    errs = []
    for n in ns:
        pts = layouts.sample(F.domain, n, "random", seed=1)
        (err_d, err_r, _), _res = errors(pts, F)
        errs.append(max(err_d, err_r))
    # error ~ spacing^p = N^(-p/2): fitted slope in log N
    slope = -2 * np.polyfit(np.log(ns), np.log(errs), 1)[0]
    assert slope >= 1.8, (errs, slope)


def test_boundary_samples_follow_the_data_spacing():
    # 1:10 density across x: the data's spacing at x = 1 is sqrt(10) smaller
    # than at x = 0, and so is the boundary samples'
    from taichi_hh.hhd.boundary import collocation_particles
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, 13000, "gradient", seed=1)
    spacing = np.sqrt(F.domain.area / len(pts))
    uniform, _ = collocation_particles(F.domain, pts, spacing)
    local, normals = collocation_particles(F.domain, pts, spacing, local=True)
    def side_gap(samples, x):
        y = np.sort(samples[np.abs(samples[:, 0] - x) < 1e-12, 1])
        return np.median(np.diff(y))
    ratio = side_gap(local, 0.0) / side_gap(local, 1.0)
    assert 2.3 < ratio < 4.3, ratio
    assert np.isclose(side_gap(uniform, 0.0), side_gap(uniform, 1.0), rtol=0.05)
    assert np.abs(F.domain.signed_distance(local)).max() < 1e-12
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["gradient", "random"])
def test_iterations_do_not_grow_with_n(layout):
    # issue 13: at most 1.5x from 13k on; before the boundary samples followed
    # the data's spacing, the 1:10 gradient took 12/12 at 13k and 36/28 at
    # 500k (docs/notes/scattered.md); deterministic counts
    F = fields.get("gaussian")
    its = {}
    for n in (13000, 200000):
        pts = layouts.sample(F.domain, n, layout, seed=1)
        res = thh.decompose(pts, F.evaluate(pts).v, F.domain, boundary_condition="neumann")
        its[n] = max(res.stats["iterations_phi"], res.stats["iterations_psi"])
    assert its[200000] <= 1.5 * its[13000] and its[200000] <= MAX_ITERATIONS, its


def test_data_short_of_the_boundary_are_named_with_the_remedy():
    from taichi_hh.errors import InputError
    from taichi_hh.geometry.domain import Box
    F = fields.get("gaussian")
    pts = Box((0.2, 0.2), (0.8, 0.8)).sample_interior(3000, kind="poisson", seed=1)
    v = F.evaluate(pts).v
    with pytest.raises(InputError, match="do not reach the domain's boundary.*domain='bbox'"):
        thh.decompose(pts, v, F.domain)
    # the remedies: the domain the data cover
    for domain in ("bbox", "hull"):
        res = thh.decompose(pts, v, domain)
        assert not res.stats["flags"]
        assert np.isfinite(res.harmonic).all()


def test_convex_hull_of_points():
    from taichi_hh.geometry.from_points import convex_hull
    rng = np.random.default_rng(0)
    pts = rng.random((500, 2))
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0]], float)   # (0.5, 0) on an edge
    hull = convex_hull(np.vstack([pts, corners]))
    assert {tuple(p) for p in hull} == {(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)}
    x, y = hull[:, 0], hull[:, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0      # counter-clockwise


def test_cli_adaptive_support_options_and_domain_from_points(tmp_path):
    from taichi_hh.app.cli import main
    pts = layouts.sample(fields.get("gaussian").domain, 2000, "random", seed=2)
    v = fields.get("gaussian").evaluate(pts).v
    path = tmp_path / "rnd.npz"
    np.savez(path, points=pts, vectors=v)
    out = tmp_path / "out"
    assert main(["decompose", str(path), "-o", str(out), "-q", "--no-figures", "--no-vtk",
                 "--support-neighbours", "8", "--domain", "hull"]) == 0
    assert np.load(out / "components.npz")["d"].shape == (2000, 2)
    with pytest.raises(SystemExit) as exc:            # a library-only option
        main(["decompose", str(path), "--multilevel-options", "x"])
    assert exc.value.code == 2
