"""The sweep-hull Delaunay triangulation (taichi_hh.geometry.delaunay) against
Qhull and against the definition (no point inside a triangle's circumcircle)."""
import numpy as np
import pytest

from taichi_hh.errors import InputError
from taichi_hh.geometry import from_points
from taichi_hh.geometry.delaunay import sweep_hull, valid_triangulation
from taichi_hh.geometry.domain import Box
from taichi_hh.geometry.from_points import (delaunay_triangles, delaunay_triangulation,
                                           unique_points)
from taichi_hh.validation import layouts


def _canonical(tri):
    return set(map(tuple, np.sort(tri, axis=1).tolist()))


def _qhull(pts):
    from matplotlib.tri import Triangulation
    return np.asarray(Triangulation(pts[:, 0], pts[:, 1]).triangles)


def _points_inside_circumcircles(pts, tri, rtol=1e-9):
    """Brute force: how many (triangle, point) pairs have the point strictly
    inside the triangle's circumcircle."""
    a, b, c = (pts[tri[:, k]] for k in range(3))
    d = 2.0 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    bl, cl = ((b - a) ** 2).sum(1), ((c - a) ** 2).sum(1)
    ux = a[:, 0] + ((c[:, 1] - a[:, 1]) * bl - (b[:, 1] - a[:, 1]) * cl) / d
    uy = a[:, 1] + ((b[:, 0] - a[:, 0]) * cl - (c[:, 0] - a[:, 0]) * bl) / d
    r2 = (a[:, 0] - ux) ** 2 + (a[:, 1] - uy) ** 2
    dist2 = (pts[None, :, 0] - ux[:, None]) ** 2 + (pts[None, :, 1] - uy[:, None]) ** 2
    inside = dist2 < r2[:, None] * (1.0 - rtol)
    inside[np.arange(len(tri))[:, None], tri] = False
    return int(inside.sum())


@pytest.mark.parametrize("layout", ["random", "poisson", "jitter0.6", "gradient", "clusters"])
def test_the_same_triangles_as_qhull(layout):
    pts = unique_points(layouts.sample(Box((0, 0), (1, 1)), 2000, layout, seed=3))
    tri, _ = sweep_hull(pts)
    assert _canonical(tri) == _canonical(_qhull(pts))


def test_empty_circumcircles_and_counter_clockwise():
    pts = unique_points(np.random.default_rng(7).random((400, 2)))
    tri, _ = sweep_hull(pts)
    assert _points_inside_circumcircles(pts, tri) == 0
    a, b, c = (pts[tri[:, k]] for k in range(3))
    assert np.all((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                  - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) > 0)


@pytest.mark.parametrize("case", ["lattice", "lattice-jittered-1e-12", "circle", "circle-centre",
                                  "large-offset", "tiny-scale"])
def test_degenerate_and_badly_scaled_input(case):
    """Cocircular points (a lattice: every square's four corners), nearly
    collinear hulls, coordinates of 1e7 or 1e-6: delaunay_triangles (the
    sweep, or Qhull where the sweep's check fails) gives a triangulation of
    every point whose circumcircles hold no point."""
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.arange(30.0), np.arange(30.0)), -1).reshape(-1, 2)
    ring = np.linspace(0.0, 2.0 * np.pi, 150, endpoint=False)
    pts = {"lattice": grid,
           "lattice-jittered-1e-12": grid + rng.uniform(-1e-12, 1e-12, grid.shape),
           "circle": np.c_[np.cos(ring), np.sin(ring)],
           "circle-centre": np.r_[np.c_[np.cos(ring), np.sin(ring)], [[0.0, 0.0]]],
           "large-offset": rng.random((2000, 2)) * 1e3 + 1e7,
           "tiny-scale": rng.random((2000, 2)) * 1e-6}[case]
    pts = unique_points(pts)
    tri = delaunay_triangles(pts)
    assert len(tri) > 0
    assert _points_inside_circumcircles(pts, tri, rtol=1e-6) == 0
    assert np.bincount(tri.ravel(), minlength=len(pts)).min() > 0


def test_points_on_a_line_fall_back_and_are_refused():
    pts = np.c_[np.arange(10.0), 2.0 * np.arange(10.0)]
    assert sweep_hull(pts) is None
    with pytest.raises(InputError, match="triangulated"):
        delaunay_triangles(pts)


def test_the_fallback_gives_the_same_triangulation(monkeypatch):
    from taichi_hh.geometry import delaunay
    pts = unique_points(np.random.default_rng(3).random((1500, 2)))
    fast = delaunay_triangles(pts)
    monkeypatch.setattr(delaunay, "sweep_hull", lambda p: None)
    slow = from_points.delaunay_triangles(pts)
    assert _canonical(fast) == _canonical(slow)


def test_the_check_rejects_a_fold_and_a_missing_point():
    pts = unique_points(np.random.default_rng(4).random((300, 2)))
    tri, _ = sweep_hull(pts)
    hull = 2 * len(pts) - 2 - len(tri)
    assert valid_triangulation(pts, tri, hull)
    folded = tri.copy()
    folded[0] = folded[0, [0, 2, 1]]
    assert not valid_triangulation(pts, folded, hull)
    assert not valid_triangulation(pts, tri[1:], hull)
    missing = np.r_[pts, [[5.0, 5.0]]]
    assert not valid_triangulation(missing, tri, hull)


def test_a_sweep_past_its_flip_budget_gives_up_and_the_fallback_takes_over(monkeypatch):
    """Every walk and the flips are bounded, so no input can hang the kernel;
    a sweep that runs out gives None and delaunay_triangles uses Qhull."""
    from taichi_hh.geometry import delaunay
    pts = unique_points(np.random.default_rng(6).random((500, 2)))
    monkeypatch.setattr(delaunay, "FLIPS_PER_POINT", 0)
    assert delaunay.sweep_hull(pts) is None
    assert _canonical(delaunay_triangles(pts)) == _canonical(_qhull(pts))


def _across_by_sorting(tri):
    """The triangle across each edge, found by sorting the edges' vertex pairs."""
    n = int(tri.max()) + 1
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = edges.min(axis=1) * n + edges.max(axis=1)
    order = np.argsort(key)
    twin = np.flatnonzero(key[order[1:]] == key[order[:-1]])
    across = np.full(len(edges), -1)
    across[order[twin]] = order[twin + 1] % len(tri)
    across[order[twin + 1]] = order[twin] % len(tri)
    return across


@pytest.mark.parametrize("path", ["sweep", "qhull"])
def test_the_triangle_across_each_edge(monkeypatch, path):
    """From the sweep's halfedges and from Qhull's neighbours, reordered with
    the triangles made counter-clockwise: the same as sorting the edges."""
    from taichi_hh.geometry import delaunay
    if path == "qhull":
        monkeypatch.setattr(delaunay, "sweep_hull", lambda p: None)
    pts = unique_points(np.random.default_rng(8).random((800, 2)))
    tri, across = delaunay_triangulation(pts)
    assert np.array_equal(across, _across_by_sorting(tri))
