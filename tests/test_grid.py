"""Gridded data (taichi_hh.decompose_grid): the domain from the valid nodes
(masked obstacles as holes, unlit corners cut off, dropouts bridged), the
results on the grid, NaN where no vector was decomposed."""
import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import AccuracyWarning, InputError
from taichi_hh.hhd.grid import cut_out
from taichi_hh.validation import fields

GAUSS = fields.get("gaussian")     # four Gaussian potentials, negligible at (0.5, 0.5)


def _grid(n=64):
    x = np.linspace(0.5 / n, 1 - 0.5 / n, n)
    X, Y = np.meshgrid(x, x)
    ex = GAUSS.evaluate(np.c_[X.ravel(), Y.ravel()])
    shape = X.shape
    return x, X, Y, {k: getattr(ex, k).reshape(shape + (2,)) for k in ("v", "d", "r", "h")}


def _error(got, want, v, where):
    vm = np.linalg.norm(v[where], axis=1).mean()
    return np.linalg.norm(got[where] - want[where], axis=1).mean() / vm


@pytest.fixture(scope="module")
def obstacle_and_dropouts():
    x, X, Y, ex = _grid()
    rng = np.random.default_rng(0)
    dropout = rng.random(X.shape) < 0.04
    obstacle = (X - 0.5) ** 2 + (Y - 0.5) ** 2 < 0.07 ** 2
    u, v = ex["v"][..., 0].copy(), ex["v"][..., 1].copy()
    u[dropout] = np.nan
    res = thh.decompose_grid(x, x, u, v, mask=obstacle)
    clean = thh.decompose_grid(x, x, ex["v"][..., 0], ex["v"][..., 1])
    return x, ex, dropout, obstacle, res, clean


def test_masked_obstacle_is_a_hole_and_dropouts_are_bridged(obstacle_and_dropouts):
    x, ex, dropout, obstacle, res, clean = obstacle_and_dropouts
    invalid = dropout | obstacle
    assert res.stats["n_holes"] == 1 and len(res.domain.holes) == 1
    # the hole covers the obstacle, and no dropout outside it makes another
    assert not res.inside[obstacle].any()
    assert res.inside[dropout & ~obstacle].all()
    assert (res.used == ~invalid).all()
    assert res.stats["n_invalid"] == invalid.sum()
    assert res.stats["n_cut_out"] == obstacle.sum()
    for comp in (res.curl_free, res.div_free, res.harmonic):
        assert comp.shape == ex["v"].shape
        assert np.isnan(comp[invalid]).all() and np.isfinite(comp[~invalid]).all()
    assert res.phi.shape == ex["v"].shape[:2] and np.isnan(res.phi[invalid]).all()
    ok = ~invalid
    # the field is negligible at the hole, so the analytic split holds there too
    # (the default on a grid: the natural condition).  64 x 64, Gaussians 4.5
    # nodes wide: measured d 0.73%, r 0.47% (the full grid: 0.32%, 0.32%)
    assert res.scattered.options.boundary_condition == "natural"
    assert _error(res.curl_free, ex["d"], ex["v"], ok) < 0.01
    assert _error(res.div_free, ex["r"], ex["v"], ok) < 0.01


def test_a_masked_obstacle_costs_no_accuracy(obstacle_and_dropouts):
    """The hole alone (no dropouts): the same error as the full grid (measured
    0.3234% against 0.3235% for d)."""
    x, ex, dropout, obstacle, res, clean = obstacle_and_dropouts
    holed = thh.decompose_grid(x, x, ex["v"][..., 0], ex["v"][..., 1], mask=obstacle)
    for name, want in (("curl_free", ex["d"]), ("div_free", ex["r"])):
        e = _error(getattr(holed, name), want, ex["v"], holed.used)
        e_clean = _error(getattr(clean, name), want, ex["v"], clean.used)
        assert e <= 1.05 * e_clean, (name, e, e_clean)


def test_grid_critical_points_are_the_fields(obstacle_and_dropouts):
    res = obstacle_and_dropouts[4]
    found = {c.kind: (c.x, c.y) for c in res.critical_points()}
    for x, y, kind in GAUSS.critical_points:
        assert kind in found and np.hypot(found[kind][0] - x, found[kind][1] - y) < 0.04


def test_mask_nan_and_numpy_mask_are_the_same():
    x, X, Y, ex = _grid(40)
    gone = (X > 0.7) & (Y > 0.7)                      # an unlit corner
    u, v = ex["v"][..., 0].copy(), ex["v"][..., 1].copy()
    by_mask = thh.decompose_grid(x, x, u, v, mask=gone)
    u_nan = u.copy()
    u_nan[gone] = np.nan
    by_nan = thh.decompose_grid(x, x, u_nan, v)
    by_ma = thh.decompose_grid(x, x, np.ma.masked_array(u, gone), v)
    for other in (by_nan, by_ma):
        np.testing.assert_array_equal(other.curl_free, by_mask.curl_free)
    # the corner is cut off the domain, not a hole
    assert not by_mask.inside[gone].any() and by_mask.stats["n_holes"] == 0
    assert by_mask.domain.area < 0.95 * (x[-1] - x[0] + x[1] - x[0]) ** 2


def test_decreasing_axes_give_the_same_decomposition():
    x, X, Y, ex = _grid(40)
    u, v = ex["v"][..., 0], ex["v"][..., 1]
    up = thh.decompose_grid(x, x, u, v)
    down = thh.decompose_grid(x, x[::-1], u[::-1], v[::-1])      # image rows: y decreasing
    np.testing.assert_allclose(down.curl_free[::-1], up.curl_free, rtol=0, atol=1e-9)
    np.testing.assert_allclose(down.psi[::-1], up.psi, rtol=0, atol=1e-9)


def test_a_separate_piece_is_left_out_and_named():
    x, X, Y, ex = _grid(40)
    wall = np.abs(X - 0.8) < 0.06                      # a masked band across the grid
    u, v = ex["v"][..., 0], ex["v"][..., 1]
    with pytest.warns(AccuracyWarning, match="separate piece"):
        res = thh.decompose_grid(x, x, u, v, mask=wall)
    right = X > 0.86
    assert res.stats["n_left_out"] == right.sum()
    assert np.isnan(res.curl_free[right]).all() and not res.used[right].any()


def test_cut_out_keeps_small_gaps():
    invalid = np.zeros((12, 12), dtype=bool)
    invalid[2, 3] = invalid[5, 5:7] = True            # dropouts: bridged
    invalid[7:10, 1:4] = True                          # a 3 x 3 block: cut out
    invalid[0:2, 9:12] = True                          # 2 rows at the edge: cut out
    cut = cut_out(invalid, 3)
    assert not cut[2, 3] and not cut[5, 5:7].any()
    assert cut[7:10, 1:4].all() and cut[0:2, 9:12].all()
    assert not (cut & ~invalid).any()


def test_grid_input_errors():
    x, X, Y, ex = _grid(20)
    u, v = ex["v"][..., 0], ex["v"][..., 1]
    with pytest.raises(InputError, match="shape"):
        thh.decompose_grid(x, x, u[:, :-1], v)
    with pytest.raises(InputError, match="strictly increasing or strictly decreasing"):
        thh.decompose_grid(np.r_[x[:5], x[4:-1]], x, u, v)
    with pytest.raises(InputError, match="makes its domain"):
        thh.decompose_grid(x, x, u, v, domain=(0, 0, 1, 1))
    with pytest.raises(InputError, match="all 400 nodes are invalid"):
        thh.decompose_grid(x, x, u * np.nan, v)
    with pytest.raises(InputError, match="hole_size"):
        thh.decompose_grid(x, x, u, v, hole_size=1)


def test_isolated_valid_nodes_are_left_out():
    """A valid node with fewer than 4 valid neighbours (of 8) in a region the
    instrument rejected is left out; a full grid's corners and edges are not
    isolated."""
    from taichi_hh.hhd.grid import isolated_nodes
    invalid = np.zeros((10, 10), dtype=bool)
    assert not isolated_nodes(invalid).any()                 # corners: 3 neighbours, all valid
    invalid[2:7, 2:7] = True
    invalid[4, 4] = False                                    # an island in a rejected block
    invalid[2, 2] = False                  # the block's corner: 5 valid neighbours outside it
    iso = isolated_nodes(invalid)
    assert iso[4, 4] and not iso[2, 2] and iso.sum() == 1
    edge = np.zeros((6, 6), dtype=bool)
    edge[3:5, 1:5] = True                  # a rejected band one node above the grid's edge
    edge[0, 0] = edge[0, 2] = True         # two dropouts on the top edge
    iso = isolated_nodes(edge)
    assert iso[5, 2:4].all() and iso.sum() == 2              # the one-node strip below the band
    assert not iso[0].any()                                  # 3 of 5 neighbours: kept
    x, X, Y, ex = _grid(40)
    u, v = ex["v"][..., 0].copy(), ex["v"][..., 1]
    rejected = (np.abs(X - 0.5) < 0.1) & (np.abs(Y - 0.5) < 0.1)
    u[rejected] = np.nan
    j, i = np.argwhere(rejected)[len(np.argwhere(rejected)) // 2]
    u[j, i] = ex["v"][j, i, 0]                               # one vector survives in the block
    res = thh.decompose_grid(x, x, u, v)
    assert res.stats["n_isolated"] == 1 and not res.used[j, i]
    assert np.isnan(res.curl_free[j, i]).all()
    kept = thh.decompose_grid(x, x, u, v, min_neighbours=0)
    assert kept.stats["n_isolated"] == 0 and kept.used[j, i]
