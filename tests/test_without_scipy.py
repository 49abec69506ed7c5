"""scipy is a test and benchmark extra only: the package's user paths run
without it (a fresh ``pip install``), and its scipy-free replacements give
what scipy gave (the k nearest neighbours, the Poisson-disk sampler's
distance test, the natural HHD's cubic-spline interpolation)."""
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from taichi_hh.errors import InputError
from taichi_hh.geometry.box import Box
from taichi_hh.geometry.poisson_disk import AvoidBins
from taichi_hh.hhd import free_space, grid_sampling
from taichi_hh.sph.knn import k_nearest

HERE = pathlib.Path(__file__).resolve().parent


def test_user_paths_run_with_scipy_blocked():
    """decompose (default, natural, petronetto2010) with critical points,
    project() and flow steps, in a process where ``import scipy`` fails."""
    run = subprocess.run([sys.executable, str(HERE / "scipy_free_run.py")],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "all ok" in run.stdout, run.stdout


def test_k_nearest_matches_kd_tree():
    rng = np.random.default_rng(5)
    pts = np.r_[rng.random((3000, 2)), 0.3 + 0.01 * rng.standard_normal((3000, 2))]
    targets = np.r_[pts[::7], rng.random((300, 2)) * 4 - 1.5]
    d, i = k_nearest(pts, targets, 21)
    dd, ii = cKDTree(pts).query(targets, k=21)
    assert np.array_equal(i, ii)
    assert np.abs(d - dd).max() < 1e-15


def test_avoid_bins_match_kd_tree():
    rng = np.random.default_rng(6)
    pts = rng.random((4000, 2))
    q = rng.random((20000, 2)) * 1.6 - 0.3
    r = 0.02
    ref = cKDTree(pts).query(q, k=1, distance_upper_bound=r)[0] < r
    assert np.array_equal(AvoidBins(pts, r).closer_than(q), ref)
    assert 0 < ref.sum() < len(q)


def test_spline_interpolation_matches_map_coordinates():
    """The same prefiltered cubic B-spline as map_coordinates(order=3) with
    the grid's edge values repeated forever (``nearest``; scipy pads 12 of
    them and starts its filter for a mirror, so the reference pads 60: the
    same spline to z^60): round-off apart, at points inside the grid, on
    its edges and up to a cell beyond it."""
    rng = np.random.default_rng(7)
    grid = free_space.Grid(Box((0.0, 0.0), (1.0, 0.7)), 0.03)
    u = rng.standard_normal(grid.shape + (2,))
    lo = grid.origin - [grid.hx, grid.hy]
    span = np.array([grid.hx, grid.hy]) * (np.array(grid.shape) + 1)
    pts = np.r_[rng.random((4000, 2)) * [1.0, 0.7], lo + rng.random((1000, 2)) * span,
                [lo, lo + span, grid.origin]]
    pad = 60
    coords = (pts - grid.origin) / [grid.hx, grid.hy] + pad
    ref = np.stack([map_coordinates(np.pad(u[..., m], pad, mode="edge"), coords.T, order=3,
                                    mode="nearest") for m in range(2)], axis=-1)
    assert np.abs(grid_sampling.at_points(grid, u, pts) - ref).max() < 1e-13
    assert np.abs(grid_sampling.at_points(grid, u[..., 0], pts) - ref[:, 0]).max() < 1e-13
    # scipy's own padding: the same to z^12 of the edge's variation
    near = np.stack([map_coordinates(u[..., m], ((pts - grid.origin) / [grid.hx, grid.hy]).T,
                                     order=3, mode="nearest") for m in range(2)], axis=-1)
    assert np.abs(near - ref).max() < abs(grid_sampling.SPLINE_POLE) ** 12 * 10


def test_k_nearest_refuses_more_neighbours_than_points():
    with pytest.raises(InputError, match="k must be 1..5"):
        k_nearest(np.random.default_rng(8).random((5, 2)), np.zeros((1, 2)), 6)
