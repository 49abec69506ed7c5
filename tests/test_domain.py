"""Domains (taichi_hh.geometry.domain): geometry, point queries and samplers against analytic
answers and brute force.  Pure numpy; no Taichi kernels run here."""
import pickle

import numpy as np
import pytest
from scipy.spatial import cKDTree

from taichi_hh.geometry.domain import Box, Polygon, as_domain
from taichi_hh.errors import InputError

UNIT = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
HOLE_A = [[0.2, 0.2], [0.4, 0.2], [0.4, 0.4], [0.2, 0.4]]          # side 0.2
HOLE_B = [[0.6, 0.5], [0.9, 0.5], [0.9, 0.8], [0.6, 0.8]]          # side 0.3


def ngon(center, radius, n, phase=0.0):
    a = phase + 2 * np.pi * np.arange(n) / n
    return np.asarray(center) + radius * np.c_[np.cos(a), np.sin(a)]


# ---- independent references ---------------------------------------------------------
def brute_distance(points, rings):
    """Unsigned distance to the rings' segments, straight from the definition."""
    best = np.full(len(points), np.inf)
    for ring in rings:
        ring = np.asarray(ring, float)
        for a, b in zip(ring, np.roll(ring, -1, axis=0)):
            d = b - a
            t = np.clip((points - a) @ d / (d @ d), 0, 1)
            best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * d), axis=1))
    return best


def even_odd_inside(points, rings):
    """Crossing-number parity over all rings (holes flip it back)."""
    inside = np.zeros(len(points), dtype=bool)
    x, y = points[:, 0], points[:, 1]
    for ring in rings:
        ring = np.asarray(ring, float)
        for a, b in zip(ring, np.roll(ring, -1, axis=0)):
            cond = (a[1] > y) != (b[1] > y)
            with np.errstate(divide="ignore", invalid="ignore"):
                xc = a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
            inside ^= cond & (x < xc)
    return inside


def box_sd(p, lo, hi):
    """Exact signed distance to an axis-aligned box."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    q = np.maximum(lo - p, p - hi)
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


@pytest.fixture(scope="module")
def holed():
    return Polygon(UNIT, holes=[HOLE_A, HOLE_B])


@pytest.fixture(scope="module")
def annulus():
    return Polygon(ngon((0.5, 0.5), 0.45, 64), holes=[ngon((0.5, 0.5), 0.2, 32)])


# ---- geometry -------------------------------------------------------------------------
def test_box_geometry_and_value_semantics():
    b = Box((-1.0, 0.5), (2.0, 1.5))
    assert b.lo == (-1.0, 0.5) and b.hi == (2.0, 1.5)
    assert b.area == pytest.approx(3.0, rel=1e-15)
    assert b.perimeter == pytest.approx(8.0, rel=1e-15)
    assert b.bounds == ((-1.0, 0.5), (2.0, 1.5))
    assert repr(b) == "Box(lo=(-1.0, 0.5), hi=(2.0, 1.5))"
    assert b == Box([-1, 0.5], np.array([2, 1.5])) and hash(b) == hash(Box((-1, 0.5), (2, 1.5)))
    assert pickle.loads(pickle.dumps(b)) == b
    with pytest.raises(AttributeError):
        b.lo = (0.0, 0.0)
    with pytest.raises(ValueError):
        b.outer[0, 0] = 5.0                       # read-only arrays
    starts, ends = b.segments()
    assert starts.shape == (4, 2) and np.array_equal(starts[0], [-1.0, 0.5])


@pytest.mark.parametrize("outer, holes, area, perimeter", [
    ([[0, 0], [4, 0], [0, 3]], [], 6.0, 12.0),
    ([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], [], 3.0, 8.0),       # L shape
    (UNIT, [HOLE_A], 1.0 - 0.04, 4.0 + 0.8),
    (UNIT, [HOLE_A, HOLE_B], 1.0 - 0.04 - 0.09, 4.0 + 0.8 + 1.2),
])
def test_area_and_perimeter(outer, holes, area, perimeter):
    for o in (outer, outer[::-1]):                               # either orientation
        for hs in (holes, [h[::-1] for h in holes]):
            p = Polygon(o, holes=hs)
            assert p.area == pytest.approx(area, rel=1e-14)
            assert p.perimeter == pytest.approx(perimeter, rel=1e-14)


def test_orientation_normalised_interior_left(holed):
    p = Polygon(UNIT[::-1], holes=[HOLE_A, HOLE_B[::-1]])
    assert p.area == holed.area and p != holed          # same region, other vertex 0
    signed = [0.5 * np.sum(r[:, 0] * np.roll(r[:, 1], -1) - np.roll(r[:, 0], -1) * r[:, 1])
              for r in p.rings]
    assert signed[0] > 0 and all(s < 0 for s in signed[1:])
    assert np.array_equal(p.outer[0], UNIT[-1])                  # vertex 0 kept first
    starts, ends = p.segments()
    d = ends - starts
    mid = 0.5 * (starts + ends)
    left = np.c_[-d[:, 1], d[:, 0]] / np.linalg.norm(d, axis=1)[:, None]
    assert p.contains(mid + 1e-3 * left).all()
    assert not p.contains(mid - 1e-3 * left).any()
    assert np.array_equal(p.segment_piece(), np.repeat([0, 1, 2], 4))
    assert "holes=[[" in repr(p) and pickle.loads(pickle.dumps(p)) == p


def test_closed_ring_accepted():
    assert Polygon(UNIT + [UNIT[0]]) == Polygon(UNIT)


# ---- point queries ------------------------------------------------------------------
def test_contains_box_edges_vertices():
    b = Box((0, 0), (1, 1))
    pts = np.array([[0.5, 0.5], [0, 0], [1, 1], [1, 0], [0.5, 0], [1, 0.3], [0, 0.999],
                    [-1e-9, 0.5], [0.5, 1 + 1e-9], [2, 2], [-0.1, -0.1], [1.0 + 1e-3, 0.5]])
    want = [True] * 7 + [False] * 5
    assert b.contains(pts).tolist() == want
    assert b.contains(pts, tol=2e-3).tolist() == [True] * 9 + [False, False, True]
    assert b.contains(np.zeros((0, 2))).shape == (0,)


def test_contains_with_holes(holed):
    pts = np.array([[0.1, 0.1], [0.3, 0.3], [0.75, 0.65], [0.2, 0.3], [0.4, 0.4], [0.9, 0.5],
                    [0.5, 0.45], [0.3, 0.2 + 1e-9], [0.6 + 1e-6, 0.7]])
    assert holed.contains(pts).tolist() == [True, False, False, True, True, True, True,
                                           False, False]
    rng = np.random.default_rng(3)
    q = rng.uniform(-0.2, 1.2, (4000, 2))
    assert np.array_equal(holed.contains(q), even_odd_inside(q, holed.rings))


def test_signed_distance_box_exact():
    lo, hi = (-0.5, 0.25), (1.5, 1.0)
    b = Box(lo, hi)
    rng = np.random.default_rng(0)
    p = np.vstack([rng.uniform(-3, 4, (20000, 2)), rng.uniform(-0.5, 1.5, (5000, 2))])
    np.testing.assert_allclose(b.signed_distance(p), box_sd(p, lo, hi), rtol=0, atol=1e-14)
    assert b.signed_distance([[0.5, 0.25], [-0.5, 1.0]]).tolist() == [0.0, 0.0]


def test_signed_distance_annulus(annulus):
    rng = np.random.default_rng(1)
    p = np.vstack([rng.uniform(-0.5, 1.5, (30000, 2)),
                   annulus.outer + rng.normal(0, 1e-7, annulus.outer.shape)])
    sd = annulus.signed_distance(p)
    d = brute_distance(p, annulus.rings)
    np.testing.assert_allclose(np.abs(sd), d, rtol=0, atol=1e-14)
    inside = even_odd_inside(p, annulus.rings)
    far = d > 1e-12
    assert np.array_equal(sd[far] < 0, inside[far])
    # and close to the annulus of the circumscribed circles (polygon sagitta)
    rho = np.linalg.norm(p - 0.5, axis=1)
    exact = np.maximum(rho - 0.45, 0.2 - rho)
    exact = np.where((rho > 0.2) & (rho < 0.45), -np.minimum(0.45 - rho, rho - 0.2), exact)
    sag = max(0.45 * (1 - np.cos(np.pi / 64)), 0.2 * (1 - np.cos(np.pi / 32)))
    assert np.abs(sd - exact).max() <= sag + 1e-12
    assert annulus.area == pytest.approx(0.5 * 64 * 0.45 ** 2 * np.sin(2 * np.pi / 64)
                                         - 0.5 * 32 * 0.2 ** 2 * np.sin(2 * np.pi / 32))


def test_signed_distance_concave_and_far_points():
    rng = np.random.default_rng(5)
    a = np.sort(rng.uniform(0, 2 * np.pi, 150))
    star = np.c_[np.cos(a), np.sin(a)] * (1 + 0.4 * rng.uniform(-1, 1, 150))[:, None]
    p = Polygon(star, holes=[ngon((0, 0), 0.1, 7)])
    q = np.vstack([rng.uniform(-1.6, 1.6, (20000, 2)), rng.uniform(-50, 50, (500, 2))])
    sd = p.signed_distance(q)
    d = brute_distance(q, p.rings)
    np.testing.assert_allclose(np.abs(sd), d, rtol=1e-14, atol=1e-14)
    assert np.array_equal(sd[d > 1e-12] < 0, even_odd_inside(q, p.rings)[d > 1e-12])
    assert np.array_equal(p.contains(q), sd <= p.boundary_tolerance)


def test_closest_boundary_points_and_normals(annulus):
    rng = np.random.default_rng(2)
    p = rng.uniform(-0.2, 1.2, (5000, 2))
    dist, q, n, seg = annulus.closest_boundary(p)
    np.testing.assert_allclose(dist, np.linalg.norm(p - q, axis=1), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-14)
    assert np.abs(annulus.signed_distance(q)).max() < 1e-14                # on the boundary
    eps = 1e-6
    assert not annulus.contains(q + eps * n).any()                         # outward
    assert annulus.contains(q - eps * n).all()
    starts, ends = annulus.segments()
    d = ends - starts
    t = np.einsum("ij,ij->i", q - starts[seg], d[seg]) / np.einsum("ij,ij->i", d[seg], d[seg])
    interior = (t > 1e-9) & (t < 1 - 1e-9)
    assert interior.sum() > 1000 and (~interior).sum() > 10
    # away from vertices: perpendicular to the edge and along p - q
    np.testing.assert_allclose(np.einsum("ij,ij->i", n[interior], d[seg[interior]]), 0,
                               atol=1e-14)
    v = (p - q)[interior] / dist[interior, None]
    cross = v[:, 0] * n[interior, 1] - v[:, 1] * n[interior, 0]
    assert np.abs(cross).max() < 1e-9
    # at vertices: normalised average of the two adjacent segment normals
    nrm = annulus.segment_normals()
    checked = 0
    for k in np.flatnonzero(~interior):
        out_seg = np.flatnonzero((starts == q[k]).all(axis=1))     # q is exactly a vertex
        in_seg = np.flatnonzero((ends == q[k]).all(axis=1))
        assert len(out_seg) == 1 and len(in_seg) == 1
        avg = nrm[out_seg[0]] + nrm[in_seg[0]]
        np.testing.assert_allclose(n[k], avg / np.linalg.norm(avg), atol=1e-14)
        checked += 1
    assert checked > 10


def test_box_corner_normal_and_sign():
    b = Box((0, 0), (1, 1))
    dist, q, n, seg = b.closest_boundary([[2.0, 2.0], [-1.0, 0.5], [0.5, 0.4]])
    np.testing.assert_allclose(q, [[1, 1], [0, 0.5], [0.5, 0]], atol=1e-15)
    np.testing.assert_allclose(n, [[2 ** -0.5, 2 ** -0.5], [-1, 0], [0, -1]], atol=1e-15)
    np.testing.assert_allclose(dist, [2 ** 0.5, 1.0, 0.4], atol=1e-15)


def test_closest_wall_is_nan_only_where_a_corner_is_closest():
    b = Box((0, 0), (1, 1))
    dist, n = b.closest_wall([[0.5, 0.01], [0.02, 0.5], [0.5, 0.0], [0.03, 0.01]])
    np.testing.assert_allclose(dist, [0.01, 0.02, 0.0, 0.01], atol=1e-15)
    np.testing.assert_allclose(n, [[0, -1], [-1, 0], [0, -1], [0, -1]], atol=1e-15)
    # a square hole's corner, seen from the domain: on its diagonal the vertex
    # normal points along the way to it; off the diagonal the corner is still
    # the closest boundary point, but no single wall's
    holed = Polygon(UNIT, holes=[[(0.4, 0.4), (0.4, 0.6), (0.6, 0.6), (0.6, 0.4)]])
    dist, n = holed.closest_wall([[0.62, 0.62], [0.62, 0.63], [0.5, 0.61]])
    np.testing.assert_allclose(dist[0], 0.02 * 2 ** 0.5, atol=1e-15)
    assert np.isnan(dist[1]) and np.isnan(n[1]).all()
    np.testing.assert_allclose(n[2], [0, -1], atol=1e-15)
    # a finely segmented circle: its vertices pass (normal within acos(0.999))
    disc = Polygon(ngon((0, 0), 1.0, 400))
    angle = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    p = 0.97 * np.c_[np.cos(angle), np.sin(angle)]
    dist, n = disc.closest_wall(p)
    assert np.isfinite(dist).all()
    np.testing.assert_allclose((n * p).sum(axis=1) / 0.97, 1.0, atol=1e-3)



def test_closest_wall_on_a_corner_bisector_is_the_corner_whatever_the_rounding():
    """A point equally far from two adjacent walls (on the bisector of
    their corner; the hull's vertices' data points are, by construction) gets
    the corner and its averaged normal, the same when it moves by a few ulps:
    the search's choice between the two walls was rounding's (the positive
    rows' wall term, and d and r with it, jumped by up to 10%)."""
    from taichi_hh.geometry.from_points import convex_hull, domain_from_points
    b = Box((0, 0), (1, 1))
    on = np.array([[0.1, 0.1], [0.7, 0.3]])           # the corners (0, 0) and (1, 0)
    corner_normals = np.array([[-1.0, -1.0], [1.0, -1.0]]) * 2 ** -0.5
    for p in (on, np.nextafter(on, 1.0), np.nextafter(on, 0.0), on * (1 + 2e-16)):
        dist, n = b.closest_wall(p)
        np.testing.assert_allclose(dist, [0.1 * 2 ** 0.5, 0.3 * 2 ** 0.5], rtol=1e-14)
        np.testing.assert_allclose(n, corner_normals, atol=1e-15)
        # closest_boundary reports the averaged normal there too
        np.testing.assert_allclose(b.closest_boundary(p)[2], corner_normals, atol=1e-15)
    # off the bisector (by more than the tie tolerance) a single wall, as before
    dist, n = b.closest_wall([[0.1, 0.1 + 1e-6], [0.02, 0.5]])
    np.testing.assert_allclose(dist, [0.1, 0.02], rtol=1e-12)
    np.testing.assert_allclose(n, [[-1, 0], [-1, 0]], atol=1e-15)
    # the hull of random points, moved out along its vertices' bisectors: each
    # vertex's data point gets that corner, the same for points moved by ulps
    rng = np.random.default_rng(5)
    pts = rng.random((300, 2))
    answers = []
    for p in (pts, np.nextafter(pts, 2.0), pts * (1 + 2e-16),
              pts + rng.uniform(-2.2e-16, 2.2e-16, pts.shape)):
        dom = domain_from_points(p, "hull")
        hull = convex_hull(p)
        dist, n = dom.closest_wall(hull)
        near = np.linalg.norm(dom.outer[:, None] - hull[None], axis=2).argmin(axis=0)
        np.testing.assert_allclose(dist, np.linalg.norm(dom.outer[near] - hull, axis=1),
                                   rtol=1e-9)
        np.testing.assert_allclose(n, dom.segment_table.vertex_normal_start[near], atol=1e-12)
        answers.append((dist, n))
    for dist, n in answers[1:]:
        np.testing.assert_allclose(dist, answers[0][0], rtol=1e-12)
        np.testing.assert_allclose(n, answers[0][1], atol=1e-12)


# ---- boundary samples -----------------------------------------------------------------
def test_sample_boundary_follows_a_local_spacing():
    # spacing 0.01 at x = 0 rising to 0.05 at x = 2: gaps follow it to within 3%
    # (each side rounded into whole gaps: 1% here); the corners stay samples
    box = Box((0, 0), (2, 1))
    def wanted(q):
        return 0.01 + 0.02 * q[:, 0]
    pts, nrm, piece = box.sample_boundary(0.04, spacing_at=wanted)     # resolves 0.01
    assert np.abs(box.signed_distance(pts)).max() < 1e-12
    gaps = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    mid = 0.5 * (pts + np.roll(pts, -1, axis=0))
    ratio = gaps / wanted(mid)
    assert 0.97 < ratio.min() and ratio.max() < 1.03, (ratio.min(), ratio.max())
    corners = np.array([[0, 0], [2, 0], [2, 1], [0, 1]], float)
    assert cKDTree(pts).query(corners)[0].max() == 0.0
    # a side's samples: its length over the mean spacing, rounded up
    bottom = pts[(np.abs(pts[:, 1]) < 1e-12)]
    n_expected = np.log(0.05 / 0.01) / 0.02                # integral of dx / (0.01 + 0.02 x)
    assert abs(len(bottom) - 1 - n_expected) <= 2
    with pytest.raises(InputError, match="spacing_at"):
        box.sample_boundary(0.05, spacing_at=lambda q: np.zeros(len(q)))


@pytest.mark.parametrize("dom, spacing", [
    (Box((0, 0), (2, 1)), 0.07),
    (Polygon(UNIT, holes=[HOLE_A, HOLE_B]), 0.03),
    (Polygon(ngon((0, 0), 1.0, 40), holes=[ngon((0.1, 0), 0.3, 200)]), 0.05),
])
def test_sample_boundary(dom, spacing):
    pts, nrm, piece = dom.sample_boundary(spacing)
    assert np.abs(dom.signed_distance(pts)).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-14)
    assert not dom.contains(pts + 1e-6 * nrm).any() and dom.contains(pts - 1e-6 * nrm).all()
    assert set(piece.tolist()) == set(range(len(dom.rings)))
    for k, ring in enumerate(dom.rings):
        r = pts[piece == k]
        gaps = np.linalg.norm(np.roll(r, -1, axis=0) - r, axis=1)
        assert gaps.min() >= 0.5 * spacing and gaps.max() <= spacing * (1 + 1e-12)
        # corners (turning by more than 10 degrees) are samples, with averaged normals
        e_in = ring - np.roll(ring, 1, axis=0)
        e_out = np.roll(ring, -1, axis=0) - ring
        cos = np.einsum("ij,ij->i", e_in, e_out) / np.linalg.norm(e_in, axis=1) / np.linalg.norm(
            e_out, axis=1)
        corners = ring[cos < np.cos(np.radians(10))]
        if len(corners) == 0:                  # smooth ring: starts at its vertex 0
            corners, cos = ring[:1], np.r_[-1.0, np.ones(len(ring) - 1)]
        tree = cKDTree(r)
        dd, idx = tree.query(corners)
        assert dd.max() == 0.0
        def right(e):
            return np.c_[e[:, 1], -e[:, 0]] / np.linalg.norm(e, axis=1)[:, None]
        avg = right(e_in) + right(e_out)
        avg = (avg / np.linalg.norm(avg, axis=1)[:, None])[cos < np.cos(np.radians(10))]
        np.testing.assert_allclose(nrm[piece == k][idx], avg, atol=1e-14)


def test_sample_boundary_box_corner_normals():
    pts, nrm, piece = Box((0, 0), (1, 1)).sample_boundary(0.25)
    assert len(pts) == 16 and (piece == 0).all()
    corner = np.flatnonzero((pts == [1.0, 1.0]).all(axis=1))
    np.testing.assert_allclose(nrm[corner[0]], [2 ** -0.5, 2 ** -0.5])
    mid = np.flatnonzero((pts == [0.5, 0.0]).all(axis=1))
    np.testing.assert_allclose(nrm[mid[0]], [0.0, -1.0])


# ---- ghosts -----------------------------------------------------------------------
@pytest.mark.parametrize("dom, spacing, width", [
    (Box((0, 0), (1, 1)), 0.02, 0.06),
    (Polygon(UNIT, holes=[HOLE_A, HOLE_B]), 0.015, 0.05),
    (Polygon(ngon((0.5, 0.5), 0.45, 64), holes=[ngon((0.5, 0.5), 0.2, 32)]), 0.01, 0.03),
])
def test_sample_ghosts_blue_noise_band(dom, spacing, width):
    g = dom.sample_ghosts(spacing, width, seed=4)
    sd = dom.signed_distance(g)
    assert (sd > 0).all() and (sd <= width).all()
    assert not dom.contains(g).any()
    tree = cKDTree(g)
    d, _ = tree.query(g, k=2)
    assert d[:, 1].min() >= 0.9 * spacing
    lo = np.array(dom.bounds[0]) - width
    hi = np.array(dom.bounds[1]) + width
    xs, ys = np.meshgrid(np.arange(lo[0], hi[0], spacing / 3), np.arange(lo[1], hi[1], spacing / 3))
    probe = np.c_[xs.ravel(), ys.ravel()]
    s = dom.signed_distance(probe)
    probe = probe[(s > 0) & (s <= width)]
    gap, _ = tree.query(probe)
    assert gap.max() <= 2 * spacing
    if dom.holes:                                     # ghosts fill the holes' rims too
        inside_holes = even_odd_inside(g, dom.holes)
        assert inside_holes.sum() > 0.1 * len(g)
    np.testing.assert_array_equal(g, dom.sample_ghosts(spacing, width, seed=4))
    assert not np.array_equal(g[:50], dom.sample_ghosts(spacing, width, seed=5)[:50])


def test_sample_ghosts_avoid():
    b = Box((0, 0), (1, 1))
    inner = b.sample_interior(0.03, seed=1)
    g = b.sample_ghosts(0.03, 0.09, avoid=inner)
    d, _ = cKDTree(inner).query(g)
    assert d.min() >= 0.03
    both = np.vstack([g, inner])
    d2, _ = cKDTree(both).query(both, k=2)
    assert d2[:, 1].min() >= 0.03


def test_mirror_ghosts_box_exact():
    b = Box((0, 0), (2, 1))
    w = 0.1
    p = np.array([[1.0, 0.5], [0.04, 0.5], [1.0, 0.97], [0.05, 0.02], [1.95, 0.93], [0.0, 0.5]])
    g, src = b.sample_ghosts_mirror(p, w)
    counts = np.bincount(src, minlength=len(p))
    assert counts.tolist() == [0, 1, 1, 3, 3, 0]           # sides, corners; none on the wall
    expect = {(-0.04, 0.5), (1.0, 1.03), (-0.05, 0.02), (0.05, -0.02), (-0.05, -0.02),
              (2.05, 0.93), (1.95, 1.07), (2.05, 1.07)}
    got = {(round(x, 12), round(y, 12)) for x, y in g}
    assert got == expect
    # exact reflections: each coordinate either kept or mirrored about a wall
    for (gx, gy), k in zip(g, src):
        px, py = p[k]
        assert gx in (px, -px, 4.0 - px) and gy in (py, -py, 2.0 - py)
    assert not b.contains(g).any()
    q = b.sample_interior(2000, kind="random", seed=3)
    g, src = b.sample_ghosts_mirror(q, w)
    near = np.minimum(np.minimum(q[:, 0], 2 - q[:, 0]), np.minimum(q[:, 1], 1 - q[:, 1])) <= w
    assert set(src.tolist()) == set(np.flatnonzero(near).tolist())
    assert (b.signed_distance(g) > 0).all()


def test_mirror_ghosts_polygon_reflect_across_closest_segment():
    tri = Polygon([[0, 0], [2, 0], [0, 1.5]])
    q = tri.sample_interior(3000, kind="random", seed=2)
    w = 0.1
    g, src = tri.sample_ghosts_mirror(q, w)
    dist, _, _, seg = tri.closest_boundary(q)
    assert set(src.tolist()) <= set(np.flatnonzero(dist <= w).tolist())
    assert len(src) > 0.9 * np.count_nonzero(dist <= w)
    starts, ends = tri.segments()
    a, b = starts[seg[src]], ends[seg[src]]
    mid = 0.5 * (q[src] + g)
    d = b - a
    # the midpoint lies on the segment's line and g - p is perpendicular to it
    on_line = (d[:, 0] * (mid[:, 1] - a[:, 1]) - d[:, 1] * (mid[:, 0] - a[:, 0]))
    assert np.abs(on_line).max() < 1e-12
    assert np.abs(np.einsum("ij,ij->i", g - q[src], d)).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(g - q[src], axis=1), 2 * dist[src], atol=1e-12)
    assert (tri.signed_distance(g) > 0).all()


# ---- interior samples ---------------------------------------------------------------
@pytest.mark.parametrize("dom", [Box((0, 0), (1, 1)), Polygon(UNIT, holes=[HOLE_A, HOLE_B]),
                                 Polygon(ngon((0.5, 0.5), 0.45, 64),
                                         holes=[ngon((0.5, 0.5), 0.2, 32)])])
@pytest.mark.parametrize("kind", ["poisson", "jittered", "random"])
def test_sample_interior_counts(dom, kind):
    n = 3000
    p = dom.sample_interior(n, kind=kind, seed=7)
    assert (dom.signed_distance(p) < 0).all()
    assert abs(len(p) - n) <= 0.1 * n
    if kind == "random":
        assert len(p) == n
    d, _ = cKDTree(p).query(p, k=2)
    h = np.sqrt(dom.area / n)
    if kind == "poisson":
        assert d[:, 1].min() >= 0.75 * h and d[:, 1].max() <= 2.5 * h
    elif kind == "jittered":
        assert d[:, 1].min() >= 0.45 * h
    np.testing.assert_array_equal(p, dom.sample_interior(n, kind=kind, seed=7))
    assert not np.array_equal(p, dom.sample_interior(n, kind=kind, seed=8))


def test_sample_interior_spacing_and_margin():
    b = Box((0, 0), (1, 1))
    p = b.sample_interior(0.02, seed=1)
    d, _ = cKDTree(p).query(p, k=2)
    assert d[:, 1].min() >= 0.02 and d[:, 1].max() < 0.04
    assert abs(len(p) - 0.633 / 0.02 ** 2) < 0.05 * len(p)
    lat = b.sample_interior(0.1, kind="jittered", jitter=0.0)
    assert len(lat) == 100 and np.allclose(np.sort(np.unique(lat[:, 0])), 0.05 + 0.1 * np.arange(10))
    for kind in ("poisson", "jittered", "random"):
        q = b.sample_interior(0.02, kind=kind, margin=0.05, seed=2)
        assert (b.signed_distance(q) <= -0.05).all() and len(q) > 100


def test_blue_noise_13k_unit_square():
    p = Box((0, 0), (1, 1)).sample_interior(13000, seed=0)
    assert abs(len(p) - 13000) <= 0.05 * 13000
    d, _ = cKDTree(p).query(p, k=2)
    r = d[:, 1].min()
    assert r >= 0.75 / np.sqrt(13000) and d[:, 1].mean() < 1.2 * r


def test_import_paths_and_the_parts_agree(holed):
    """The split modules are one implementation: every import path gives the same
    classes, and the public pieces (segment table, locator, disc classification)
    agree with the queries built on them."""
    import taichi_hh
    from taichi_hh import geometry
    from taichi_hh.geometry import box, polygon
    assert geometry.Box is Box is box.Box is taichi_hh.Box
    assert geometry.Polygon is Polygon is polygon.Polygon is taichi_hh.Polygon
    assert geometry.as_domain is as_domain
    segs = holed.segment_table
    assert len(segs) == 12 and list(segs.ring_start) == [0, 4, 8, 12]
    with pytest.raises(ValueError):
        segs.starts[0, 0] = 5.0                            # read-only
    np.testing.assert_array_equal(segs.normal, holed.segment_normals())
    p = np.random.default_rng(2).uniform(-0.2, 1.2, (2000, 2))
    sd = holed.signed_distance(p)
    st = holed.classify_discs(p, 0.05, -np.inf, 0.0)
    assert (st == 1).sum() and (st == 0).sum() and (st == 2).sum()
    assert np.all(sd[st == 1] <= -0.05) and np.all(sd[st == 0] >= 0.05)
    np.testing.assert_array_equal(holed.classify_discs(p, 0.0, -np.inf, 0.0) == 1, sd <= 0)
    loc = holed.locator()
    assert loc.covers(*map(np.array, holed.bounds))
    wide = holed.locator(np.array([-3.0, -3.0]), np.array([4.0, 4.0]))
    assert wide.covers(np.array([-3.0, -3.0]), np.array([4.0, 4.0])) and holed.locator() is wide
    np.testing.assert_allclose(holed.signed_distance(p), sd, rtol=0, atol=0)


def test_poisson_disk_band_is_maximal():
    """Every point of the band lies within 2 r of a sample (maximality) and no two
    samples are closer than r."""
    from taichi_hh.geometry.poisson_disk import poisson_disk
    d = Polygon(UNIT, holes=[HOLE_B])
    r = 0.03
    pts = poisson_disk(d, r, -np.inf, -0.01, np.random.default_rng(5))
    assert np.all(d.signed_distance(pts) <= -0.01)
    dd, _ = cKDTree(pts).query(pts, k=2)
    assert dd[:, 1].min() >= r
    probe = d.sample_interior(0.005, "jittered", seed=1, margin=0.01)
    far, _ = cKDTree(pts).query(probe)
    assert far.max() < 2 * r


def test_as_domain():
    assert as_domain((0, 0, 2, 1)) == Box((0, 0), (2, 1))
    assert as_domain(UNIT) == Polygon(UNIT)
    b = Box((0, 0), (1, 1))
    assert as_domain(b) is b
    with pytest.raises(InputError, match="cannot make a domain"):
        as_domain("box")


# ---- validation -------------------------------------------------------------------------
@pytest.mark.parametrize("outer, holes, match", [
    ([[0, 0], [1, 0]], [], "at least 3"),
    ([[0, 0], [1, 0], [0, 0]], [], "at least 3"),
    ([[0, 0], [1, 0], [1, 0], [0, 1]], [], "repeats vertex 1"),
    ([[0, 0], [1, np.nan], [0, 1]], [], "non-finite"),
    ([[0, 0], [1, np.inf], [0, 1]], [], "non-finite"),
    ([[0, 0], [1, 1], [2, 2]], [], "degenerate"),
    ([[0, 0], [1, 1], [1, 0], [0, 1]], [], "degenerate.*crossing"),      # symmetric bow tie
    ([[0, 0], [2, 2], [2, 0], [0, 1]], [], "intersects itself"),                  # bow tie
    ([[0, 0], [2, 0], [1, 0], [1, 1]], [], "folds back|intersects itself"),
    ([[0, 0], [2, 0], [2, 2], [1, 2], [1, -1], [0, 2]], [], "intersects itself"),
    (UNIT, [[[2, 2], [3, 2], [3, 3]]], "outside the outer ring"),
    (UNIT, [[[0.5, 0.5], [1.5, 0.5], [1.5, 0.6]]], "intersect"),
    (UNIT, [[[0, 0.5], [0.5, 0.4], [0.5, 0.6]]], "touch"),
    (UNIT, [HOLE_A, [[0.3, 0.3], [0.5, 0.3], [0.5, 0.5]]], "intersect"),
    (UNIT, [[[0.1, 0.1], [0.9, 0.1], [0.9, 0.9], [0.1, 0.9]], HOLE_A], "inside holes\\[0\\]"),
    ("abc", [], "vertex coordinates"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [], "shape"),
    (UNIT, np.array(HOLE_A), "list"),
    (UNIT, [[[0.2, 0.2], [0.3, 0.2]]], "holes\\[0\\] needs at least 3"),
    (UNIT, 5, "sequence"),
])
def test_polygon_validation(outer, holes, match):
    with pytest.raises(InputError, match=match):
        Polygon(outer, holes=holes)


@pytest.mark.parametrize("lo, hi, match", [
    ((0, 0), (0, 1), "lo < hi"), ((1, 0), (0, 1), "lo < hi"), ((0, 0, 0), (1, 1), "two coord"),
    ((0, np.nan), (1, 1), "finite"), ("ab", (1, 1), "two coord"),
])
def test_box_validation(lo, hi, match):
    with pytest.raises(InputError, match=match):
        Box(lo, hi)


def test_query_and_sampler_validation():
    b = Box((0, 0), (1, 1))
    for bad, match in [(np.zeros(4), "shape"), (np.zeros((3, 3)), "shape"),
                       ([[0, np.nan]], "non-finite.*index 0"), ("x", "numeric")]:
        for f in (b.contains, b.signed_distance, b.closest_boundary):
            with pytest.raises(InputError, match=match):
                f(bad)
    with pytest.raises(InputError, match="tol"):
        b.contains([[0.5, 0.5]], tol=-1)
    for bad in (0, -0.1, np.inf, np.nan, "a", None, True):
        with pytest.raises(InputError, match="spacing"):
            b.sample_boundary(bad)
        with pytest.raises(InputError, match="spacing"):
            b.sample_ghosts(bad, 0.1)
        with pytest.raises(InputError, match="width"):
            b.sample_ghosts(0.1, bad)
        with pytest.raises(InputError, match="width"):
            b.sample_ghosts_mirror([[0.5, 0.5]], bad)
    with pytest.raises(InputError, match="corner_angle"):
        b.sample_boundary(0.1, corner_angle=200)
    with pytest.raises(InputError, match="too small"):
        b.sample_ghosts(1e-6, 0.1)
    with pytest.raises(InputError, match="seed"):
        b.sample_ghosts(0.1, 0.1, seed=-1)
    with pytest.raises(InputError, match="avoid"):
        b.sample_ghosts(0.1, 0.1, avoid=[[0.0, np.inf]])
    with pytest.raises(InputError, match="lie in the domain.*index 1"):
        b.sample_ghosts_mirror([[0.5, 0.5], [1.5, 0.5]], 0.1)
    with pytest.raises(InputError, match="kind"):
        b.sample_interior(100, kind="halton")
    for bad, match in [(0, "at least 1"), (-5, "at least 1"), (-0.1, "spacing"),
                       (np.nan, "spacing"), (True, "count"), ("10", "spacing"), (10 ** 9, "5e7")]:
        with pytest.raises(InputError, match=match):
            b.sample_interior(bad)
    with pytest.raises(InputError, match="jitter"):
        b.sample_interior(100, kind="jittered", jitter=1.5)
    with pytest.raises(InputError, match="margin"):
        b.sample_interior(100, margin=-0.1)
    with pytest.raises(InputError, match="margin 0.6 leaves no room"):
        b.sample_interior(100, margin=0.6)
    with pytest.raises(InputError, match="n must be"):
        Polygon.circle(n=2)


@pytest.mark.parametrize("radius, lo, hi", [
    (0.0, -np.inf, None), (0.0, -np.inf, -0.01), (0.0, -np.inf, 0.2), (0.0, 1e-3, np.inf),
    (0.0, -0.1, 0.2), (0.05, -np.inf, 0.0), (0.02, -0.1, 0.1), (0.3, 0.01, 0.2)])
def test_box_classifies_discs_as_the_polygon_of_its_corners(radius, lo, hi):
    """Box.classify_discs (closed form, no locator) gives the polygon's answer
    on the same rectangle for points inside, outside, on the sides, on the
    corners and in the grown corners' quarter discs."""
    box = Box((-0.5, 0.25), (1.5, 1.25))
    poly = Polygon(np.array([[-0.5, 0.25], [1.5, 0.25], [1.5, 1.25], [-0.5, 1.25]]))
    rng = np.random.default_rng(4)
    p = rng.uniform([-0.9, -0.15], [1.9, 1.65], (20000, 2))
    p[:400] = rng.uniform([-0.5, 0.25], [1.5, 1.25], (400, 2))
    p[:100, 0], p[100:200, 0], p[200:300, 1], p[300:400, 1] = -0.5, 1.5, 0.25, 1.25
    p[400:404] = [[-0.5, 0.25], [1.5, 0.25], [1.5, 1.25], [-0.5, 1.25]]
    angle = rng.uniform(0.0, 0.5 * np.pi, 400)
    p[404:804] = [1.5, 1.25] + rng.uniform(0.0, 0.25, 400)[:, None] * np.c_[np.cos(angle),
                                                                             np.sin(angle)]
    hi = box.boundary_tolerance if hi is None else hi
    got = box.classify_discs(p, radius, lo, hi)
    np.testing.assert_array_equal(got, poly.classify_discs(p, radius, lo, hi))
    assert len(np.unique(got)) > 1
    np.testing.assert_array_equal(box.contains(p), poly.contains(p))


@pytest.mark.parametrize("radius, lo, hi", [
    (0.0, -np.inf, None), (0.0, -np.inf, -0.01), (0.05, -np.inf, 0.0), (0.0, 1e-3, np.inf),
    (0.02, -0.1, 0.1), (0.3, 0.01, 0.2)])
def test_polygon_classification_kernel_is_the_numpy_steps(monkeypatch, radius, lo, hi):
    """The whole-cell decisions of classify_discs as a Taichi kernel (taken
    from cell_decisions.KERNEL_MIN_POINTS points on) give the numpy steps'
    answer, point for point, on a holed polygon; points beyond the locator's
    grid included."""
    from taichi_hh.geometry import cell_decisions
    holed = Polygon(UNIT, holes=[HOLE_A, HOLE_B])
    p = np.random.default_rng(5).uniform(-0.6, 1.6, (30000, 2))
    hi = holed.boundary_tolerance if hi is None else hi
    monkeypatch.setattr(cell_decisions, "KERNEL_MIN_POINTS", 1)
    got = holed.classify_discs(p, radius, lo, hi)
    monkeypatch.setattr(cell_decisions, "KERNEL_MIN_POINTS", 10 ** 12)
    np.testing.assert_array_equal(got, holed.classify_discs(p, radius, lo, hi))
    assert len(np.unique(got)) > 1
