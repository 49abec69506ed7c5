"""The assembled SPH Poisson system: Neumann problems with exact answers, the
solver against scipy on the same matrix, transposes, and reported failures."""
import numpy as np
import pytest
import scipy.sparse.linalg as spl

import taichi_hh as thh
from taichi_hh.sph.particles import BOUNDARY, FLUID, GHOST
from taichi_hh.poisson.matrix import PoissonMatrix
from fieldgen import lattice


def box_boundary(dx):
    """Boundary particles on the unit square's edges at spacing dx, outward normals,
    corner normals averaged (diagonal)."""
    m = int(round(1 / dx))
    t = np.linspace(0, 1, m + 1)
    pts = np.concatenate([np.c_[t, 0 * t], np.c_[t, 1 + 0 * t],
                          np.c_[0 * t[1:-1], t[1:-1]], np.c_[1 + 0 * t[1:-1], t[1:-1]]])
    nrm = np.concatenate([np.tile([0.0, -1.0], (m + 1, 1)), np.tile([0.0, 1.0], (m + 1, 1)),
                          np.tile([-1.0, 0.0], (m - 1, 1)), np.tile([1.0, 0.0], (m - 1, 1))])
    corner = np.isclose(pts[:, 0] % 1, 0) & np.isclose(pts[:, 1] % 1, 0)
    nrm[corner] = np.sign(pts[corner] - 0.5) / np.sqrt(2)
    return pts, nrm


def neumann_square(m, seed=0):
    pts, dx = lattice(m, jitter=0.3, seed=seed)
    ps = thh.PointSet(pts, area=1.0, boundary=box_boundary(dx))
    X = ps.particles.get("position")
    kind = ps.particles.get("kind")
    phi = np.cos(np.pi * X[:, 0]) * np.cos(np.pi * X[:, 1])
    b = np.where(kind == FLUID, -2 * np.pi ** 2 * phi, 0.0)
    return ps, phi, b, kind


def _centered_error(ps, x, phi, kind):
    V = ps.particles.get("volume")
    f = kind == FLUID
    e = x[f] - phi[f]
    return np.abs(e - np.average(e, weights=V[f]))


@pytest.fixture(scope="module")
def neumann_runs():
    out = {}
    for m in (24, 48, 96):
        ps, phi, b, kind = neumann_square(m, seed=m)
        A = PoissonMatrix(ps.ops, bordered=True)
        res = A.solve(b, tol=1e-10)
        out[m] = (ps, A, res, phi, b, kind)
    return out


def test_neumann_unit_square_converges(neumann_runs):
    """phi = cos(pi x) cos(pi y), d phi/dn = 0 on the unit square, 30%-jittered points:
    the potential converges at second order (measured 1.9e-3, 5.1e-4, 1.4e-4)."""
    errs = []
    for m, (ps, A, res, phi, b, kind) in sorted(neumann_runs.items()):
        assert res.converged and res.relative_residual <= 1e-10
        errs.append(_centered_error(ps, res.x, phi, kind).mean())
    order = np.polyfit(np.log([1 / 24, 1 / 48, 1 / 96]), np.log(errs), 1)[0]
    assert order > 1.5, errs
    assert errs[-1] < 3e-4, errs


def test_neumann_gradient_accuracy(neumann_runs):
    ps, A, res, phi, b, kind = neumann_runs[48]
    st = ps.ops.gradient_coefficients("quadratic", row_kinds=(FLUID,),
                                      source_kinds=(FLUID, BOUNDARY))
    x = ps.new_array(1)
    x.from_numpy(res.x)
    g = ps.new_array(2)
    ps.ops.gradient(st, x, g)
    X = ps.particles.get("position")[ps.slot_of]
    exact = np.c_[-np.pi * np.sin(np.pi * X[:, 0]) * np.cos(np.pi * X[:, 1]),
                  -np.pi * np.cos(np.pi * X[:, 0]) * np.sin(np.pi * X[:, 1])]
    err = np.linalg.norm(ps.download(g) - exact, axis=1).mean() / np.linalg.norm(exact, axis=1).mean()
    assert err < 0.01   # measured 0.7%


def test_first_order_neumann_rows_pollute_the_solution():
    """With the first-order corrected gradient in the Neumann rows the boundary error
    (support x curvature) spreads through the solution: about 30x worse than quadratic."""
    ps, phi, b, kind = neumann_square(48, seed=1)
    err = {}
    for grad in ("corrected", "quadratic"):
        res = PoissonMatrix(ps.ops, gradient=grad, bordered=True).solve(b, tol=1e-10)
        err[grad] = _centered_error(ps, res.x, phi, kind).mean()
    assert err["corrected"] > 10 * err["quadratic"]


def test_solver_matches_scipy_on_the_same_matrix(neumann_runs):
    ps, A, res, phi, b, kind = neumann_runs[24]
    S = A.to_scipy()
    ref = spl.spsolve(S.tocsc(), np.append(b, 0.0))
    assert abs(res.border - ref[-1]) < 1e-6 * max(1.0, abs(ref[-1]))
    assert np.abs(res.x - ref[:-1]).max() < 1e-7 * np.abs(ref).max()
    # the matrix-free apply is the assembled matrix
    x = np.random.default_rng(0).normal(size=A.n)
    import taichi as ti
    xa = ti.ndarray(ti.f64, shape=(A.n,))
    ya = ti.ndarray(ti.f64, shape=(A.n,))
    xa.from_numpy(x)
    A.apply(xa, ya)
    assert np.allclose(ya.to_numpy(), S @ x, rtol=1e-12, atol=1e-9)
    A.apply_transpose(xa, ya)
    assert np.allclose(ya.to_numpy(), S.T @ x, rtol=1e-12, atol=1e-9)
    A.normal_diagonal(ya)
    assert np.allclose(ya.to_numpy(), np.asarray(S.multiply(S).sum(axis=0)).ravel(), rtol=1e-12)


def test_bicgstab_and_cg_agree_on_a_symmetric_system():
    """Brookshaw's Laplacian with equal volumes is symmetric; with a ridge term it is
    definite: Jacobi-BiCGSTAB and CG give the same solution."""
    pts, dx = lattice(30, jitter=0.2, seed=4)
    ps = thh.PointSet(pts, area=1.0)
    ps.particles.set("mass", np.full(ps.n_total, dx * dx))
    ps.particles.set("density", np.ones(ps.n_total))
    A = PoissonMatrix(ps.ops, laplacian="brookshaw", kappa=-50.0)
    S = A.to_scipy()
    assert abs(S - S.T).max() < 1e-9 * abs(S).max()
    b = np.sin(3 * ps.particles.get("position")[:, 0])
    r1 = A.solve(b, method="bicgstab", tol=1e-10)
    r2 = A.solve(b, method="cg", tol=1e-10)
    assert np.abs(r1.x - r2.x).max() < 1e-8 * np.abs(r1.x).max()
    assert r2.iterations < r1.applies      # CG: one apply per iteration


def test_incompatible_pure_neumann_without_ridge_is_flagged():
    """kappa = 0, no border: the system is singular and b is not in its range; the
    solve must end flagged (stagnation, breakdown or divergence), never 'converged'."""
    ps, phi, b, kind = neumann_square(24, seed=2)
    b = b + (kind == FLUID) * 5.0          # incompatible: nonzero net source
    A = PoissonMatrix(ps.ops, kappa=0.0)
    res = A.solve(b, tol=1e-10, raise_on_failure=False, max_iterations=5000)
    assert not res.converged
    assert res.reason in ("stagnation", "breakdown", "divergence")
    with pytest.raises(thh.SolverError) as exc:
        A.solve(b, tol=1e-10, max_iterations=5000)
    assert exc.value.reason == res.reason and res.reason in str(exc.value)
    # the bordered system takes the incompatibility into lambda and converges
    resb = PoissonMatrix(ps.ops, bordered=True).solve(b, tol=1e-10)
    assert resb.converged and abs(resb.border) > 1.0


@pytest.mark.parametrize("kappa", [0.0, 0.5, 1.0, 2.0])
def test_bordered_system_is_regular_for_every_ridge(kappa):
    """The border row sum V phi + c lambda = 0: with the fluid rows' A 1 =
    kappa e the candidate null vector (1, -kappa) needs W - c kappa = 0, W =
    sum V.  With c = +W (kept for kappa = 0) that is kappa = 1: the bordered
    matrix was singular there and every solve stagnated; with a ridge the
    corner is now c = -W, regular for every kappa > 0.  The multilevel solve
    matches SuperLU on the assembled bordered matrix."""
    import scipy.sparse.linalg as spl
    ps, phi, b, kind = neumann_square(24, seed=5)
    A = PoissonMatrix(ps.ops, kappa=kappa, bordered=True)
    M = A.to_scipy().tocsc()
    lu = spl.splu(M)
    rhs = np.r_[b, 0.0]
    ref = lu.solve(rhs)
    assert np.linalg.norm(M @ ref - rhs) <= 1e-10 * np.linalg.norm(rhs)
    res = A.solve(b, tol=1e-10, preconditioner="multilevel")
    assert res.converged
    x = np.r_[res.x, res.border]
    assert np.abs(x - ref).max() <= 1e-7 * np.abs(ref).max()


def test_non_finite_and_iteration_cap_are_reported(neumann_runs):
    ps, A, res, phi, b, kind = neumann_runs[24]
    bad = b.copy()
    bad[3] = np.nan
    with pytest.raises(thh.SolverError, match="non-finite") as exc:
        A.solve(bad)
    assert exc.value.reason == "non-finite"
    capped = A.solve(b, tol=1e-12, max_iterations=5, raise_on_failure=False)
    assert capped.reason == "max_iterations" and capped.iterations == 5 and not capped.converged
    with pytest.raises(thh.InputError, match="shape"):
        A.solve(b[:-1])


def test_warm_start(neumann_runs):
    ps, A, res, phi, b, kind = neumann_runs[48]
    again = A.solve(b, x0=res.x, border0=res.border, tol=1e-8)
    assert again.iterations <= 2


def test_ghost_rows_are_shepard_sums():
    """Petronetto Sec. 5b: a ghost's potential equals the Shepard sum of the real
    ones around it: its row is identity minus nonnegative weights summing to one."""
    pts, dx = lattice(20, jitter=0.2, seed=6)
    g = (np.arange(-2, 22) + 0.5) * dx
    G = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    G = G[(G < 0).any(axis=1) | (G > 1).any(axis=1)]
    G = G[np.linalg.norm(G - np.clip(G, 0, 1), axis=1) < 2.0 * dx]
    ps = thh.PointSet(pts, area=1.0, ghosts=G)
    S = PoissonMatrix(ps.ops, laplacian="brookshaw", gradient="difference", kappa=1.0).to_scipy()
    kind = ps.particles.get("kind")
    ghosts = np.flatnonzero(kind == GHOST)
    rows = S[ghosts].toarray()
    assert np.allclose(rows.sum(axis=1), 0.0, atol=1e-12)
    assert np.array_equal(rows[:, ghosts], np.eye(len(ghosts)))
    assert (rows[:, kind == FLUID] <= 0).all()
    assert (rows[:, kind == FLUID] < 0).sum(axis=1).min() >= 1


def test_a_small_system_at_the_cap_is_solved_directly():
    """118 clustered points: the projection's Poisson step took 848-900 of its
    1000 BiCGSTAB iterations, so whether it met tol depended on rounding; a
    system of at most DIRECT_MAX unknowns that BiCGSTAB leaves at the default
    cap or stagnating is solved by dense LU, to tol; a cap the caller sets
    still raises."""
    import warnings
    import taichi_hh as thh
    from taichi_hh.errors import SolverError
    from taichi_hh.poisson.matrix import DIRECT_MAX
    from taichi_hh.validation import layouts
    from taichi_hh.geometry.domain import Box
    assert DIRECT_MAX >= 118
    pts = layouts.sample(Box((0, 0), (1, 1)), 118, "clusters", seed=287)
    v = np.c_[pts[:, 0] - 0.5, pts[:, 1] - 0.5] + 0.3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = thh.project(pts, v, "bbox")
    assert res.max_divergence[-1] < 1e-6 * res.max_divergence[0]
    ps, phi, b, kind = neumann_square(10, seed=1)
    A = PoissonMatrix(ps.ops, bordered=True)
    b = np.append(b, 0.0)                       # the border's row, as solve() appends it
    direct = A.solve_densely_instead(b, 1e-12, SolverError("stuck", reason="stagnation",
                                                      iteration=7, residual=1e-3),
                               "bicgstab", {})
    assert direct.converged and direct.relative_residual <= 1e-12
    assert "dense LU" in direct.message and direct.iterations == 7
    with pytest.raises(SolverError):
        A.solve_densely_instead(b, 1e-12, SolverError("cap", reason="max_iterations", iteration=3,
                                                residual=1e-3), "bicgstab",
                          {"max_iterations": 3})
