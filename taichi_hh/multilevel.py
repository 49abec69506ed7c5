"""Multilevel (aggregation) preconditioner for the SPH Poisson rows.

Jacobi-preconditioned BiCGSTAB needs iterations growing like sqrt(N) on the
SPH Poisson systems; this preconditioner makes them grow slowly, from the
structure we already have: the neighbour grid.

Hierarchy
---------
Level 0 is the particle system, Jacobi-scaled: ``B = D^-1 A`` with ``D`` the
diagonal of ``A``.  Every row of ``B`` then reads ``x_i - sum_j w_ij x_j`` with
weights summing to one (Laplacian, Neumann and Shepard rows all vanish on
constants), whatever the row's kind and scale, so that summing rows of
different kinds into one aggregate keeps a consistent sign and scale.

Level 1 aggregates the particles by cells of a grid of side ``support`` (the
neighbour grid's): piecewise-constant prolongation ``P`` (particle ``i`` takes
its cell's value), restriction ``P^T`` (a cell sums its particles) and the
Galerkin operator ``B_1 = P^T B P``.  Neighbours are closer than the support,
so ``B_1`` couples a cell only to its 3 x 3 block: a 9-point stencil on a
structured grid.  Each further level aggregates 2 x 2 cells, which keeps the
9-point form, down to at most ``COARSEST`` cells, solved by a dense
pseudo-inverse (the coarse operators of a pure Neumann problem are singular:
constants are their null space).  Cells
without particles give empty rows; they are left out (zero correction).

Cycle
-----
A V-cycle with damped Jacobi smoothing (``omega``; one sweep from zero
before the coarse correction, ``post`` sweeps after it) on every level and
the coarse correction scaled by ``correction`` (plain aggregation under-corrects: interpolation
by constants has too much energy; an over-correction of about 1.5-2 is the
classic remedy, Blaheta 1986, Vanek et al. 1996).  The cycle is a fixed
linear operator, so it can precondition BiCGSTAB (right preconditioning:
``A M^-1 y = b``, ``x = M^-1 y``).

The whole cycle is one kernel launch (at 10k particles launches, not
arithmetic, dominate).  On level 0 the pre-smoothing from zero, the residual
and the restriction are one gather loop over cells (a cell's particles are
listed contiguously by a counting sort); the prolongation and the first
post-smoothing sweep are another.  So a cycle costs ``1 + post`` passes over
the pairs plus the (cheap) structured levels.

Bordered systems (:class:`~taichi_hh.poisson.PoissonMatrix` with
``bordered=True``): the border unknown is treated by Jacobi alone.
"""

import math

import numpy as np
import taichi as ti

from . import runtime
from .errors import InputError
from .neighbors import CellGrid, GridSpec, _CELL_PAD

#: cells of the coarsest level at most, solved by a dense pseudo-inverse
COARSEST = 16

# ---------------------------------------------------------------------------
# Level 0 (particles) <-> level 1 (cells)


@ti.kernel
def _level1_stencil(l1: ti.template(), nc: ti.i32, nx: ti.i32, start: ti.types.ndarray(),
                    order: ti.types.ndarray(), cell_of: ti.types.ndarray(),
                    offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                    K: ti.types.ndarray(), D: ti.types.ndarray(), dinv: ti.types.ndarray(),
                    S: ti.types.ndarray(), bad: ti.types.ndarray()):
    """S[I, o] = sum over i in cell I, j in cell I + o of (D^-1 A)_ij; o = 3 (dy + 1) + dx + 1.
    Also dinv = 1 / D (0 where D = 0)."""
    for c in range(nc):
        cx = c % nx
        cy = c // nx
        acc = ti.Vector([0.0] * 9)
        for s in range(start[c], start[c + 1]):
            i = order[s]
            di = D[i]
            inv = 0.0
            if ti.static(l1):
                # l1 scaling: rows that are not diagonally dominant (the
                # quadratic-exact Laplacian has some) take smaller Jacobi steps
                off = 0.0
                for k in range(offsets[i], offsets[i + 1]):
                    off += ti.abs(K[k])
                if di != 0.0:
                    inv = 1.0 / (ti.math.sign(di) * ti.max(ti.abs(di), off))
            elif di != 0.0:
                inv = 1.0 / di
            dinv[i] = inv
            acc[4] += di * inv
            for k in range(offsets[i], offsets[i + 1]):
                cj = cell_of[nbrs[k]]
                dx = cj % nx - cx
                dy = cj // nx - cy
                if dx < -1 or dx > 1 or dy < -1 or dy > 1:
                    ti.atomic_max(bad[0], i)
                else:
                    acc[3 * (dy + 1) + dx + 1] += K[k] * inv
        for o in ti.static(range(9)):
            S[c, o] = acc[o]


# ---------------------------------------------------------------------------
# Structured levels, stored flat: level k occupies rows off_k .. off_k + nx_k ny_k
# of S (9-point stencils S[c, 3 (dy+1) + dx+1]) and of the level vectors;
# lvl[k] = (off_k, nx_k, ny_k).


@ti.func
def _stencil_apply(S: ti.template(), x: ti.template(), off, c, nx, ny):
    cx = c % nx
    cy = c // nx
    acc = 0.0
    for o in ti.static(range(9)):
        jx = cx + o % 3 - 1
        jy = cy + o // 3 - 1
        if 0 <= jx < nx and 0 <= jy < ny:
            acc += S[off + c, o] * x[off + jy * nx + jx]
    return acc


@ti.kernel
def _coarsen_stencil(S: ti.types.ndarray(), off: ti.i32, nx: ti.i32, ny: ti.i32,
                     coff: ti.i32, ncx: ti.i32, ncy: ti.i32):
    """Galerkin operator of 2 x 2 aggregation: S_coarse = P^T S P."""
    for c in range(ncx * ncy):
        cx = c % ncx
        cy = c // ncx
        acc = ti.Vector([0.0] * 9)
        for a, b in ti.static(ti.ndrange(2, 2)):
            ix = 2 * cx + a
            iy = 2 * cy + b
            if ix < nx and iy < ny:
                f = off + iy * nx + ix
                for o in ti.static(range(9)):
                    jx = ix + o % 3 - 1
                    jy = iy + o // 3 - 1
                    if 0 <= jx < nx and 0 <= jy < ny:
                        acc[3 * (jy // 2 - cy + 1) + jx // 2 - cx + 1] += S[f, o]
        for o in ti.static(range(9)):
            S[coff + c, o] = acc[o]


@ti.kernel
def _stencil_dinv(m: ti.i32, S: ti.types.ndarray(), dinv: ti.types.ndarray(), noise: float):
    for c in range(m):
        d = S[c, 4]
        inv = 0.0
        if ti.abs(d) > noise:
            inv = 1.0 / d
        dinv[c] = inv


@ti.func
def _restrict_level(S: ti.template(), cr: ti.template(), cx: ti.template(), off, nx, ny,
                    coff, c, ncx):
    """Coarse cell c of level k+1: the sum over its 2 x 2 children of r - S x."""
    px = c % ncx
    py = c // ncx
    acc = 0.0
    for a, b in ti.static(ti.ndrange(2, 2)):
        ix = 2 * px + a
        iy = 2 * py + b
        if ix < nx and iy < ny:
            f = iy * nx + ix
            acc += cr[off + f] - _stencil_apply(S, cx, off, f, nx, ny)
    cr[coff + c] = acc


@ti.func
def _parent(c, nx, ncx):
    return ((c // nx) // 2) * ncx + (c % nx) // 2


@ti.kernel
def _cycle(post: ti.template(), omega: ti.template(), correction: ti.template(),
           bordered: ti.template(), L: ti.i32, n: ti.i32,
           start: ti.types.ndarray(), order: ti.types.ndarray(), cell_of: ti.types.ndarray(),
           offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), K: ti.types.ndarray(),
           D: ti.types.ndarray(), dinv: ti.types.ndarray(), lvl: ti.types.ndarray(),
           S: ti.types.ndarray(), cdinv: ti.types.ndarray(), cr: ti.types.ndarray(),
           cx: ti.types.ndarray(), ctmp: ti.types.ndarray(), Minv: ti.types.ndarray(),
           ftmp: ti.types.ndarray(), border_c: float, r: ti.types.ndarray(),
           z: ti.types.ndarray()):
    """z = M^-1 r: one V-cycle from zero, in one launch.  The particle level
    and the first (largest) cell level run in parallel loops; the smaller
    levels run in one serial loop whose level count is a runtime value (one
    compiled kernel for every hierarchy; a parallel loop per small level would
    cost more in thread synchronisation than its work)."""
    # particles: pre-smoothing from zero x = omega D^-1 r (on the fly, never
    # stored); the scaled residual D^-1 (r - A x) summed per cell
    for c in range(lvl[0, 1] * lvl[0, 2]):
        acc = 0.0
        for s in range(start[c], start[c + 1]):
            i = order[s]
            ax = D[i] * (omega * dinv[i] * r[i])
            for k in range(offsets[i], offsets[i + 1]):
                j = nbrs[k]
                ax += K[k] * (omega * dinv[j] * r[j])
            acc += dinv[i] * (r[i] - ax)
        cr[c] = acc
    # cell level 0, down: pre-smoothing from zero, then restriction
    for c in range(lvl[0, 1] * lvl[0, 2]):
        cx[c] = omega * cdinv[c] * cr[c]
    for c in range(lvl[1, 1] * lvl[1, 2]):
        _restrict_level(S, cr, cx, 0, lvl[0, 1], lvl[0, 2], lvl[1, 0], c, lvl[1, 1])
    # levels 1 .. L-1, serially: down, coarsest solve, up
    ti.loop_config(serialize=True)
    for _ in range(1):
        for k in range(1, L - 1):
            off, nx, ny = lvl[k, 0], lvl[k, 1], lvl[k, 2]
            for c in range(nx * ny):
                cx[off + c] = omega * cdinv[off + c] * cr[off + c]
            for c in range(lvl[k + 1, 1] * lvl[k + 1, 2]):
                _restrict_level(S, cr, cx, off, nx, ny, lvl[k + 1, 0], c, lvl[k + 1, 1])
        loff, lm = lvl[L - 1, 0], lvl[L - 1, 1] * lvl[L - 1, 2]
        for i in range(lm):
            acc = 0.0
            for j in range(lm):
                acc += Minv[i, j] * cr[loff + j]
            cx[loff + i] = acc
        for kk in range(L - 2):
            k = L - 2 - kk
            off, nx, ny = lvl[k, 0], lvl[k, 1], lvl[k, 2]
            coff, ncx = lvl[k + 1, 0], lvl[k + 1, 1]
            for c in range(nx * ny):
                cx[off + c] += correction * cx[coff + _parent(c, nx, ncx)]
            for _s in range(post):
                for c in range(nx * ny):
                    ctmp[off + c] = cx[off + c] + omega * cdinv[off + c] * (
                        cr[off + c] - _stencil_apply(S, cx, off, c, nx, ny))
                for c in range(nx * ny):
                    cx[off + c] = ctmp[off + c]
    # cell level 0, up: prolongation, post-smoothing
    for c in range(lvl[0, 1] * lvl[0, 2]):
        cx[c] += correction * cx[lvl[1, 0] + _parent(c, lvl[0, 1], lvl[1, 1])]
    for _s in ti.static(range(post)):
        for c in range(lvl[0, 1] * lvl[0, 2]):
            ctmp[c] = cx[c] + omega * cdinv[c] * (
                cr[c] - _stencil_apply(S, cx, 0, c, lvl[0, 1], lvl[0, 2]))
        for c in range(lvl[0, 1] * lvl[0, 2]):
            cx[c] = ctmp[c]
    # particles, up: x = omega D^-1 r + correction P x_0 (on the fly), post-smoothing
    for i in range(n):
        xi = omega * dinv[i] * r[i] + correction * cx[cell_of[i]]
        ax = D[i] * xi
        for k in range(offsets[i], offsets[i + 1]):
            j = nbrs[k]
            ax += K[k] * (omega * dinv[j] * r[j] + correction * cx[cell_of[j]])
        zi = xi + omega * dinv[i] * (r[i] - ax)
        if ti.static(post > 1):
            ftmp[i] = zi
        else:
            z[i] = zi
    for _s in ti.static(range(post - 1)):
        for i in range(n):
            ax = D[i] * ftmp[i]
            for k in range(offsets[i], offsets[i + 1]):
                ax += K[k] * ftmp[nbrs[k]]
            z[i] = ftmp[i] + omega * dinv[i] * (r[i] - ax)
        if ti.static(post > 2):
            for i in range(n):
                ftmp[i] = z[i]
    if ti.static(bordered):
        z[n] = r[n] / border_c


def _stencil_to_dense(S: np.ndarray, nx: int, ny: int) -> np.ndarray:
    m = nx * ny
    c = np.arange(m)
    cx, cy = c % nx, c // nx
    M = np.zeros((m, m))
    for o in range(9):
        jx, jy = cx + o % 3 - 1, cy + o // 3 - 1
        ok = (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny)
        np.add.at(M, (c[ok], (jy * nx + jx)[ok]), S[ok, o])
    return M


class MultilevelPreconditioner:
    """Aggregation-multigrid V-cycle approximating ``A^-1`` (module doc).

    A: a :class:`~taichi_hh.poisson.PoissonMatrix` (rows assembled).
    post: damped-Jacobi sweeps after the coarse correction on every level (one
    sweep before it, from zero, is always done); omega: Jacobi damping;
    correction: coarse-correction scale; l1: scale rows by
    ``max(|a_ii|, sum_j |a_ij|)`` instead of ``a_ii`` (smaller Jacobi steps on
    rows that are not diagonally dominant; measured: 86 -> 48-63 iterations on
    the default decomposition at 53k particles, 49 -> 53-60 at 13k, so off by
    default).
    """

    name = "multilevel"

    def __init__(self, A, *, post: int = 2, omega: float = 0.7, correction: float = 1.5,
                 l1: bool = False):
        runtime.ensure_init()
        self.l1 = bool(l1)
        if not (1 <= post <= 3) or not (0 < omega < 2) or not correction > 0:
            raise InputError("multilevel: need 1 <= post <= 3, 0 < omega < 2, "
                             "correction > 0")
        self.post, self.omega, self.correction = int(post), float(omega), float(correction)
        self.A = A
        ops = A.ops
        p = ops.particles
        n = p.n
        self.n = n
        real = runtime.real_dtype()
        pos = p.position.to_numpy()[:n]
        lo, hi = pos.min(axis=0), pos.max(axis=0)
        size = ops.support * _CELL_PAD
        shapes = [(max(1, int(math.floor((hi[0] - lo[0]) / size)) + 1),
                   max(1, int(math.floor((hi[1] - lo[1]) / size)) + 1))]
        # at least two cell levels (the cycle's first two are fixed)
        while shapes[-1][0] * shapes[-1][1] > COARSEST or len(shapes) < 2:
            shapes.append(((shapes[-1][0] + 1) // 2, (shapes[-1][1] + 1) // 2))
        sizes = [nx * ny for nx, ny in shapes]
        offs = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
        total = int(offs[-1])
        self.shapes = shapes
        self.lvl = ti.ndarray(ti.i32, shape=(len(shapes), 3))
        self.lvl.from_numpy(np.c_[offs[:-1], shapes].astype(np.int32))
        nx, ny = shapes[0]
        self.grid = CellGrid(GridSpec(float(lo[0]), float(lo[1]), size, nx, ny))
        self.grid.sort(p.position, n)
        self.S = ti.ndarray(real, shape=(total, 9))
        self.dinv = ti.ndarray(real, shape=(max(n, 1),))
        bad = ti.ndarray(ti.i32, shape=(1,))
        bad.fill(-1)
        pr = ops.pairs
        _level1_stencil(self.l1, nx * ny, nx, self.grid.cell_start, self.grid.order, self.grid.cell_of,
                        pr.offsets, pr.neighbours, A.K, A.D, self.dinv, self.S, bad)
        if int(bad.to_numpy()[0]) >= 0:
            raise InputError("multilevel: a neighbour pair spans more than one cell of the "
                             "support grid (pairs longer than the kernel support?)")
        for k in range(len(shapes) - 1):
            _coarsen_stencil(self.S, int(offs[k]), *shapes[k], int(offs[k + 1]), *shapes[k + 1])
        # Constants are (nearly) in the null space of every level of a Neumann
        # problem, so the coarsest levels' entries are sums of terms that cancel:
        # values below the round-off of such a sum are zero, not pivots.
        S_np = self.S.to_numpy()
        noise = 1e3 * np.finfo(runtime.np_real()).eps * float(np.abs(S_np[: sizes[0]]).sum())
        self.cdinv = ti.ndarray(real, shape=(total,))
        _stencil_dinv(total, self.S, self.cdinv, noise)
        self.cr = ti.ndarray(real, shape=(total,))
        self.cx = ti.ndarray(real, shape=(total,))
        self.ctmp = ti.ndarray(real, shape=(total,))
        self.ftmp = ti.ndarray(real, shape=(max(n, 1) if self.post > 1 else 1,))
        # coarsest level: pseudo-inverse (singular for a Neumann problem)
        cnx, cny = shapes[-1]
        M = _stencil_to_dense(S_np[offs[-2]:], cnx, cny)
        U, sv, Vt = np.linalg.svd(M)
        keep = sv > noise
        if getattr(A, "bordered", False) and len(sv):
            # a bordered system fixes the constant through its border unknown:
            # the coarse level must not (inverting a small ridge kappa there
            # produced corrections of order 1/kappa and BiCGSTAB diverged)
            keep &= sv > 1e-3 * sv[0]
        Minv = (Vt[keep].T / sv[keep]) @ U[:, keep].T
        self.coarse_inverse = ti.ndarray(real, shape=M.shape)
        self.coarse_inverse.from_numpy(Minv.astype(runtime.np_real()))
        self._bordered = bool(getattr(A, "bordered", False))
        self._border_c = float(getattr(A, "border_c", 1.0)) if self._bordered else 1.0

    @property
    def n_levels(self) -> int:
        return 1 + len(self.shapes)

    def describe(self) -> str:
        real = [s for k, s in enumerate(self.shapes) if k == 0 or s != self.shapes[k - 1]]
        sizes = [str(self.n)] + [f"{nx}x{ny}" for nx, ny in real]
        return "V-cycle, levels " + " > ".join(sizes)

    def apply(self, r, z) -> None:
        """z = M^-1 r (one V-cycle from zero)."""
        A, pr, g = self.A, self.A.ops.pairs, self.grid
        _cycle(self.post, self.omega, self.correction, self._bordered, len(self.shapes),
               self.n, g.cell_start, g.order, g.cell_of, pr.offsets, pr.neighbours, A.K, A.D,
               self.dinv, self.lvl, self.S, self.cdinv, self.cr, self.cx, self.ctmp,
               self.coarse_inverse, self.ftmp, self._border_c, r, z)
