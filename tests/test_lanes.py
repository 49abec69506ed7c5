"""The GPU's schedule runs on the CPU too when forced
($TAICHI_HH_GPU_SCHEDULE=1, :func:`taichi_hh.runtime.on_gpu`): its sums in
lanes (taichi_hh.linalg.lanes) give the CPU loops' sums, to round-off, and
exact where the values are integers; its parallel prefix sums, counting
sort and multilevel set-up give the serial ones' results; a solve and a few
flow steps give the CPU schedule's answer.  CI has no GPU: this is how every
run checks the GPU's code paths (CUDA ran them on an H200, docs/arch.md)."""
import numpy as np
import pytest
import taichi as ti

from taichi_hh import runtime
from taichi_hh.linalg import lanes


@pytest.fixture
def forced(monkeypatch):
    def use(flag: bool):
        if not flag and runtime.state().arch == "cuda":
            # the CPU's schedule (f64 sums in kernel-scope vectors) faults in
            # Taichi 1.7.4's CUDA backend, so there is no loop result to
            # compare with; CUDA's lanes are compared with the CPU arch in
            # test_arch.py and benchmarks/arch.py
            pytest.skip("the CPU's loop schedule does not run on CUDA (docs/arch.md)")
        monkeypatch.setenv(runtime.GPU_SCHEDULE_VARIABLE, "1" if flag else "0")
    return use


@pytest.mark.parametrize("n", [0, 1, 7, lanes.LANES - 1, lanes.LANES + 3, 3 * lanes.LANES + 17])
def test_lane_sums_are_exact_on_integers(n, forced):
    """Sums of integers below 2^53 are exact in any order: lanes and loop agree
    bit for bit, and with numpy, at sizes below, at and above one lane each."""
    from taichi_hh.linalg.krylov_kernels import solver_kernels
    runtime.ensure_init()
    values = np.arange(n, dtype=np.float64) % 1000 - 300.0
    want = float((values * values).sum())
    for flag in (True,) if runtime.state().arch == "cuda" else (False, True):
        forced(flag)
        k = solver_kernels(max(n, 1))
        a = runtime.array(None, max(n, 1))
        a.from_numpy(np.r_[values, np.zeros(max(n, 1) - n)])
        assert k.norm2(a, n) == want


def test_lane_maxima_and_mixed_folds(forced):
    """The flow's statistics fold maxima and sums together (divergence_stats):
    lanes and loop agree, on fluid rows only."""
    from taichi_hh.flow import update
    from taichi_hh.sph.particles import FLUID
    runtime.ensure_init()
    rng = np.random.default_rng(3)
    n = 3 * lanes.LANES + 5
    kind = runtime.array(ti.i32, n)
    kind.from_numpy(np.where(rng.random(n) < 0.8, FLUID, FLUID + 1).astype(np.int32))
    d = runtime.array(None, n)
    d.from_numpy(rng.standard_normal(n))
    w = runtime.array(None, n, 2)
    w.from_numpy(rng.standard_normal((n, 2)))
    got = {}
    for flag in (False, True):
        forced(flag)
        got[flag] = (update.divergence_stats(n, kind, d, w), update.max_speed2(n, kind, w))
    (dmax0, dsq0, wmax0), speed0 = got[False]
    (dmax1, dsq1, wmax1), speed1 = got[True]
    assert dmax1 == dmax0 and wmax1 == wmax0 and speed1 == speed0 == wmax0
    assert dsq1 == pytest.approx(dsq0, rel=1e-13)
    fluid = kind.to_numpy() == FLUID
    assert dmax0 == np.abs(d.to_numpy()[fluid]).max()


def test_flow_steps_agree_with_and_without_lanes(forced):
    """Three droplet steps (the Poisson apply's fused dots, BiCGSTAB's sums,
    the flow's statistics, all in lanes) give the loops' flow to round-off."""
    from taichi_hh.flow.twophase import FlowParams, TwoPhaseFlow
    runtime.ensure_init()
    dx = 1.0 / 24
    side_x, side_y = (np.arange(24) + 0.5) * dx, (np.arange(48) + 0.5) * dx
    pts = np.stack(np.meshgrid(side_x, side_y), -1).reshape(-1, 2)
    phases = np.where(np.linalg.norm(pts - [0.5, 0.5], axis=1) < 0.25, 0, 1)
    state = {}
    for flag in (False, True):
        forced(flag)
        flow = TwoPhaseFlow(pts, phases, dx, FlowParams(box=(0, 0, 1, 2), densities=(1.0, 2.0),
                                                        nu=5e-3, solver_tol=1e-10))
        for _ in range(3):
            flow.step()
        pos, vel, _, _ = flow.fluid_state()
        state[flag] = pos, vel
    (p0, v0), (p1, v1) = state[False], state[True]
    assert np.abs(v0).max() > 0
    assert np.abs(p1 - p0).max() <= 1e-9
    assert np.abs(v1 - v0).max() <= 1e-8 * np.abs(v0).max()


def test_bicgstab_agrees_with_and_without_lanes(forced):
    """A BiCGSTAB solve of a general sparse system (the iteration's sums in
    lanes) gives the loops' answer to round-off."""
    import scipy.sparse as sp
    from taichi_hh.linalg.csr import CSRMatrix
    from taichi_hh.linalg.krylov import bicgstab
    runtime.ensure_init()
    rng = np.random.default_rng(0)
    n = 2 * lanes.LANES + 11
    M = sp.random(n, n, density=8.0 / n, random_state=1, format="csr")
    M = (M + M.T + sp.diags(np.full(n, 20.0))).tocsr()
    b = rng.standard_normal(n)
    x = {}
    for flag in (False, True):
        forced(flag)
        res = bicgstab(CSRMatrix(M.indptr, M.indices, M.data, (n, n)), b, tol=1e-12)
        assert res.converged
        x[flag] = res.x
    assert np.abs(x[True] - x[False]).max() <= 1e-10 * np.abs(x[False]).max()


def test_cg_and_cgnr_agree_with_and_without_lanes(forced):
    """CG on a symmetric definite system and CGNR on an overdetermined one
    (their sums in lanes, as `project` and the flow's shifting solve them on
    a GPU) give the loops' answers to round-off."""
    import scipy.sparse as sp
    from taichi_hh.linalg.csr import CSRMatrix
    from taichi_hh.linalg.krylov import cg, cgnr
    runtime.ensure_init()
    rng = np.random.default_rng(1)
    n = 2 * lanes.LANES + 11
    M = sp.random(n, n, density=8.0 / n, random_state=2, format="csr")
    M = (M + M.T + sp.diags(np.full(n, 20.0))).tocsr()
    R = sp.vstack([M, sp.random(n // 3, n, density=6.0 / n, random_state=3)]).tocsr()
    b, c = rng.standard_normal(n), rng.standard_normal(R.shape[0])
    got = {}
    for flag in (False, True):
        forced(flag)
        spd = cg(CSRMatrix(M.indptr, M.indices, M.data, M.shape), b, tol=1e-12)
        ls = cgnr(CSRMatrix(R.indptr, R.indices, R.data, R.shape), c, tol=1e-10,
                  least_squares=True)
        assert spd.converged and ls.converged
        got[flag] = spd.x, ls.x, spd.iterations, ls.iterations
    for k in (0, 1):
        assert np.abs(got[True][k] - got[False][k]).max() <= 1e-9 * np.abs(got[False][k]).max()
    assert abs(got[True][2] - got[False][2]) <= 1 and abs(got[True][3] - got[False][3]) <= 1
    # the least-squares answer is the normal equations' (scipy's, as a check)
    want = sp.linalg.lsqr(R, c, atol=1e-14, btol=1e-14)[0]
    assert np.abs(got[True][1] - want).max() <= 1e-7 * np.abs(want).max()


def test_parallel_prefix_sums_and_counting_sorts_are_the_serial_ones(forced):
    """The GPU's blocked prefix sum (i64 total), its counting sort (atomic
    slots, then each cell's run in input order) and the neighbour grid's
    parallel scatter with its inverse permutation: the serial results, bit
    for bit, on clustered cells (many points in a few cells) and shuffled
    input."""
    from taichi_hh.sph.cell_sort import counting_sort
    from taichi_hh.sph.neighbors import SCAN_BLOCK, CellGrid, GridSpec, exclusive_scan
    runtime.ensure_init()
    rng = np.random.default_rng(5)
    counts = rng.integers(0, 50, 3 * SCAN_BLOCK + 7).astype(np.int32)
    cell = np.minimum(rng.geometric(0.05, 20_000) - 1, 399).astype(np.int32)
    pts = np.vstack([rng.random((60_000, 2)), 0.5 + 0.01 * rng.random((10_000, 2))])
    pts = pts[rng.permutation(len(pts))]
    spec = GridSpec.covering(pts.min(axis=0), pts.max(axis=0), 0.01)
    got = {}
    for flag in (False, True):
        forced(flag)
        c = runtime.array(ti.i32, len(counts) + 1)
        c.from_numpy(np.r_[counts, 0])
        start = runtime.array(ti.i32, len(counts) + 1)
        total = exclusive_scan(c, start, len(counts))
        order, cstart = counting_sort(cell, 400)
        grid = CellGrid(spec)
        pos = runtime.array(None, len(pts), 2)
        pos.from_numpy(pts)
        slots = grid.sort(pos, len(pts)).to_numpy()[: len(pts)].copy()
        rank = grid.rank.to_numpy()[: len(pts)].copy() if grid.rank is not None else None
        got[flag] = (total, start.to_numpy().copy(), order, cstart, slots, rank,
                     grid.cell_start.to_numpy().copy())
    serial, parallel = got[False], got[True]
    assert serial[0] == parallel[0] == int(counts.sum())
    assert np.array_equal(serial[1], np.r_[0, np.cumsum(counts)])
    assert np.array_equal(serial[2], np.argsort(cell, kind="stable"))
    assert serial[5] is not None     # shuffled and over RANK_MIN_N: the rank is recorded
    for a, b in zip(serial[1:], parallel[1:]):
        assert np.array_equal(a, b)


def test_multilevel_levels_built_in_parallel_are_the_serial_ones(forced):
    """The grid levels' coarsening, one launch per level under the GPU's
    schedule, gives the serial loop's Galerkin operators bit for bit; the
    cycles agree to round-off."""
    from test_poisson import neumann_square
    from taichi_hh.poisson.matrix import PoissonMatrix
    from taichi_hh.poisson.multilevel import MultilevelPreconditioner
    runtime.ensure_init()
    ps, phi, b, kind = neumann_square(48, seed=1)
    A = PoissonMatrix(ps.ops, bordered=True)
    built = {}
    for flag in (False, True):
        forced(flag)
        M = MultilevelPreconditioner(A)
        built[flag] = [M.level_matrix(k).toarray() for k in range(len(M.level_sizes))]
    assert len(built[False]) == len(built[True]) >= 3
    for a, b in zip(built[False], built[True]):
        assert np.array_equal(a, b)


def test_joint_two_column_solve_agrees_with_and_without_lanes(forced):
    """decompose's Neumann split solves phi and psi as two columns of one
    BiCGSTAB (``bicg_full`` on two columns: its sums folded in lanes, then the
    new direction); with the GPU's schedule it gives the loops' answer.  The
    fold and the direction's loop in one kernel gave p off by 1e13 and z = 0
    on lavapipe (the direction loop is now a kernel of its own there,
    docs/arch.md)."""
    import taichi_hh as thh
    dom = thh.Box((0.0, 0.0), (1.0, 1.0))
    p = dom.sample_interior(2500, kind="random", seed=4)
    v = np.c_[np.sin(3 * p[:, 0]) * p[:, 1], np.cos(2 * p[:, 1]) + p[:, 0] ** 2]
    out = {}
    for flag in (False, True):
        forced(flag)
        res = thh.decompose(p, v, domain=dom, boundary_condition="neumann", tol=1e-9)
        out[flag] = np.c_[res.curl_free, res.div_free]
    assert np.abs(out[True] - out[False]).max() <= 1e-7 * np.abs(out[False]).max()
