"""Our multilevel W-cycle as the preconditioner of two Krylov methods on
Petronetto's Poisson systems: is a slow solve the fault of the preconditioner
or of BiCGSTAB?

BiCGSTAB (ours: two operator applies and two cycles per iteration) against
scipy's GMRES (restart 200: one apply and one cycle per iteration; its
residual norm never rises, so its count measures the preconditioned spectrum
alone).  scipy's GMRES watches the preconditioned residual inside a restart and
the true one between restarts, so it gets up to 5 restarts and both methods'
answers are compared by their true relative residuals.  Used by
``benchmarks/krylov_samples.py``.
"""
from __future__ import annotations

import numpy as np

from .. import runtime
from ..hhd.decompose import poisson_problems
from . import fields

GMRES_RESTART = 200
GMRES_RESTARTS = 5


def gmres_iterations(A_scipy, M, b, tol: float) -> tuple[int, float]:
    """GMRES (scipy, the cycle M as its preconditioner) to ``tol``: (iterations,
    true relative residual ||b - A x|| / ||b|| of its answer)."""
    import scipy.sparse.linalg as spla
    import taichi as ti
    n = A_scipy.shape[0]
    r_nd = runtime.array(ti.f64, n)
    z_nd = runtime.array(ti.f64, n)

    def cycle(r):
        r_nd.from_numpy(np.ascontiguousarray(r, dtype=np.float64))
        M.apply(r_nd, z_nd)
        return z_nd.to_numpy()

    count = [0]

    def tick(_residual):
        count[0] += 1

    x, _info = spla.gmres(A_scipy, b, M=spla.LinearOperator((n, n), matvec=cycle), rtol=tol,
                          restart=GMRES_RESTART, maxiter=GMRES_RESTARTS, callback=tick,
                          callback_type="pr_norm")
    return count[0], float(np.linalg.norm(b - A_scipy @ x) / np.linalg.norm(b))


def compare_on_sample(n: int, seed: int, kappa: float = 1e-2, tol: float = 1e-6) -> list[dict]:
    """Both potentials' systems of the ``gaussian`` field on a 30%-jittered
    lattice of about ``n`` points (``seed``), method ``petronetto2010`` with
    ridge ``kappa``, solved to ``tol`` by both methods: one row per potential."""
    F = fields.get("gaussian")
    pts = F.sample(n, "jittered", seed=seed)
    P = poisson_problems(pts, F.evaluate(pts).v, F.domain, method="petronetto2010",
                         kappa=kappa, remove_mean=True)
    A = P.A.to_scipy().tocsr()
    M = P.A.multilevel()
    rows = []
    for name in ("phi", "psi"):
        res = P.A.solve(P.rhs[name], tol=tol, preconditioner=M, raise_on_failure=False)
        b = np.asarray(P.rhs[name], dtype=np.float64)
        its, rel = gmres_iterations(A, M, b, tol)
        rows.append({"n": n, "seed": seed, "potential": name,
                     "bicgstab_iterations": res.iterations,
                     "bicgstab_cycles": 2 * res.iterations,
                     "bicgstab_relative_residual": res.relative_residual,
                     "gmres_iterations": its, "gmres_relative_residual": rel})
    return rows
