"""Domains drawn from the data (issue 13): the alpha shape follows concave
outlines and leaves the gaps in the data out as holes, and no triangle of
points without a gap is left out."""
import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import InputError
from taichi_hh.geometry.from_points import alpha_shape, delaunay_triangles, unique_points
from taichi_hh.validation import fields, layouts


def _ring_area(ring):
    x, y = np.asarray(ring).T
    return 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def test_delaunay_triangles_cover_the_hull_counter_clockwise():
    pts = np.random.default_rng(0).random((400, 2))
    tri = delaunay_triangles(pts)
    a, b, c = (pts[tri[:, k]] for k in range(3))
    signed = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                    - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    assert (signed > 0).all()
    from taichi_hh.geometry.from_points import convex_hull
    assert signed.sum() == pytest.approx(_ring_area(convex_hull(pts)), rel=1e-12)
    assert len(tri) == 2 * len(pts) - 2 - len(convex_hull(pts))      # Euler, points in general position


@pytest.mark.parametrize("layout", ["random", "poisson", "clusters", "gradient"])
def test_alpha_shape_of_points_filling_a_square_has_no_holes(layout):
    pts = layouts.sample(fields.get("gaussian").domain, 13000, layout, seed=3)
    shape = alpha_shape(pts, margin=0.0)
    assert len(shape.rings) == 1
    assert 0.98 < shape.area <= 1.0
    assert shape.contains(pts, tol=1e-9).all()


def test_alpha_shape_finds_the_hole_and_follows_a_concave_outline():
    F = fields.get("hole")                         # unit square minus a disc of radius 0.15
    pts = layouts.sample(F.domain, 13000, "random", seed=1)
    shape = alpha_shape(pts, margin=0.0)           # through the outermost points
    assert len(shape.rings) == 2
    hole = _ring_area(shape.rings[1])
    assert hole == pytest.approx(np.pi * 0.15 ** 2, rel=0.05)   # rim points lie inside the disc's edge
    assert shape.contains(pts, tol=1e-9).all()
    # the default moves the boundary out, off the data points, by about a
    # quarter of a spacing (0.24 for the closest point, half that at half the
    # margin; the 200 closest at a median of 0.47, 0.29 at half the margin)
    spacing = np.sqrt(F.domain.area / len(pts))
    moved = alpha_shape(pts)
    dist = moved.closest_boundary(pts)[0]
    assert moved.contains(pts).all()
    assert 0.2 * spacing < dist.min()
    assert 0.35 * spacing < np.median(np.sort(dist)[:200]) < 1.5 * spacing
    # an L: the square without its upper-right quarter; the hull would fill it
    rng = np.random.default_rng(2)
    q = rng.random((20000, 2))
    q = q[(q[:, 0] < 0.5) | (q[:, 1] < 0.5)]
    assert alpha_shape(q, margin=0.0).area == pytest.approx(0.75, abs=0.015)


_LAND = (((0.3, -0.1), (0.55, -0.1), (0.55, 0.45), (0.3, 0.45)),     # a tongue from the south
         ((0.75, 0.2), (1.1, 0.2), (1.1, 0.3), (0.75, 0.3)))         # a narrow bay from the east


@pytest.mark.parametrize("n", [13000, 50000])
def test_alpha_shape_follows_a_coast_and_bridges_no_bay(n):
    """Random points over a sea with land: a tongue, a bay 0.1 wide (13 and
    25 spacings) and an island.  The shape keeps no triangle across the bay
    (its circumradius is half the bay's width at least) and finds the island:
    the land it covers lies at the coast, in the corners a kept triangle's
    circle (under 3 local spacings) reaches into, and in the notches filled
    (under a spacing from the outermost points).  Before, a coast point's
    spacing counted its long edges across the land (1.4-2.5 spacings, 1.15
    inside): the bay's triangles were kept (land covered 6 and 12 spacings
    deep, pockets of it as holes), and the notch filling, measured from each pass's chords, crept
    into the tongue's corners."""
    from taichi_hh.geometry.polygon import Polygon
    land = [Polygon(ring) for ring in _LAND] + [Polygon.circle((0.7, 0.7), 0.1, n=64)]

    def on_land(p):
        return np.any([piece.contains(p) for piece in land], axis=0)

    rng = np.random.default_rng(n)
    pts = rng.random((int(1.4 * n), 2))
    pts = pts[~on_land(pts)][:n]
    probe = np.random.default_rng(1).random((200000, 2))
    wet = ~on_land(probe)
    spacing = np.sqrt(wet.mean() / n)
    shape = alpha_shape(pts, margin=0.0)
    assert len(shape.rings) == 2                                  # the island, no other hole
    assert _ring_area(shape.rings[1]) == pytest.approx(np.pi * 0.1 ** 2, rel=0.05)
    dry = probe[~wet]
    depth = np.min([np.where(piece.contains(dry), piece.closest_boundary(dry)[0], np.inf)
                    for piece in land], axis=0)
    assert depth[shape.contains(dry)].max() < 3.5 * spacing       # 2.9 and 2.2
    assert shape.contains(probe[wet]).mean() > 0.99
    assert shape.contains(pts, tol=1e-9).all()


def test_alpha_shape_refuses_data_in_pieces_and_bad_alpha():
    rng = np.random.default_rng(4)
    two = np.vstack([rng.random((2000, 2)) * 0.3, 0.7 + rng.random((2000, 2)) * 0.3])
    with pytest.raises(InputError, match=r"pieces.*give alpha=\d+ or more"):
        alpha_shape(two)
    with pytest.raises(InputError, match="alpha"):
        alpha_shape(two, alpha=-1.0)
    assert len(alpha_shape(two, alpha=100.0).rings) == 1          # wide enough: the hull


def test_decompose_on_the_alpha_shape_matches_the_exact_domain():
    """The hole field sampled on blue noise: on the alpha shape the
    decomposition is as accurate as on the exact domain, and better than on the
    convex hull, which fills the hole."""
    F = fields.get("hole")
    pts = layouts.sample(F.domain, 6000, "poisson", seed=1)
    ex = F.evaluate(pts)
    scale = np.linalg.norm(ex.v, axis=1).mean()

    def err_r(domain):
        res = thh.decompose(pts, ex.v, domain)
        return np.linalg.norm(res.div_free - ex.r, axis=1).mean() / scale

    exact, alpha, hull = err_r(F.domain), err_r("alpha"), err_r("hull")
    assert alpha < 1.1 * exact
    assert alpha < 0.95 * hull


def test_cli_domain_alpha(tmp_path):
    from taichi_hh.app.cli import main
    F = fields.get("hole")
    pts = layouts.sample(F.domain, 3000, "random", seed=2)
    path = tmp_path / "hole.npz"
    np.savez(path, points=pts, vectors=F.evaluate(pts).v)
    out = tmp_path / "out"
    assert main(["decompose", str(path), "-o", str(out), "-q", "--no-figures", "--no-vtk",
                 "--domain", "alpha"]) == 0
    assert np.isfinite(np.load(out / "components.npz")["h"]).all()



def _lattice_with_gap(width):
    """Unit-spaced lattice rows (10 of them) with a gap ``width`` spacings wide
    between columns 7 and 7 + width: the triangles across it have a
    circumradius of sqrt(width^2 + 1) / 2 spacings (3.04 at 6: two pieces at
    the default radius of 3)."""
    x, y = np.meshgrid(np.arange(14.0 + width), np.arange(10.0))
    pts = np.c_[x.ravel(), y.ravel()]
    return pts[(pts[:, 0] <= 7) | (pts[:, 0] >= 7 + width)]


def test_the_alpha_radius_joins_pieces_and_each_message_names_the_radius_that_does():
    """Data in pieces at one radius: the message names the radius from which
    they form one, in the caller's syntax (``alpha=`` of alpha_shape,
    ``domain=('alpha', A)`` of decompose), never the domain that just failed;
    at that radius they form one piece (the gap filled)."""
    pts = _lattice_with_gap(6)
    with pytest.raises(InputError, match=r"2 pieces at an alpha-shape radius of 3 local "
                                         r"spacings.*give alpha=3\.1 or more") as exc:
        alpha_shape(pts)
    assert "domain='alpha'" not in str(exc.value)
    shape = alpha_shape(pts, alpha=3.1, margin=0.0)
    assert len(shape.rings) == 1 and shape.area == pytest.approx(19 * 9)   # the gap filled
    from taichi_hh.geometry.from_points import domain_from_points
    assert domain_from_points(pts, "alpha", 5.0).area > 19 * 9
    v = np.c_[np.sin(pts[:, 1] / 3), np.cos(pts[:, 0] / 4)]
    with pytest.raises(InputError, match="pieces") as exc:
        thh.decompose(pts, v, "alpha")
    msg = str(exc.value)
    assert "give domain=('alpha', 3.1) or more, or domain='hull'" in msg
    assert "domain='alpha'" not in msg and " alpha=" not in msg
    assert "near (13, " in msg                      # the caller's coordinates, not the unit frame
    res = thh.decompose(pts, v, ("alpha", 5))
    assert res.domain.area > 19 * 9 and np.isfinite(res.harmonic).all()
    # a radius twice too small for a gap in random points: the joining radius is exact
    rng = np.random.default_rng(4)
    two = np.vstack([rng.random((2000, 2)) * 0.3, 0.7 + rng.random((2000, 2)) * 0.3])
    with pytest.raises(InputError) as exc:
        alpha_shape(two)
    radius = float(str(exc.value).split("give alpha=")[1].split()[0])
    assert len(alpha_shape(two, alpha=radius).rings) == 1
    with pytest.raises(InputError, match="pieces"):
        alpha_shape(two, alpha=0.98 * radius)


def test_a_domain_from_the_points_takes_its_radius_as_a_pair():
    """``("alpha", A)`` is the alpha shape at A local spacings; other pairs and
    bad radii are refused, saying what is accepted."""
    pts = _lattice_with_gap(6)
    v = np.ones_like(pts)
    for domain, match in ((("hull", 4), r"only the alpha shape takes a radius.*'hull' alone"),
                          (("alpha", 0), "alpha .*positive number"),
                          (("alpha", float("nan")), "alpha .*positive number"),
                          (("alpha", "5"), "alpha .*positive number"),
                          (("alpha", True), "alpha .*positive number"),
                          (("circle", 2), r"\('alpha', A\)")):
        with pytest.raises(InputError, match=match):
            thh.decompose(pts, v, domain)
    with pytest.raises(InputError, match="positive number"):
        alpha_shape(pts, alpha=-1.0)


def test_data_short_of_a_domain_drawn_from_them_are_not_told_to_draw_it_again():
    """The refusal of data short of the boundary offers the domains drawn closer
    to the data than the one asked for: never the one that just failed."""
    from taichi_hh.geometry.domain import Box
    rng = np.random.default_rng(2)
    q = rng.random((6000, 2))
    ell = q[(q[:, 0] < 0.4) | (q[:, 1] < 0.4)]          # an L: its hull spans the notch
    v = np.c_[-ell[:, 1], ell[:, 0]]
    with pytest.raises(InputError, match="do not reach the domain's boundary") as exc:
        thh.decompose(ell, v, "hull")
    msg = str(exc.value)
    assert "domain='alpha'" in msg and "domain='hull'" not in msg and "'bbox'" not in msg
    with pytest.raises(InputError, match="do not reach the domain's boundary") as exc:
        thh.decompose(ell, v)                            # the bounding box, the default
    assert "domain='hull'" in str(exc.value) and "domain='bbox'" not in str(exc.value)
    # the alpha shape across a gap wider than a kernel support: a smaller radius
    pts = _lattice_with_gap(16)
    with pytest.raises(InputError, match="do not reach the domain's boundary") as exc:
        thh.decompose(pts, np.c_[np.sin(pts[:, 1] / 3), np.cos(pts[:, 0] / 4)], ("alpha", 10))
    msg = str(exc.value)
    assert "domain=('alpha', 6.7) (a smaller alpha-shape radius" in msg
    assert "domain='alpha'" not in msg and "domain='hull'" not in msg
    # the caller's own domain: every domain drawn from the points is offered
    inner = Box((0.2, 0.2), (0.8, 0.8)).sample_interior(2000, kind="poisson", seed=1)
    with pytest.raises(InputError, match="domain='bbox'.*domain='hull'.*domain='alpha'"):
        thh.decompose(inner, np.ones_like(inner), Box((0, 0), (1, 1)))

@pytest.mark.parametrize("domain", ["hull", "alpha"])
def test_data_covering_part_of_the_domain_decompose_on_the_shape_they_draw(domain):
    """Random points in the inner [0.05, 0.95]^2 of the unit square: on their
    hull or alpha shape (moved off the points by the margin) within the
    random-points bound and the issue's 25 iterations per potential (34/30
    with the points on the boundary itself)."""
    from taichi_hh.geometry.domain import Box
    F = fields.get("gaussian")         # its bumps' normal derivative at that edge: < 4e-4 of peak
    pts = layouts.sample(Box((0.05, 0.05), (0.95, 0.95)), 13000, "random", seed=1)
    ex = F.evaluate(pts)
    scale = np.linalg.norm(ex.v, axis=1).mean()
    # the default (natural here: the field's stream crosses the outline) and
    # Neumann, whose iteration target this is
    for condition in ("auto", "neumann"):
        res = thh.decompose(pts, ex.v, domain, boundary_condition=condition)
        for got, want in ((res.curl_free, ex.d), (res.div_free, ex.r)):
            assert np.linalg.norm(got - want, axis=1).mean() / scale < 0.01
    assert max(res.stats["iterations_phi"], res.stats["iterations_psi"]) <= 25


# ---- lattices (PIV grids): the shape must not depend on the input's rounding -----------
def _lattice(shape, step, offset=(0.0, 0.0), keep=None):
    """(N, 2) points of an nx x ny lattice of steps ``step`` (one, or (dx, dy)) from
    ``offset``; ``keep(i, j)`` masks lattice indices out."""
    i, j = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    i, j = i.ravel(), j.ravel()
    on = np.ones(i.size, bool) if keep is None else keep(i, j)
    return np.c_[i[on] * np.broadcast_to(step, 2)[0], j[on] * np.broadcast_to(step, 2)[1]] \
        + np.asarray(offset)


LATTICES = {
    "20x15 step 0.1": _lattice((20, 15), 0.1),
    "20x15 step 1/3": _lattice((20, 15), 1 / 3),
    "20x15 step 0.1 at 1e3": _lattice((20, 15), 0.1, (1e3, 1e3)),
    "16x12 steps 0.1 x 0.05 at (5, -2)": _lattice((16, 12), (0.1, 0.05), (5.0, -2.0)),
    "30x30 L": _lattice((30, 30), 1 / 30, keep=lambda i, j: (i < 15) | (j < 15)),
    "30x30 round hole": _lattice((30, 30), 1 / 30,
                                 keep=lambda i, j: (i - 15) ** 2 + (j - 15) ** 2 > 25),
    "25x25 5% missing": _lattice((25, 25), 0.04)[np.random.default_rng(0).random(625) > 0.05],
}


@pytest.mark.parametrize("name", sorted(LATTICES))
def test_alpha_shape_of_a_lattice_does_not_depend_on_rounding(name):
    """A lattice (cocircular squares, collinear rows) and the same lattice moved
    by a few ulps, scaled by 1 + 2e-16, jiggled by rounding and written with 6
    decimals (a CSV): the same rings (vertex counts) and the same area, to
    1e-9 or what the 6 decimals move the points.  Before, rounding chose each
    square's diagonal and the rim's sliver triangles, and with them the local
    spacing: margins of 0.25 or 0.37 spacings, 66 or 11-27 vertices, the area
    within +-4% (20x15 at 0.1: 2.8328 against 2.8567-2.8720), and the exact L
    failed (a folded triangulation)."""
    pts = LATTICES[name]
    rng = np.random.default_rng(1)
    ref = alpha_shape(pts)
    rings = [len(r) for r in ref.rings]
    jiggle = rng.uniform(-1, 1, pts.shape) * 2.2e-16 * np.maximum(1.0, np.abs(pts))
    for moved in (np.nextafter(pts, np.inf), np.nextafter(pts, -np.inf), pts * (1 + 2e-16),
                  pts + jiggle, np.round(pts, 6)):
        got = alpha_shape(moved)
        assert [len(r) for r in got.rings] == rings
        moved_by = np.abs(moved - pts).max()
        assert abs(got.area - ref.area) <= 1e-9 * ref.area + 4.0 * ref.perimeter * moved_by


@pytest.mark.parametrize("name", sorted(LATTICES))
def test_alpha_shape_of_a_lattice_on_qhulls_triangulation_is_the_sweeps(name, monkeypatch):
    """On a GPU the triangulation is Qhull's (the sweep is one serial kernel,
    one GPU thread): the same rings and area as on the sweep's, the lattice
    as given, jiggled by rounding or written with 6 decimals.  Qhull fans a
    rim moved by an ulp into flat triangles, which were turned
    counter-clockwise one by one by the sign of their area (rounding):
    against their neighbours, a rim point's edges went uncounted, and its
    spacing, the margin and the area changed (16x12 at 0.1 x 0.05: 1.1e-3
    of the area)."""
    from taichi_hh.runtime import GPU_SCHEDULE_VARIABLE
    pts = LATTICES[name]
    ref = alpha_shape(pts)                                   # the sweep's
    jiggle = np.random.default_rng(1).uniform(-1, 1, pts.shape) * 2.2e-16 \
        * np.maximum(1.0, np.abs(pts))
    monkeypatch.setenv(GPU_SCHEDULE_VARIABLE, "1")
    for moved in (pts, pts + jiggle, np.round(pts, 6)):
        got = alpha_shape(moved)
        assert [len(r) for r in got.rings] == [len(r) for r in ref.rings]
        moved_by = np.abs(moved - pts).max()
        assert abs(got.area - ref.area) <= 1e-9 * ref.area + 4.0 * ref.perimeter * moved_by


def test_alpha_shape_of_a_full_lattice_is_its_box_moved_out_by_the_margin():
    """Every lattice point's spacing is the step (the squares' diagonals and the
    rim's slivers are left out of it): the shape is the lattice's box moved out
    by a quarter step, its rim points all vertices (none turns)."""
    from taichi_hh.geometry.from_points import MARGIN
    for pts, (w, h), step in ((_lattice((20, 15), 0.1), (1.9, 1.4), 0.1),
                              (_lattice((20, 15), 1 / 3, (1e3, -7.0)), (19 / 3, 14 / 3), 1 / 3)):
        shape = alpha_shape(pts + np.random.default_rng(2).uniform(-1e-13, 1e-13, pts.shape))
        assert len(shape.rings) == 1 and len(shape.outer) == 2 * (19 + 14)
        grown = 2 * MARGIN * step
        assert shape.area == pytest.approx((w + grown) * (h + grown), rel=1e-9)


def test_the_triangulation_of_an_l_shaped_lattice_covers_its_hull_once():
    """The sweep folded the hull of an exact L-shaped lattice (collinear hull
    points) and kept Euler's count; the check now sees the fold (the hull turns
    twice around) and Qhull triangulates it."""
    from taichi_hh.geometry.from_points import convex_hull, delaunay_triangulation
    pts = unique_points(LATTICES["30x30 L"])
    tri, across = delaunay_triangulation(pts)
    a, b, c = (pts[tri[:, k]] for k in range(3))
    area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                  - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    assert (area > 0).all()
    assert area.sum() == pytest.approx(_ring_area(convex_hull(pts)), rel=1e-12)


@pytest.mark.parametrize("name", sorted(LATTICES))
def test_qhulls_triangles_of_a_jiggled_lattice_are_turned_alike(name, monkeypatch):
    """Qhull's triangulation (the GPU's) of a lattice jiggled by rounding: each
    edge inside runs one way in one triangle and the other way in the other,
    the flat triangles of the rim's fans too, and every triangle with area is
    counter-clockwise (turned one by one by the sign of their area, 54 edges
    of the 16 x 12 lattice ran one way in both)."""
    from taichi_hh.geometry import delaunay
    from taichi_hh.geometry.from_points import delaunay_triangulation
    monkeypatch.setattr(delaunay, "sweep_hull", lambda p: None)
    pts = LATTICES[name]
    jiggle = np.random.default_rng(1).uniform(-1, 1, pts.shape) * 2.2e-16 \
        * np.maximum(1.0, np.abs(pts))
    pts = unique_points(pts + jiggle)
    tri, across = delaunay_triangulation(pts)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    inner = np.flatnonzero(across >= 0)
    other = tri[across[inner]]
    reversed_there = np.zeros(inner.size, dtype=bool)
    for k in range(3):
        reversed_there |= (other[:, k] == edges[inner, 1]) \
            & (other[:, (k + 1) % 3] == edges[inner, 0])
    assert reversed_there.all()
    a, b, c = (pts[tri[:, k]] for k in range(3))
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    longest2 = np.maximum.reduce([((b - a) ** 2).sum(1), ((c - b) ** 2).sum(1),
                                  ((a - c) ** 2).sum(1)])
    assert (area2[np.abs(area2) > 1e-4 * longest2] > 0).all()


@pytest.mark.filterwarnings("ignore::taichi_hh.errors.AccuracyWarning")   # h: net curl
def test_decompose_on_the_alpha_shape_of_a_lattice_does_not_depend_on_rounding():
    """The whole chain: a 20 x 15 PIV-like grid and the same grid moved by up to
    2 ulps give the same components, to the solver's tolerance (1e-9 of the
    field; 3e-2 before, the shapes differing)."""
    pts = _lattice((20, 15), 0.1, (3.0, 1e3))
    x, y = (pts - pts.mean(axis=0)).T
    v = np.c_[np.sin(2 * x) - y, np.cos(3 * y) + x]
    ref = thh.decompose(pts, v, "alpha", boundary_condition="neumann")
    moved = pts + np.spacing(pts) * np.random.default_rng(0).integers(-2, 3, pts.shape)
    got = thh.decompose(moved, v, "alpha", boundary_condition="neumann")
    scale = np.abs(v).max()
    for a, b in ((ref.curl_free, got.curl_free), (ref.div_free, got.div_free)):
        assert np.abs(a - b).max() <= 2e-8 * scale


@pytest.mark.filterwarnings("ignore::taichi_hh.errors.AccuracyWarning")   # h: net curl
@pytest.mark.parametrize("condition", ["neumann", "normal-parallel"])
def test_decompose_on_the_hull_does_not_depend_on_rounding(condition):
    """Each hull vertex's data point lies on the bisector of its corner of the
    moved-out hull, as far from both walls: the positive rows' wall term took
    one wall's normal by rounding, and d and r changed by up to 10% when the
    points moved by 2e-16 (Neumann).  Now it takes the corner (its averaged
    normal), and the components agree to the solver's tolerance."""
    rng = np.random.default_rng(0)
    pts = rng.random((200, 2))
    v = np.c_[np.sin(3 * pts[:, 0]) * np.cos(2 * pts[:, 1]), np.cos(4 * pts[:, 0] * pts[:, 1])]
    ref = thh.decompose(pts, v, "hull", boundary_condition=condition)
    assert ref.stats["positive_rows"]["wall"] > 0
    scale = max(np.abs(ref.curl_free).max(), np.abs(ref.div_free).max(), np.abs(v).max())
    for moved in (pts + rng.uniform(-2.2e-16, 2.2e-16, pts.shape), np.nextafter(pts, 2.0),
                  pts * (1 + 2e-16)):
        got = thh.decompose(moved, v, "hull", boundary_condition=condition)
        for a, b in ((ref.curl_free, got.curl_free), (ref.div_free, got.div_free)):
            assert np.abs(a - b).max() <= 2e-8 * scale
