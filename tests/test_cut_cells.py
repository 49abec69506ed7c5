"""The cut cells of the natural decomposition's grid (hhd/cut_cells.py): the
inside parts' boundaries give the polygon's area exactly, their centroids
and the Green's function's integral over them in closed form."""
import math

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.hhd import cut_cells, free_space


def _square(hx, hy):
    return np.array([[-hx / 2, -hy / 2], [hx / 2, -hy / 2], [hx / 2, hy / 2], [-hx / 2, hy / 2]])


@pytest.mark.parametrize("target", [(0.0, 0.0), (1.0, 2.0), (0.3, 0.1), (0.5, 0.0), (0.5, 0.5),
                                    (-3.0, 0.25)])
def test_log_integral_over_a_cell_is_the_closed_form(target):
    """Summed over a cell's four edges, the edge formula is the rectangle's
    closed form (free_space.cell_integral) for targets inside, outside, on
    an edge and at a corner (in cells)."""
    hx, hy = 0.03, 0.021
    sq = _square(hx, hy)
    x = np.array(target) * [hx, hy]
    edge = cut_cells.log_integral(np.broadcast_to(x, (4, 2)), sq, np.roll(sq, -1, axis=0))
    want = free_space.cell_integral(-x[0], -x[1], hx, hy)
    assert abs(edge.sum() / (2 * math.pi) - want) < 1e-15 * hx * hy * 100


def test_log_integral_of_a_triangle_against_quadrature():
    tri = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 0.9]])
    x = np.array([0.45, 0.3])                        # inside
    edge = cut_cells.log_integral(np.broadcast_to(x, (3, 2)), tri, np.roll(tri, -1, axis=0)).sum()
    # the centroid rule on n^2 congruent sub-triangles (second order; the log
    # singularity at x costs O(h^2 log h))
    n = 600
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = i + j < n
    down = i + j < n - 1
    uv = np.concatenate([np.c_[i[up] + 1 / 3, j[up] + 1 / 3], np.c_[i[down] + 2 / 3, j[down] + 2 / 3]]) / n
    p = tri[0] + uv[:, :1] * (tri[1] - tri[0]) + uv[:, 1:] * (tri[2] - tri[0])
    area = 0.5 * abs(np.cross(tri[1] - tri[0], tri[2] - tri[0]))
    quad = np.log(np.hypot(*(p - x).T)).sum() * area / n ** 2
    assert abs(edge - quad) < 1e-6 * abs(quad)


def _areas(domain, cell):
    grid = free_space.Grid(domain, cell)
    cut = cut_cells.cut_cells(grid, domain)
    frac = grid.coverage(domain, 4).ravel()
    whole = np.ones(len(frac), dtype=bool)
    whole[cut.cells] = False
    total = (frac[whole] == 1.0).sum() * grid.hx * grid.hy + cut.area.sum()
    return grid, cut, total


@pytest.mark.parametrize("make", [
    lambda: thh.Polygon.circle((0.5, 0.5), 0.5, n=4096),
    lambda: thh.Polygon([(0.5, 0.0), (1.0, 0.5), (0.5, 1.0), (0.0, 0.5)],
                        holes=[thh.Polygon.circle((0.5, 0.5), 0.2, n=50).outer[::-1]]),
    # vertices on grid lines and corners (the bounding box makes 0.25 one)
    lambda: thh.Polygon([(0.0, 0.0), (1.0, 0.0), (1.0, 0.25), (0.5, 0.6), (0.25, 1.0), (0.0, 1.0)]),
])
def test_cut_parts_and_whole_cells_make_the_polygon(make):
    domain = make()
    grid, cut, total = _areas(domain, 0.037)
    assert abs(total - domain.area) < 1e-12 * domain.area
    assert (cut.area >= 0).all() and (cut.area <= grid.hx * grid.hy * (1 + 1e-12)).all()


def test_cut_part_centroids_against_subsamples():
    disk = thh.Polygon.circle((0.5, 0.5), 0.5, n=4096)
    grid = free_space.Grid(disk, 0.05)
    cut = cut_cells.cut_cells(grid, disk)
    frac, offset = grid.coverage(disk, 256, centroids=True)
    sub = grid.centres()[cut.cells] + offset.reshape(-1, 2)[cut.cells]
    big = frac.ravel()[cut.cells] > 0.05                 # the subsamples' centroid is noisy below
    assert np.abs(cut.centroid - sub)[big].max() < 2e-3 * grid.hx


def test_a_polygon_along_the_grid_lines_cuts_no_cell():
    L = thh.Polygon([(0, 0), (1, 0), (1, 0.5), (0.5, 0.5), (0.5, 1), (0, 1)])
    assert cut_cells.cut_cells(free_space.Grid(L, 0.05), L) is None


def test_the_exact_kernel_near_a_node():
    """Grid.kernel holds the cell integrals within EXACT_CELLS, G times the
    area beyond, and its own value at offset 0 is the self integral."""
    grid = free_space.Grid(thh.Box((0.0, 0.0), (1.0, 0.7)), 0.05)
    K = grid.kernel()
    E = free_space.EXACT_CELLS
    assert K[0, 0] == pytest.approx(grid.self_integral(), rel=1e-14)
    assert K[1, 2] == pytest.approx(float(free_space.cell_integral(grid.hx, 2 * grid.hy, grid.hx,
                                                                   grid.hy)), rel=1e-14)
    far = math.log((E + 1) ** 2 * grid.hx ** 2) / (4 * math.pi) * grid.hx * grid.hy
    assert K[E + 1, 0] == pytest.approx(far, rel=1e-14)
    assert grid.kernel_at(-1, 2) == pytest.approx(K[-1, 2], rel=1e-14)


def test_cut_part_moments_against_subsamples():
    """part_moments' Q_n (Green's theorem along each part's boundary) against
    the mean of w^n over 256 x 256 subsamples of the cell."""
    disk = thh.Polygon.circle((0.5, 0.5), 0.5, n=4096)
    grid = free_space.Grid(disk, 0.05, cell_average=True)
    cut = cut_cells.cut_cells(grid, disk)
    Q = cut_cells.part_moments(grid, cut, cut_cells.MULTIPOLE_ORDER)
    s = (np.arange(256) + 0.5) / 256 - 0.5
    X, Y = (a.ravel() for a in np.meshgrid(s, s, indexing="ij"))
    ci, cj = np.divmod(cut.cells, grid.ny)
    worst = 0.0
    for k in range(0, len(cut.cells), 7):
        centre = grid.origin + np.array([ci[k] * grid.hx, cj[k] * grid.hy])
        inside = disk.contains(centre + np.c_[X * grid.hx, Y * grid.hy])
        w = (X + 1j * Y * grid.hy / grid.hx)[inside]
        for n in range(Q.shape[1]):
            worst = max(worst, abs((w ** n).sum() / len(X) - Q[k, n]))
    # the subsamples' own error: about a row of them, 1 / 256 of a cell
    assert worst < 2e-3, worst


@pytest.mark.parametrize("ratio", [1.0, 0.9])
def test_patches_carry_the_parts_moments(ratio):
    """A cut part's charge on the grid (its cell's charge spread over the
    cell, the 5 x 5 patch as cells' charges) has the part's moments Q_0 ..
    Q_MULTIPOLE_ORDER, on square and on oblong cells."""
    dom = thh.Polygon.circle((0.5, 0.5 * ratio), 0.5, n=4096)
    dom = thh.Polygon(dom.outer * [1.0, ratio])
    grid = free_space.Grid(dom, 0.05, cell_average=True)
    cut = cut_cells.cut_cells(grid, dom)
    order = cut_cells.MULTIPOLE_ORDER
    Q = cut_cells.part_moments(grid, cut, order)
    patches = cut_cells.multipole_patches(grid, Q)
    k = np.arange(-2, 3)
    z = (k[:, None] + 1j * (grid.hy / grid.hx) * k[None, :]).ravel()
    M = cut_cells.cell_moments(grid.hx, grid.hy, order)
    for n in range(order + 1):
        of_cells = sum(math.comb(n, j) * z ** (n - j) * M[j] for j in range(n + 1))
        got = patches.reshape(len(Q), 25) @ of_cells + Q[:, 0] * M[n]
        assert np.abs(got - Q[:, n]).max() < 1e-13, n
    assert abs(patches.sum(axis=(1, 2))).max() < 1e-15


def test_the_cell_average_kernel_beyond_exact_cells():
    """With ``cell_average`` the kernel beyond EXACT_CELLS is the integral of G
    over the cell (the closed form, cell_integral) to rounding, where G times
    the area errs by 1e-6 - 1e-5 (oblong cells: the second moment)."""
    dom = thh.Polygon.circle((0.5, 0.4), 0.4, n=256)
    grid = free_space.Grid(dom, 0.03, cell_average=True)
    K = grid.kernel()
    E = free_space.EXACT_CELLS
    for i, j in [(E + 1, 0), (E + 1, 3), (7, -7), (-12, 5), (30, 1)]:
        exact = float(free_space.cell_integral(i * grid.hx, j * grid.hy, grid.hx, grid.hy))
        assert K[i, j] == pytest.approx(exact, rel=2e-13, abs=0)
        assert grid.kernel_at(i, j) == pytest.approx(exact, rel=2e-13, abs=0)
        midpoint = math.log((i * grid.hx) ** 2 + (j * grid.hy) ** 2) / (4 * math.pi) \
            * grid.hx * grid.hy
        assert abs(midpoint - exact) > 1e-9 * abs(exact)


def test_a_vertex_on_a_grid_corner_is_no_crossing():
    """The 16384-gon's leftmost vertex on a grid corner (cells of 1/78): the
    boundary touches the corner cell there, rounded to either side of its
    lines; counted as an exit and an entry it left 0.25 of that cell where
    0.997 is inside."""
    disk = thh.Polygon.circle((0.5, 0.5), 0.5, n=16384)
    grid = free_space.Grid(disk, 1.0 / 78.0)
    cut = cut_cells.cut_cells(grid, disk)
    sub = grid.coverage(disk, 64).ravel()[cut.cells]
    # the subsamples err by a fraction of a row of them (1 / 64 of a cell)
    assert np.abs(cut.area / (grid.hx * grid.hy) - sub).max() < 1e-2
    _, _, total = _areas(disk, 1.0 / 78.0)
    assert abs(total - disk.area) < 1e-12 * disk.area
