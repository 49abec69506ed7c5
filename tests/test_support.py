"""Adaptive support (taichi_hh.sph.support): k-th neighbour distances against
brute force, the pair list against the max(H_i, H_j) rule, and the operators'
consistency (exactness on the polynomials each variant promises) on points
whose density varies, where one fixed support fails."""
import math

import numpy as np
import pytest

from taichi_hh.errors import InputError
from taichi_hh.geometry.domain import Box
from taichi_hh.sph.pointset import PointSet
from taichi_hh.sph.support import adaptive_supports, kth_neighbour_distance
from taichi_hh.validation import layouts

UNIT = Box((0, 0), (1, 1))


def brute_kth(points, k):
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return np.sort(d, axis=1)[:, k - 1]


@pytest.mark.parametrize("sampling", ["random", "clusters", "gradient"])
@pytest.mark.parametrize("k", [1, 6, 12, 24])
def test_kth_distance_matches_brute_force(sampling, k):
    pts = layouts.sample(UNIT, 1500, sampling, seed=3)
    np.testing.assert_allclose(kth_neighbour_distance(pts, k, 1.0), brute_kth(pts, k),
                               rtol=1e-12)


def test_isolated_points_get_their_neighbours_by_widening():
    # a dense blob and a few far points: the first search radius misses the far ones
    rng = np.random.default_rng(0)
    pts = np.vstack([0.5 + 0.01 * rng.standard_normal((500, 2)),
                     [[0.01, 0.01], [0.99, 0.02], [0.02, 0.98], [0.97, 0.99]]])
    np.testing.assert_allclose(kth_neighbour_distance(pts, 4, 1.0), brute_kth(pts, 4),
                               rtol=1e-12)


def test_too_few_points_or_bad_k_is_refused():
    pts = np.random.default_rng(1).random((5, 2))
    with pytest.raises(InputError, match="too few"):
        kth_neighbour_distance(pts, 6, 1.0)
    with pytest.raises(InputError, match="1..24"):
        kth_neighbour_distance(pts, 0, 1.0)


def test_uniform_lattice_gets_the_fixed_support():
    pts, dx = layouts.lattice_in_box(2500, (0, 0, 1, 1))
    h = adaptive_supports(pts, 2.5, 12, 1.0)
    interior = np.all((pts > 0.1) & (pts < 0.9), axis=1)
    # the 12th neighbour of a lattice point is at distance 2 dx (the 12 closest:
    # 4 at dx, 4 at sqrt2 dx, 4 at 2 dx): support 2.5 * 2 dx sqrt(pi/12)
    np.testing.assert_allclose(h[interior], 2.5 * 2 * dx * math.sqrt(math.pi / 12), rtol=1e-9)


@pytest.mark.parametrize("sampling", ["gradient", "clusters", "far"])
def test_pairs_follow_the_max_rule(sampling):
    """Every pair closer than the larger of its supports, and no other, boundary
    samples (larger supports) included; rows sorted by slot (the reverse index
    bisects them)."""
    if sampling == "far":           # a tiny dense cluster and a few far points
        rng = np.random.default_rng(4)
        pts = np.vstack([0.5 + 1e-3 * rng.standard_normal((1190, 2)), rng.random((10, 2))])
    else:
        pts = layouts.sample(UNIT, 1200, sampling, seed=2)
    bpts, bnrm, _ = UNIT.sample_boundary(1 / math.sqrt(1200))
    ps = PointSet(pts, area=1.0, support_ratio=2.5, support_neighbours=12,
                  boundary=(bpts, bnrm))
    allpts = np.vstack([pts, bpts])
    h = ps.ops.supports.to_numpy()[: ps.n_total][ps.slot_of_all]     # input order
    d = np.linalg.norm(allpts[:, None, :] - allpts[None, :, :], axis=2)
    want = (d < np.maximum(h[:, None], h[None, :])) & ~np.eye(len(allpts), dtype=bool)
    off, nb = ps.pairs.to_numpy()
    got = np.zeros_like(want)
    rows = np.repeat(np.arange(ps.n_total), np.diff(off))
    orig = ps.particles.get("original_index")
    got[orig[rows], orig[nb]] = True
    assert np.array_equal(got, want)
    assert np.all(np.diff(nb)[np.diff(rows) == 0] > 0)
    ps.pairs.reverse_index()            # raises if the relation were not symmetric
    # every point keeps at least its k nearest neighbours
    assert ps.neighbour_counts.min() >= 12


@pytest.mark.parametrize("sampling", ["random", "clusters", "gradient"])
def test_operators_stay_exact_with_adaptive_support(sampling):
    pts = layouts.sample(UNIT, 3000, sampling, seed=5)
    ps = PointSet(pts, area=1.0, support_ratio=3.0, support_neighbours=12)
    x, y = pts[:, 0], pts[:, 1]
    lin = 0.3 + 2.0 * x - 1.5 * y
    quad = lin + 0.7 * x * x - 1.1 * x * y + 0.4 * y * y
    np.testing.assert_allclose(ps.gradient(lin, "corrected"), np.tile([2.0, -1.5], (len(pts), 1)),
                               atol=1e-9)
    g = ps.gradient(quad, "quadratic")
    np.testing.assert_allclose(g[:, 0], 2.0 + 1.4 * x - 1.1 * y, atol=1e-8)
    np.testing.assert_allclose(g[:, 1], -1.5 - 1.1 * x + 0.8 * y, atol=1e-8)
    np.testing.assert_allclose(ps.laplacian(quad, "corrected"), 2 * 0.7 + 2 * 0.4, atol=1e-7)


def test_fixed_support_is_unchanged_by_the_adaptive_path():
    """support_neighbours=None keeps the one support: same pairs and densities
    as an explicit support."""
    pts = layouts.sample(UNIT, 2000, "poisson", seed=4)
    a = PointSet(pts, area=1.0, support_ratio=2.5)
    b = PointSet(pts, area=1.0, support=a.support)
    assert np.array_equal(a.pairs.to_numpy()[1], b.pairs.to_numpy()[1])
    assert np.array_equal(a.density(), b.density())
    assert np.all(a.supports == a.support)


@pytest.mark.parametrize("sampling", ["poisson", "random", "clusters"])
def test_cubic_gradient_is_exact_on_cubics(sampling):
    pts = layouts.sample(UNIT, 3000, sampling, seed=6)
    ps = PointSet(pts, area=1.0, support_ratio=3.0, support_neighbours=12)
    x, y = pts[:, 0], pts[:, 1]
    f = 0.2 + x - 2 * y + 0.5 * x * x + x * y - y * y + 0.3 * x ** 3 - 0.6 * x * x * y \
        + 0.9 * x * y * y + 0.4 * y ** 3
    gx = 1 + x + y + 0.9 * x * x - 1.2 * x * y + 0.9 * y * y
    gy = -2 + x - 2 * y - 0.6 * x * x + 1.8 * x * y + 1.2 * y * y
    g = ps.gradient(f, "cubic")
    np.testing.assert_allclose(g, np.c_[gx, gy], atol=1e-8)
    # and the quadratic fit is not (the test could fail)
    assert np.abs(ps.gradient(f, "quadratic") - np.c_[gx, gy]).max() > 1e-4


# --------------------------------------------------------------------------- ties on lattices
def _lattice(m=16):
    g = np.arange(m) / (m - 1.0)
    return np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)


def test_nearest_weights_are_continuous_at_rank_ties():
    """A target midway between lattice points has its m-th and (m+1)-th
    nearest equally far: the plain mean over the m nearest jumps with the
    rounding of a 1e-16 move, the tapered mean of nearest_weights does not."""
    from taichi_hh.sph.knn import KNearest
    src = _lattice(8)
    values = np.random.default_rng(0).random(len(src))
    search = KNearest(src)
    step = 1 / 7
    # half a step outside the lattice's edge (as boundary samples are), midway
    # between two columns: the 3rd to 6th nearest are equally far (sqrt(2.5) steps)
    tg = np.c_[(np.arange(6) + 0.5) * step, np.full(6, -0.5 * step)]
    rng = np.random.default_rng(1)
    plain, tapered = [], []
    for _ in range(8):
        moved = tg + rng.uniform(-4e-16, 4e-16, tg.shape)
        idx = search.query(moved, 4)[1]
        plain.append(values[idx].mean(axis=1))
        near, w = search.nearest_weights(moved, 4)
        assert near.shape == w.shape == (len(tg), 4)
        np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-15)
        tapered.append((w * values[near]).sum(axis=1))
    assert np.ptp(plain, axis=0).max() > 1e-3          # the tie is real
    assert np.ptp(tapered, axis=0).max() < 1e-12


def test_nearest_weights_are_the_plain_mean_away_from_ties():
    from taichi_hh.sph.knn import KNearest
    rng = np.random.default_rng(2)
    src, tg = rng.random((400, 2)), rng.random((300, 2))
    search = KNearest(src)
    d, idx = search.query(tg, 5)
    clear = d[:, 3] < 0.95 * d[:, 4]
    assert clear.sum() > 100
    near, w = search.nearest_weights(tg, 4)
    assert np.array_equal(near, idx[:, :4])
    np.testing.assert_allclose(w[clear], 0.25, rtol=1e-15)
    assert (w >= 0).all() and (w[:, 0] > 0).all()
    # as many as the sources or more: all of them, equally
    near, w = KNearest(src[:3]).nearest_weights(tg[:5], 4)
    assert near.shape == (5, 3) and np.allclose(w, 1 / 3)


def _lattice_case(domain):
    pts = _lattice(16)
    x, y = pts[:, 0], pts[:, 1]
    vec = np.c_[np.sin(2 * x) * np.cos(y) + y * y, x * y - np.cos(3 * x) * np.sin(2 * y)]
    if domain == "margin":          # the fuzz suite's box_margin: 5% of the extent
        domain = (-0.05, -0.05, 1.05, 1.05)
    return pts, vec, domain


@pytest.mark.parametrize("domain, condition, tol", [("margin", "normal-parallel", 1e-9),
                                                    (None, "neumann", 1e-7)])
def test_lattice_decomposition_is_continuous_with_adaptive_support(domain, condition, tol):
    """A 16 x 16 lattice moved by 4e-16: the boundary samples at the data's
    local spacing moved by 7e-4 (the spacing averaged over a boundary point's
    4 nearest data points, its 4th and 5th tied), and r and d by 7e-5 of the
    field; in the points' bounding box, where also the sampler's fine-step
    count is 64 +- rounding, the samples numbered 36 or 35.  Now they move
    by what the solver's tolerance allows."""
    import taichi_hh as thh
    pts, vec, dom = _lattice_case(domain)
    ref = thh.decompose(pts, vec, dom, boundary_condition=condition, adaptive_support=True)
    moved = pts + np.random.default_rng(0).uniform(-4e-16, 4e-16, pts.shape)
    got = thh.decompose(moved, vec, dom, boundary_condition=condition, adaptive_support=True)
    assert ref.stats["n_boundary"] == got.stats["n_boundary"]
    scale = np.abs(vec).max()
    for a, b in ((ref.div_free, got.div_free), (ref.curl_free, got.curl_free)):
        assert np.abs(a - b).max() / scale < tol
