"""The flow's exact-projection clean-up as a matrix: its system assembled with
scipy, its conditioning and the preconditioners that would make it cheap.

The clean-up (``FlowParams.exact_projection``) solves ``S lam = D w`` with
``S = D M^-1 D^T``, ``D`` the corrected SPH divergence of the fluid rows (walls
at rest) and ``w`` the velocity the Poisson step left.  :func:`capture_cleanup`
takes one flow step and records what the clean-up saw; :func:`assemble` builds
``D`` and ``S`` from it (checked against the flow's own ``D w``), and the
remaining functions measure ``S``: Jacobi-CG histories, extreme and small
eigenvalues, and plain-aggregation AMG with lattice null modes as candidates.
Used by ``benchmarks/projection_conditioning.py``, whose docstring has the
findings.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..flow.twophase import TwoPhaseFlow
from ..sph.particles import FLUID


def advance(points, phases, spacing, params, t_end: float):
    """A flow from these particles advanced to ``t_end``: (state dict, volume
    error (mean, max) at the end, median step seconds over the steps after
    the first, from the flow's own clock)."""
    flow = TwoPhaseFlow(points, phases, spacing, params)
    seconds = []
    while flow.time < t_end:
        seconds.append(flow.step()["seconds"]["total"])
    return flow.state_dict(), flow.volume_error(), float(np.median(seconds[1:]))


def _record_cleanup(seen: dict):
    """A :attr:`TwoPhaseFlow.step_callback` that keeps in ``seen`` what the
    clean-up sees (its ``"clean_up"`` event) and the pairs and particles it
    works on."""
    def record(flow, event, data):
        if event != "clean_up":
            return
        p, st = flow.particles, data["operators"].gradient
        n = p.n
        offsets = flow.pairs.offsets.to_numpy()[: n + 1]
        seen.update(w=data["velocity"].copy(), d=data["divergence"].copy(),
                    norm_before=data["norm_before"], G=st.G.to_numpy()[: offsets[-1]],
                    s=st.s.to_numpy()[:n], offsets=offsets,
                    nbrs=flow.pairs.neighbours.to_numpy()[: offsets[-1]],
                    kind=p.get("kind"), mass=p.get("mass"), pos=p.get("position"))
    return record


def capture_cleanup(state: dict, params):
    """One step from ``state`` with the clean-up on (cold start).  Returns (what
    the clean-up saw: velocity ``w``, ``d`` = D w, ``norm_before`` = ||D w*||,
    coefficients ``G``, ``s``, pairs ``offsets``, ``nbrs``, particle ``kind``,
    ``mass``, ``pos``, plus its CG ``iterations`` and ``seconds`` from the
    flow's clock; the spacing)."""
    flow = TwoPhaseFlow.from_state(state, replace(params, exact_projection=True,
                                                  cleanup_warm_start=False))
    flow.lam_by_id[:] = 0.0
    seen = {}
    flow.step_callback = _record_cleanup(seen)
    before = dict(flow.clock.detail)
    info = flow.step()
    after = flow.clock.detail
    seen["iterations"] = info["cleanup_iterations"]
    seen["seconds"] = sum(after.get(k, 0.0) - before.get(k, 0.0)
                          for k in ("operators.cleanup", "solve.cleanup"))
    return seen, flow.dx


def assemble(seen):
    """D (fluid rows x 2 fluid velocities) and S = D M^-1 D^T as scipy matrices,
    with the fluid positions and the right-hand side D w; raises if D w
    disagrees with the flow's by more than 1e-10 (relative)."""
    import scipy.sparse as sp
    kind, off = seen["kind"], seen["offsets"]
    n = len(kind)
    fluid = kind == FLUID
    rows = np.repeat(np.arange(n), np.diff(off))
    cols = seen["nbrs"]
    G = seen["G"]
    diag = seen["s"].copy()
    np.add.at(diag, rows, -G)                    # (D u)_i = s_i.u_i + sum G_ij.(u_j - u_i)
    idx = -np.ones(n, dtype=np.int64)
    fi = np.flatnonzero(fluid)
    idx[fi] = np.arange(len(fi))
    keep = fluid[rows] & fluid[cols]             # wall velocities are zero
    r = np.r_[idx[rows[keep]], idx[rows[keep]], idx[fi], idx[fi]]
    c = np.r_[2 * idx[cols[keep]], 2 * idx[cols[keep]] + 1, 2 * idx[fi], 2 * idx[fi] + 1]
    v = np.r_[G[keep, 0], G[keep, 1], diag[fi, 0], diag[fi, 1]]
    D = sp.csr_matrix((v, (r, c)), shape=(len(fi), 2 * len(fi)))
    D.eliminate_zeros()
    m = seen["mass"][fi]
    S = (D @ sp.diags(np.repeat(1.0 / m, 2)) @ D.T).tocsr()
    d = seen["d"][fi]
    check = np.abs(D @ seen["w"][fi].ravel() - d).max() / max(np.abs(d).max(), 1e-300)
    if check > 1e-10:
        raise RuntimeError(f"assembled D disagrees with the flow's D w by {check:.2e}")
    return D, S, seen["pos"][fi], d


def jacobi(S):
    """The Jacobi preconditioner of S (its inverse diagonal) as a scipy matrix."""
    import scipy.sparse as sp
    return sp.diags(1.0 / S.diagonal())


def cg_history(S, b, M, tol: float, maxiter: int = 5000) -> np.ndarray:
    """True residual norms ||b - S x|| after each iteration of scipy's CG with
    preconditioner M, to relative tolerance ``tol``."""
    import scipy.sparse.linalg as spla
    norms = []
    spla.cg(S, b, rtol=tol, maxiter=maxiter, M=M,
            callback=lambda x: norms.append(float(np.linalg.norm(b - S @ x))))
    return np.array(norms)


def first_below(norms, level) -> int | str:
    """The first iteration (1-based) whose residual norm is <= level, or
    ``">N"`` when none is."""
    hit = np.flatnonzero(norms <= level)
    return int(hit[0]) + 1 if len(hit) else f">{len(norms)}"


def geometric_aggregates(pos, dx, ncand: int, cell: float = 3.0):
    """Aggregation operators per level: cells of ``cell`` spacings, then 2 x 2 cells."""
    import scipy.sparse as sp
    out = []
    cells = np.floor(pos / (cell * dx)).astype(np.int64)
    n = len(pos)
    while True:
        key = cells[:, 0] * 1_000_003 + cells[:, 1]
        uniq, agg = np.unique(key, return_inverse=True)
        nd = n if not out else n * ncand
        out.append(sp.csr_matrix((np.ones(nd), (np.arange(nd), agg if not out
                                                 else np.repeat(agg, ncand)))))
        parents = np.c_[uniq // 1_000_003, uniq % 1_000_003]
        if len(uniq) * ncand <= 200 or len(uniq) < 4:
            return out
        n, cells = len(uniq), parents // 2


def aggregation_iterations(S, d, pos, dx, rtol: float, ncand: int) -> tuple:
    """(CG iterations to ``rtol``, operator complexity) of pyamg plain aggregation
    on :func:`geometric_aggregates`, with the first ``ncand`` candidates of: the
    constants, then the odd-even carriers (-1)^i, (-1)^j, (-1)^(i+j) of the
    lattice indices (the null modes of an SPH gradient on a lattice)."""
    import pyamg
    ij = np.rint((pos - pos.min(axis=0)) / dx).astype(np.int64)
    px, py = (-1.0) ** ij[:, 0], (-1.0) ** ij[:, 1]
    B = np.c_[np.ones(len(d)), px, py, px * py][:, :ncand]
    aggs = geometric_aggregates(pos, dx, ncand)
    ml = pyamg.smoothed_aggregation_solver(
        S, B=B, aggregate=[("predefined", {"AggOp": A}) for A in aggs], smooth=None,
        strength=None, max_levels=len(aggs) + 1, max_coarse=10)
    norms = cg_history(S, d, ml.aspreconditioner(), rtol)
    return first_below(norms, rtol * np.linalg.norm(d)), ml.operator_complexity()


def _jacobi_scaled(S):
    import scipy.sparse as sp
    h = sp.diags(1.0 / np.sqrt(S.diagonal()))
    return h @ S @ h


def extreme_eigenvalues(S) -> tuple[float, float]:
    """(smallest, largest) eigenvalue of the Jacobi-scaled S (ARPACK;
    shift-invert for the smallest)."""
    import scipy.sparse.linalg as spla
    Sh = _jacobi_scaled(S).tocsc()
    lmax = float(spla.eigsh(Sh, k=1, which="LA", return_eigenvectors=False)[0])
    lmin = float(spla.eigsh(Sh, k=1, sigma=0.0, which="LM", return_eigenvectors=False)[0])
    return lmin, lmax


def eigenvalue_counts(S, fractions=(1e-3, 1e-2)) -> list:
    """How many eigenvalues of the Jacobi-scaled S lie below each fraction of the
    largest (dense: O(N^3))."""
    import scipy.linalg as sl
    ev = sl.eigh(_jacobi_scaled(S).toarray(), eigvals_only=True)
    return [int((ev < f * ev[-1]).sum()) for f in fractions]
