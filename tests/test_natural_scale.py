"""The natural HHD's fast paths (hhd/natural.py) against their references:
a rectangle's closed-form coverage against the polygon subsamples, the
Taichi spline prefilter and boundary fit against numpy, the batched FFT
against single convolutions (and its helper thread against none), the batch's
node densities and assembled outputs against numpy's steps, the k-nearest
search's counting sort against numpy's stable sort."""
import types

import numpy as np

import taichi_hh as thh
from taichi_hh.hhd import free_space, grid_sampling, natural
from taichi_hh.sph.knn import KNearest

RECT = thh.Box((0.1, -0.2), (2.1, 0.8))
# the same rectangle as a polygon with an extra vertex on its bottom side:
# not recognised as a rectangle, so it takes the polygon path
RECT_POLY = thh.Polygon([[0.1, -0.2], [1.3, -0.2], [2.1, -0.2], [2.1, 0.8], [0.1, 0.8]])


def test_rectangle_coverage_is_the_polygon_subsamples():
    for cell in (0.037, 0.05, 0.1):
        grid = free_space.Grid(RECT, cell)
        a = grid.coverage(RECT, 16, centroids=True, inside=True)
        b = grid.coverage(RECT_POLY, 16, centroids=True, inside=True)
        assert np.array_equal(a[0], b[0])
        assert np.abs(a[1] - b[1]).max() < 1e-15
        assert np.array_equal(a[2], b[2])
        assert np.array_equal(a[2].ravel(), RECT.contains(grid.centres()))


def test_natural_potentials_same_on_a_rectangle_and_its_polygon():
    pts = RECT.sample_interior(3000, kind="random", seed=2)
    src = {"phi": np.sin(2 * pts[:, 0]) * pts[:, 1], "psi": np.cos(3 * pts[:, 1])}
    sp = np.sqrt(RECT.area / len(pts))
    a = natural.natural_potentials(pts, RECT, src, sp)
    b = natural.natural_potentials(pts, RECT_POLY, src, sp)
    for name in src:
        for k in (0, 1):
            assert np.abs(a[name][k] - b[name][k]).max() < 1e-12 * np.abs(a[name][k]).max()
    assert set(a["seconds"]) >= {"coverage", "reconstruct", "convolve", "interpolate"}


def test_spline_prefilter_kernel_is_the_numpy_filter():
    u = np.random.default_rng(0).standard_normal((37, 23, 3))
    a = grid_sampling.spline_coefficients(u)
    b = grid_sampling.spline_coefficients_numpy(u)
    assert np.abs(a - b).max() < 1e-13 * np.abs(b).max()
    assert np.abs(grid_sampling.spline_coefficients(u[..., 0]) - b[..., 0]).max() < 1e-13 * 10


def test_spline_prefilter_kernel_on_odd_lines_and_short_axes():
    """The prefilter's lanes (adjacent lines per thread, the last block
    partly past the end) on lines of any length, down to one node: the
    numpy filter's coefficients to round-off, and a constant grid's
    coefficients the constant (the starts exact for the edge values
    repeated forever)."""
    rng = np.random.default_rng(1)
    for shape in ((5, 7), (40, 3, 1), (61, 29, 5), (3, 50, 7), (1, 4), (2, 1, 3)):
        u = rng.standard_normal(shape) * 10.0 ** rng.integers(-2, 3, shape)
        a = grid_sampling.spline_coefficients(u)
        b = grid_sampling.spline_coefficients_numpy(u)
        assert np.abs(a - b).max() < 1e-14 * np.abs(b).max()
        c = grid_sampling.spline_coefficients(np.full(shape, 2.5))
        assert np.abs(c - 2.5).max() < 1e-14


def test_lagrange_and_spline_gathers_take_any_columns():
    """lagrange_at and spline_values take any number of columns (blocks of
    SPLINE_COLUMNS read in place): the tensor cubic Lagrange interpolant is
    exact on bicubics, each column as it is alone, and the rows go where
    ``dest`` says."""
    grid = free_space.Grid(RECT, 0.05)
    nx, ny = grid.shape
    x, y = np.meshgrid(grid.origin[0] + grid.hx * np.arange(nx),
                       grid.origin[1] + grid.hy * np.arange(ny), indexing="ij")
    polys = [lambda a, b, k=k: (a - 0.3 * k) ** 3 * (b + 0.1 * k) ** 2 - k * a * b + k
             for k in range(9)]
    u = np.stack([p(x, y) for p in polys], axis=-1)                       # (nx, ny, 9)
    rng = np.random.default_rng(3)
    pts = RECT.sample_interior(500, kind="random", seed=4)
    dest = rng.permutation(len(pts))
    got = grid_sampling.lagrange_at(grid, u, pts, dest)
    exact = np.stack([p(pts[:, 0], pts[:, 1]) for p in polys], axis=-1)
    assert np.abs(got[dest] - exact).max() < 1e-12 * np.abs(exact).max()
    coef = grid_sampling.spline_coefficients(u)
    many = grid_sampling.spline_values(grid, coef, pts, dest=dest)
    # (to round-off: each width compiles, and rounds, its own way)
    for c in range(u.shape[2]):
        one = grid_sampling.lagrange_at(grid, u[..., c:c + 1], pts, dest)[:, 0]
        assert np.abs(one - got[:, c]).max() < 1e-14 * np.abs(u[..., c]).max()
        one = grid_sampling.at_points(grid, u[..., c], pts, dest=dest)
        assert np.abs(one - many[:, c]).max() < 1e-14 * np.abs(u[..., c]).max()


def _gradient_numpy(grid, u):
    """The grid gradient as numpy: np.gradient (second order, one-sided at
    the edges) with fourth-order central differences from 2 nodes in."""
    g = np.empty(u.shape + (2,))
    for axis, h in ((0, grid.hx), (1, grid.hy)):
        d = np.gradient(u, h, axis=axis, edge_order=2)
        v = np.moveaxis(u, axis, 0)
        inner = np.moveaxis(d, axis, 0)
        inner[2:-2] = (-v[4:] + 8 * v[3:-1] - 8 * v[1:-3] + v[:-4]) / (12 * h)
        g[..., axis] = d
    return g


def test_grid_gradient_kernel_is_the_numpy_differences():
    """free_space.values_and_gradients (a kernel: the values and gradients of
    several potentials, padded by repeated edge nodes for the spline) gives
    numpy's differences, and is exact on a cubic inside (fourth order)."""
    grid = free_space.Grid(RECT, 0.07)
    nx, ny = grid.shape
    x, y = np.meshgrid(grid.origin[0] + grid.hx * np.arange(nx),
                       grid.origin[1] + grid.hy * np.arange(ny), indexing="ij")
    u = np.stack([np.sin(3 * x) * np.cos(2 * y), x ** 3 - 2 * x * y ** 2 + y,
                  np.random.default_rng(2).standard_normal(grid.shape)])
    pad = 4
    got = free_space.values_and_gradients(grid, u, pad)
    assert got.shape == (nx + 2 * pad, ny + 2 * pad, 3, 3)
    for k in range(3):
        ref = np.concatenate([u[k][..., None], _gradient_numpy(grid, u[k])], axis=-1)
        ref = np.pad(ref, [(pad, pad), (pad, pad), (0, 0)], mode="edge")
        assert np.abs(got[:, :, k] - ref).max() <= 1e-14 * np.abs(ref).max()
        assert np.abs(free_space.grid_gradient(grid, u[k]) - ref[pad:-pad, pad:-pad, 1:]).max() \
            <= 1e-14 * np.abs(ref).max()
    exact = np.stack([3 * x ** 2 - 2 * y ** 2, -4 * x * y + 1], axis=-1)
    inner = got[pad + 2:-pad - 2, pad + 2:-pad - 2, 1, 1:]
    assert np.abs(inner - exact[2:-2, 2:-2]).max() < 1e-12


def _linear_continuation(a, pad):
    """``a`` (nx, ny, ...) continued ``pad`` nodes beyond each side with its
    edge's slope, along axis 0 then axis 1 (numpy)."""
    for axis in (0, 1):
        v = np.moveaxis(a, axis, 0)
        steps = np.arange(1, pad + 1).reshape((-1,) + (1,) * (v.ndim - 1))
        lo = v[0] - (v[1] - v[0]) * steps[::-1]
        hi = v[-1] + (v[-1] - v[-2]) * steps
        a = np.moveaxis(np.concatenate([lo, v, hi]), 0, axis)
    return a


def test_spline_columns_continue_linearly_and_commute_with_the_differences():
    """The natural path's spline columns (natural._at_points): the
    potentials continued linearly beyond the grid (free_space.edge_padded),
    the prefilter started exactly for that continuation (scipy's mirror
    filter on the grid continued 80 nodes, to round-off; a linear field's
    coefficients are its values), and the coefficients' differences
    (free_space.with_differences, the same kernel as values_and_gradients):
    inside, the spline of the differences is the differences of the
    spline's coefficients, so the gradient columns give the grid gradient at
    the nodes."""
    from scipy.ndimage import spline_filter
    grid = free_space.Grid(RECT, 0.07)
    nx, ny = grid.shape
    x, y = np.meshgrid(grid.origin[0] + grid.hx * np.arange(nx),
                       grid.origin[1] + grid.hy * np.arange(ny), indexing="ij")
    u = np.stack([np.sin(3 * x) * np.cos(2 * y), x ** 3 - 2 * x * y ** 2 + y,
                  np.random.default_rng(2).standard_normal(grid.shape), 2.0 + 3.0 * x - y])
    pad = grid_sampling.SPLINE_PAD
    c = free_space.edge_padded(grid, u, pad)
    assert c.shape == (nx + 2 * pad, ny + 2 * pad, 4)
    for k in range(4):
        assert np.abs(c[..., k] - _linear_continuation(u[k], pad)).max() \
            <= 1e-14 * np.abs(u[k]).max()
    grid_sampling.prefilter(c, linear=True)
    far = 80
    for k in range(4):
        ref = spline_filter(_linear_continuation(u[k], far), order=3, mode="mirror")
        ref = ref[far - pad:far + nx + pad, far - pad:far + ny + pad]
        assert np.abs(c[..., k] - ref).max() <= 1e-12 * np.abs(ref).max(), k
    assert np.abs(c[..., 3] - _linear_continuation(u[3], pad)).max() < 1e-13
    cols = free_space.with_differences(grid, c)
    assert cols.shape == c.shape + (3,)
    # the channels-first layout's kernel on the same values: the same bits
    padded = types.SimpleNamespace(shape=c.shape[:2], hx=grid.hx, hy=grid.hy)
    assert np.array_equal(free_space.values_and_gradients(
        padded, np.ascontiguousarray(np.moveaxis(c, -1, 0))), cols)
    # the spline of the coefficients' differences at the nodes: the grid
    # gradient (inside: the edges' one-sided differences differ)
    nodes = np.c_[x.ravel(), y.ravel()]
    inside = np.zeros(grid.shape, dtype=bool)
    inside[4:-4, 4:-4] = True
    for k in range(4):
        got = grid_sampling.spline_values(grid, np.ascontiguousarray(cols[:, :, k]), nodes)
        got = got.reshape(nx, ny, 3)
        want = np.concatenate([u[k][..., None], _gradient_numpy(grid, u[k])], -1)
        assert np.abs(got[..., 0] - u[k]).max() <= 1e-12 * np.abs(u[k]).max()
        assert np.abs(got[inside] - want[inside]).max() <= 1e-12 * np.abs(want).max(), k


def test_batched_fft_convolution_is_each_single_one():
    grid = free_space.Grid(RECT, 0.04)
    d = np.random.default_rng(1).standard_normal((2,) + grid.shape)
    both = free_space.convolve_fft(grid, d)
    for m in range(2):
        one = free_space.convolve_fft(grid, d[m])
        assert np.abs(both[m] - one).max() < 1e-13 * np.abs(one).max()


def test_fft_padded_to_the_densities_reach_is_the_direct_sum():
    """convolve_fft pads each axis to the offsets the densities' nonzero
    rows and columns need (free_space.padded_lengths): with empty margins
    (a window's grid), support against one side only, or a single charge,
    the direct sum's potentials at every node to round-off, and the padded
    sides shorter than 2 n where the margins are empty."""
    grid = free_space.Grid(RECT, 0.05)
    nx, ny = grid.shape
    rng = np.random.default_rng(9)
    cases = []
    d = np.zeros(grid.shape)
    d[3:-3, 3:-3] = rng.standard_normal((nx - 6, ny - 6))   # the margins empty
    cases.append(d)
    d = np.zeros(grid.shape)
    d[:nx // 2, ny // 3:] = rng.standard_normal((nx // 2, ny - ny // 3))
    cases.append(d)
    d = np.zeros(grid.shape)
    d[nx - 1, 0] = 1.0                                      # a charge in a corner
    cases.append(d)
    assert not free_space.convolve_fft(grid, np.zeros(grid.shape)).any()
    for d in cases:
        fast = free_space.convolve_fft(grid, d)
        ref = free_space.convolve_direct(grid, d)
        assert np.abs(fast - ref).max() < 1e-12 * np.abs(ref).max()
    L1, L2 = free_space.padded_lengths(cases[0][None])
    assert L1 < free_space.fast_length(2 * nx - 1) or L2 < free_space.fast_length(2 * ny - 1)
    assert (L1, L2) == (free_space.fast_length(2 * (nx - 4) + 2),
                        free_space.fast_length(2 * (ny - 4) + 2))


def test_threaded_fft_convolution_is_the_serial_one_bit_for_bit():
    """From FFT_THREAD_DENSITIES densities on, half go through a helper thread:
    the same transforms, the same bits, for odd counts and repeated calls."""
    grid = free_space.Grid(RECT, 0.04)
    rng = np.random.default_rng(5)
    for count in (2, 3, 8):
        d = rng.standard_normal((count,) + grid.shape)
        serial = free_space.convolve_fft(grid, d, threads=False)
        for _ in range(3):
            assert np.array_equal(free_space.convolve_fft(grid, d), serial)
        assert np.array_equal(serial[-1], free_space.convolve_fft(grid, d[-1]))


def test_columns_kernel_is_numpys_take():
    """natural_assemble.columns (a batch's fields side by side in the bins'
    order, one kernel writing each point's row at its place) against
    numpy's take by the order, for 1 to 8 fields, from a stack or a list."""
    from taichi_hh.hhd.natural_assemble import columns
    rng = np.random.default_rng(10)
    n = 900
    order = rng.permutation(n)
    for k in (1, 3, 8):
        fields = rng.standard_normal((k, n, 2))
        want = fields[:, order].transpose(1, 0, 2).reshape(n, 2 * k)
        pos = np.empty(n, dtype=np.int32)
        pos[order] = np.arange(n)
        assert np.array_equal(columns(fields, pos), want)
        assert np.array_equal(columns(list(fields), pos), want)


def test_assembled_outputs_are_the_numpy_steps():
    """natural_assemble's kernel against the numpy it replaced: the one-sided
    fits over the spline's gradients, the fits of v near the boundary over
    the Lagrange interpolant, r = J grad psi, h = v - d - r, h in the bins'
    order and the energy check's sums (to rounding)."""
    from taichi_hh.hhd.natural_assemble import assemble, row_index
    from taichi_hh.hhd.rotation import J
    rng = np.random.default_rng(6)
    n, k = 700, 3
    at = rng.standard_normal((n, 2 * k, 3))
    v = rng.standard_normal((k, n, 2))
    order = rng.permutation(n)
    pos = np.empty(n, dtype=np.int32)
    pos[order] = np.arange(n)
    near = rng.choice(n, 90, replace=False)
    ok = rng.random(90) < 0.8
    fitted = rng.standard_normal((90, 2 * k, 2))
    gn = rng.standard_normal((90, 2 * k, 2))
    lag = rng.standard_normal((n, 2 * k))
    vol = rng.random(n)
    vs = v[:, order].transpose(1, 0, 2).reshape(n, 2 * k)          # the bins' order
    out = assemble(at, vs, pos, row_index(n, near[ok], np.flatnonzero(ok)), fitted,
                   row_index(n, near), gn, lag, vol)
    ref = at.copy()
    ref[near[ok], :, 1:] = fitted[ok]
    d = ref[:, 0::2, 1:].transpose(1, 0, 2)
    gp = ref[:, 1::2, 1:].transpose(1, 0, 2)
    h = v - d - J(gp)
    dc = lag.reshape(n, k, 2).copy()
    g = gn.reshape(90, k, 2, 2)
    dc[near, :, 0] = g[:, :, 0, 0] + g[:, :, 1, 1]
    dc[near, :, 1] = g[:, :, 1, 0] - g[:, :, 0, 1]
    assert np.array_equal(out["pot"][:, 0], ref[:, 0::2, 0].T)
    assert np.array_equal(out["pot"][:, 1], ref[:, 1::2, 0].T)
    assert np.array_equal(out["grads"], d)
    assert np.array_equal(out["comps"][:, 0], J(gp))
    assert np.abs(out["comps"][:, 1] - h).max() < 1e-15 * np.abs(h).max()
    assert np.array_equal(out["dc"], dc.transpose(1, 2, 0))
    assert np.array_equal(out["hs"].reshape(n, k, 2), out["comps"][:, 1][:, order].transpose(1, 0, 2))
    for s in range(k):
        for q, x in enumerate((v[s], d[s], J(gp[s]), h[s])):
            e = float((vol * np.einsum("ij,ij->i", x, x)).sum())
            assert abs(out["energies"][q, s] - e) < 1e-14 * e


def test_node_densities_are_the_numpy_steps():
    """natural_assemble.node_densities against the numpy it replaced: div v
    and -curl v on the grid (0 off the live cells), the charges (times the
    inside fraction), the Lagrange grid of div v and curl v, and the check's
    scale (to rounding: its sum in another order)."""
    from taichi_hh.hhd.natural_assemble import node_densities, row_index
    rng = np.random.default_rng(7)
    cells, k = 400, 3
    live = np.sort(rng.choice(cells, 250, replace=False))
    frac = np.zeros(cells)
    frac[live] = rng.random(250) + 0.01
    g = rng.standard_normal((250, 2 * k, 2)).reshape(250, k, 2, 2)
    check = np.sort(rng.choice(250, 90, replace=False))
    out = node_densities(g.reshape(250, 2 * k, 2), row_index(cells, live), frac, check)
    div = g[:, :, 0, 0] + g[:, :, 1, 1]
    curl = g[:, :, 1, 0] - g[:, :, 0, 1]
    values = np.zeros((2 * k, cells))
    values[0::2, live], values[1::2, live] = div.T, -curl.T
    assert np.array_equal(out["values"], values)
    assert np.array_equal(out["dens"], values * frac)
    alone = node_densities(g.reshape(250, 2 * k, 2), row_index(cells, live), frac, check,
                           with_values=False)
    assert alone["values"] is None and np.array_equal(alone["dens"], out["dens"])
    dc = np.zeros((cells, 2 * k))
    dc[live, 0::2], dc[live, 1::2] = div, curl
    assert np.array_equal(out["dc"], dc)
    scale = np.sqrt(div[check] ** 2 + curl[check] ** 2).sum(axis=0) / len(check)
    assert np.abs(out["check_scale"] - scale).max() < 1e-14 * scale.max()


def _one_sided_numpy(grid, u, inside, pts):
    """The boundary fit as first written (numpy, LU solve), the values less
    the nearest node's (as the kernel fits them)."""
    R = grid_sampling.ONE_SIDED_REACH
    offs = np.arange(-R, R + 1)
    oi, oj = np.meshgrid(offs, offs, indexing="ij")
    oi, oj = oi.ravel(), oj.ravel()
    h = np.array([grid.hx, grid.hy])
    c = np.rint((pts - grid.origin) / h).astype(np.int64)
    ii = np.clip(c[:, :1] + oi[None], 0, grid.nx - 1)
    jj = np.clip(c[:, 1:] + oj[None], 0, grid.ny - 1)
    node = np.stack([grid.origin[0] + ii * grid.hx, grid.origin[1] + jj * grid.hy], -1)
    d = (node - pts[:, None, :]) / h
    q = np.hypot(d[..., 0], d[..., 1]) / (R - 0.5)
    w = np.where(inside[ii, jj] & (q < 1.0), (1 - q) ** 4 * (1 + 4 * q), 0.0)
    B = np.stack([np.ones_like(q), d[..., 0], d[..., 1], d[..., 0] ** 2,
                  d[..., 0] * d[..., 1], d[..., 1] ** 2], axis=-1)
    BW = B * w[..., None]
    M = np.einsum("mki,mkj->mij", BW, B)
    M += 1e-12 * np.trace(M, axis1=1, axis2=2)[:, None, None] * np.eye(6)
    # the values less the nearest node's, as the kernel fits them
    near = u[np.clip(c[:, 0], 0, grid.nx - 1), np.clip(c[:, 1], 0, grid.ny - 1)]
    rhs = np.einsum("mki,mk->mi", BW, u[ii, jj] - near[:, None])
    coef = np.linalg.solve(M, rhs[..., None])[..., 0]
    out = coef[:, 1:3] / h
    out[(w > 0).sum(axis=1) < grid_sampling.ONE_SIDED_MIN_NODES] = np.nan
    return out


def test_boundary_fit_kernel_is_the_numpy_fit():
    grid = free_space.Grid(RECT, 0.02)
    c = grid.centres()
    u = (np.sin(3 * c[:, 0]) * np.cos(2 * c[:, 1]) + c[:, 0] ** 2).reshape(grid.shape)
    inside = RECT.contains(c).reshape(grid.shape)
    pts = RECT.sample_interior(2000, kind="random", seed=4)
    a = grid_sampling.one_sided_gradient(grid, u, inside, pts)
    b = _one_sided_numpy(grid, u, inside, pts)
    ok = np.isfinite(b).all(axis=1)
    assert np.array_equal(np.isfinite(a).all(axis=1), ok) and ok.any() and not ok.all()
    assert np.abs(a[ok] - b[ok]).max() < 1e-10 * np.abs(b[ok]).max()
    both = grid_sampling.one_sided_gradient(grid, np.stack([u, 2 * u], -1), inside, pts)
    assert np.allclose(both[ok, 0], a[ok], rtol=0, atol=1e-12) and \
        np.allclose(both[ok, 1], 2 * a[ok], rtol=0, atol=1e-11)


def test_knearest_bins_its_sources_as_a_stable_sort():
    pts = np.random.default_rng(3).random((20000, 2)) * [2.0, 1.0]
    search = KNearest(pts)
    cells = search.cells(pts)
    order = np.argsort(cells, kind="stable")
    assert np.array_equal(search.order.to_numpy(), order)
    assert np.array_equal(search.pos.to_numpy(), pts[order])
    assert np.array_equal(search.start.to_numpy(),
                          np.r_[0, np.cumsum(np.bincount(cells, minlength=search.spec.ncells))])
