"""Streamlets (app/streamlets.py): the vectorised tracer of the magnitude figure."""
import numpy as np

from taichi_hh.app import streamlets


def _grid(n=61):
    g = np.linspace(-1.0, 1.0, n)
    X, Y = np.meshgrid(g, g)
    return g, g, X, Y


def test_uniform_field_gives_straight_lines_of_the_set_length():
    gx, gy, X, Y = _grid()
    U = np.ma.masked_array(np.full_like(X, 3.0))
    V = np.ma.masked_array(np.full_like(X, 4.0))
    lines, heads = streamlets.trace(gx, gy, U, V, seeds=10, half_length=0.5, steps=8)
    assert len(lines) > 0
    spacing = 2.0 / 10
    seg = np.diff(lines, axis=1)
    # every step along (0.6, 0.8); lines cut by the box's edge stop (zero steps)
    lengths = np.hypot(seg[..., 0], seg[..., 1])
    moving = lengths > 0
    directions = seg[moving] / lengths[moving][:, None]
    assert np.allclose(directions, [0.6, 0.8], atol=1e-12)
    full = moving.all(axis=1)
    assert full.sum() > len(lines) // 3
    assert np.allclose(lengths[full].sum(axis=1), spacing, rtol=1e-9)   # 2 x 0.5 spacings
    assert np.allclose(heads[:, 1], [0.6, 0.8], atol=1e-12)


def test_rotation_keeps_each_streamlet_on_its_circle():
    gx, gy, X, Y = _grid(121)
    U, V = np.ma.masked_array(-Y), np.ma.masked_array(X)
    lines, _ = streamlets.trace(gx, gy, U, V, seeds=12, half_length=1.0, steps=16)
    r = np.hypot(lines[..., 0], lines[..., 1])
    inner = r[:, 0] < 0.8
    # the midpoint rule on the bilinear field: the radius drifts by O(h^2)
    assert np.abs(r[inner] - r[inner][:, :1]).max() < 2e-3 * 1.0


def test_masked_nodes_and_calm_regions_stop_the_lines():
    gx, gy, X, Y = _grid()
    outside = X > 0.0
    U = np.ma.masked_array(np.ones_like(X), mask=outside)
    V = np.ma.masked_array(np.zeros_like(X), mask=outside)
    lines, heads = streamlets.trace(gx, gy, U, V, seeds=10)
    assert len(lines) > 0 and lines[..., 0].max() <= 0.0 + 1e-12
    calm = streamlets.trace(gx, gy, np.ma.masked_array(0 * X), np.ma.masked_array(0 * X))
    assert len(calm[0]) == 0 and len(calm[1]) == 0


def test_linear_on_equals_matplotlibs_linear_interpolator():
    from matplotlib.tri import LinearTriInterpolator

    from taichi_hh.app import figures
    from taichi_hh.geometry.domain import Polygon
    rng = np.random.default_rng(3)
    pts = rng.uniform(0.0, 1.0, (400, 2))
    domain = Polygon([(0, 0), (1, 0), (1, 1), (0.5, 0.4), (0, 1)])   # concave: masked triangles
    pts = pts[domain.contains(pts)]
    tri = figures.masked_triangulation(pts, domain)
    g = np.linspace(-0.05, 1.05, 57)
    X, Y = np.meshgrid(g, g)
    values = np.sin(3 * pts[:, 0]) * pts[:, 1] + 2.0
    got = figures.linear_on(tri, X, Y)(values)
    ref = LinearTriInterpolator(tri, values)(X, Y)
    assert np.array_equal(np.ma.getmaskarray(got), np.ma.getmaskarray(ref))
    assert np.ma.getmaskarray(got).sum() > 0 and (~np.ma.getmaskarray(got)).sum() > 1000
    assert np.abs(got - ref).max() < 1e-12
    # exact on linear fields
    lin = figures.linear_on(tri, X, Y)(3 * pts[:, 0] - 2 * pts[:, 1])
    ok = ~np.ma.getmaskarray(lin)
    assert np.allclose(lin[ok], (3 * X - 2 * Y)[ok], atol=1e-12)
