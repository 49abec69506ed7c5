"""The natural decomposition with div v and curl v fitted at the grid nodes
(hhd/natural.py: fit_gradients, natural_decomposition; the default's path in
decompose): the fit's exactness, agreement with the SPH operator at the
points (the path it replaced, still taken with non-default operator
options), the points' divergence and curl, the volumes, the lazy point set."""
import math

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.hhd import free_space, natural, node_fits
from taichi_hh.validation.windows import window_field

BOX = thh.Box((0.0, 0.0), (2.0, 1.0))


def _cubic(p):
    """A cubic field (u, v) and its gradients (du/dx, du/dy), (dv/dx, dv/dy)."""
    x, y = p[:, 0], p[:, 1]
    u = 1.5 + 0.3 * x - 0.7 * y + x * x * y - 0.4 * y ** 3 + 0.2 * x ** 3
    v = -0.2 + x * y + 0.5 * x ** 2 * y - y ** 2 * x + 0.1 * y ** 3
    gu = np.c_[0.3 + 2 * x * y + 0.6 * x ** 2, -0.7 + x * x - 1.2 * y ** 2]
    gv = np.c_[y + x * y - y ** 2, x + 0.5 * x ** 2 - 2 * x * y + 0.3 * y ** 2]
    return np.c_[u, v], np.stack([gu, gv], axis=1)


def _binned(pts, cell):
    grid = free_space.Grid(BOX, cell)
    return grid, node_fits.PointBins(grid, pts)


def test_node_fit_is_exact_on_cubics_inside_and_on_quadratics_at_the_boundary():
    """The fit reproduces a cubic field's gradient where its first radius holds
    FIT_MIN_POINTS points (inside), a quadratic's anywhere: at the boundary
    and corners the radius grows and the fit is quadratic (EDGE_DEGREE: a
    one-sided cubic amplifies noise).  To the rounding of the normal
    equations and their 1e-12 ridge (measured at most 5e-8 of the gradient; a
    quadratic fit errs on the cubic by 1e-2)."""
    pts = np.random.default_rng(3).random((4000, 2)) * [2.0, 1.0]
    grid, b = _binned(pts, math.sqrt(2.0 / len(pts)))
    targets = np.vstack([grid.centres()[::7], pts[:300],
                         [[0.0, 0.0], [2.0, 1.0], [1.0, 0.0], [0.0, 0.5]]])
    inside = (targets[:, 0] >= 0) & (targets[:, 0] <= 2) & (targets[:, 1] >= 0) \
        & (targets[:, 1] <= 1)
    vals, _ = _cubic(b.points)
    g, count = node_fits.fit_gradients(grid, b, vals, targets, counts=True)
    _, exact = _cubic(targets)
    R0 = node_fits.FIT_RADII[0] * max(grid.hx, grid.hy)
    within = (np.linalg.norm(targets[:, None] - pts[None], axis=2) < R0).sum(axis=1)
    first = inside & (within >= node_fits.FIT_MIN_POINTS)
    assert first.sum() > 300
    assert np.abs(g - exact)[first].max() < 1e-6 * np.abs(exact).max()
    x, y = b.points[:, 0], b.points[:, 1]
    quad = np.c_[1 + x * x - 3 * x * y + 0.5 * y, y * y + 2 * x * y - x]
    g = node_fits.fit_gradients(grid, b, quad, targets)
    tx, ty = targets[:, 0], targets[:, 1]
    exact = np.stack([np.c_[2 * tx - 3 * ty, -3 * tx + 0.5],
                      np.c_[2 * ty - 1, 2 * ty + 2 * tx]], axis=1)
    assert np.abs(g - exact)[inside].max() < 1e-6 * np.abs(exact).max()
    assert count[inside].min() >= 12


def test_node_fit_with_few_points_falls_to_a_lower_degree():
    """Eight points: too few for a cubic (10 terms), the quadratic's 6 + 2
    suffice: a quadratic field's gradient, exactly."""
    pts = np.random.default_rng(4).random((8, 2)) * [2.0, 1.0]
    grid, b = _binned(pts, 0.5)
    x, y = b.points[:, 0], b.points[:, 1]
    vals = np.c_[x * x + 2 * x * y, y * y - x]
    g, count = node_fits.fit_gradients(grid, b, vals, [[1.0, 0.5]], counts=True)
    assert count[0] == 8
    assert np.allclose(g[0], [[2.0 + 1.0, 2.0], [-1.0, 1.0]], atol=1e-9)


def test_node_fit_on_three_rows_drops_to_a_lower_degree(monkeypatch):
    """Points on three rows within the fit's radius (a lattice with rows
    twice as far apart as its columns, cut by a straight edge, the rows bent
    as a map bends them, issue 33): a cubic in y is (nearly) undetermined,
    its normal equations' smallest relative pivot 1e-9-1e-6.  The guard
    (FIT_MIN_PIVOT) drops such a fit to the quadratic: the gradient errs by
    the quadratic's truncation (1.5e-3 of its size here), against 7e-3 to
    2.6e-2 with the near-singular cubic (the guard off)."""
    grid = free_space.Grid(BOX, 0.03)
    x = np.arange(0.0, 2.0 + 1e-9, 0.02)

    def field(p):
        a, b = 2 * p[:, 0] + p[:, 1], p[:, 0] - 1.5 * p[:, 1]
        return np.c_[np.sin(a), np.cos(b)], np.stack(
            [np.c_[2 * np.cos(a), np.cos(a)], np.c_[-np.sin(b), 1.5 * np.sin(b)]], axis=1)

    for bend in (0.0, 0.02, 0.05):
        rows = [np.c_[x, 1.0 - j * 0.04 - bend * (x - 1) ** 2] for j in range(25)]
        b = node_fits.PointBins(grid, np.concatenate(rows))
        vals, _ = field(b.points)
        off = np.linspace(-0.5, 0.5, 11)
        targets = np.c_[1.0 + off, 1.0 - bend * off ** 2]        # on the top row
        _, exact = field(targets)
        err = []
        for guard in (node_fits.FIT_MIN_PIVOT, 0.0):
            monkeypatch.setattr(node_fits, "FIT_MIN_PIVOT", guard)
            g, count = node_fits.fit_gradients(grid, b, vals, targets, counts=True,
                                               scale=np.full(len(targets), 0.03),
                                               edge=np.zeros(len(targets), bool))
            err.append(np.abs(g - exact).max() / np.abs(exact).max())
        monkeypatch.undo()
        assert count.min() >= node_fits.FIT_MIN_POINTS          # the first radius: a cubic
        guarded, unguarded = err
        assert guarded < 2.5e-3
        # the fits kept as weights take the same lower degree
        w = node_fits.FitWeights(grid, b, targets, scale=np.full(len(targets), 0.03),
                                 edge=np.zeros(len(targets), bool))
        g = node_fits.fit_gradients(grid, b, vals, targets, scale=np.full(len(targets), 0.03),
                                    edge=np.zeros(len(targets), bool))
        assert np.abs(w.gradients(vals) - g).max() < 1e-9 * np.abs(g).max()
        assert unguarded > 4 * guarded


def test_node_fit_is_the_same_in_any_input_order():
    """The points binned by cell (a stable sort) and the fit's sums in that
    order: a shuffled input gives the same gradients up to rounding (at the
    nodes inside the domain; those in the grid's margin extrapolate)."""
    pts = np.random.default_rng(5).random((3000, 2)) * [2.0, 1.0]
    cell = math.sqrt(2.0 / len(pts))
    perm = np.random.default_rng(6).permutation(len(pts))
    out = []
    for p in (pts, pts[perm]):
        grid, b = _binned(p, cell)
        c = grid.centres()
        out.append(node_fits.fit_gradients(grid, b, np.sin(3 * b.points), c[BOX.contains(c)]))
    assert np.abs(out[0] - out[1]).max() < 1e-9 * np.abs(out[0]).max()


@pytest.fixture(scope="module")
def window_6k():
    W = window_field(seed=0)
    pts = np.random.default_rng(7).random((6000, 2)) * [2.0, 1.0]
    return W, pts, W.evaluate(pts)


def _err(a, b, v):
    return float(np.linalg.norm(a - b, axis=1).mean() / np.linalg.norm(v, axis=1).mean())


def test_nodes_agree_with_the_point_operator(window_6k):
    """div v and curl v fitted at the nodes against the cubic SPH operator at
    the points reconstructed at the nodes (the path before): both within
    0.1% of the expected split, the nodes' no less accurate (measured
    6k points: d 0.05% against 0.06%)."""
    W, pts, ex = window_6k
    sp = math.sqrt(W.domain.area / len(pts))
    new = natural.natural_decomposition(pts, ex.v, W.domain, sp)
    ps = thh.PointSet(pts, area=W.domain.area, support_neighbours=12)
    div, curl = ps.divergence(ex.v, "cubic"), ps.curl(ex.v, "cubic")
    old = natural.natural_potentials(pts, W.domain, {"phi": div, "psi": -curl}, sp)
    e_new = _err(new.d, ex.d, ex.v), _err(new.grad_psi, _jt(ex.r), ex.v)
    e_old = _err(old["phi"][1], ex.d, ex.v), _err(old["psi"][1], _jt(ex.r), ex.v)
    assert max(e_new + e_old) < 1e-3, (e_new, e_old)
    assert e_new[0] < 1.5 * e_old[0] and e_new[1] < 1.5 * e_old[1], (e_new, e_old)
    # the points' divergence and curl against the operator's
    scale = np.hypot(div, curl).mean()
    assert np.abs(new.divergence - div).mean() < 0.02 * scale
    assert np.abs(new.curl - curl).mean() < 0.02 * scale


def _jt(r):
    """grad psi from r = J grad psi (J (a, b) = (b, -a))."""
    return np.c_[-r[:, 1], r[:, 0]]


def test_points_divergence_and_curl_against_the_field(window_6k):
    """The result's div v and curl v at the points (the nodes' values inside,
    the fit at the point near the boundary) against central differences of
    the analytic field."""
    W, pts, ex = window_6k
    res = thh.decompose(pts, ex.v, W.domain)
    assert res.stats["boundary_condition"] == "natural"
    eps = 1e-6
    gx = (W.evaluate(pts + [eps, 0]).v - W.evaluate(pts - [eps, 0]).v) / (2 * eps)
    gy = (W.evaluate(pts + [0, eps]).v - W.evaluate(pts - [0, eps]).v) / (2 * eps)
    div, curl = gx[:, 0] + gy[:, 1], gx[:, 1] - gy[:, 0]
    scale = np.hypot(div, curl).mean()
    near = np.minimum.reduce([pts[:, 0], 2 - pts[:, 0], pts[:, 1], 1 - pts[:, 1]]) \
        < 3 * res.stats["spacing"]
    for got, want in ((res.divergence, div), (res.curl, curl)):
        assert np.abs(got - want).mean() < 0.02 * scale
        assert np.abs(got - want)[near].mean() < 0.05 * scale


def test_volumes_fill_the_domain(window_6k):
    W, pts, ex = window_6k
    split = natural.natural_decomposition(pts, ex.v, W.domain,
                                          math.sqrt(W.domain.area / len(pts)))
    assert split.volume.min() > 0
    assert abs(split.volume.sum() / W.domain.area - 1.0) < 0.02


def test_default_takes_the_nodes_and_other_operators_the_points(window_6k):
    """The default's natural decomposition fits at the nodes and builds its
    point set only when asked (critical points); a non-default operator
    option takes the SPH operator at the points."""
    W, pts, ex = window_6k
    res = thh.decompose(pts, ex.v, W.domain)
    sec = res.stats["seconds"]
    assert "natural_fit" in sec and "natural_reconstruct" not in sec
    assert set(sec) >= {"setup", "divergence", "natural", "total"}
    assert not res.unit.pointset.built
    found = res.critical_points()
    assert len(found) == len(W.critical_points())
    assert res.unit.pointset.built
    other = thh.decompose(pts, ex.v, W.domain, support_ratio=3.0)
    assert "natural_reconstruct" in other.stats["seconds"]
    vm = np.linalg.norm(ex.v, axis=1).mean()
    for a, b in ((res.curl_free, other.curl_free), (res.div_free, other.div_free)):
        assert np.linalg.norm(a - b, axis=1).mean() < 2e-3 * vm


def test_fit_weights_are_the_fits():
    """The fits kept as weights (node_fits.FitWeights, one gather per field)
    give fit_gradients' gradients (to the rounding of the normal equations'
    solve: inverse rows against a solve per field) with the same counts, for
    any number of columns, inside, at the boundary and at the corners."""
    pts = np.random.default_rng(4).random((3000, 2)) * [2.0, 1.0]
    grid, b = _binned(pts, math.sqrt(2.0 / len(pts)))
    targets = np.vstack([grid.centres()[::5], [[0.0, 0.0], [2.0, 1.0], [1.0, 0.0]]])
    vals, _ = _cubic(b.points)
    g, count = node_fits.fit_gradients(grid, b, vals, targets, counts=True)
    w = node_fits.FitWeights(grid, b, targets)
    assert np.array_equal(w.counts, count)
    assert np.abs(w.gradients(vals) - g).max() < 1e-9 * np.abs(g).max()
    four = w.gradients(np.c_[vals, 2 * vals[:, ::-1]])
    assert np.abs(four[:, 2:] - 2 * g[:, ::-1]).max() < 1e-9 * np.abs(g).max()


def test_fit_weights_gather_is_the_sum_over_slots():
    """FitWeights.gradients (a kernel reading rows padded to a multiple of 4
    columns, in blocks of 8 and 4, at most 16 columns a launch) is the plain sum over each target's slots of the weights times
    the values less the reference's, for any number of columns: numpy in
    slot order agrees to round-off, and each column with that column alone
    (no block mixes columns)."""
    pts = np.random.default_rng(5).random((2000, 2))
    grid, b = _binned(pts, math.sqrt(1.0 / len(pts)))
    w = node_fits.FitWeights(grid, b, grid.centres()[::3])
    rows = np.repeat(np.arange(w.n_targets), np.diff(w.start))
    n = int(w.start[-1])
    rng = np.random.default_rng(6)
    for m in (1, 2, 3, 5, 6, 7, 8, 13, 16, 21):
        vals = rng.standard_normal((len(pts), m)) * 10.0 ** rng.integers(-3, 4, m)
        if m == 6:             # a strided view: read as its values
            vals = np.asfortranarray(vals)
        diff = vals[w.index[:n]] - vals[w.reference[rows]]                   # (S, m)
        ref = np.zeros((w.n_targets, m, 2))
        np.add.at(ref, rows, diff[:, :, None] * w.weights[:n, None, :])
        got = w.gradients(vals)
        assert got.shape == (w.n_targets, m, 2)
        # round-off: a few ulps of the largest term, times the slots summed
        scale = np.abs(diff).max(axis=0)[:, None] * np.abs(w.weights).max()
        bound = 1e-13 * scale * np.diff(w.start).max()
        assert (np.abs(got - ref) <= bound).all()
        for c in range(m):
            assert (np.abs(w.gradients(vals[:, c])[:, 0] - got[:, c]) <= bound[c]).all()


def test_fit_weights_div_curl_is_numpys_of_the_gradients():
    """FitWeights.gradients(div_curl=True) (the harmonic check's |div| and
    |curl| in the gather) against node_fits.abs_div_curl of the gradients,
    bit for bit, for 1 to 10 fields (20 columns: two launches), and the
    divergence and curl of a linear field (to the normal equations' rounding)."""
    pts = np.random.default_rng(5).random((2000, 2))
    grid, b = _binned(pts, math.sqrt(1.0 / len(pts)))
    w = node_fits.FitWeights(grid, b, grid.centres()[::3])
    rng = np.random.default_rng(7)
    for k in (1, 2, 3, 4, 8, 10):
        vals = rng.standard_normal((len(pts), 2 * k))
        got = w.gradients(vals, div_curl=True)
        assert got.shape == (w.n_targets, k, 2)
        assert np.array_equal(got, node_fits.abs_div_curl(w.gradients(vals)))
    # v = (2x + 3y, 5x - y): div 1, curl 2 at the targets inside
    lin = np.c_[2 * b.points[:, 0] + 3 * b.points[:, 1], 5 * b.points[:, 0] - b.points[:, 1]]
    terms = w.gradients(lin, div_curl=True)
    inside = (np.abs(grid.centres()[::3] - 0.5) < 0.4).all(axis=1)
    assert inside.sum() > 400 and np.abs(terms[inside] - [1.0, 2.0]).max() < 1e-7
    with pytest.raises(ValueError, match="pairs"):
        w.gradients(vals[:, :3], div_curl=True)


def test_a_kept_natural_setup_splits_as_a_call():
    """NaturalSetup with the fits kept as weights (the Decomposer's) splits
    each field as natural_decomposition does, to rounding."""
    disk = thh.Polygon.circle((0.5, 0.5), 0.5, n=200)
    pts = disk.sample_interior(3000, kind="random", seed=2)
    sp = math.sqrt(disk.area / len(pts))
    setup = natural.NaturalSetup(pts, disk, sp, reuse_fits=True)
    assert setup.fits is not None
    for k in range(2):
        v = np.c_[np.sin(3 * pts[:, 0] + k) + pts[:, 1] ** 2, np.cos(2 * pts[:, 1] - k) * pts[:, 0]]
        a = setup.split(v)
        b = natural.natural_decomposition(pts, v, disk, sp)
        for name in ("phi", "psi", "d", "grad_psi", "divergence", "curl", "harmonic"):
            x, y = getattr(a, name), getattr(b, name)
            assert np.abs(x - y).max() < 1e-9 * np.abs(y).max(), name
        # each split checks its own h, and the two h differ by the fits'
        # rounding (1e-9 of |h| above): the ratios, in units of the field's
        # derivative (about 1e-3 here), move by as much
        assert np.allclose(a.harmonic_ratios(), b.harmonic_ratios(), rtol=0, atol=1e-9)


def _numpy_cell_counts(grid, frac, binned):
    """The set-up's per-cell quantities written out in numpy (summed-area
    tables, bincounts): the reference of hhd/cell_counts.py's kernels."""
    from taichi_hh.hhd import cell_counts
    pts = binned.points
    tx = np.clip((pts[:, 0] - grid.origin[0]) / grid.hx, 0, grid.nx - 1)
    ty = np.clip((pts[:, 1] - grid.origin[1]) / grid.hy, 0, grid.ny - 1)
    lx = np.minimum(np.floor(tx).astype(int), grid.nx - 2)
    ly = np.minimum(np.floor(ty).astype(int), grid.ny - 2)
    fx, fy = tx - lx, ty - ly
    count = np.zeros(grid.nx * grid.ny)
    for di, wx in ((0, 1 - fx), (1, fx)):
        for dj, wy in ((0, 1 - fy), (1, fy)):
            count += np.bincount((lx + di) * grid.ny + ly + dj, wx * wy, grid.nx * grid.ny)
    count = count.reshape(grid.shape)

    def box(a, k):
        c = np.pad(a, ((k + 1, k), (k + 1, k))).cumsum(0).cumsum(1)
        w = 2 * k + 1
        return c[w:, w:] - c[:grid.nx, w:] - c[w:, :grid.ny] + c[:grid.nx, :grid.ny]

    f = frac.reshape(grid.shape)
    area = np.maximum(box(f, cell_counts.LOCAL_CELLS), 0) * grid.hx * grid.hy
    h = np.sqrt(area / np.maximum(box(count, cell_counts.LOCAL_CELLS), 1))
    cell = max(grid.hx, grid.hy)
    spacing = np.where(h > cell_counts.SPARSE_RATIO * cell, h, cell)
    edge = box((f < 1).astype(float), cell_counts.EDGE_CELLS) > 0.5
    binned_count = np.diff(binned.start).reshape(grid.shape).astype(float)

    def box3(a):                     # summed directly: no summed-area table's rounding
        p = np.pad(a, 1)
        s = p[:-2] + p[1:-1] + p[2:]
        return s[:, :-2] + s[:, 1:-1] + s[:, 2:]

    per = box3(f * grid.hx * grid.hy) / np.maximum(box3(binned_count), 1)
    cell_of = np.repeat(np.arange(grid.nx * grid.ny), np.diff(binned.start))
    volume = np.empty(len(pts))
    volume[binned.order] = per.ravel()[cell_of]
    return count, spacing.ravel(), edge.ravel(), volume


@pytest.mark.parametrize("layout", ["uniform", "clustered", "holed"])
def test_cell_counts_are_the_numpy_sums(layout):
    """The set-up's kernels (cloud-in-cell counts by gathers, box sums slid
    along y then summed along x, the points' areas) against the same sums in
    numpy: uniform points in a box, clustered points (sparse regions, where
    the local spacing exceeds a cell), points in a domain with a hole (cut
    cells, fractions below 1); points on the box's sides and corners."""
    from taichi_hh.hhd import cell_counts
    rng = np.random.default_rng(7)
    domain = BOX
    if layout == "uniform":
        pts = rng.random((6000, 2)) * [2.0, 1.0]
        pts[:4] = [[0, 0], [2, 0], [2, 1], [0, 1]]
    elif layout == "clustered":
        pts = np.clip(np.r_[rng.normal([0.5, 0.5], 0.08, (4000, 2)),
                            rng.random((300, 2)) * [2.0, 1.0]], [0, 0], [2, 1])
    else:
        domain = thh.Polygon(np.array([[0, 0], [2, 0], [2, 1], [0, 1.0]]),
                             holes=[np.array([[0.8, 0.3], [0.8, 0.7], [1.2, 0.7], [1.2, 0.3]])])
        pts = rng.random((8000, 2)) * [2.0, 1.0]
        pts = pts[domain.contains(pts)]
    setup = natural.NaturalSetup(pts, domain, math.sqrt(2.0 / len(pts)))
    cells, binned = setup.cells, setup.binned
    grid = cells.grid
    count, spacing, edge, volume = _numpy_cell_counts(grid, cells.frac, binned)
    np.testing.assert_allclose(cell_counts.shared_counts(grid, binned), count, rtol=0,
                               atol=1e-13)
    got_spacing, got_edge, got_volume = cell_counts.spacing_edge_volume(grid, cells.frac,
                                                                        binned)
    np.testing.assert_allclose(got_spacing, spacing, rtol=1e-12)
    np.testing.assert_array_equal(got_edge, edge)
    np.testing.assert_allclose(got_volume, volume, rtol=1e-13)
    np.testing.assert_array_equal(setup.volume, got_volume)
    assert got_edge.any() and not got_edge.all()
    if layout == "clustered":
        assert (got_spacing > max(grid.hx, grid.hy)).any()        # the sparse rule taken


def test_fit_weights_of_some_targets_are_their_rows():
    """FitWeights.rows (the harmonic check's fits, taken from the nodes'):
    the weights of a subset of targets equal, bit for bit, the weights built
    for those targets alone; all rows give the same object."""
    pts = np.random.default_rng(8).random((2500, 2)) * [1.5, 1.0]
    grid, b = _binned(pts, math.sqrt(1.5 / len(pts)))
    targets = grid.centres()
    w = node_fits.FitWeights(grid, b, targets)
    assert w.rows(np.arange(w.n_targets)) is w
    for rows in (np.arange(0, len(targets), 7), np.array([0, len(targets) - 1]),
                 np.zeros(0, dtype=int)):
        sub, alone = w.rows(rows), node_fits.FitWeights(grid, b, targets[rows])
        n = int(alone.start[-1])
        assert np.array_equal(sub.start, alone.start)
        assert np.array_equal(sub.index[:n], alone.index[:n])
        assert np.array_equal(sub.weights[:n], alone.weights[:n])
        assert np.array_equal(sub.reference[:len(rows)], alone.reference[:len(rows)])
        assert np.array_equal(sub.counts, alone.counts)
        vals = np.sin(3 * b.points)
        assert np.array_equal(sub.gradients(vals), alone.gradients(vals))
