"""Bad input is refused with an error that names the problem; nothing crashes.
The shared validators of taichi_hh.checks are tested directly at the end."""
import argparse

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh import checks
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


# ---- taichi_hh.checks: the shared validators -----------------------------------------

@pytest.mark.parametrize("bad, match", [
    (np.array([[0.0, 1.0], [np.nan, 2.0]]), r"pts contains 1 non-finite.*first at index 1"),
    (np.array([[0.0, 1.0], [1.0, 2.0], [np.inf, -np.inf]]), r"pts contains 1 non-finite.*index 2"),
    (np.zeros((4, 3)), r"pts must have shape \(N, 2\), got \(4, 3\)"),
    (np.zeros(6), r"pts must have shape \(N, 2\), got \(6,\)"),
    ([[1, 2], [3]], "pts must be a numeric"),
    ("abc", "pts must be a numeric"),
    (np.zeros((0, 2)), "pts is empty"),
])
def test_check_points_refuses(bad, match):
    with pytest.raises(thh.InputError, match=match):
        checks.check_points(bad, "pts")


def test_check_points_accepts_and_converts():
    out = checks.check_points([[1, 2], [3, 4]])
    assert out.dtype == np.float64 and out.shape == (2, 2)
    assert checks.check_points(np.zeros((0, 2)), allow_empty=True).shape == (0, 2)
    with pytest.raises(thh.InputError, match="q contains 1 non-finite"):
        checks.check_points([[np.nan, 0.0]], "q", allow_empty=True)


def test_check_values_refuses():
    with pytest.raises(thh.InputError, match=r"f must have shape \(3,\) \(one per point\)"):
        checks.check_values(np.ones(4), 3, 1, "f")
    with pytest.raises(thh.InputError, match=r"v must have shape \(3, 2\)"):
        checks.check_values(np.ones(3), 3, 2, "v")
    with pytest.raises(thh.InputError, match="v contains 1 non-finite.*first at point 2"):
        checks.check_values([[0, 0], [1, 1], [np.nan, 0]], 3, 2, "v")
    with pytest.raises(thh.InputError, match="f must be numeric"):
        checks.check_values("abc", 3, 1, "f")
    assert checks.check_values([1, 2, 3], 3, 1).dtype == np.float64


@pytest.mark.parametrize("value, kwargs, match", [
    (True, {}, "x must be a real number, got True"),
    ("1", {}, "x must be a real number"),
    (np.nan, {}, "x must be finite, got nan"),
    (np.inf, {"positive": False}, "x must be finite"),
    (0.0, {}, "x must be positive, got 0.0"),
    (-1, {"allow_zero": True}, "x must be non-negative, got -1.0"),
])
def test_check_real_refuses(value, kwargs, match):
    with pytest.raises(thh.InputError, match=match):
        checks.check_real(value, "x", **kwargs)


def test_check_real_and_seed_accept():
    assert checks.check_real(2, "x") == 2.0
    assert checks.check_real(0, "x", allow_zero=True) == 0.0
    assert checks.check_real(-3.5, "x", positive=False) == -3.5
    g = np.random.default_rng(1)
    assert checks.check_seed(g) is g
    assert checks.check_seed(7).random() == np.random.default_rng(7).random()
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(thh.InputError, match="seed must be a non-negative integer"):
            checks.check_seed(bad)


@pytest.mark.parametrize("parse, text, match", [
    (checks.positive_float, "abc", "not a number"),
    (checks.positive_float, "0", "must be a positive number"),
    (checks.positive_float, "-2.5", "must be a positive number"),
    (checks.positive_float, "nan", "must be a positive number"),
    (checks.positive_float, "inf", "must be a positive number"),
    (checks.nonnegative_float, "x1", "not a number"),
    (checks.nonnegative_float, "-1e-9", "must be a non-negative number"),
    (checks.nonnegative_float, "inf", "must be a non-negative number"),
    (checks.positive_int, "1.5", "not an integer"),
    (checks.positive_int, "0", "must be a positive integer"),
    (checks.positive_int, "", "not an integer"),
    (checks.nonnegative_int, "-1", "must be a non-negative integer"),
    (checks.nonnegative_int, "two", "not an integer"),
])
def test_argparse_types_refuse(parse, text, match):
    with pytest.raises(argparse.ArgumentTypeError, match=match):
        parse(text)


def test_argparse_types_accept_and_report_through_argparse(capsys):
    assert checks.positive_float("2.5") == 2.5
    assert checks.nonnegative_float("0") == 0.0
    assert checks.positive_int("12") == 12
    assert checks.nonnegative_int("0") == 0
    parser = argparse.ArgumentParser(prog="t")
    parser.add_argument("--n", type=checks.positive_int)
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["--n", "-3"])
    assert exc.value.code == 2
    assert "argument --n: must be a positive integer, got '-3'" in capsys.readouterr().err


def test_pointset_keeps_exporting_the_checks():
    from taichi_hh.sph import pointset
    assert pointset.check_points is checks.check_points
    assert pointset.check_values is checks.check_values
