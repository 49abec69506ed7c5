"""The adjoint of the SPH divergence and the normal operator ``S = D W^-1 D^T``,
matrix-free: the orthogonal projection of :func:`taichi_hh.hhd.project.project`
and the flow's clean-up step (:mod:`taichi_hh.flow.twophase`, where ``W`` is
the particle mass and only the fluid block is active) share it."""
import taichi as ti

from .. import runtime
from .pointset import PointSet


@ti.kernel
def _adjoint_divergence(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                        reverse: ti.types.ndarray(), G: ti.types.ndarray(),
                        s: ti.types.ndarray(), weight: ti.types.ndarray(),
                        kind: ti.types.ndarray(), rows: ti.i32, cols: ti.i32,
                        lam: ti.types.ndarray(), out: ti.types.ndarray()):
    """out_k = (W^-1 D^T lam)_k for (D v)_i = sum_j G_ij . (v_j - v_i) + s_i . v_i
    restricted to the rows i whose kind is in the bit mask ``rows`` and the
    columns k whose kind is in ``cols`` (out_k = 0 on the other columns):
    (D^T lam)_k = sum_{i ~ k} lam_i G_ik + lam_k (s_k - sum_j G_kj), a gather over
    k's neighbours through the reverse pair index (the relation is symmetric)."""
    for k in range(n):
        acc = ti.Vector.zero(float, 2)
        if (cols >> kind[k]) & 1:
            own = (rows >> kind[k]) & 1
            if own:
                acc = s[k] * lam[k]
            for p in range(offsets[k], offsets[k + 1]):
                j = nbrs[p]
                if (rows >> kind[j]) & 1:
                    acc += lam[j] * G[reverse[p]]
                if own:
                    acc -= lam[k] * G[p]
            acc /= weight[k]
        out[k] = acc


@ti.kernel
def _adjoint_diagonal(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                      G: ti.types.ndarray(), s: ti.types.ndarray(), weight: ti.types.ndarray(),
                      kind: ti.types.ndarray(), rows: ti.i32, cols: ti.i32,
                      out: ti.types.ndarray()):
    """diag(D W^-1 D^T)_i = sum_j |G_ij|^2 / W_j + |s_i - sum_j G_ij|^2 / W_i over
    the columns j (and i) in ``cols``; 1 on rows outside ``rows`` or with an
    empty stencil, where S has a zero row (their unknown stays 0)."""
    for i in range(n):
        d = 0.0
        if (rows >> kind[i]) & 1:
            c = s[i]
            acc = 0.0
            for p in range(offsets[i], offsets[i + 1]):
                g = G[p]
                if (cols >> kind[nbrs[p]]) & 1:
                    acc += g.dot(g) / weight[nbrs[p]]
                c -= g
            d = acc
            if (cols >> kind[i]) & 1:
                d += c.dot(c) / weight[i]
        if d == 0.0:
            d = 1.0
        out[i] = d


class NormalOperator:
    """``S = D W^-1 D^T`` as a linear operator for :mod:`taichi_hh.linalg.krylov`.

    ``D`` is the divergence of the gradient stencil ``st`` (``ops.divergence``)
    restricted to the rows whose particle kind is in ``rows`` and the columns
    (velocities) whose kind is in ``cols``: the velocity of the other columns is
    taken as zero, and :meth:`correction` leaves it zero.  ``weight``: the
    per-particle weight ``W`` of the norm ``sum_k W_k |u_k|^2`` (volumes for
    :func:`project`, masses for the flow's clean-up).  scratch: a 2-vector
    ndarray of at least ``n`` rows for the intermediate ``W^-1 D^T x`` (a
    caller that keeps one across calls), default a new one."""

    def __init__(self, ops, pairs, st, weight, n: int, *, rows=None, cols=None, scratch=None):
        from .operators import ALL_KINDS, kind_bits
        self.ops, self.pairs, self.st, self.weight = ops, pairs, st, weight
        self.n = n
        self.kind = ops.particles.kind
        self.rows = kind_bits(ALL_KINDS if rows is None else rows)
        self.cols = kind_bits(ALL_KINDS if cols is None else cols)
        self.reverse = pairs.reverse_index()
        self.tmp = scratch if scratch is not None else \
            runtime.array(runtime.real_dtype(), max(n, 1), vector=2)

    @classmethod
    def of_pointset(cls, ps: PointSet, st) -> "NormalOperator":
        """Volume-weighted, every point a row and a column (:func:`project`)."""
        return cls(ps.ops, ps.pairs, st, ps.particles.volume, ps.n_total)

    def correction(self, lam, out) -> None:
        """out = W^-1 D^T lam (vector per particle; zero outside ``cols``)."""
        pr = self.pairs
        _adjoint_divergence(self.n, pr.offsets, pr.neighbours, self.reverse, self.st.G,
                            self.st.s, self.weight, self.kind, self.rows, self.cols, lam, out)

    def apply(self, x, y) -> None:
        self.correction(x, self.tmp)
        self.ops.divergence(self.st, self.tmp, y)

    def diagonal(self, d) -> None:
        pr = self.pairs
        _adjoint_diagonal(self.n, pr.offsets, pr.neighbours, self.st.G, self.st.s, self.weight,
                          self.kind, self.rows, self.cols, d)
