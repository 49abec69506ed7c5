"""Two right-hand sides solved together (taichi_hh.linalg.columns): the kernels
on two columns compute exactly what they compute on each column alone, and
the joint BiCGSTAB gives each column its own solve's answer and stopping."""
import numpy as np
import pytest

from taichi_hh import runtime
from taichi_hh.errors import SolverError
from taichi_hh.hhd.decompose import poisson_problems
from taichi_hh.linalg import krylov
from taichi_hh.linalg.csr import CSRMatrix
from taichi_hh.poisson.matrix import PoissonMatrix
from taichi_hh.validation import fields, layouts
from test_poisson import neumann_square


def _nd(values):
    values = np.asarray(values, dtype=runtime.np_real())
    cols = None if values.ndim == 1 else values.shape[1]
    out = runtime.array(None, values.shape[0], cols)
    out.from_numpy(values)
    return out


@pytest.fixture(scope="module", params=[48, 96], ids=["serial-cycle", "parallel-cycle"])
def bordered(request):
    """A bordered Neumann problem (2.3k particles: the cycle's serial loops;
    9.2k: its parallel schedule) and a second right-hand side."""
    ps, phi, b, kind = neumann_square(request.param, seed=1)
    A = PoissonMatrix(ps.ops, bordered=True)
    rng = np.random.default_rng(3)
    b2 = np.where(kind == kind[0], rng.standard_normal(len(b)), 0.0)
    return A, np.stack([b, b2], axis=1)


@pytest.fixture(scope="module")
def decomposition_rows():
    """The default decomposition's matrix and its phi, psi right-hand sides on
    3k uniformly random points."""
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, 3000, "random", seed=4)
    P = poisson_problems(pts, F.evaluate(pts).v, F.domain, boundary_condition="neumann")
    M = P.A.preconditioner_for("auto", "bicgstab", dict(P.opts.multilevel_options))
    return P.A, M, np.stack([P.rhs["phi"], P.rhs["psi"]], axis=1), P.opts.tol


def test_apply_on_two_columns_is_the_apply_on_each(bordered):
    A, B = bordered
    X = np.vstack([B, [[0.5, -2.0]]])            # the border unknown too
    x2, y2 = _nd(X), _nd(np.zeros_like(X))
    dots2 = A.apply_dot(x2, y2, x2)
    # the same sums in the same order; the compiler may contract a column's
    # multiply-adds differently in the vector kernel (FMA: bit-identical on
    # some CPUs, not on this AMD EPYC), so the bound is the sums' rounding:
    # a few ulps of sum |a_ij x_j| per row
    bound = 8 * np.finfo(float).eps * (abs(A.to_scipy()) @ np.abs(X))
    for c in range(2):
        x1, y1 = _nd(X[:, c]), _nd(np.zeros(len(X)))
        dots1 = A.apply_dot(x1, y1, x1)
        assert (np.abs(y2.to_numpy()[:, c] - y1.to_numpy()) <= bound[:, c]).all()
        assert np.allclose([d[c] for d in dots2], dots1, rtol=1e-12, atol=0.0)


def test_cycle_on_two_columns_is_the_cycle_on_each(bordered, decomposition_rows):
    for A, M in ((bordered[0], bordered[0].multilevel()), decomposition_rows[:2]):
        rng = np.random.default_rng(0)
        R = rng.standard_normal((A.n, 2))
        z2 = _nd(np.zeros_like(R))
        M.apply(_nd(R), z2)
        for c in range(2):
            z1 = _nd(np.zeros(A.n))
            M.apply(_nd(R[:, c]), z1)
            assert np.abs(z2.to_numpy()[:, c] - z1.to_numpy()).max() \
                <= 1e-13 * np.abs(z1.to_numpy()).max()


@pytest.mark.parametrize("preconditioner", ["multilevel", "jacobi"])
def test_joint_solve_is_each_columns_own_solve(bordered, preconditioner):
    A, B = bordered
    joint = A.solve_columns(B, tol=1e-10, preconditioner=preconditioner)
    for c, res in enumerate(joint):
        alone = A.solve(B[:, c], tol=1e-10, preconditioner=preconditioner)
        assert res.converged and res.relative_residual <= 1e-10
        # the same iteration, up to the rounding of the sums (the apply test).
        # With the cycle (about 10 iterations) that changes the count by one at
        # most.  Jacobi's 300-odd erratic BiCGSTAB iterations amplify it into
        # another path where the two kernels round differently (on an AMD EPYC:
        # 315 against 351, 352 against 479 iterations, the solutions differing
        # by a constant of 1e-10, the mode the bordered row pins only to the
        # residual), so there the answers are compared, not the paths
        if preconditioner == "multilevel":
            assert abs(res.iterations - alone.iterations) <= 1, (res.iterations,
                                                                 alone.iterations)
        scale = np.abs(alone.x).max()
        diff = res.x - alone.x
        assert np.abs(diff - diff.mean()).max() <= 1e-8 * scale
        assert res.border == pytest.approx(alone.border, abs=1e-8 * max(abs(alone.border), 1))
        # its residual, recomputed here
        Ad = A.to_scipy()
        x = np.append(res.x, res.border)
        rhs = np.append(B[:, c], 0.0)
        assert np.linalg.norm(rhs - Ad @ x) <= 1.01e-10 * np.linalg.norm(rhs)


def test_joint_solve_of_the_decomposition_rows(decomposition_rows):
    """The default's systems on random points: both potentials to tol, the
    iterations of the solves alone."""
    A, M, B, tol = decomposition_rows
    joint = A.solve_columns(B, tol=tol, preconditioner=M)
    for c, res in enumerate(joint):
        alone = A.solve(B[:, c], tol=tol, preconditioner=M)
        assert res.converged and res.relative_residual <= tol
        assert abs(res.iterations - alone.iterations) <= 1
        assert np.abs(res.x - alone.x).max() <= 1e-6 * np.abs(alone.x).max()


def test_a_zero_column_is_zero_at_once_and_frees_the_other(bordered):
    A, B = bordered
    Z = B.copy()
    Z[:, 0] = 0.0
    zero, other = A.solve_columns(Z, tol=1e-10)
    assert zero.converged and zero.iterations == 0 and not zero.x.any()
    alone = A.solve(B[:, 1], tol=1e-10)
    assert other.converged and abs(other.iterations - alone.iterations) <= 1


def test_a_column_that_converges_first_is_frozen(bordered):
    """The two columns need different counts: the one that meets tol first
    stops at its own solve's count, with its own history, while the other
    goes on; identical columns stay identical.  At tol 1e-8: the joint and the
    single solves sum their reductions in different orders, a 1e-16 relative
    difference that BiCGSTAB amplifies (measured on this matrix: the residual
    histories part by 1e-13 .. 1e-8 relative in the teens, O(1) by iteration
    25), so near 1e-11 the counts
    part by rounding alone (26 against 28 after the cubic stencil's moment
    sums were reordered) while at 1e-8 (18 and 20 iterations) they agree."""
    A, B = bordered
    alone = [A.solve(B[:, c], tol=1e-8) for c in range(2)]
    joint = A.solve_columns(B, tol=1e-8)
    assert alone[0].iterations != alone[1].iterations     # one of them stops first
    for c in range(2):
        assert abs(joint[c].iterations - alone[c].iterations) <= 1
        assert len(joint[c].history) == joint[c].iterations + 1
    twins = A.solve_columns(np.stack([B[:, 0], B[:, 0]], axis=1), tol=1e-8)
    assert twins[0].iterations == twins[1].iterations
    assert np.array_equal(twins[0].x, twins[1].x)


def test_a_failing_column_is_reported_as_its_own_solve_and_the_other_converges(bordered):
    A, B = bordered
    bad = B.copy()
    bad[5, 1] = np.nan
    with pytest.raises(SolverError) as info:
        A.solve_columns(bad, tol=1e-10)
    assert info.value.reason == "non-finite"
    good, failed = A.solve_columns(bad, tol=1e-10, raise_on_failure=False)
    assert good.converged and good.relative_residual <= 1e-10
    assert not failed.converged and failed.reason == "non-finite"


def test_the_iteration_cap_counts_the_joint_iterations(bordered):
    A, B = bordered
    results = A.solve_columns(B, tol=1e-14, max_iterations=3, raise_on_failure=False,
                              preconditioner="jacobi")
    for res in results:
        assert res.reason == "max_iterations" and res.iterations == 3
        assert len(res.history) == 4


def test_operators_without_columns_are_solved_one_column_after_the_other():
    """A CSR matrix has no column kernels: bicgstab_columns solves each alone."""
    import scipy.sparse as sp
    n = 200
    T = sp.diags([-1.0, 2.05, -1.0], [-1, 0, 1], shape=(n, n)).tocsr()
    A = CSRMatrix.from_scipy(T)
    rng = np.random.default_rng(1)
    B = rng.standard_normal((n, 2))
    results = krylov.bicgstab_columns(A, B, tol=1e-10)
    for c, res in enumerate(results):
        alone = krylov.bicgstab(A, B[:, c], tol=1e-10)
        assert res.iterations == alone.iterations
        assert np.array_equal(res.x, alone.x)


def test_the_matrix_and_its_preconditioner_are_freed_without_the_cycle_collector():
    """The matrix caches its multilevel preconditioner; the preconditioner must
    not refer back to the matrix, or the two (gigabytes at 1M particles) stay
    alive until Python's cycle collector happens to run."""
    import gc
    import weakref
    F = fields.get("gaussian")
    pts = layouts.sample(F.domain, 2000, "random", seed=5)
    gc.collect()
    gc.disable()
    try:
        P = poisson_problems(pts, F.evaluate(pts).v, F.domain, boundary_condition="neumann")
        M = P.A.multilevel(**dict(P.opts.multilevel_options))
        P.A.solve_columns(np.stack([P.rhs["phi"], P.rhs["psi"]], axis=1), preconditioner=M)
        refs = [weakref.ref(P.A), weakref.ref(M)]
        del P, M
        assert [r() for r in refs] == [None, None]
    finally:
        gc.enable()


def test_three_columns_together(bordered):
    """Any number of columns: the kernels are generic over it."""
    A, B = bordered
    B3 = np.column_stack([B, B[:, 0] - 2.0 * B[:, 1]])
    joint = A.solve_columns(B3, tol=1e-10)
    for c, res in enumerate(joint):
        alone = A.solve(B3[:, c], tol=1e-10)
        assert res.converged and abs(res.iterations - alone.iterations) <= 1
        assert np.abs(res.x - alone.x).max() <= 1e-8 * np.abs(alone.x).max()


class ScipyColumns:
    """An operator that takes several columns (``accepts_columns``), applied in
    numpy: the joint driver's failure paths on systems built to fail."""

    accepts_columns = True

    def __init__(self, matrix):
        self.A = matrix.tocsr()
        self.n = matrix.shape[0]

    def apply(self, x, y):
        self.apply_dot(x, y, y)

    def apply_dot(self, x, y, a):
        X = x.to_numpy()
        cols = 1 if X.ndim == 1 else X.shape[1]
        Y = self.A @ X.reshape(len(X), cols)[: self.n]
        out = y.to_numpy().reshape(-1, cols)
        out[: self.n] = Y
        y.from_numpy(out.reshape(y.to_numpy().shape))
        Aa = Y if a is y else a.to_numpy().reshape(-1, cols)[: self.n]
        ay, yy = (Aa * Y).sum(axis=0), (Y * Y).sum(axis=0)
        return (float(ay[0]), float(yy[0])) if cols == 1 else (ay, yy)

    def diagonal(self, d):
        d.from_numpy(np.resize(self.A.diagonal(), d.shape[0]).astype(runtime.np_real()))


def _both_ways(A, B, **kwargs):
    """The joint solve of the columns of B and each column's solve alone."""
    joint = krylov.bicgstab_columns(ScipyColumns(A), B, raise_on_failure=False, **kwargs)
    alone = [krylov.bicgstab(ScipyColumns(A), B[:, c], raise_on_failure=False, **kwargs)
             for c in range(B.shape[1])]
    return joint, alone


def test_a_column_that_breaks_down_fails_alone_while_the_other_converges():
    """A block diagonal system: an SPD block, where the first column lives, and
    a skew block, where <r, A r> = 0 breaks the second column down at every
    restart.  The second fails with the reason, count and message of its own
    solve; the first converges as alone."""
    import scipy.sparse as sp
    S = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(30, 30))
    A = sp.block_diag([S, sp.csr_matrix(np.array([[0.0, 1.0], [-1.0, 0.0]]))]).tocsr()
    B = np.zeros((32, 2))
    B[:30, 0] = np.random.default_rng(2).standard_normal(30)
    B[30, 1] = 1.0
    joint, alone = _both_ways(A, B, tol=1e-10, preconditioner=None)
    assert joint[0].converged and abs(joint[0].iterations - alone[0].iterations) <= 1
    assert np.abs(joint[0].x - alone[0].x).max() <= 1e-8 * np.abs(alone[0].x).max()
    assert joint[1].reason == alone[1].reason == "breakdown"
    assert joint[1].iterations == alone[1].iterations
    assert joint[1].message == alone[1].message and "restarts did not cure it" in joint[1].detail
    assert not joint[1].x.any()
    with pytest.raises(SolverError) as info:
        krylov.bicgstab_columns(ScipyColumns(A), B, tol=1e-10, preconditioner=None)
    assert info.value.reason == "breakdown"


def test_the_cap_stops_the_slow_column_after_the_fast_one_converged():
    """An eigenvector converges at once and is frozen; a random right-hand side
    meets the cap with the count, history and residual of its solve alone."""
    import scipy.sparse as sp
    n = 60
    A = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n)).tocsr()
    B = np.stack([np.sin(3 * np.pi * np.arange(1, n + 1) / (n + 1)),
                  np.random.default_rng(5).standard_normal(n)], axis=1)
    joint, alone = _both_ways(A, B, tol=1e-10, max_iterations=6)
    assert joint[0].converged and joint[0].iterations == alone[0].iterations <= 2
    assert len(joint[0].history) == joint[0].iterations + 1
    assert joint[1].reason == alone[1].reason == "max_iterations"
    assert joint[1].iterations == 6 and len(joint[1].history) == 7
    np.testing.assert_allclose(joint[1].history, alone[1].history, rtol=1e-10)
    assert joint[1].relative_residual == pytest.approx(alone[1].relative_residual, rel=1e-10)
