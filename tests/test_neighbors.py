"""Dense-grid binning and pair lists against brute force."""
import re

import numpy as np
import pytest
import taichi as ti
from scipy.spatial import cKDTree

import taichi_hh
from taichi_hh.sph.neighbors import CellGrid, GridSpec, PairList, bin_particles
from taichi_hh.sph.particles import BOUNDARY, FLUID, GHOST, QUANTITIES, Particles


# ---------------------------------------------------------------------------
# helpers

def build(points, support, spec=None, pairs=None):
    """Particles -> bin -> self pair list, as PointSet does."""
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    p = Particles.from_numpy(pts)
    if spec is None:
        spec = GridSpec.covering(pts.min(axis=0), pts.max(axis=0), support)
    grid = bin_particles(p, spec)
    pl = (pairs or PairList()).build(p.position, n, p.position, grid, support)
    return p, grid, pl


def encode(i, j, n):
    return np.asarray(i, np.int64) * n + np.asarray(j, np.int64)


def fast_pairs(pl, row_ids, col_ids, ncols):
    """Encoded (query id, source id) pairs of a pair list; checks row structure."""
    off, nb = pl.to_numpy()
    assert off[0] == 0 and np.all(np.diff(off) >= 0) and off[-1] == pl.n_pairs == nb.size
    np.testing.assert_array_equal(pl.counts(), np.diff(off))
    rows = np.repeat(np.arange(off.size - 1), np.diff(off))
    # rows list sources in cell order, and slots inside a cell in order: strictly increasing
    same_row = rows[1:] == rows[:-1]
    assert np.all(nb[1:][same_row] > nb[:-1][same_row]), "row not sorted / pair listed twice"
    if nb.size:
        assert nb.min() >= 0 and nb.max() < len(col_ids)
    codes = encode(np.asarray(row_ids)[rows], np.asarray(col_ids)[nb], ncols)
    assert np.unique(codes).size == codes.size
    return np.sort(codes)


def self_pairs(p, pl):
    orig = p.get("original_index")
    return fast_pairs(pl, orig, orig, p.n)


def brute(q, s, support, exclude_self):
    """Encoded (i, j) with |s_j - q_i| < support (strict, squared distances)."""
    q = np.asarray(q, np.float64)
    s = np.asarray(s, np.float64)
    cand = cKDTree(s).query_ball_point(q, support * (1 + 1e-9) + 1e-300)
    i = np.repeat(np.arange(len(q)), [len(c) for c in cand])
    j = np.fromiter((k for c in cand for k in c), dtype=np.int64, count=i.size)
    d = s[j] - q[i]
    keep = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] < support * support
    if exclude_self:
        keep &= i != j
    return np.sort(encode(i[keep], j[keep], len(s)))


def brute_all(pts, support):
    """O(N^2) reference (independent of cKDTree) for small sets."""
    pts = np.asarray(pts, np.float64)
    d = pts[:, None, :] - pts[None, :, :]
    r2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
    i, j = np.nonzero((r2 < support * support) & ~np.eye(len(pts), dtype=bool))
    return np.sort(encode(i, j, len(pts)))


def check_self(points, support, spec=None):
    p, grid, pl = build(points, support, spec)
    got = self_pairs(p, pl)
    want = brute(points, points, support, exclude_self=True)
    np.testing.assert_array_equal(got, want)
    return p, grid, pl, got


def lattice(m, spacing=1.0, jitter=0.0, seed=0):
    g = np.arange(m) * spacing
    pts = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    if jitter:
        pts = pts + np.random.default_rng(seed).uniform(-jitter, jitter, pts.shape) * spacing
    return pts


def clustered(seed=0):
    rng = np.random.default_rng(seed)
    blobs = [((0.2, 0.3), 0.004, 500), ((0.7, 0.6), 0.03, 400), ((0.45, 0.8), 0.12, 300)]
    parts = [rng.normal(c, s, (k, 2)) for c, s, k in blobs]
    parts.append(rng.uniform(-0.5, 1.5, (150, 2)))          # sparse background
    return np.concatenate(parts)


def boundary_hugging(seed=0):
    rng = np.random.default_rng(seed)
    t = np.concatenate([np.linspace(0, 1, 41), rng.uniform(0, 1, 60)])
    z, o = np.zeros_like(t), np.ones_like(t)
    edges = np.concatenate([np.stack([t, z], 1), np.stack([t, o], 1),
                            np.stack([z, t], 1), np.stack([o, t], 1)])
    corners = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float)
    interior = rng.uniform(0, 1, (300, 2))
    pts = np.unique(np.concatenate([edges, corners, interior]), axis=0)   # no duplicates
    return rng.permutation(pts)


# ---------------------------------------------------------------------------
# layouts against brute force

@pytest.mark.parametrize("layout,support", [
    ("lattice", 3.0 * 0.02),
    ("lattice_ratio_2", 2.0 * 0.02),      # lattice distances exactly = support: excluded
    ("jittered", 3.0 * 0.02),
    ("clustered", 0.02),
    ("clustered_wide", 0.15),
    ("boundary", 0.1),
])
def test_pairs_match_brute_force(layout, support):
    pts = {
        "lattice": lambda: lattice(45, 0.02),
        "lattice_ratio_2": lambda: lattice(45, 0.02),
        "jittered": lambda: lattice(45, 0.02, jitter=0.3, seed=1),
        "clustered": clustered,
        "clustered_wide": clustered,
        "boundary": boundary_hugging,
    }[layout]()
    p, grid, pl, got = check_self(pts, support)
    assert got.size > 0
    # symmetric: j in N(i) <=> i in N(j)
    n = len(pts)
    np.testing.assert_array_equal(got, np.sort(encode(got % n, got // n, n)))


def test_small_sets_against_quadratic_brute_force():
    # the cKDTree-based reference itself against the O(N^2) one
    for pts, support in ((boundary_hugging(3), 0.1), (clustered(4)[::5], 0.05),
                         (lattice(15, 0.1, 0.3, 2), 0.25)):
        np.testing.assert_array_equal(brute(pts, pts, support, True), brute_all(pts, support))
        p, grid, pl = build(pts, support)
        np.testing.assert_array_equal(self_pairs(p, pl), brute_all(pts, support))


def test_boundary_points_on_hand_made_grid_edges():
    # unit square = exactly 8 x 8 cells of 1/8: the edges x = 1 and y = 1 fall on the
    # outer cell boundary (clamped into the last cells)
    pts = boundary_hugging(7)
    spec = GridSpec(0.0, 0.0, 0.125, 8, 8)
    for support in (0.125, 0.1, 0.0625):
        check_self(pts, support, spec)


# ---------------------------------------------------------------------------
# points exactly on cell edges, distances exactly equal to the support

def _edge_lattice(lo, cell, k=6):
    g = np.arange(k + 1) * cell
    return np.stack(np.meshgrid(lo[0] + g, lo[1] + g, indexing="ij"), -1).reshape(-1, 2)


@pytest.mark.parametrize("cell_pad", [1.0, 1.5])
def test_points_on_cell_edges_at_exact_support(cell_pad):
    # all numbers dyadic: every coordinate, difference and squared distance is exact
    support = 0.125
    lo = (-0.5, 0.25)
    spec = GridSpec(lo[0], lo[1], support * cell_pad, 8, 8)
    pts = _edge_lattice(lo, support)                 # lattice step == support
    p, grid, pl = build(pts, support, spec)
    # every lattice neighbour is at distance exactly the support: no pair at all
    assert pl.n_pairs == 0
    assert self_pairs(p, pl).size == 0

    a = np.array([lo[0] + 2 * support, lo[1] + 3 * support])   # on a cell corner
    eps = 2.0**-20
    extra = np.array([
        a + [support - eps, 0.0],                  # 0.125 - 2^-20 from a: included
        a + [0.0, -(support - eps)],               # below a, across the cell edge: included
        a + [np.nextafter(support, 0), 0.5 * support],   # r > support: excluded
        a + [-(support - 2.0**-40), 0.0],          # just below the support: included
    ])
    pts2 = np.concatenate([pts, extra])
    p, grid, pl, got = check_self(pts2, support, spec)
    n = len(pts2)
    ia = int(np.flatnonzero(np.all(pts2 == a, axis=1))[0])
    i_right = int(np.flatnonzero(np.all(pts2 == a + [support, 0.0], axis=1))[0])
    gotset = set(got.tolist())
    for k, inside in zip(range(len(pts), n), (True, True, False, True)):
        assert (encode(ia, k, n) in gotset) == inside, (k, pts2[k] - a)
        assert (encode(k, ia, n) in gotset) == inside
    assert encode(ia, i_right, n) not in gotset       # exactly the support apart
    assert np.linalg.norm(pts2[ia] - pts2[i_right]) == support


def test_diagonal_pair_at_exact_support():
    # 3-4-5 triangle in eighths: r = 5/8 exactly, r^2 = 25/64 exactly
    support = 0.625
    spec = GridSpec(0.0, 0.0, support, 6, 6)
    a = np.array([1.25, 1.25])                       # = 2 cells: on a cell corner
    pts = np.array([
        a,
        a + [0.375, 0.5],                            # r = support: excluded
        a - [0.5, 0.375],                            # r = support: excluded
        a + [0.375 - 2.0**-10, 0.5],                 # r < support: included
        a + [-0.375, 0.5 - 2.0**-10],                # r < support: included
        a + [0.625, 0.0],                            # r = support on an axis: excluded
        a + [0.0, -0.625 + 2.0**-30],                # included
    ])
    p, grid, pl, got = check_self(pts, support, spec)
    with_a = sorted(int(c % 7) for c in got if c // 7 == 0)
    assert with_a == [3, 4, 6]
    np.testing.assert_array_equal(got, brute_all(pts, support))


# ---------------------------------------------------------------------------
# tiny and degenerate sets

def test_single_point():
    p, grid, pl = build(np.array([[0.3, -0.2]]), 0.1)
    off, nb = pl.to_numpy()
    np.testing.assert_array_equal(off, [0, 0])
    assert nb.size == 0 and pl.n_pairs == 0
    assert grid.cell_start.to_numpy()[-1] == 1


@pytest.mark.parametrize("dist,expected", [(0.05, 2), (0.0999, 2), (0.1, 0), (0.3, 0)])
def test_two_points(dist, expected):
    pts = np.array([[0.0, 0.0], [dist, 0.0]])
    p, grid, pl, got = check_self(pts, 0.1)
    assert pl.n_pairs == expected
    if expected:
        np.testing.assert_array_equal(got, [1, 2])   # (0, 1) and (1, 0)


def test_many_points_in_one_cell():
    rng = np.random.default_rng(9)
    pts = rng.uniform(0.21, 0.27, (300, 2))       # diameter < 0.1
    spec = GridSpec(0.0, 0.0, 0.1, 5, 5)
    p, grid, pl, got = check_self(pts, 0.1, spec)
    cs = grid.cell_start.to_numpy()
    counts = np.diff(cs)
    assert counts[2 * 5 + 2] == 300 and counts.sum() == 300
    assert pl.n_pairs == 300 * 299                   # everyone sees everyone else
    # a smaller support inside the same single cell
    check_self(pts, 0.02, spec)


@pytest.mark.parametrize("support", [0.2, 1.0])
def test_grid_of_one_cell(support):
    rng = np.random.default_rng(4)
    pts = rng.uniform(0.0, 1.0, (400, 2))
    spec = GridSpec(0.0, 0.0, 1.0, 1, 1)
    assert spec.ncells == 1
    p, grid, pl, got = check_self(pts, support, spec)
    np.testing.assert_array_equal(grid.cell_start.to_numpy(), [0, 400])
    # the points keep their input order in a single cell
    np.testing.assert_array_equal(p.get("original_index"), np.arange(400))


def test_covering_grid_of_one_cell():
    spec = GridSpec.covering((0.0, 0.0), (0.0, 0.0), 0.5)
    assert (spec.nx, spec.ny) == (1, 1)
    with pytest.raises(taichi_hh.InputError):
        GridSpec.covering((0.0, 0.0), (1.0, 1.0), 0.0)
    with pytest.raises(taichi_hh.InputError):
        GridSpec.covering((0.0, 0.0), (1.0, 1.0), float("nan"))


# ---------------------------------------------------------------------------
# binning

def test_binning_sorts_stably_and_moves_everything():
    rng = np.random.default_rng(21)
    n = 3000
    pts = rng.uniform(-1.0, 2.0, (n, 2))
    pts[:200] = rng.uniform(0.4, 0.45, (200, 2))     # crowded cells
    vel = rng.normal(size=(n, 2))
    mass = rng.uniform(1, 2, n)
    kind = rng.choice([FLUID, BOUNDARY, GHOST], n).astype(np.int32)
    phase = rng.integers(0, 7, n).astype(np.int32)
    dens = rng.uniform(5, 6, n)
    vol = rng.uniform(7, 8, n)

    p = Particles.from_numpy(pts, velocity=vel, mass=mass, kind=kind, phase=phase)
    p.set("density", dens)
    p.set("volume", vol)
    spec = GridSpec.covering(pts.min(0), pts.max(0), 0.07)
    grid = bin_particles(p, spec)

    order = grid.order.to_numpy()[:n]
    orig = p.get("original_index")
    # bijection, and original_index is the applied permutation
    np.testing.assert_array_equal(np.sort(order), np.arange(n))
    np.testing.assert_array_equal(orig, order)
    # every quantity moved together
    np.testing.assert_array_equal(p.get("position"), pts[orig])
    np.testing.assert_array_equal(p.get("velocity"), vel[orig])
    np.testing.assert_array_equal(p.get("mass"), mass[orig])
    np.testing.assert_array_equal(p.get("kind"), kind[orig])
    np.testing.assert_array_equal(p.get("phase"), phase[orig])
    np.testing.assert_array_equal(p.get("density"), dens[orig])
    np.testing.assert_array_equal(p.get("volume"), vol[orig])

    # cells along the slots: computed independently, non-decreasing
    pos = p.get("position")
    cx = np.clip(np.floor((pos[:, 0] - spec.lo_x) * spec.inv_cell), 0, spec.nx - 1).astype(int)
    cy = np.clip(np.floor((pos[:, 1] - spec.lo_y) * spec.inv_cell), 0, spec.ny - 1).astype(int)
    cell = cy * spec.nx + cx
    np.testing.assert_array_equal(cell, grid.cell_of.to_numpy()[:n][orig])
    assert np.all(np.diff(cell) >= 0)
    # cell_start consistent with the counts
    cs = grid.cell_start.to_numpy()
    assert cs.shape == (spec.ncells + 1,)
    assert cs[0] == 0 and cs[-1] == n
    np.testing.assert_array_equal(np.diff(cs), np.bincount(cell, minlength=spec.ncells))
    for c in np.unique(cell)[::7]:
        assert np.all(cell[cs[c]:cs[c + 1]] == c)
    # stable: inside a cell, the input order is kept
    same = cell[1:] == cell[:-1]
    assert np.all(orig[1:][same] > orig[:-1][same])
    assert same.sum() > 500


def test_binning_and_pairs_are_deterministic():
    pts = clustered(5)
    runs = []
    for _ in range(2):
        p, grid, pl = build(pts, 0.03)
        off, nb = pl.to_numpy()
        runs.append((p.get("original_index"), grid.cell_start.to_numpy(), off, nb))
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)
    # rebuilding on the same objects gives the same rows again
    p, grid, pl = build(pts, 0.03)
    off1, nb1 = pl.to_numpy()
    pl.build(p.position, p.n, p.position, grid, 0.03)
    off2, nb2 = pl.to_numpy()
    np.testing.assert_array_equal(off1, off2)
    np.testing.assert_array_equal(nb1, nb2)


def test_cellgrid_sort_reuse():
    # sorting twice with one CellGrid (buffers reused) gives a fresh, correct result
    rng = np.random.default_rng(2)
    spec = GridSpec(0.0, 0.0, 0.25, 4, 4)
    grid = CellGrid(spec)
    for n in (50, 10, 120):
        pts = rng.uniform(0, 1, (n, 2))
        nd = ti.Vector.ndarray(2, ti.f64, shape=(n,))
        nd.from_numpy(pts)
        order = grid.sort(nd, n).to_numpy()[:n]
        np.testing.assert_array_equal(np.sort(order), np.arange(n))
        cx = np.clip(np.floor(pts[:, 0] * 4), 0, 3)
        cy = np.clip(np.floor(pts[:, 1] * 4), 0, 3)
        cell = (cy * 4 + cx).astype(int)
        np.testing.assert_array_equal(order, np.argsort(cell, kind="stable"))
        np.testing.assert_array_equal(np.diff(grid.cell_start.to_numpy()),
                                      np.bincount(cell, minlength=16))


# ---------------------------------------------------------------------------
# pair list reuse, cross queries

def test_pairlist_reuse_across_sizes():
    pl = PairList()
    rng = np.random.default_rng(8)
    for n, support in ((500, 0.08), (40, 0.3), (2000, 0.05), (2000, 0.01), (3, 5.0)):
        pts = rng.uniform(0, 1, (n, 2))
        p, grid, pl2 = build(pts, support, pairs=pl)
        assert pl2 is pl
        np.testing.assert_array_equal(self_pairs(p, pl), brute(pts, pts, support, True))


@pytest.mark.parametrize("support", [0.05, 0.13])
def test_cross_queries(support):
    rng = np.random.default_rng(13)
    src = np.concatenate([rng.uniform(0, 1, (900, 2)), clustered(1)[::4]])
    ns = len(src)
    p = Particles.from_numpy(src)
    grid = bin_particles(p, GridSpec.covering(src.min(0), src.max(0), support))
    orig = p.get("original_index")

    q = np.concatenate([
        rng.uniform(-0.3, 1.3, (700, 2)),        # partly outside the sources' box
        src[:25],                                # exactly on sources: r = 0 included
        src[100:110] + [support, 0.0],           # exactly the support away (mostly)
        [[50.0, 50.0], [-40.0, 3.0]],            # nothing near
    ])
    nq = len(q)
    qnd = ti.Vector.ndarray(2, ti.f64, shape=(nq,))
    qnd.from_numpy(q)
    pl = PairList().build(qnd, nq, p.position, grid, support, exclude_self=False)
    assert pl.n_queries == nq
    got = fast_pairs(pl, np.arange(nq), orig, ns)
    want = brute(q, src, support, exclude_self=False)
    np.testing.assert_array_equal(got, want)
    gotset = set(got.tolist())
    assert all(encode(700 + k, k, ns) in gotset for k in range(25))
    assert pl.counts()[-2:].tolist() == [0, 0]


def test_self_query_without_exclusion_includes_self():
    pts = lattice(20, 0.05, 0.3, 3)
    n = len(pts)
    p, grid, pl = build(pts, 0.12)
    excl = self_pairs(p, pl)
    pl2 = PairList().build(p.position, n, p.position, grid, 0.12, exclude_self=False)
    incl = self_pairs(p, pl2)
    np.testing.assert_array_equal(incl, np.sort(np.concatenate([excl, encode(np.arange(n),
                                                                              np.arange(n), n)])))


# ---------------------------------------------------------------------------
# duplicates

def test_pointset_rejects_exact_duplicate():
    from taichi_hh.sph.pointset import PointSet

    rng = np.random.default_rng(17)
    pts = rng.uniform(0, 1, (120, 2))
    pts[93] = pts[38]
    with pytest.raises(taichi_hh.InputError) as info:
        PointSet(pts)
    msg = str(info.value)
    assert "duplicate" in msg.lower()
    assert re.search(r"\b38\b", msg) and re.search(r"\b93\b", msg), msg


def test_pointset_rejects_near_duplicate_and_accepts_distinct():
    from taichi_hh.sph.pointset import DUPLICATE_FRACTION, PointSet

    rng = np.random.default_rng(18)
    pts = rng.uniform(0, 1, (150, 2))
    spacing = np.sqrt(np.prod(pts.max(0) - pts.min(0)) / len(pts))
    near = pts.copy()
    near[7] = near[120] + [0.25 * DUPLICATE_FRACTION * spacing, 0.0]
    with pytest.raises(taichi_hh.InputError, match="duplicate") as info:
        PointSet(near)
    assert re.search(r"\b7\b", str(info.value)) and re.search(r"\b120\b", str(info.value))
    ps = PointSet(pts)                                 # no duplicates: fine
    assert ps.neighbour_counts.min() > 0


def test_pairlist_duplicate_tolerance():
    pts = np.array([[0.0, 0.0], [0.5, 0.5], [0.5, 0.5], [0.9, 0.1]])
    p, grid, pl = build(pts, 0.3)                     # no tolerance: r = 0 is just a pair
    np.testing.assert_array_equal(self_pairs(p, pl), brute_all(pts, 0.3))
    pl2 = PairList()
    with pytest.raises(taichi_hh.InputError, match="duplicate"):
        pl2.build(p.position, p.n, p.position, grid, 0.3, duplicate_tolerance=1e-9)
    assert p.get("original_index")[pl2.duplicate_query] in (1, 2)


# ---------------------------------------------------------------------------
# points outside the grid

def test_points_outside_grid_are_clamped():
    # grid over the unit square only; points moderately outside it (cell indices in
    # i32 range) land in the edge cells, so every pair is still found
    rng = np.random.default_rng(31)
    spec = GridSpec(0.0, 0.0, 0.125, 8, 8)
    support = 0.1
    inside = rng.uniform(0, 1, (400, 2))
    outside = np.concatenate([
        rng.uniform(-0.3, 1.3, (200, 2)),
        [[-0.05, 0.5], [0.02, 0.5], [1.04, 0.97], [0.99, 1.03], [-5.0, -5.0], [-5.01, -5.02],
         [70.0, 0.5], [70.05, 0.52], [0.5, -1e6], [0.55, -1e6]],
    ])
    pts = np.concatenate([inside, outside])
    p, grid, pl, got = check_self(pts, support, spec)
    cs = grid.cell_start.to_numpy()
    assert cs[-1] == len(pts)


def test_points_far_outside_grid_no_crash():
    # coordinates whose cell index does not fit in 32 bits: no crash, no spurious pair,
    # and the points inside the grid keep exactly their neighbours
    rng = np.random.default_rng(32)
    spec = GridSpec(0.0, 0.0, 0.125, 8, 8)
    support = 0.1
    inside = rng.uniform(0, 1, (400, 2))
    far = np.array([[1e12, 0.5], [1e12 + 0.05, 0.5], [-1e12, -1e12], [-1e12, -1e12 + 0.01],
                    [0.5, 1e30], [1e300, 1e300], [-1e300, 0.3], [2.0**40, 2.0**40]])
    pts = np.concatenate([inside, far])
    n = len(pts)
    p, grid, pl = build(pts, support, spec)
    assert grid.cell_start.to_numpy()[-1] == n
    got = self_pairs(p, pl)
    with np.errstate(over="ignore", invalid="ignore"):
        want = brute_all(pts, support)
    assert np.all(np.isin(got, want)), "a pair farther than the support was listed"
    ni = len(inside)
    inside_rows = lambda codes: codes[codes // n < ni]   # noqa: E731
    np.testing.assert_array_equal(inside_rows(got), inside_rows(want))


def test_far_points_clamped_to_nearest_edge():
    spec = GridSpec(0.0, 0.0, 1.0, 4, 4)
    pts = np.array([[2.0**31 - 0.05, 0.5], [2.0**31 + 0.05, 0.5], [1e12, 2.5],
                    [0.5, 1e30], [0.5, 0.5]])
    p, grid, pl = build(pts, 0.5, spec)
    cell_of = grid.cell_of.to_numpy()[: len(pts)]         # indexed by input point
    # (cx, cy) = (3, 0), (3, 0), (3, 2), (0, 3), (0, 0); today: cells 3, 0, 8, 0, 0
    np.testing.assert_array_equal(cell_of, [0 * 4 + 3, 0 * 4 + 3, 2 * 4 + 3, 3 * 4 + 0, 0])
    np.testing.assert_array_equal(self_pairs(p, pl), brute_all(pts, 0.5))


# ---------------------------------------------------------------------------
# Particles: reserve / append / permute

def _snapshot(p):
    return {name: p.get(name) for name in QUANTITIES}


def test_particles_reserve_and_append_keep_contents():
    rng = np.random.default_rng(41)
    pts = rng.uniform(0, 1, (5, 2))
    vel = rng.normal(size=(5, 2))
    p = Particles.from_numpy(pts, velocity=vel, mass=[1.0, 2.0, 3.0, 4.0, 5.0],
                             kind=BOUNDARY, phase=[0, 1, 2, 3, 4])
    p.set("density", np.arange(5.0) + 10)
    p.set("volume", np.arange(5.0) + 20)
    assert p.capacity == 5 and p.n == 5
    before = _snapshot(p)
    np.testing.assert_array_equal(before["position"], pts)
    np.testing.assert_array_equal(before["kind"], [BOUNDARY] * 5)
    np.testing.assert_array_equal(before["original_index"], np.arange(5))

    p.reserve(3)                                       # never shrinks
    assert p.capacity == 5
    p.reserve(100)
    assert p.capacity >= 100 and p.n == 5
    for name, val in _snapshot(p).items():
        np.testing.assert_array_equal(val, before[name], err_msg=name)

    pts2 = rng.uniform(0, 1, (200, 2))                 # beyond the capacity: grows again
    sl = p.append(pts2, velocity=np.ones((200, 2)), mass=0.5, kind=GHOST, phase=3)
    assert sl == slice(5, 205) and p.n == 205 and p.capacity >= 205
    after = _snapshot(p)
    for name, val in after.items():
        np.testing.assert_array_equal(val[:5], before[name], err_msg=name)
    np.testing.assert_array_equal(after["position"][5:], pts2)
    np.testing.assert_array_equal(after["velocity"][5:], 1.0)
    np.testing.assert_array_equal(after["mass"][5:], 0.5)
    np.testing.assert_array_equal(after["kind"][5:], GHOST)
    np.testing.assert_array_equal(after["phase"][5:], 3)
    np.testing.assert_array_equal(after["density"][5:], 0.0)
    np.testing.assert_array_equal(after["original_index"], np.arange(205))


def test_particles_permute_numpy_order():
    rng = np.random.default_rng(42)
    n = 64
    p = Particles.from_numpy(rng.uniform(0, 1, (n, 2)), velocity=rng.normal(size=(n, 2)),
                             mass=rng.uniform(1, 2, n), kind=rng.integers(0, 3, n),
                             phase=rng.integers(0, 5, n), capacity=100)
    p.set("density", rng.uniform(size=n))
    p.set("volume", rng.uniform(size=n))
    before = _snapshot(p)
    order = rng.permutation(n)
    p.permute(order)
    assert p.n == n and p.capacity == 100
    for name, val in _snapshot(p).items():
        np.testing.assert_array_equal(val, before[name][order], err_msg=name)
    # a second permutation composes (scratch buffers are reused)
    order2 = rng.permutation(n).astype(np.int64)
    p.permute(order2)
    for name, val in _snapshot(p).items():
        np.testing.assert_array_equal(val, before[name][order][order2], err_msg=name)
    # and permuting after growth (scratch re-made at the new capacity)
    p.append(np.array([[5.0, 5.0]]), mass=9.0)
    order3 = np.roll(np.arange(n + 1), 1)
    p.permute(order3)
    pos = p.get("position")
    np.testing.assert_array_equal(pos[0], [5.0, 5.0])
    np.testing.assert_array_equal(pos[1:], before["position"][order][order2])
    assert p.get("original_index")[0] == n
