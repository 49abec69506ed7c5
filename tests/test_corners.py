"""Corners (issue 28): no spike where data points lie on a box's corners; at a
re-entrant corner the conditions with boundary rows are singular (d and r
unbounded; h takes the opposite spike), which is reported, and the default
(natural on such data) has no singularity."""
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import AccuracyWarning
from taichi_hh.geometry.domain import Polygon
from taichi_hh.hhd.corners import reentrant_corners
from taichi_hh.validation.windows import window_field

W = window_field()
L_SHAPE = np.array([[0, 0], [2, 0], [2, 0.5], [1, 0.5], [1, 1], [0, 1]], float)


def test_reentrant_corners_of_rings():
    assert len(reentrant_corners(thh.Box((0, 0), (1, 1)))) == 0
    np.testing.assert_allclose(reentrant_corners(Polygon(L_SHAPE)), [[1.0, 0.5]])
    # a square hole: each of its corners is re-entrant seen from the domain
    hole = np.array([[0.4, 0.4], [0.6, 0.4], [0.6, 0.6], [0.4, 0.6]])
    assert len(reentrant_corners(Polygon(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float),
                                         holes=[hole]))) == 4
    # a finely segmented round hole turns by 3.75 degrees a vertex: none
    t = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    ring = 0.5 + 0.15 * np.c_[np.cos(t), np.sin(t)]
    assert len(reentrant_corners(Polygon(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float),
                                         holes=[ring]))) == 0


@pytest.fixture(scope="module")
def l_shape_case():
    """The window flow on 12k random points of an L, in metres at a UTM-like
    origin (the message must name the corner in those units)."""
    unit = Polygon(L_SHAPE)
    pts = unit.sample_interior(12000, kind="random", seed=1)
    ex = W.evaluate(pts)
    scale, origin = 1000.0, np.array([5e5, 4e6])
    return pts * scale + origin, ex.v, Polygon(L_SHAPE * scale + origin), scale, origin


def test_the_default_has_no_corner_singularity(l_shape_case):
    pts, v, dom, scale, origin = l_shape_case
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)
        res = thh.decompose(pts, v, dom)
    assert res.stats["boundary_condition"] == "natural"
    near = np.hypot(*((pts - origin) / scale - [1.0, 0.5]).T) < 0.05
    vmax = np.abs(v).max()
    # measured 0.07 of max |v| for both within 0.05 of the corner
    assert np.abs(res.curl_free[near]).max() < 0.15 * vmax
    assert np.abs(res.div_free[near]).max() < 0.15 * vmax


@pytest.mark.parametrize("condition", ["neumann", "no-flux"])
def test_a_singular_corner_is_reported_where_it_is(l_shape_case, condition):
    """Under Neumann rows d grows like rho^(-1/3) at the L's 270-degree corner
    (measured: 0.22 of max |v| within 0.02, 0.07 at 0.1): flagged, the corner
    named in the caller's units."""
    pts, v, dom, scale, origin = l_shape_case
    with pytest.warns(AccuracyWarning, match=r"1 re-entrant corner.*abs\(d\) next to one, "
                                             r"near \(501000, 4000500\).*singular.*"
                                             r"boundary_condition='natural'"):
        res = thh.decompose(pts, v, dom, boundary_condition=condition)
    assert res.stats["reentrant_corners"] == 1
    assert res.stats["corner_spike"] > 1.5                  # measured 2.1
    assert any("re-entrant corner" in f for f in res.stats["flags"])


def test_no_spike_where_data_lie_on_the_box_corners():
    """A PIV-like grid with nodes on the box's four corners: the default's
    largest error anywhere 0.2% of max |v| (measured), at the corners below."""
    x, y = np.linspace(0, 2, 161), np.linspace(0, 1, 81)
    X, Y = np.meshgrid(x, y)
    pts = np.c_[X.ravel(), Y.ravel()]
    ex = W.evaluate(pts)
    res = thh.decompose(pts, ex.v, (0, 0, 2, 1))
    vmax = np.abs(ex.v).max()
    for got, want in ((res.curl_free, ex.d), (res.div_free, ex.r), (res.harmonic, ex.h)):
        assert np.abs(got - want).max() < 0.01 * vmax
    assert "corner_spike" not in res.stats


def test_a_masked_grid_under_neumann_is_reported():
    """A building masked in a PIV grid: its outline's corners are re-entrant
    seen from the flow; the default (natural) is quiet, Neumann flags them."""
    x, y = np.linspace(0, 2, 121), np.linspace(0, 1, 61)
    X, Y = np.meshgrid(x, y)
    ex = W.evaluate(np.c_[X.ravel(), Y.ravel()])
    u, v = ex.v[:, 0].reshape(X.shape), ex.v[:, 1].reshape(X.shape)
    building = (np.abs(X - 1.0) < 0.15) & (Y < 0.35)
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)
        thh.decompose_grid(x, y, u, v, mask=building)
    with pytest.warns(AccuracyWarning, match="re-entrant corner"):
        thh.decompose_grid(x, y, u, v, mask=building, boundary_condition="neumann")


def test_neumann_rows_keep_clear_of_reentrant_corners():
    """Samples on both walls of a re-entrant corner and at its vertex make
    nearly dependent Neumann rows (taichi_hh.hhd.boundary.CORNER_CLEARANCE):
    without them a box with a square island solves in about a box's
    iterations, not 3-4 times them, and as accurately."""
    from taichi_hh.hhd.boundary import CORNER_CLEARANCE, collocation_particles
    from taichi_hh.hhd.corners import reentrant_corners
    from taichi_hh.geometry.domain import Polygon
    island = np.array([[0.45, 0.37], [0.65, 0.37], [0.65, 0.53], [0.45, 0.53]])
    box = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    dom = Polygon(box, holes=[island])
    rng = np.random.default_rng(0)
    pts = rng.random((40000, 2)) * [2.0, 1.0]
    pts = pts[dom.contains(pts)][:8000]
    spacing = np.sqrt(dom.area / len(pts))
    corners = reentrant_corners(dom)
    assert len(corners) == 4
    for local in (False, True):
        every, _ = collocation_particles(dom, pts, spacing, local=local)
        clear, _ = collocation_particles(dom, pts, spacing, local=local, clear_corners=True)
        near = np.hypot(*(clear[:, None, :] - corners[None]).transpose(2, 0, 1)).min(axis=1)
        assert near.min() > 0.5 * CORNER_CLEARANCE * spacing
        assert 0 < len(every) - len(clear) <= 4 * 5          # a few a corner, no more
    # Gaussian potentials three widths and more from every wall, a uniform stream
    from taichi_hh.validation.fields import Bump
    bumps = (Bump((1.3, 0.5), 0.01, 0.08), Bump((0.25, 0.7), -0.01, 0.08))
    stream = np.array([0.05, 0.02])

    def split(at):
        g = sum(b(at)[1] for b in bumps)
        return g, np.c_[g[:, 1], -g[:, 0]], g + np.c_[g[:, 1], -g[:, 0]] + stream

    def solve(at, domain, condition):
        d, r, v = split(at)
        res = thh.decompose(at, v, domain, boundary_condition=condition)
        scale = np.linalg.norm(v, axis=1).mean()
        err = max(np.linalg.norm(res.curl_free - d, axis=1).mean(),
                  np.linalg.norm(res.div_free - r, axis=1).mean()) / scale
        return err, max(res.stats["iterations_phi"], res.stats["iterations_psi"])

    island_err, island_its = solve(pts, dom, "neumann")
    dirichlet_err, _ = solve(pts, dom, "normal-parallel")
    _, box_its = solve(rng.random((len(pts), 2)) * [2.0, 1.0], (0.0, 0.0, 2.0, 1.0), "neumann")
    # with the corner samples: 33 iterations against 9, 2.2x normal-parallel's error
    assert island_its <= 2 * box_its, (island_its, box_its)
    assert island_err <= 1.25 * dirichlet_err, (island_err, dirichlet_err)
