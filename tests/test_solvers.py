"""Correctness of the Krylov solvers in taichi_hh.linalg.krylov and of the CSR
matrix in taichi_hh.linalg.csr (no timing assertions)."""
import math
import os

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from taichi_hh import runtime

from taichi_hh.linalg import krylov as solvers
from taichi_hh.linalg.csr import CSRMatrix
from taichi_hh.errors import InputError, SolverError

_HAS_CONFTEST = os.path.exists(os.path.join(os.path.dirname(__file__), "conftest.py"))

if not _HAS_CONFTEST:
    @pytest.fixture(scope="session", autouse=True)
    def _taichi_runtime():
        # init() returns at once when already initialised with these settings.
        runtime.init(arch="cpu", precision="f64",
                     offline_cache_dir=os.path.join(os.path.dirname(__file__), os.pardir,
                                                    ".taichi_cache"))


# --------------------------------------------------------------------------
# Test matrices (scipy)
# --------------------------------------------------------------------------

def _second_difference(N, neumann=False):
    T = sp.diags([-np.ones(N - 1), 2.0 * np.ones(N), -np.ones(N - 1)], [-1, 0, 1]).tolil()
    if neumann:
        T[0, 0] = T[N - 1, N - 1] = 1.0
    return T.tocsr()


def poisson_dirichlet(N):
    """5-point Laplacian on an N x N interior grid; the Dirichlet boundary rows
    are eliminated symmetrically, so the matrix is SPD."""
    I = sp.identity(N, format="csr")
    T = _second_difference(N)
    return (sp.kron(I, T) + sp.kron(T, I)).tocsr() * (N + 1) ** 2


def poisson_neumann(N):
    """Pure-Neumann 5-point Laplacian: singular, null space = constants."""
    I = sp.identity(N, format="csr")
    T = _second_difference(N, neumann=True)
    return (sp.kron(I, T) + sp.kron(T, I)).tocsr()


def convection_diffusion(N, velocity=(40.0, -25.0)):
    """-Laplace(u) + c . grad(u), central differences, Dirichlet: nonsymmetric."""
    h = 1.0 / (N + 1)
    I = sp.identity(N, format="csr")
    T = _second_difference(N) / h**2
    D = sp.diags([-np.ones(N - 1), np.ones(N - 1)], [-1, 1]) / (2 * h)
    return (sp.kron(I, T) + sp.kron(T, I) + velocity[0] * sp.kron(I, D)
            + velocity[1] * sp.kron(D, I)).tocsr()


def rhs(n, seed=0):
    return np.random.default_rng(seed).standard_normal(n)


def csr(A):
    return CSRMatrix.from_scipy(A)


def rel_err(x, ref):
    return np.linalg.norm(x - ref) / np.linalg.norm(ref)


def true_relres(A, x, b):
    return np.linalg.norm(b - A @ x) / np.linalg.norm(b)


class CountingOperator:
    """A protocol operator that is not a CSRMatrix: wraps one and counts
    applies; after ``poison_after`` applies it writes NaN into its output."""

    def __init__(self, matrix, poison_after=None):
        self.inner = matrix
        self.n = matrix.n
        self.count = 0
        self.poison_after = poison_after

    def apply(self, x, y):
        self.inner.apply(x, y)
        self.count += 1
        if self.poison_after is not None and self.count > self.poison_after:
            y[0] = math.nan

    def diagonal(self, d):
        self.inner.diagonal(d)


# --------------------------------------------------------------------------
# CSRMatrix
# --------------------------------------------------------------------------

def _to_numpy_apply(op_apply, x, out_len):
    import taichi as ti
    xa = ti.ndarray(runtime.real_dtype(), shape=(x.size,))
    xa.from_numpy(x)
    ya = ti.ndarray(runtime.real_dtype(), shape=(out_len,))
    op_apply(xa, ya)
    return ya.to_numpy()


def test_csr_apply_transpose_and_diagonals_match_scipy():
    rng = np.random.default_rng(3)
    A = sp.random(40, 25, density=0.2, random_state=4, format="csr") + sp.eye(40, 25)
    M = csr(A)
    assert M.shape == (40, 25) and M.nnz == A.nnz
    x = rng.standard_normal(25)
    y = rng.standard_normal(40)
    np.testing.assert_allclose(_to_numpy_apply(M.apply, x, 40), A @ x, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(_to_numpy_apply(M.apply_transpose, y, 25), A.T @ y,
                               rtol=1e-13, atol=1e-13)
    import taichi as ti
    d = ti.ndarray(runtime.real_dtype(), shape=(25,))
    M.normal_diagonal(d)
    np.testing.assert_allclose(d.to_numpy(), np.asarray(A.multiply(A).sum(axis=0)).ravel(),
                               rtol=1e-13)
    M.diagonal(d)
    np.testing.assert_allclose(d.to_numpy(), A.diagonal(), rtol=1e-13)


def test_apply_dot_returns_the_dot_products_of_its_output():
    import taichi as ti
    rng = np.random.default_rng(5)
    A = sp.random(30, 30, density=0.3, random_state=6, format="csr") + sp.eye(30)
    M = csr(A)
    x, a = rng.standard_normal(30), rng.standard_normal(30)
    nd = [ti.ndarray(runtime.real_dtype(), shape=(30,)) for _ in range(3)]
    nd[0].from_numpy(x)
    nd[2].from_numpy(a)
    ay, yy = M.apply_dot(nd[0], nd[1], nd[2])
    y = A @ x
    np.testing.assert_allclose(nd[1].to_numpy(), y, rtol=1e-13, atol=1e-13)
    assert ay == pytest.approx(a @ y, rel=1e-12) and yy == pytest.approx(y @ y, rel=1e-12)


def test_fused_dot_products_change_nothing():
    """BiCGSTAB takes its dot products from apply_dot when the operator has it
    (CSRMatrix) and computes them after apply otherwise (CountingOperator):
    the same iteration up to rounding (the sums are ordered differently).
    On the nonsymmetric system BiCGSTAB amplifies rounding (measured: the
    histories agree to 1e-9 for 12 iterations, then drift), so there only the
    answers are compared."""
    M = csr(poisson_dirichlet(12))
    b = rhs(M.n)
    fused = solvers.bicgstab(M, b, tol=1e-10)
    plain = solvers.bicgstab(CountingOperator(M), b, tol=1e-10)
    assert fused.iterations == plain.iterations
    np.testing.assert_allclose(fused.history[:20], plain.history[:20], rtol=1e-8)
    np.testing.assert_allclose(fused.x, plain.x, rtol=1e-8, atol=1e-12)
    M = csr(convection_diffusion(12))
    fused = solvers.bicgstab(M, b, tol=1e-10)
    plain = solvers.bicgstab(CountingOperator(M), b, tol=1e-10)
    assert fused.converged and plain.converged
    np.testing.assert_allclose(fused.history[:8], plain.history[:8], rtol=1e-8)
    scale = np.abs(plain.x).max()
    assert np.abs(fused.x - plain.x).max() < 1e-8 * scale


def test_csr_sums_duplicates_and_handles_empty_rows():
    indptr = [0, 2, 2, 4]
    indices = [0, 0, 2, 1]
    data = [1.0, 2.0, 5.0, 7.0]
    M = CSRMatrix(indptr, indices, data)
    ref = sp.csr_matrix((data, indices, indptr), shape=(3, 3))
    x = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(_to_numpy_apply(M.apply, x, 3), ref @ x)


@pytest.mark.parametrize("args, match", [
    (([0, 1, 2], [0, 1], [1.0]), "differ in length"),
    (([0, 2, 1], [0, 1], [1.0, 2.0]), "non-decreasing"),
    (([0, 1, 2], [0, 5], [1.0, 2.0]), "column indices"),
    (([0, 1, 2], [0, 1], [1.0, np.nan]), "non-finite"),
])
def test_csr_rejects_bad_input(args, match):
    with pytest.raises(InputError, match=match):
        CSRMatrix(*args)


# --------------------------------------------------------------------------
# Accuracy against scipy
# --------------------------------------------------------------------------

@pytest.mark.parametrize("method", [solvers.bicgstab, solvers.cg])
def test_spd_poisson_matches_spsolve(method):
    A = poisson_dirichlet(24)
    b = rhs(A.shape[0])
    ref = spla.spsolve(A.tocsc(), b)
    res = method(csr(A), b, tol=1e-10)
    assert res.converged and res.reason == "converged"
    assert res.relative_residual <= 1e-10
    assert true_relres(A, res.x, b) <= 1e-10 * 1.01
    # Error <= cond(A) * tol; cond of this Laplacian is ~ 300.
    assert rel_err(res.x, ref) < 1e-7
    assert res.history[0] == pytest.approx(1.0) and len(res.history) == res.iterations + 1
    np.testing.assert_array_equal(res.x_ndarray.to_numpy(), res.x)


def test_bicgstab_and_cg_agree_on_spd():
    A = poisson_dirichlet(20)
    b = rhs(A.shape[0], seed=5)
    x1 = solvers.bicgstab(csr(A), b, tol=1e-11).x
    x2 = solvers.cg(csr(A), b, tol=1e-11).x
    assert rel_err(x1, x2) < 1e-8


@pytest.mark.parametrize("preconditioner", ["jacobi", None])
def test_bicgstab_nonsymmetric_convection_diffusion(preconditioner):
    A = convection_diffusion(30)
    assert abs(A - A.T).max() > 1.0
    b = rhs(A.shape[0], seed=1)
    ref = spla.spsolve(A.tocsc(), b)
    res = solvers.bicgstab(csr(A), b, tol=1e-10, preconditioner=preconditioner)
    assert res.converged
    assert true_relres(A, res.x, b) <= 1e-10 * 1.01
    assert rel_err(res.x, ref) < 1e-7
    assert res.applies >= 2 * res.iterations


def test_cgnr_nonsymmetric_square():
    A = convection_diffusion(10)
    b = rhs(A.shape[0], seed=2)
    ref = spla.spsolve(A.tocsc(), b)
    res = solvers.cgnr(csr(A), b, tol=1e-10)
    assert res.converged and res.method == "cgnr"
    assert true_relres(A, res.x, b) <= 1e-10 * 1.01
    assert rel_err(res.x, ref) < 1e-6


@pytest.mark.parametrize("preconditioner", ["jacobi", None])
def test_cgnr_overdetermined_consistent(preconditioner):
    rng = np.random.default_rng(7)
    m, n = 300, 80
    A = (sp.random(m, n, density=0.08, random_state=8, format="csr")
         + sp.vstack([sp.identity(n), sp.csr_matrix((m - n, n))])).tocsr()
    A = sp.diags(rng.uniform(0.5, 20.0, m)) @ A     # badly scaled rows, as in a stacked system
    x_true = rng.standard_normal(n)
    b = A @ x_true
    res = solvers.cgnr(csr(A), b, tol=1e-10, preconditioner=preconditioner)
    assert res.converged
    assert true_relres(A, res.x, b) <= 1e-10 * 1.01
    assert rel_err(res.x, x_true) < 1e-7
    assert res.normal_residual is not None and res.normal_residual < 1e-8


def test_cgnr_least_squares_inconsistent():
    rng = np.random.default_rng(9)
    m, n = 120, 30
    A = sp.random(m, n, density=0.2, random_state=10, format="csr") + sp.eye(m, n)
    b = rng.standard_normal(m)      # not in range(A)
    ref = np.linalg.lstsq(A.toarray(), b, rcond=None)[0]
    with pytest.raises(SolverError) as err:    # ||b - A x|| cannot reach tol
        solvers.cgnr(csr(A), b, tol=1e-10)
    assert err.value.reason in ("stagnation", "breakdown")
    res = solvers.cgnr(csr(A), b, tol=1e-10, least_squares=True)
    assert res.converged and res.normal_residual <= 1e-10
    assert rel_err(res.x, ref) < 1e-7
    assert res.relative_residual > 0.1


def test_warm_start_from_exact_solution():
    A = poisson_dirichlet(20)
    b = rhs(A.shape[0])
    exact = spla.spsolve(A.tocsc(), b)
    for method in (solvers.bicgstab, solvers.cg, solvers.cgnr):
        res = method(csr(A), b, exact, tol=1e-8)
        assert res.converged and res.iterations <= 1, method.__name__


def test_warm_start_reduces_iterations():
    A = poisson_dirichlet(20)
    b = rhs(A.shape[0])
    cold = solvers.bicgstab(csr(A), b, tol=1e-10)
    warm = solvers.bicgstab(csr(A), b, cold.x + 1e-6 * rhs(A.shape[0], 3), tol=1e-10)
    assert warm.iterations < cold.iterations


@pytest.mark.parametrize("method", [solvers.bicgstab, solvers.cg])
def test_jacobi_not_worse_on_badly_scaled_diagonal_system(method):
    n = 400
    d = np.logspace(0, 4, n)
    A = sp.diags(d).tocsr()
    b = rhs(n)
    with_jacobi = method(csr(A), b, tol=1e-10)
    without = method(csr(A), b, tol=1e-10, preconditioner=None, max_iterations=5000)
    assert with_jacobi.converged and without.converged
    assert with_jacobi.iterations <= without.iterations
    assert with_jacobi.iterations <= 1
    np.testing.assert_allclose(with_jacobi.x, b / d, rtol=1e-9)


def test_jacobi_not_worse_on_row_scaled_poisson():
    A0 = poisson_dirichlet(16)
    n = A0.shape[0]
    A = (sp.diags(np.logspace(0, 4, n)[np.random.default_rng(0).permutation(n)]) @ A0).tocsr()
    b = rhs(n)
    with_jacobi = solvers.bicgstab(csr(A), b, tol=1e-8)
    without = solvers.bicgstab(csr(A), b, tol=1e-8, preconditioner=None,
                               raise_on_failure=False, max_iterations=3000)
    assert with_jacobi.converged
    assert with_jacobi.iterations <= without.iterations


# --------------------------------------------------------------------------
# Inputs: ndarrays, zero right-hand side, workspace, callback, custom operator
# --------------------------------------------------------------------------

def test_ndarray_inputs_with_larger_capacity():
    import taichi as ti
    A = poisson_dirichlet(12)
    n = A.shape[0]
    b = rhs(n)
    b_nd = ti.ndarray(runtime.real_dtype(), shape=(n + 7,))
    b_nd.from_numpy(np.concatenate([b, np.full(7, 1e30)]))
    x0_nd = ti.ndarray(runtime.real_dtype(), shape=(n + 3,))
    res = solvers.bicgstab(csr(A), b_nd, x0_nd, tol=1e-10)
    assert res.converged
    assert true_relres(A, res.x, b) <= 1e-10 * 1.01
    assert res.x.shape == (n,)


def test_zero_rhs_returns_zero_at_once():
    A = poisson_dirichlet(8)
    n = A.shape[0]
    for method in (solvers.bicgstab, solvers.cg, solvers.cgnr):
        res = method(csr(A), np.zeros(n), rhs(n))
        assert res.converged and res.iterations == 0 and res.applies <= 1
        assert not np.any(res.x) and res.relative_residual == 0.0


def test_workspace_is_reused_between_solves_of_the_same_size():
    A = csr(poisson_dirichlet(10))
    b = rhs(A.n)
    solvers.bicgstab(A, b)
    ws = solvers.get_workspace(A.n)
    vectors = ws.vectors
    first = solvers.bicgstab(A, b)
    second = solvers.bicgstab(A, 2 * b)
    assert solvers.get_workspace(A.n) is ws and ws.vectors == vectors
    # The solution arrays belong to the results, not to the workspace.
    np.testing.assert_allclose(first.x_ndarray.to_numpy() * 2, second.x, rtol=1e-5)


def test_callback_and_custom_operator():
    A = poisson_dirichlet(10)
    op = CountingOperator(csr(A))
    assert isinstance(op, solvers.LinearOperator) and isinstance(op.inner, solvers.LinearOperator)
    seen = []
    res = solvers.bicgstab(op, rhs(op.n), callback=lambda it, rel: seen.append((it, rel)))
    assert res.converged and op.count == res.applies
    assert [it for it, _ in seen] == list(range(1, res.iterations + 1))
    np.testing.assert_allclose([rel for _, rel in seen], res.history[1:])


def test_input_errors():
    A = csr(poisson_dirichlet(6))
    with pytest.raises(InputError, match="shape"):
        solvers.bicgstab(A, np.ones(A.n + 1))
    with pytest.raises(InputError, match="square"):
        solvers.cg(csr(sp.random(5, 3, density=0.5, random_state=0) + sp.eye(5, 3)), np.ones(5))
    with pytest.raises(InputError, match="preconditioner"):
        solvers.cg(A, np.ones(A.n), preconditioner="ilu")
    with pytest.raises(InputError, match="protocol"):
        solvers.bicgstab(object(), np.ones(3))


# --------------------------------------------------------------------------
# Failures: every reason provoked
# --------------------------------------------------------------------------

def _assert_failure(exc_info, reason):
    err = exc_info.value
    assert err.reason == reason
    assert reason in str(err)
    assert f"iteration {err.iteration}" in str(err)
    assert "relative residual" in str(err)


@pytest.mark.parametrize("method", [solvers.bicgstab, solvers.cg])
def test_singular_incompatible_system_is_flagged(method):
    A = poisson_neumann(16)
    b = rhs(A.shape[0], seed=4) + 0.5           # nonzero mean: no solution
    with pytest.raises(SolverError) as err:
        method(csr(A), b, tol=1e-8)
    # BiCGSTAB stagnates; CG's residual grows by orders of magnitude as x runs
    # off along the null space, which the divergence test catches first.
    assert err.value.reason in ("stagnation", "breakdown", "divergence")
    assert err.value.reason in str(err.value)
    res = method(csr(A), b, tol=1e-8, raise_on_failure=False)
    assert not res.converged and res.reason == err.value.reason
    assert res.relative_residual > 1e-8 and res.reason in res.message


def test_singular_compatible_system_converges():
    A = poisson_neumann(16)
    b = rhs(A.shape[0], seed=4)
    b -= b.mean()                                # in the range: solvable
    res = solvers.cg(csr(A), b, tol=1e-8)
    assert res.converged and true_relres(A, res.x, b) <= 1e-8 * 1.01


@pytest.mark.parametrize("method", [solvers.bicgstab, solvers.cg, solvers.cgnr])
def test_nan_in_rhs_is_non_finite_before_iterating(method):
    A = poisson_dirichlet(8)
    b = rhs(A.shape[0])
    b[5] = np.nan
    with pytest.raises(SolverError) as err:
        method(csr(A), b)
    _assert_failure(err, "non-finite")
    assert err.value.iteration == 0
    res = method(csr(A), b, raise_on_failure=False)
    assert not res.converged and res.reason == "non-finite" and res.iterations == 0


def test_nan_in_initial_guess_is_non_finite():
    A = poisson_dirichlet(8)
    x0 = np.zeros(A.shape[0])
    x0[3] = np.inf
    with pytest.raises(SolverError) as err:
        solvers.bicgstab(csr(A), rhs(A.shape[0]), x0)
    _assert_failure(err, "non-finite")


def test_nan_during_iteration_is_non_finite():
    op = CountingOperator(csr(poisson_dirichlet(10)), poison_after=4)
    with pytest.raises(SolverError) as err:
        solvers.bicgstab(op, rhs(op.n))
    _assert_failure(err, "non-finite")
    assert err.value.iteration >= 1


@pytest.mark.parametrize("method", [solvers.bicgstab, solvers.cg, solvers.cgnr])
def test_iteration_cap(method):
    A = csr(poisson_dirichlet(20))
    b = rhs(A.n)
    with pytest.raises(SolverError) as err:
        method(A, b, tol=1e-12, max_iterations=5)
    _assert_failure(err, "max_iterations")
    assert err.value.iteration == 5
    res = method(A, b, tol=1e-12, max_iterations=5, raise_on_failure=False)
    assert not res.converged and res.reason == "max_iterations" and res.iterations == 5
    assert "max_iterations" in res.message
    assert 1e-12 < res.relative_residual < 1.0    # progress was made and is reported
    assert len(res.history) == 6


def test_zero_diagonal_with_jacobi_names_the_row():
    A = poisson_dirichlet(6).tolil()
    A[3, 3] = 0.0
    A = A.tocsr()
    A.eliminate_zeros()
    b = rhs(A.shape[0])
    for method in (solvers.bicgstab, solvers.cg):
        with pytest.raises(InputError, match=r"row 3\b.*zero"):
            method(csr(A), b)
    assert solvers.bicgstab(csr(A), b, preconditioner=None, tol=1e-10).converged


def test_zero_column_with_cgnr_jacobi_names_the_column():
    A = sp.random(20, 6, density=0.5, random_state=1, format="lil") + sp.eye(20, 6)
    A = sp.lil_matrix(A)
    A[:, 2] = 0.0
    with pytest.raises(InputError, match=r"column 2\b.*zero"):
        solvers.cgnr(csr(A.tocsr()), np.ones(20))


def test_bicgstab_breakdown():
    # Skew-symmetric A: <r0, A r0> = 0, so alpha's denominator vanishes at once.
    A = sp.csr_matrix(np.array([[0.0, 1.0], [-1.0, 0.0]]))
    b = np.array([1.0, 0.0])
    with pytest.raises(SolverError) as err:
        solvers.bicgstab(csr(A), b, preconditioner=None)
    _assert_failure(err, "breakdown")
    res = solvers.bicgstab(csr(A), b, preconditioner=None, raise_on_failure=False)
    assert res.reason == "breakdown" and not res.converged
    assert res.relative_residual == pytest.approx(1.0)       # x left at x0 = 0
    np.testing.assert_array_equal(res.x, 0.0)


def test_cg_breakdown_on_indefinite_matrix():
    A = sp.csr_matrix(np.diag([1.0, -1.0]))
    with pytest.raises(SolverError) as err:
        solvers.cg(csr(A), np.array([1.0, 1.0]), preconditioner=None)
    _assert_failure(err, "breakdown")


@pytest.mark.parametrize("method", [solvers.cg, solvers.bicgstab])
def test_divergence(method):
    # Nearly indefinite: <p, A p> = 1e-8 is small but not a breakdown, and the
    # resulting step blows the residual up by ~1e8.
    A = sp.csr_matrix(np.diag([1.0, -1.0 + 1e-8]))
    with pytest.raises(SolverError) as err:
        method(csr(A), np.array([1.0, 1.0]), preconditioner=None)
    _assert_failure(err, "divergence")
    res = method(csr(A), np.array([1.0, 1.0]), preconditioner=None, raise_on_failure=False,
                 divergence_factor=1e12)
    assert res.converged     # the same solve is fine with a looser divergence test


def test_stagnation_window_is_configurable():
    A = poisson_neumann(12)
    b = rhs(A.shape[0], seed=4) + 0.5
    short = solvers.cg(csr(A), b, raise_on_failure=False, stagnation_window=5)
    long = solvers.cg(csr(A), b, raise_on_failure=False, stagnation_window=20)
    assert short.reason == long.reason == "stagnation"
    assert short.iterations < long.iterations
