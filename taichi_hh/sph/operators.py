"""SPH differential operators in 2D as precomputed pair coefficients.

One mechanism serves every variant.  For a particle ``i`` with neighbours
``j`` (from a :class:`~taichi_hh.sph.neighbors.PairList`), every operator is

    gradient   grad f_i = sum_j G_ij (f_j - f_i) + s_i f_i          (G_ij a 2-vector)
    divergence div v_i  = sum_j G_ij . (v_j - v_i) + s_i . v_i
    curl       curl v_i = div (J v)_i,  J(v1, v2) = (v2, -v1)       (Petronetto Eq. 4)
    Laplacian  lap f_i  = sum_j C_ij (f_j - f_i) + c_i f_i          (C_ij a scalar)

The variant only changes the coefficients, computed once per particle
configuration (:meth:`Operators.gradient_coefficients`,
:meth:`Operators.laplacian_coefficients`); applying an operator is then a
gather over the pair list, like a sparse matrix-vector product.  Difference
forms have ``s_i = 0`` and are therefore exactly zero on constants.

The variants and how their coefficients are computed: :mod:`taichi_hh.sph.stencils`.

Operators evaluate at every particle of the set, taking all particles
(fluid, boundary, ghost) as neighbours; the caller decides which rows it uses.
"""

from dataclasses import dataclass

import taichi as ti

from .. import runtime
from ..errors import NeighbourError
from .kernels import kernel_id, kernel_terms
from .particles import BOUNDARY, FLUID
from .stencils import (ALL_KINDS, GRADIENT_VARIANTS, LAPLACIAN_VARIANTS,
                       fit_decomposition_stencils, fit_gradient_stencil, fit_laplacian_stencil,
                       kind_bits, variant_id, weight_gradient_by_mean_density,
                       weight_laplacian_by_mean_density)
from .support import pair_support


# ---------------------------------------------------------------------------
# Taichi kernels

@ti.kernel
def number_density(kernel_id: ti.template(), pos: ti.types.ndarray(), mass: ti.types.ndarray(),
             n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
             adaptive: ti.template(), hs: ti.types.ndarray(),
             rho: ti.types.ndarray(), vol: ti.types.ndarray()):
    """rho_i = sum_j m_j W_ij including j = i (Petronetto Sec. 5a); V_i = m_i / rho_i.
    ``H`` the support, or (``adaptive``) per particle ``hs`` (:mod:`taichi_hh.sph.support`)."""
    for i in range(n):
        W0, _F0, _L0 = kernel_terms(kernel_id, 0.0, pair_support(adaptive, hs, i, i, H))
        s = mass[i] * W0
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            W, _F, _L = kernel_terms(kernel_id, (pos[i] - pos[j]).norm(),
                                     pair_support(adaptive, hs, i, j, H))
            s += mass[j] * W
        rho[i] = s
        vol[i] = mass[i] / s



@ti.kernel
def _apply_difference_stencil(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                              coef: ti.types.ndarray(), s: ti.types.ndarray(),
                              f: ti.types.ndarray(), out: ti.types.ndarray()):
    """out_i = s_i f_i + sum_j coef_ij (f_j - f_i): the gradient (coef a 2-vector)
    and the Laplacian (coef a scalar) of a scalar field, one kernel for both."""
    for i in range(n):
        fi = f[i]
        acc = s[i] * fi
        for k in range(offsets[i], offsets[i + 1]):
            acc += coef[k] * (f[nbrs[k]] - fi)
        out[i] = acc


@ti.kernel
def _apply_divergence(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                      G: ti.types.ndarray(), s: ti.types.ndarray(), v: ti.types.ndarray(),
                      rotate: ti.i32, out: ti.types.ndarray()):
    # rotate = 1 evaluates div(J v) = curl v with J(v1, v2) = (v2, -v1)
    for i in range(n):
        vi = v[i]
        if rotate:
            vi = ti.Vector([vi[1], -vi[0]])
        acc = s[i].dot(vi)
        for k in range(offsets[i], offsets[i + 1]):
            vj = v[nbrs[k]]
            if rotate:
                vj = ti.Vector([vj[1], -vj[0]])
            acc += G[k].dot(vj - vi)
        out[i] = acc


@ti.kernel
def _apply_divergence_curl(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                           G: ti.types.ndarray(), s: ti.types.ndarray(), v: ti.types.ndarray(),
                           out: ti.types.ndarray()):
    """out_i = (div v_i, curl v_i) in one pass over the pairs: the values of
    ``_apply_divergence`` with rotate 0 and 1."""
    for i in range(n):
        vi = v[i]
        ri = ti.Vector([vi[1], -vi[0]])
        acc = s[i].dot(vi)
        rot = s[i].dot(ri)
        for k in range(offsets[i], offsets[i + 1]):
            vj = v[nbrs[k]]
            rj = ti.Vector([vj[1], -vj[0]])
            acc += G[k].dot(vj - vi)
            rot += G[k].dot(rj - ri)
        out[i] = ti.Vector([acc, rot])


@ti.kernel
def _apply_gradient_pair(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                         G: ti.types.ndarray(), s: ti.types.ndarray(), f: ti.types.ndarray(),
                         out_a: ti.types.ndarray(), out_b: ti.types.ndarray()):
    """The gradients of two scalar fields (the columns of ``f``) in one pass over
    the pairs: the values of ``_apply_difference_stencil`` on each."""
    for i in range(n):
        fi = f[i]
        acc_a = s[i] * fi[0]
        acc_b = s[i] * fi[1]
        for k in range(offsets[i], offsets[i + 1]):
            fj = f[nbrs[k]]
            acc_a += G[k] * (fj[0] - fi[0])
            acc_b += G[k] * (fj[1] - fi[1])
        out_a[i] = acc_a
        out_b[i] = acc_b


@ti.kernel
def _laplacian_diagonal(n: ti.i32, offsets: ti.types.ndarray(), C: ti.types.ndarray(),
                        s: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(n):
        d = s[i]
        for k in range(offsets[i], offsets[i + 1]):
            d -= C[k]
        out[i] = d


@ti.func
def shepard_weight(kernel_id: ti.template(), pos: ti.template(), vol: ti.template(), i, j, H):
    """V_j W_ij: the weight of particle j in the Shepard sum at i (Petronetto Eq. 14);
    ``H`` the pair's support."""
    W, _F, _L = kernel_terms(kernel_id, (pos[i] - pos[j]).norm(), H)
    return vol[j] * W


@ti.func
def shepard_sums(kernel_id: ti.template(), i, offsets: ti.template(), nbrs: ti.template(),
                 pos: ti.template(), vol: ti.template(), kind: ti.template(), H,
                 adaptive: ti.template(), hs: ti.template(), src_kinds, f: ti.template(), num,
                 den):
    """(num + sum_j V_j W_ij f_j, den + sum_j V_j W_ij) over the neighbours j of i
    whose kind is in the bit mask ``src_kinds``: the numerator and denominator of
    the Shepard-normalised sum of ``f`` (scalar or vector), continued from
    ``num``, ``den`` (the caller's own terms, added first)."""
    for k in range(offsets[i], offsets[i + 1]):
        j = nbrs[k]
        if (src_kinds >> kind[j]) & 1:
            w = shepard_weight(kernel_id, pos, vol, i, j, pair_support(adaptive, hs, i, j, H))
            num += w * f[j]
            den += w
    return num, den


@ti.kernel
def _shepard(kernel_id: ti.template(), pos: ti.types.ndarray(), vol: ti.types.ndarray(), n: ti.i32,
             offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), H: float,
             adaptive: ti.template(), hs: ti.types.ndarray(),
             f: ti.types.ndarray(), out: ti.types.ndarray(), kind: ti.types.ndarray(),
             src_kinds: ti.i32):
    """Shepard-normalised interpolation (Petronetto Eq. 14) from the neighbours of
    the given kinds, the particle itself included when its kind is one of them."""
    for i in range(n):
        W0, _F0, _L0 = kernel_terms(kernel_id, 0.0, pair_support(adaptive, hs, i, i, H))
        num = out[i] * 0.0
        den = 0.0
        if (src_kinds >> kind[i]) & 1:
            num += vol[i] * W0 * f[i]
            den += vol[i] * W0
        num, den = shepard_sums(kernel_id, i, offsets, nbrs, pos, vol, kind, H, adaptive, hs,
                                src_kinds, f, num, den)
        if den > 0.0:
            out[i] = num / den
        else:
            out[i] = num * 0.0


# ---------------------------------------------------------------------------

@dataclass
class GradientStencil:
    """Pair coefficients G_ij and self coefficients s_i of one gradient variant."""
    G: object
    s: object
    variant: str
    row_kinds: tuple = ALL_KINDS
    source_kinds: tuple = ALL_KINDS


@dataclass
class LaplacianStencil:
    """Pair coefficients C_ij and self coefficients c_i of one Laplacian variant."""
    C: object
    s: object
    variant: str
    row_kinds: tuple = ALL_KINDS
    source_kinds: tuple = ALL_KINDS


class Operators:
    """SPH operators on a binned particle set and its pair list.

    ``particles`` must carry mass; call :meth:`compute_density` (summation)
    or fill ``density``/``volume`` yourself before building coefficients.
    supports: optional per-slot kernel supports (a Taichi array, slot order),
    the adaptive support of :mod:`taichi_hh.sph.support` (pairs then use
    ``max(H_i, H_j)``; ``support`` is their largest); default the fixed ``support``.
    """

    def __init__(self, particles, pairs, support: float, kernel: str = "wendland",
                 supports=None):
        runtime.ensure_init()
        self.particles = particles
        self.pairs = pairs
        self.support = float(support)
        self.kernel = kernel
        self.kernel_id = int(kernel_id(kernel))    # a plain int: the kernels take it as a template
        # stands in for the gradient arrays of a Laplacian-only coefficient build
        self._no_vectors = runtime.array(runtime.real_dtype(), 1, vector=2)
        self._no_scalars = runtime.array(runtime.real_dtype(), 1)
        self.supports = supports
        if supports is None:                       # fixed support: never read by the kernels
            supports = runtime.array(runtime.real_dtype(), 1)
        self.adaptive = int(self.supports is not None)
        self._hs = supports

    def support_args(self):
        """``(H, adaptive, hs)``: the support arguments of the operator kernels."""
        return self.support, self.adaptive, self._hs

    @property
    def n(self) -> int:
        return self.particles.n

    def _pair_args(self):
        return self.pairs.offsets, self.pairs.neighbours

    def compute_density(self) -> None:
        p = self.particles
        number_density(self.kernel_id, p.position, p.mass, p.n, *self._pair_args(),
                       *self.support_args(), p.density, p.volume)

    def _check_bad(self, what: str, bad: int) -> None:
        if bad >= 0:
            p = self.particles
            pos = p.position.to_numpy()[bad]
            orig = int(p.original_index.to_numpy()[bad])
            count = int(self.pairs.counts()[bad])
            support = (self.support if self.supports is None
                       else float(self.supports.to_numpy()[bad]))
            raise NeighbourError(
                f"{what}: the correction matrix of particle {orig} at ({pos[0]:.6g}, {pos[1]:.6g}) "
                f"is singular: it has {count} neighbours within the kernel support "
                f"{support:.6g}, too few or all on one line. Increase the support "
                "(support_ratio) or use an uncorrected variant.")

    def gradient_coefficients(self, variant: str = "corrected",
                              row_kinds=ALL_KINDS, source_kinds=ALL_KINDS,
                              density_weighted: bool = False, into=None) -> GradientStencil:
        """Coefficients of a gradient variant for the rows whose particle kind is in
        ``row_kinds`` (other rows get zeros: e.g. ghosts, which need no derivatives),
        summing over the neighbours whose kind is in ``source_kinds``.  into: the
        arrays ``(G, s)`` to write (2-vector ndarrays of at least as many rows as
        pairs and particles), for a caller that keeps them across particle
        configurations; default new ones."""
        vid = variant_id(variant, GRADIENT_VARIANTS)
        p = self.particles
        real = runtime.real_dtype()
        if into is None:
            G = runtime.array(real, max(self.pairs.n_pairs, 1), vector=2, zeroed=False)
            s = runtime.array(real, max(p.n, 1), vector=2, zeroed=False)
        else:
            G, s = into
            if G.shape[0] < self.pairs.n_pairs or s.shape[0] < p.n:
                raise ValueError(f"gradient arrays too small: {G.shape[0]} pair and {s.shape[0]} "
                                 f"particle rows for {self.pairs.n_pairs} pairs, {p.n} particles")
        bad = fit_gradient_stencil(self.kernel_id, vid, p.position, p.mass, p.density, p.n,
                               *self._pair_args(), *self.support_args(), G, s, p.kind,
                               kind_bits(row_kinds), kind_bits(source_kinds), p.normal)
        self._check_bad(f"{variant} gradient", bad)
        if density_weighted:
            if variant in ("basic", "symmetric"):
                raise ValueError("density weighting needs a difference-form gradient")
            weight_gradient_by_mean_density(p.n, *self._pair_args(), p.density, G, G)
        return GradientStencil(G, s, variant, tuple(row_kinds), tuple(source_kinds))

    def laplacian_coefficients(self, variant: str = "corrected",
                               row_kinds=ALL_KINDS, source_kinds=ALL_KINDS,
                               density_weighted: bool = False, into=None,
                               gradient_into=None):
        """Coefficients of a Laplacian variant for the rows of the given kinds,
        summing over neighbours of the given kinds.  ``density_weighted`` turns it
        into div(grad f / rho) (pair coefficient times 2 / (rho_i + rho_j)); only
        for the difference forms, whose self coefficient is zero.  into: the
        arrays ``(C, s)`` to write (scalar ndarrays of at least as many rows as
        pairs and particles); default new ones.  gradient_into (corrected variant
        only, what the two-phase flow needs): arrays ``(G, s, Cw, Gw, grad_one)``;
        then the corrected gradient's coefficients ``(G, s)`` of the same rows and
        sources (the values :meth:`gradient_coefficients` gives), both stencils
        weighted by the pair's mean density (``Cw``, ``Gw``: the values of
        ``density_weighted=True``) and, per row, ``grad_one`` = sum_j V_j grad W_ij
        (the basic gradient of 1) come from the same pair passes, and the result
        is the four stencils ``(Laplacian, gradient, weighted Laplacian, weighted
        gradient)``, the weighted ones sharing the self coefficients (zero for
        these difference forms)."""
        vid = variant_id(variant, LAPLACIAN_VARIANTS)
        p = self.particles
        real = runtime.real_dtype()
        if into is None:
            C = runtime.array(real, max(self.pairs.n_pairs, 1), zeroed=False)
            s = runtime.array(real, max(p.n, 1), zeroed=False)
        else:
            C, s = into
            if C.shape[0] < self.pairs.n_pairs or s.shape[0] < p.n:
                raise ValueError(f"Laplacian arrays too small: {C.shape[0]} pair and {s.shape[0]} "
                                 f"particle rows for {self.pairs.n_pairs} pairs, {p.n} particles")
        with_gradient = gradient_into is not None
        if with_gradient:
            if variant != "corrected" or density_weighted:
                raise ValueError("gradient_into: only with the corrected Laplacian, "
                                 "not density weighted (the weighted copies come with it)")
            G, sG, Cw, Gw, grad_one = gradient_into
            if min(G.shape[0], Cw.shape[0], Gw.shape[0]) < self.pairs.n_pairs \
                    or min(sG.shape[0], grad_one.shape[0]) < p.n:
                raise ValueError(f"gradient arrays too small for {self.pairs.n_pairs} pairs, "
                                 f"{p.n} particles")
        else:
            G = sG = Gw = grad_one = self._no_vectors
            Cw = self._no_scalars
        bad = fit_laplacian_stencil(self.kernel_id, vid, p.position, p.mass, p.density, p.n,
                                *self._pair_args(), *self.support_args(), C, s, p.kind,
                                kind_bits(row_kinds), kind_bits(source_kinds), with_gradient,
                                G, sG, Cw, Gw, grad_one)
        self._check_bad(f"{variant} Laplacian", bad)
        if density_weighted:
            if variant == "basic":
                raise ValueError("density weighting needs a difference-form Laplacian")
            weight_laplacian_by_mean_density(p.n, *self._pair_args(), p.density, C, C)
        rows, sources = tuple(row_kinds), tuple(source_kinds)
        lap = LaplacianStencil(C, s, variant, rows, sources)
        if with_gradient:
            return (lap, GradientStencil(G, sG, variant, rows, sources),
                    LaplacianStencil(Cw, s, variant, rows, sources),
                    GradientStencil(Gw, sG, variant, rows, sources))
        return lap

    def decomposition_coefficients(self):
        """The default decomposition's three stencils from one kernel
        (:func:`~taichi_hh.sph.stencils.fit_decomposition_stencils`): ``(divergence, gradient, laplacian)``, what
        ``gradient_coefficients("cubic", (FLUID,), (FLUID,))``,
        ``gradient_coefficients("quadratic", (FLUID, BOUNDARY))`` and
        ``laplacian_coefficients("corrected", (FLUID,))`` give, up to round-off."""
        p = self.particles
        real = runtime.real_dtype()
        npairs, size = max(self.pairs.n_pairs, 1), max(p.n, 1)
        G3, G2 = (runtime.array(real, npairs, vector=2, zeroed=False) for _ in range(2))
        s3, s2 = (runtime.array(real, size, vector=2, zeroed=False) for _ in range(2))
        C = runtime.array(real, npairs, zeroed=False)
        sC = runtime.array(real, size, zeroed=False)
        bad = fit_decomposition_stencils(self.kernel_id, p.position, p.mass, p.density, p.n,
                                    *self._pair_args(), *self.support_args(), p.kind,
                                    G3, s3, G2, s2, C, sC, p.normal)
        for what, b in zip(("cubic gradient", "quadratic gradient", "corrected Laplacian"), bad):
            self._check_bad(what, b)
        return (GradientStencil(G3, s3, "cubic", (FLUID,), (FLUID,)),
                GradientStencil(G2, s2, "quadratic", (FLUID, BOUNDARY), ALL_KINDS),
                LaplacianStencil(C, sC, "corrected", (FLUID,), ALL_KINDS))

    def density_weighted(self, st: LaplacianStencil, into=None) -> LaplacianStencil:
        """A copy of a difference-form Laplacian's coefficients times
        2 / (rho_i + rho_j): what ``laplacian_coefficients(..., density_weighted=True)``
        returns, without computing the coefficients again.  into: the pair array
        to write (at least as many rows as pairs); default a new one."""
        if st.variant == "basic":
            raise ValueError("density weighting needs a difference-form Laplacian")
        if into is None:
            into = runtime.array(runtime.real_dtype(), st.C.shape)
        elif into.shape[0] < self.pairs.n_pairs:
            raise ValueError(f"Laplacian array too small: {into.shape[0]} rows for "
                             f"{self.pairs.n_pairs} pairs")
        weight_laplacian_by_mean_density(self.particles.n, *self._pair_args(), self.particles.density,
                                st.C, into)
        return LaplacianStencil(into, st.s, st.variant, st.row_kinds, st.source_kinds)

    # ---- applies (Taichi arrays in, Taichi arrays out) --------------------------
    def gradient(self, st: GradientStencil, f, out) -> None:
        _apply_difference_stencil(self.n, *self._pair_args(), st.G, st.s, f, out)

    def divergence(self, st: GradientStencil, v, out) -> None:
        _apply_divergence(self.n, *self._pair_args(), st.G, st.s, v, 0, out)

    def curl(self, st: GradientStencil, v, out) -> None:
        _apply_divergence(self.n, *self._pair_args(), st.G, st.s, v, 1, out)

    def divergence_and_curl(self, st: GradientStencil, v, out) -> None:
        """``out`` (2-vectors): (div v, curl v), one pass for both."""
        _apply_divergence_curl(self.n, *self._pair_args(), st.G, st.s, v, out)

    def gradients(self, st: GradientStencil, f2, out_a, out_b) -> None:
        """The gradients of the two columns of ``f2`` (2-vectors) into ``out_a``,
        ``out_b``, one pass for both."""
        _apply_gradient_pair(self.n, *self._pair_args(), st.G, st.s, f2, out_a, out_b)

    def laplacian(self, st: LaplacianStencil, f, out) -> None:
        _apply_difference_stencil(self.n, *self._pair_args(), st.C, st.s, f, out)

    def laplacian_diagonal(self, st: LaplacianStencil, out) -> None:
        _laplacian_diagonal(self.n, self.pairs.offsets, st.C, st.s, out)

    def shepard(self, f, out, source_kinds=ALL_KINDS) -> None:
        """Shepard interpolation of f (scalar or vector) at every particle from the
        neighbours of the given kinds; 0 where there are none."""
        p = self.particles
        _shepard(self.kernel_id, p.position, p.volume, p.n, *self._pair_args(), *self.support_args(),
                 f, out, p.kind, kind_bits(source_kinds))
