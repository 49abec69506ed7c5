"""Degenerate point sets given to the public calls (issue 29: nothing that
hangs, nothing silently wrong): points on a line, copies of a point.

Collinear points once sent ``domain="hull"`` into a boundary sampler that never
returned (500 points) or failed after 10 s with "boundary points is empty"
(20 points); 13 or more copies of a point passed unseen (the adaptive support
from 12 nearest neighbours was zero there, so the copies had no pairs and the
pair search's duplicate test never saw them).  Each is now refused at once,
with a message about the data."""
import math
import re
import time

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.geometry import Box, Polygon
from taichi_hh.geometry import sampling
from taichi_hh.geometry.from_points import check_spread, domain_from_points
from taichi_hh.hhd.boundary import collocation_particles
from taichi_hh.sph.pointset import DUPLICATE_FRACTION, check_distinct, close_pair

#: internal names no message reachable from the public calls may carry
INTERNAL = ("spacing_at", "boundary points", "is empty", "query point", "data_spacing",
            "duplicate_query", "support_neighbours", "PointSet", "sample_boundary")
#: seconds: the refusals take milliseconds; this only catches a hang's return
QUICK = 10.0


def no_internal_names(msg: str) -> None:
    for name in INTERNAL:
        assert name not in msg, f"{name!r} in {msg!r}"


def lines(n):
    """Points on a line: in general position (collinear to rounding only), all
    x equal, all y equal."""
    t = np.linspace(0.0, 1.0, n)
    return {"slanted": np.c_[t, 0.3 * t + 0.1],
            "x equal": np.c_[np.full(n, 0.5), t],
            "y equal": np.c_[t, np.full(n, 0.25)]}


def field(pts):
    return np.c_[np.sin(3 * pts[:, 0]), np.cos(2 * pts[:, 1])]


def refused(call):
    """The InputError ``call()`` raises, checked to come quickly and to name no
    internal identifier."""
    t = time.perf_counter()
    with pytest.raises(thh.InputError) as info:
        call()
    assert time.perf_counter() - t < QUICK
    msg = str(info.value)
    no_internal_names(msg)
    return msg


# --------------------------------------------------------------------------- collinear
DOMAINS = [None, "bbox", "hull", "alpha", (-1.0, -1.0, 2.0, 2.0),
           Polygon([(-1.0, -1.0), (2.0, -1.0), (0.5, 2.5)])]


@pytest.mark.parametrize("n", [20, 500])
@pytest.mark.parametrize("domain", DOMAINS, ids=["default", "bbox", "hull", "alpha", "box",
                                                 "polygon"])
def test_collinear_points_refused_quickly(n, domain):
    for kind, pts in lines(n).items():
        msg = refused(lambda: thh.decompose(pts, field(pts), domain))
        assert "lie on a line" in msg and "spread over an area" in msg, (kind, msg)


@pytest.mark.parametrize("method", ["petronetto2010", "colin2006"])
def test_collinear_points_refused_by_the_other_boundary_methods(method):
    pts = lines(50)["slanted"]
    for domain in ("hull", (-1.0, -1.0, 2.0, 2.0)):
        msg = refused(lambda: thh.decompose(pts, field(pts), domain, method=method))
        assert "lie on a line" in msg


def test_nearly_collinear_single_row_refused():
    """A row of points jittered far less than their gap: no 2D neighbourhood."""
    t = np.linspace(0.0, 1.0, 200)
    pts = np.c_[t, 0.5 + 1e-5 * np.sin(37.0 * t)]
    msg = refused(lambda: thh.decompose(pts, field(pts), "hull"))
    assert "lie on a line, or nearly" in msg


def test_one_point_repeated_refused():
    pts = np.tile([[0.3, 0.7]], (20, 1))
    msg = refused(lambda: thh.decompose(pts, field(pts)))
    assert "same point" in msg or "copies" in msg


def test_check_spread_accepts_areas():
    rng = np.random.default_rng(5)
    check_spread(rng.random((10, 2)))                       # few random points
    x, y = np.meshgrid(np.linspace(0, 1, 50), [0.0, 0.02])  # two rows of a lattice
    check_spread(np.c_[x.ravel(), y.ravel()])
    ring = np.c_[np.cos(np.linspace(0, 6, 30)), np.sin(np.linspace(0, 6, 30))]
    check_spread(ring)                                      # a ring: an area inside
    with pytest.raises(thh.InputError, match="lie on a line"):
        check_spread(np.c_[x[0], 1e-3 * x[0]])              # one row, slanted


@pytest.mark.parametrize("kind", ["bbox", "hull", "alpha"])
def test_domain_from_collinear_points_refused(kind):
    for pts in lines(30).values():
        msg = refused(lambda: domain_from_points(pts, kind))
        assert "lie on a line" in msg


# --------------------------------------------------------------------------- loops bounded
def test_boundary_sampler_with_local_spacing_is_bounded():
    """A boundary far longer than the finest spacing (a domain as thin as a
    line) evaluates the local spacing a bounded number of times."""
    calls = []

    def spacing_at(q):
        calls.append(len(q))
        return np.full(len(q), 0.05)

    thin = Polygon([(0.0, 0.0), (1.0, 0.3), (1.0, 0.3 + 1e-9), (0.0, 1e-9)])
    t = time.perf_counter()
    pts, nrm, _ = thin.sample_boundary(1e-10, spacing_at=spacing_at)
    assert time.perf_counter() - t < QUICK
    assert sum(calls) <= sampling.MAX_SPACING_EVALUATIONS + 8
    assert 30 < len(pts) < 60                       # 2 x 1.04 / 0.05 and the corners


def test_domain_too_narrow_for_the_points_refused():
    """A domain far narrower than the points' spacing (its boundary would take
    hours to sample) is refused before any sample is made.  Points spread
    over an area cannot lie in one (check_spread refuses them first), so the
    guard is called as collocation_particles calls it."""
    from taichi_hh.hhd.boundary import check_not_too_narrow
    sliver = Box((0.0, 0.0), (1.0, 1e-6))
    spacing = math.sqrt(sliver.area / 100)
    msg = refused(lambda: check_not_too_narrow(sliver, 100, spacing))
    assert "too narrow" in msg
    check_not_too_narrow(Box((0.0, 0.0), (1.0, 0.01)), 100, math.sqrt(0.01 / 100))


def test_boundary_covered_by_the_points_refused():
    """Every boundary sample within a quarter spacing of a data point: a clear
    refusal, not "boundary points is empty"."""
    s = np.linspace(0.0, 1.0, 101)[:-1]
    ring = np.concatenate([np.c_[s, 0 * s], np.c_[1 + 0 * s, s], np.c_[1 - s, 1 + 0 * s],
                           np.c_[0 * s, 1 - s]])
    rng = np.random.default_rng(4)
    pts = np.concatenate([ring, 0.1 + 0.8 * rng.random((100, 2))])
    box = Box((0.0, 0.0), (1.0, 1.0))
    spacing = math.sqrt(box.area / len(pts))
    msg = refused(lambda: collocation_particles(box, pts, spacing))
    assert "covered by the points" in msg


# --------------------------------------------------------------------------- copies
def square_points(n=150, seed=11):
    """Random points in [-0.5, 0.5]^2 with two opposite corners: the unit frame
    the public calls run in is then this very frame (centre 0, length 1), so
    coordinates in messages read the same whichever frame names them."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.5, 0.5, (n, 2))
    pts[0], pts[1] = (-0.5, -0.5), (0.5, 0.5)
    return pts


@pytest.mark.parametrize("copies", [2, 13, 50])
def test_copies_of_a_point_refused_naming_point_and_count(copies):
    pts = square_points()
    pts[40] = (0.25, -0.125)
    pts = np.concatenate([pts, np.tile(pts[40], (copies - 1, 1))])
    msg = refused(lambda: thh.decompose(pts, field(pts)))
    assert f"{copies} copies" in msg, msg
    assert "(0.25, -0.125)" in msg, msg
    assert re.search(r"\b40\b", msg) and re.search(r"\b150\b", msg), msg


@pytest.mark.parametrize("copies", [2, 13, 50])
def test_check_distinct_names_coordinates_and_count(copies):
    rng = np.random.default_rng(copies)
    pts = 1e3 + 50.0 * rng.random((300, 2))                 # any units, any offset
    dup = pts[123].copy()
    where = rng.choice(np.arange(300), copies - 1, replace=False)
    where = where[where != 123][: copies - 1]
    pts[where] = dup
    with pytest.raises(thh.InputError) as info:
        check_distinct(pts)
    msg = str(info.value)
    count = len(set(where.tolist()) | {123})
    assert f"{count} copies of the point ({dup[0]:.9g}, {dup[1]:.9g})" in msg, msg
    # the caller's row numbers, when the points are a selection of its rows
    first = min(set(where.tolist()) | {123})
    rows = np.arange(300) * 2 + 1
    with pytest.raises(thh.InputError, match=rf"duplicate points: points {2 * first + 1}\b"):
        check_distinct(pts, rows=rows)


def test_check_distinct_in_float64_whatever_the_precision():
    """Two points that single precision would round together but that are
    farther apart than the tolerance are distinct; closer ones are copies."""
    rng = np.random.default_rng(8)
    pts = rng.uniform(0.5, 1.0, (2500, 2))
    spacing = math.sqrt(np.prod(np.ptp(pts, axis=0)) / len(pts))
    tol = DUPLICATE_FRACTION * spacing
    pts[7] = pts[120] + [1.5 * tol, 0.0]
    assert (pts[7].astype(np.float32) == pts[120].astype(np.float32)).all()
    check_distinct(pts)                                     # not copies
    pts[7] = pts[120] + [0.5 * tol, 0.0]
    with pytest.raises(thh.InputError, match=r"points 7 and 120 are 2 points within"):
        check_distinct(pts)


def test_close_pair_on_lattices_is_quick():
    """A lattice, also one turned so that its rows lie across the search's sort
    direction (every row one projected value), costs a sort or two."""
    g = np.arange(300) / 299.0
    lattice = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    d = np.array([1.0, (1 + 5 ** 0.5) / 2]) / math.hypot(1.0, (1 + 5 ** 0.5) / 2)
    turn = np.array([[d[1], d[0]], [-d[0], d[1]]])          # rows across d
    for pts in (lattice, lattice @ turn):
        t = time.perf_counter()
        assert close_pair(pts, 1e-9) is None
        copy = np.vstack([pts, pts[4321]])
        assert close_pair(copy, 0.0) == (4321, len(pts))
        assert time.perf_counter() - t < QUICK


def test_copies_refused_by_pointset_in_any_number():
    pts = square_points(120, seed=3)
    for copies in (2, 13, 30):
        more = np.concatenate([pts, np.tile(pts[9], (copies - 1, 1))])
        with pytest.raises(thh.InputError, match=rf"{copies} copies") as info:
            thh.PointSet(more, support_neighbours=12)
        no_internal_names(str(info.value))


def test_close_screen_finds_every_planted_pair_and_agrees_with_the_sort(monkeypatch):
    """The O(N) screen that close_pair asks first from SCREEN_MIN_POINTS points
    on: no pair on distinct random points; a pair planted within the
    tolerance found wherever it lies, across a cell's side or corner
    included; close_pair's answer the same with the screen and without it;
    a cluster (a cell of more than MAX_CELL_POINTS) left to the sort."""
    from taichi_hh.arrays import bounds
    from taichi_hh.sph import close_screen, pointset
    rng = np.random.default_rng(11)
    n = 60_000
    pts = 1e3 + rng.random((n, 2)) * [2.0, 1.0]              # any offset
    lo, hi = bounds(pts)
    h = math.sqrt(float(np.prod(hi - lo)) / n)                 # the screen's cells
    tol = DUPLICATE_FRACTION * h
    assert close_screen.screen(pts, lo, hi, tol) is False
    for k in range(24):
        q = pts.copy()
        a, b = rng.choice(n, 2, replace=False)
        if k % 3 == 1:                                         # on a cell's corner
            q[a] = lo + np.round((q[a] - lo) / h) * h
        elif k % 3 == 2:                                       # on a cell's side
            q[a, 0] = lo[0] + np.round((q[a, 0] - lo[0]) / h) * h
        step = rng.normal(size=2)
        q[b] = q[a] + step / np.linalg.norm(step) * tol * rng.uniform(0.0, 0.99)
        lo_q, hi_q = bounds(q)
        assert close_screen.screen(q, lo_q, hi_q, tol) is True
        with_screen = close_pair(q, tol)
        monkeypatch.setattr(pointset, "SCREEN_MIN_POINTS", 10 ** 12)
        assert close_pair(q, tol) == with_screen == (min(a, b), max(a, b))
        monkeypatch.undo()
    cluster = pts.copy()
    cluster[:100] = pts[0] + rng.random((100, 2)) * 1e-3 * h
    assert close_screen.screen(cluster, *bounds(cluster), 0.0) is None
    assert close_pair(cluster, 0.0) is None
