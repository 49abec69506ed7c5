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
A W-cycle (or, as an option, a V-cycle) with damped Jacobi smoothing
(``omega``; one sweep from zero before the coarse correction, ``post`` sweeps
after it) on every level and the coarse correction scaled by ``correction``
(plain aggregation under-corrects: interpolation by constants has too much
energy; an over-correction of about 1.5-2 is the classic remedy, Blaheta
1986, Vanek et al. 1996).  Each level's error compounds in a V-cycle of
plain aggregation, so its iterations grow with the number of levels (Notay
2010 accelerates the coarse levels for this reason); the W-cycle solves each
structured level's coarse problem with two cycles, which keeps the iteration
count nearly flat in N at the cost of the structured levels only (they hold
a few percent of the work).  The cycle is a fixed linear operator, so it can
precondition BiCGSTAB (right preconditioning: ``A M^-1 y = b``,
``x = M^-1 y``).

The whole cycle is one kernel launch (at 10k particles launches, not
arithmetic, dominate).  On level 0 the pre-smoothing from zero, the residual
and the restriction are one gather loop over cells (a cell's particles are
listed contiguously by a counting sort); the prolongation and the first
post-smoothing sweep are another.  So a cycle costs ``1 + post`` passes over
the pairs plus the (cheap) structured levels, which run in one serial loop
driven as a state machine (kernels cannot recurse).

Bordered systems (:class:`~taichi_hh.linalg.poisson.PoissonMatrix` with
``bordered=True``): the border unknown is treated by Jacobi alone.
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import InputError
from ..sph.neighbors import CellGrid, GridSpec, CELL_PAD

#: cells of the coarsest level at most, solved by a dense pseudo-inverse
COARSEST = 16

#: below this many particles every loop of the cycle runs on one thread: a
#: cycle has about 15 loops, and waking the thread pool for each costs more
#: than the second core saves on small levels (docs/notes/linalg.md)
SERIAL_MAX_N = 64_000

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


@ti.func
def _smooth_level(S: ti.template(), cdinv: ti.template(), cr: ti.template(),
                  cx: ti.template(), ctmp: ti.template(), off, nx, ny, sweeps, omega):
    """``sweeps`` damped-Jacobi sweeps on a structured level (serial)."""
    for _s in range(sweeps):
        for c in range(nx * ny):
            ctmp[off + c] = cx[off + c] + omega * cdinv[off + c] * (
                cr[off + c] - _stencil_apply(S, cx, off, c, nx, ny))
        for c in range(nx * ny):
            cx[off + c] = ctmp[off + c]


@ti.kernel
def _cycle(serial: ti.template(), post: ti.template(), omega: ti.template(), correction: ti.template(),
           bordered: ti.template(), gamma: ti.template(), L: ti.i32, n: ti.i32,
           start: ti.types.ndarray(), order: ti.types.ndarray(), cell_of: ti.types.ndarray(),
           offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), K: ti.types.ndarray(),
           D: ti.types.ndarray(), dinv: ti.types.ndarray(), lvl: ti.types.ndarray(),
           visits: ti.types.ndarray(), S: ti.types.ndarray(), cdinv: ti.types.ndarray(),
           cr: ti.types.ndarray(), cx: ti.types.ndarray(), ctmp: ti.types.ndarray(),
           Minv: ti.types.ndarray(), fx: ti.types.ndarray(), ftmp: ti.types.ndarray(),
           border_c: float, constant_mode: ti.template(), colsum: ti.types.ndarray(),
           const_c: float,
           r: ti.types.ndarray(), z: ti.types.ndarray()):
    """z = M^-1 r: one cycle from zero, in one launch.  The particle level and
    the first (largest) cell level run in parallel loops; the smaller levels
    run in one serial loop whose level count is a runtime value (one compiled
    kernel for every hierarchy; a parallel loop per small level would cost
    more in thread synchronisation than its work).  ``gamma`` coarse cycles
    per cell level: 1 is a V-cycle, 2 a W-cycle."""
    # particles: pre-smoothing from zero x = omega D^-1 r, stored so that the
    # gather below reads one value per neighbour; the scaled residual
    # D^-1 (r - A x) summed per cell
    ti.loop_config(serialize=serial)
    for i in range(n):
        fx[i] = omega * dinv[i] * r[i]
    ti.loop_config(serialize=serial)
    for c in range(lvl[0, 1] * lvl[0, 2]):
        acc = 0.0
        for s in range(start[c], start[c + 1]):
            i = order[s]
            ax = D[i] * fx[i]
            for k in range(offsets[i], offsets[i + 1]):
                ax += K[k] * fx[nbrs[k]]
            acc += dinv[i] * (r[i] - ax)
        cr[c] = acc
    # cell level 0: pre-smoothing from zero
    ti.loop_config(serialize=serial)
    for c in range(lvl[0, 1] * lvl[0, 2]):
        cx[c] = omega * cdinv[c] * cr[c]
    # restriction of the residual to cell level 1
    ti.loop_config(serialize=serial)
    for c in range(lvl[1, 1] * lvl[1, 2]):
        _restrict_level(S, cr, cx, 0, lvl[0, 1], lvl[0, 2], lvl[1, 0], c, lvl[1, 1])
    # levels 1 .. L-1, serially, as a state machine (no recursion in kernels)
    ti.loop_config(serialize=True)
    for _ in range(1):
        k = 1
        going_down = 1
        while True:
            off, nx, ny = lvl[k, 0], lvl[k, 1], lvl[k, 2]
            if k == L - 1:
                # coarsest: (pseudo-)inverse, from zero
                for i in range(nx * ny):
                    acc = 0.0
                    for j in range(nx * ny):
                        acc += Minv[i, j] * cr[off + j]
                    cx[off + i] = acc
                if k == 1:
                    break
                going_down = 0
                k -= 1
            elif going_down == 1:
                for c in range(nx * ny):
                    cx[off + c] = omega * cdinv[off + c] * cr[off + c]
                for c in range(lvl[k + 1, 1] * lvl[k + 1, 2]):
                    _restrict_level(S, cr, cx, off, nx, ny, lvl[k + 1, 0], c,
                                    lvl[k + 1, 1])
                visits[k] = 1
                k += 1
            else:
                coff, ncx = lvl[k + 1, 0], lvl[k + 1, 1]
                for c in range(nx * ny):
                    cx[off + c] += correction * cx[coff + _parent(c, nx, ncx)]
                if visits[k] < gamma and k + 1 < L - 1:
                    # another coarse cycle on the new residual (the coarsest
                    # level is solved exactly: once is enough)
                    visits[k] += 1
                    for c in range(lvl[k + 1, 1] * lvl[k + 1, 2]):
                        _restrict_level(S, cr, cx, off, nx, ny, coff, c, ncx)
                    k += 1
                    going_down = 1
                else:
                    _smooth_level(S, cdinv, cr, cx, ctmp, off, nx, ny, post, omega)
                    if k == 1:
                        break
                    k -= 1
    # cell level 0: prolongation of the correction
    ti.loop_config(serialize=serial)
    for c in range(lvl[0, 1] * lvl[0, 2]):
        cx[c] += correction * cx[lvl[1, 0] + _parent(c, lvl[0, 1], lvl[1, 1])]
    for _s in ti.static(range(post)):
        ti.loop_config(serialize=serial)
        for c in range(lvl[0, 1] * lvl[0, 2]):
            ctmp[c] = cx[c] + omega * cdinv[c] * (
                cr[c] - _stencil_apply(S, cx, 0, c, lvl[0, 1], lvl[0, 2]))
        ti.loop_config(serialize=serial)
        for c in range(lvl[0, 1] * lvl[0, 2]):
            cx[c] = ctmp[c]
    # particles, up: x += correction P x_0, then post-smoothing
    ti.loop_config(serialize=serial)
    for i in range(n):
        fx[i] += correction * cx[cell_of[i]]
    ti.loop_config(serialize=serial)
    for i in range(n):
        xi = fx[i]
        ax = D[i] * xi
        for k in range(offsets[i], offsets[i + 1]):
            ax += K[k] * fx[nbrs[k]]
        zi = xi + omega * dinv[i] * (r[i] - ax)
        if ti.static(post > 1):
            ftmp[i] = zi
        else:
            z[i] = zi
    for _s in ti.static(range(post - 1)):
        ti.loop_config(serialize=serial)
        for i in range(n):
            ax = D[i] * ftmp[i]
            for k in range(offsets[i], offsets[i + 1]):
                ax += K[k] * ftmp[nbrs[k]]
            z[i] = ftmp[i] + omega * dinv[i] * (r[i] - ax)
        if ti.static(post > 2):
            ti.loop_config(serialize=serial)
            for i in range(n):
                ftmp[i] = z[i]
    if ti.static(bordered):
        z[n] = r[n] / border_c
    if ti.static(constant_mode):
        # Petrov-Galerkin correction along the constants (the near-null vector
        # of L + kappa I): z += 1 (1.(r - A z)) / (1.A 1), with 1.A z = colsum.z
        rsum = 0.0
        azsum = 0.0
        ti.loop_config(serialize=serial)
        for i in range(n):
            rsum += r[i]
            azsum += colsum[i] * z[i]
        shift = (rsum - azsum) / const_c
        ti.loop_config(serialize=serial)
        for i in range(n):
            z[i] += shift


def stencil_to_dense(S: np.ndarray, nx: int, ny: int) -> np.ndarray:
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
    """Aggregation-multigrid cycle approximating ``A^-1`` (module doc).

    A: a :class:`~taichi_hh.linalg.poisson.PoissonMatrix` (rows assembled).
    cycle: ``"W"`` (default) or ``"V"``.  The W-cycle visits every structured
    level below the first cell level twice per visit of its parent (the
    particle level and the first cell level, which carry almost all the
    work, are visited once either way).  Plain aggregation's V-cycle loses
    accuracy with every level, so its iterations grow with N; the W-cycle's
    stay nearly flat.
    post: damped-Jacobi sweeps after the coarse correction on every level (one
    sweep before it, from zero, is always done); default 1 for W, 2 for V (the
    fastest measured for each: the decomposition's and the flow's systems);
    omega: Jacobi damping;
    correction: coarse-correction scale (default 1.4 for W, 1.5 for V: the
    fastest measured);
    l1: scale rows by ``max(|a_ii|, sum_j |a_ij|)`` instead of ``a_ii``
    (smaller Jacobi steps on rows that are not diagonally dominant; it helps
    some systems and hurts others, so off by default).  The measurements
    behind each default: docs/notes/linalg.md.
    """

    name = "multilevel"

    def __init__(self, A, *, cycle: str = "W", post: int | None = None, omega: float = 0.7,
                 correction: float | None = None, l1: bool = False):
        runtime.ensure_init()
        self.l1 = bool(l1)
        if cycle not in ("V", "W"):
            raise InputError(f"multilevel: cycle must be 'V' or 'W', got {cycle!r}")
        self.cycle = cycle
        self.gamma = 1 if cycle == "V" else 2
        if correction is None:
            correction = 1.5 if cycle == "V" else 1.4
        if post is None:
            post = 2 if cycle == "V" else 1
        if not (1 <= post <= 3) or not (0 < omega < 2) or not correction > 0:
            raise InputError("multilevel: need 1 <= post <= 3, 0 < omega < 2, "
                             "correction > 0")
        self.post, self.omega, self.correction = int(post), float(omega), float(correction)
        # below SERIAL_MAX_N particles the cycle's loops run on one thread
        self.serial = A.n_particles < SERIAL_MAX_N
        self.A = A
        ops = A.ops
        p = ops.particles
        n = p.n
        self.n = n
        real = runtime.real_dtype()
        pos = p.position.to_numpy()[:n]
        lo, hi = pos.min(axis=0), pos.max(axis=0)
        size = ops.support * CELL_PAD
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
        self.visits = ti.ndarray(ti.i32, shape=(len(shapes),))
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
        self.fx = ti.ndarray(real, shape=(max(n, 1),))
        self.ftmp = ti.ndarray(real, shape=(max(n, 1) if self.post > 1 else 1,))
        # coarsest level: pseudo-inverse (singular for a Neumann problem)
        cnx, cny = shapes[-1]
        M = stencil_to_dense(S_np[offs[-2]:], cnx, cny)
        U, sv, Vt = np.linalg.svd(M)
        self._bordered = bool(getattr(A, "bordered", False))
        self._border_c = float(getattr(A, "border_c", 1.0)) if self._bordered else 1.0
        self._constant_mode_setup(A, n)
        keep = sv > noise
        if (self._bordered or self._constant_mode) and len(sv):
            # the constant is fixed elsewhere: by the border unknown of a
            # bordered system, or by the exact rank-one correction below; the
            # coarse level must not invert its round-off-level image (inverting a
            # small ridge kappa there produced corrections of order 1/kappa:
            # BiCGSTAB diverged on bordered systems, and on a ridge system with a
            # 4 x 4 coarsest level it took twice the iterations)
            keep &= sv > 1e-3 * sv[0]
        Minv = (Vt[keep].T / sv[keep]) @ U[:, keep].T
        self.coarse_inverse = ti.ndarray(real, shape=M.shape)
        self.coarse_inverse.from_numpy(Minv.astype(runtime.np_real()))

    def _constant_mode_setup(self, A, n: int) -> None:
        """A ridge system ``(L + kappa I)`` with a small kappa and no border is
        nearly singular along the constants (L's null vector): the exact
        solution carries a constant of order (incompatibility of b) / kappa,
        which Krylov builds only slowly, while the coarse levels cannot tell
        kappa from round-off (their constant-mode entries are sums that
        cancel).  So the cycle ends with an exact rank-one correction along
        the constants, computed from the fine matrix: ``1 . A 1`` is kappa times
        the fluid count, resolved to round-off (without it a ridge of 1e-8
        tripled the iterations: docs/notes/linalg.md).  Skipped
        for bordered systems (the border fixes the constant) and when
        ``1 . A 1`` is round-off (kappa = 0: a singular, pure-Neumann matrix)."""
        real = runtime.real_dtype()
        self.colsum = ti.ndarray(real, shape=(max(n, 1),))
        self._constant_c = 1.0
        self._constant_mode = False
        if self._bordered or not callable(getattr(A, "apply_transpose", None)):
            return
        ones = ti.ndarray(real, shape=(A.n,))
        ones.fill(1.0)
        A.apply_transpose(ones, self.colsum)
        colsum = self.colsum.to_numpy()[:n]
        total = float(colsum.sum())                     # 1 . A 1
        off = A.ops.pairs.offsets.to_numpy()[: n + 1].astype(np.int64)
        K = np.abs(A.K.to_numpy()[: off[-1]])
        rows = np.repeat(np.arange(n), np.diff(off))
        row_abs = np.bincount(rows, weights=K, minlength=n) + np.abs(A.D.to_numpy()[:n])
        eps = float(np.finfo(runtime.np_real()).eps)
        noise = 100.0 * eps * math.sqrt(n) * float(row_abs.max())
        if abs(total) > noise:
            self._constant_mode = True
            self._constant_c = total

    @property
    def n_levels(self) -> int:
        return 1 + len(self.shapes)

    def describe(self) -> str:
        real = [s for k, s in enumerate(self.shapes) if k == 0 or s != self.shapes[k - 1]]
        sizes = [str(self.n)] + [f"{nx}x{ny}" for nx, ny in real]
        return f"{self.cycle}-cycle, levels " + " > ".join(sizes)

    def apply(self, r, z) -> None:
        """z = M^-1 r (one cycle from zero)."""
        A, pr, g = self.A, self.A.ops.pairs, self.grid
        _cycle(self.serial, self.post, self.omega, self.correction, self._bordered, self.gamma,
               len(self.shapes), self.n, g.cell_start, g.order, g.cell_of, pr.offsets,
               pr.neighbours, A.K, A.D, self.dinv, self.lvl, self.visits, self.S, self.cdinv, self.cr, self.cx, self.ctmp,
               self.coarse_inverse, self.fx, self.ftmp, self._border_c, self._constant_mode,
               self.colsum, self._constant_c, r, z)
