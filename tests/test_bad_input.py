"""Bad input is refused with an error that names the problem; nothing crashes."""
import numpy as np
import pytest

import taichi_hh as thh
from fieldgen import lattice


@pytest.fixture(scope="module")
def good():
    pts, _ = lattice(12, jitter=0.2, seed=0)
    return pts, thh.PointSet(pts, area=1.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_positions(bad):
    pts, _ = lattice(8)
    pts[5, 1] = bad
    with pytest.raises(thh.InputError, match="non-finite.*index 5"):
        thh.PointSet(pts)


@pytest.mark.parametrize("pts", [np.zeros((0, 2)), np.zeros((5, 3)), np.zeros(10), [[1, 2], [3]],
                                 "abc"])
def test_empty_or_misshaped_points(pts):
    with pytest.raises(thh.InputError, match="empty|shape|numeric"):
        thh.PointSet(pts)


def test_points_spanning_no_area():
    pts = np.c_[np.linspace(0, 1, 10), np.zeros(10)]
    with pytest.raises(thh.InputError, match="no area"):
        thh.PointSet(pts)


def test_duplicate_points_named():
    pts, _ = lattice(10)
    pts = np.vstack([pts, pts[37]])
    with pytest.raises(thh.InputError, match=r"duplicate points: points (37 and 100|100 and 37)"):
        thh.PointSet(pts, area=1.0)


def test_non_finite_values(good):
    pts, ps = good
    f = np.ones(len(pts))
    f[3] = np.nan
    with pytest.raises(thh.InputError, match="non-finite.*point 3"):
        ps.gradient(f)
    v = np.ones((len(pts), 2))
    v[7, 0] = np.inf
    with pytest.raises(thh.InputError, match="non-finite.*point 7"):
        ps.divergence(v)


def test_value_shape_mismatch(good):
    pts, ps = good
    with pytest.raises(thh.InputError, match=r"shape \(144,\)"):
        ps.laplacian(np.ones(len(pts) + 1))
    with pytest.raises(thh.InputError, match=r"shape \(144, 2\)"):
        ps.curl(np.ones(len(pts)))


def test_unknown_variant_and_kernel(good):
    pts, ps = good
    with pytest.raises(ValueError, match="unknown operator variant"):
        ps.gradient(np.ones(len(pts)), "fancy")
    with pytest.raises(ValueError, match="unknown kernel"):
        thh.PointSet(pts, kernel="gauss")


def test_isolated_point_reported():
    pts, _ = lattice(10)
    pts = np.vstack([pts, [[3.0, 3.0]]])
    with pytest.raises(thh.NeighbourError, match="point 100 .* no neighbour"):
        thh.PointSet(pts, area=1.0, support=0.25)


def test_too_few_neighbours_for_corrected_operators():
    """Corrected operators need neighbours spanning the plane: a point with a single
    neighbour has a rank-one correction matrix; a lattice with axis-only neighbours has
    only two pair directions, too few for the three second-derivative moments of the
    corrected Laplacian.  Plain operators still run; corrected ones refuse, naming the point."""
    pts, dx = lattice(10)
    ps = thh.PointSet(pts, area=1.0, support=1.05 * dx)    # 2-4 axis neighbours each
    f = pts[:, 0]
    ps.gradient(f, "difference")
    ps.gradient(f, "corrected")                             # two directions suffice here
    with pytest.raises(thh.NeighbourError, match="Laplacian.*singular.*neighbours"):
        ps.laplacian(f, "corrected")
    lone = np.vstack([pts, [[1.05, 0.95]]])                 # one neighbour, at (0.95, 0.95)
    ps_lone = thh.PointSet(lone, area=1.0, support=1.05 * dx)
    with pytest.raises(thh.NeighbourError, match=r"particle 100 at \(1.05, 0.95\).* 1 neighbours"):
        ps_lone.gradient(lone[:, 0], "corrected")
    # a line of points: every correction matrix is rank one
    line = np.c_[np.linspace(0, 1, 20), 0.5 + np.zeros(20)]
    ps_line = thh.PointSet(line, area=1.0, support=0.2)
    with pytest.raises(thh.NeighbourError, match="one line"):
        ps_line.gradient(line[:, 0], "corrected")


def test_bad_support():
    pts, _ = lattice(5)
    for s in (0.0, -1.0, np.nan):
        with pytest.raises(thh.InputError, match="support"):
            thh.PointSet(pts, support=s)


def test_bad_runtime_options():
    with pytest.raises(ValueError, match="arch"):
        thh.init(arch="tpu")
    with pytest.raises(ValueError, match="precision"):
        thh.init(precision="f16")
