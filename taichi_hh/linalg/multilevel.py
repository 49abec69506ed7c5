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

Level 1 aggregates the particles by the cells of a grid: piecewise-constant
prolongation ``P`` (particle ``i`` takes its cell's value), restriction
``P^T`` (a cell sums its particles) and the Galerkin operator ``B_1 = P^T B P``.
Each further level aggregates 2 x 2 cells of the one below, down to the first
grid of at most ``COARSEST`` cells, solved by a dense pseudo-inverse (the
coarse operators of a pure Neumann problem are singular: constants are their
null space).  Empty cells are left out.  Every cell level is stored as one
sparse (CSR) matrix, so a pair may span any number of cells.

The cells' side (``cells``): by default the largest kernel support (the
flow's fixed support: each cell couples to its 3 x 3 block); with adaptive
support the largest is 1.5-4 times the median, and cells that large hold
30-120 particles, too coarse an aggregation for Jacobi smoothing to bridge
(the decomposition takes cells of a quarter of the median support: 1-1.5
particles each on level 1, which then acts as a second, Galerkin smoothing
level; docs/notes/scattered.md).

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
cell level's coarse problem with two cycles, which keeps the iteration
count nearly flat in N at the cost of the coarser levels only.  The cycle is a fixed linear operator, so it can
precondition BiCGSTAB (right preconditioning: ``A M^-1 y = b``,
``x = M^-1 y``).

The whole cycle is one kernel launch (at 10k particles launches, not
arithmetic, dominate).  On level 0 the pre-smoothing from zero, the residual
and the restriction are one gather loop over cells (a cell's particles are
listed contiguously); the prolongation and the first post-smoothing sweep
are another.  So a cycle costs ``1 + post`` passes over the pairs plus the
cell levels (a few percent of that with the largest support's cells, about
as much again with a quarter of the median support's).  The first cell level
and, from ``SERIAL_MAX_N`` particles on, the next ones with at least
``PARALLEL_MIN_NNZ`` entries run as parallel loops in a static schedule; the
rest in one serial loop driven as a state machine (kernels cannot recurse).  The
Galerkin operators are formed once per matrix in numpy (:class:`CellMatrix`:
entries summed by cell pairs; scipy is not a run-time dependency).

Bordered systems (:class:`~taichi_hh.linalg.poisson.PoissonMatrix` with
``bordered=True``): the border unknown is treated by Jacobi alone.
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import InputError
from ..sph.neighbors import CELL_PAD
from .columns import columns_of, zeros

#: cells of the coarsest level at most, solved by a dense pseudo-inverse
COARSEST = 16

#: below this many particles every loop of the cycle runs on one thread: a
#: cycle has about 15 loops, and waking the thread pool for each costs more
#: than the second core saves on small levels (with the workers bound to
#: their cores, 2.5k particles: serial faster; 10k: parallel faster;
#: docs/notes/flow.md, "Worker threads")
SERIAL_MAX_N = 5_000

#: parallel loops of the cycle's unrolled schedule at most (a W-cycle's
#: doubles per parallel level: 4, 10, 22, 46, ...; Taichi warns beyond 32)
MAX_SCHEDULE_OPS = 32

#: rows per parallel run of the Galerkin products' set-up (:func:`_csr_galerkin`),
#: and the most runs: Taichi's CPU backend hands its threads 512 iterations of a
#: parallel loop at a time (measured: 64 runs stayed on one thread, 1000 used
#: two), so the runs must be many and short
GALERKIN_CHUNK_ROWS = 32
GALERKIN_MAX_CHUNKS = 4096

#: cell levels below the first with at least this many entries run in parallel
#: loops (with the particles, from SERIAL_MAX_N on); smaller ones in the serial
#: state machine.  A parallel loop needs about 1000 rows to reach the second
#: thread (Taichi's 512-iteration tasks), some 30k-50k entries; with the
#: worker threads bound to cores 50k beat 400k: 13k random points 0.41 against
#: 0.44-0.51 s a call, 200k 5.7 against 6.8 s (docs/notes/scattered.md)
PARALLEL_MIN_NNZ = 50_000

# ---------------------------------------------------------------------------
# Cell levels, stored flat as one CSR matrix: level k owns rows lvl[k, 0] ..
# lvl[k, 1] (its non-empty cells); a row's columns are global row indices of
# the same level.  parent[c]: the row of c's cell on the next level (-1 on the
# coarsest); the children of a row: kids[kid_start[c] .. kid_start[c + 1]]
# (cells of the finer level), or for level 0 the particles
# porder[pstart[c] .. pstart[c + 1]].


@ti.func
def _row_apply(cols: ti.template(), S_off: ti.template(), S_col: ti.template(),
               S_val: ti.template(), x: ti.template(), c):
    acc = zeros(cols)
    for k in range(S_off[c], S_off[c + 1]):
        acc += S_val[k] * x[S_col[k]]
    return acc


@ti.func
def _restrict_row(cols: ti.template(), S_off: ti.template(), S_col: ti.template(), S_val: ti.template(),
                  kid_start: ti.template(), kids: ti.template(), cr: ti.template(),
                  cx: ti.template(), p):
    """Coarse row p: the sum over its children c of r_c - (S x)_c."""
    acc = zeros(cols)
    for m in range(kid_start[p], kid_start[p + 1]):
        c = kids[m]
        acc += cr[c] - _row_apply(cols, S_off, S_col, S_val, cx, c)
    cr[p] = acc


@ti.func
def _smooth_level(cols: ti.template(), S_off: ti.template(), S_col: ti.template(), S_val: ti.template(),
                  cdinv: ti.template(), cr: ti.template(), cx: ti.template(),
                  ctmp: ti.template(), lo, hi, sweeps, omega):
    """``sweeps`` damped-Jacobi sweeps on the rows lo .. hi of a cell level (serial)."""
    for _s in range(sweeps):
        for c in range(lo, hi):
            ctmp[c] = cx[c] + omega * cdinv[c] * (cr[c] - _row_apply(cols, S_off, S_col, S_val, cx, c))
        for c in range(lo, hi):
            cx[c] = ctmp[c]


@ti.func
def _serial_levels(cols: ti.template(), k_start, L, gamma: ti.template(), post: ti.template(), omega: ti.template(),
                   correction: ti.template(), lvl: ti.template(), visits: ti.template(),
                   S_off: ti.template(), S_col: ti.template(), S_val: ti.template(),
                   parent: ti.template(), kid_start: ti.template(), kids: ti.template(),
                   cdinv: ti.template(), cr: ti.template(), cx: ti.template(),
                   ctmp: ti.template(), Minv: ti.template()):
    """The cycle of levels k_start .. L-1 (their residual in cr on level k_start),
    serially, as a state machine (kernels cannot recurse); ``gamma`` coarse
    cycles per level below k_start's parent."""
    k = k_start
    going_down = 1
    while True:
        lo, hi = lvl[k, 0], lvl[k, 1]
        if k == L - 1:
            # coarsest: (pseudo-)inverse, from zero
            for i in range(hi - lo):
                acc = zeros(cols)
                for j in range(hi - lo):
                    acc += Minv[i, j] * cr[lo + j]
                cx[lo + i] = acc
            if k == k_start:
                break
            going_down = 0
            k -= 1
        elif going_down == 1:
            for c in range(lo, hi):
                cx[c] = omega * cdinv[c] * cr[c]
            for p in range(lvl[k + 1, 0], lvl[k + 1, 1]):
                _restrict_row(cols, S_off, S_col, S_val, kid_start, kids, cr, cx, p)
            visits[k] = 1
            k += 1
        else:
            for c in range(lo, hi):
                cx[c] += correction * cx[parent[c]]
            if visits[k] < gamma and k + 1 < L - 1:
                # another coarse cycle on the new residual (the coarsest
                # level is solved exactly: once is enough)
                visits[k] += 1
                for p in range(lvl[k + 1, 0], lvl[k + 1, 1]):
                    _restrict_row(cols, S_off, S_col, S_val, kid_start, kids, cr, cx, p)
                k += 1
                going_down = 1
            else:
                _smooth_level(cols, S_off, S_col, S_val, cdinv, cr, cx, ctmp, lo, hi, post, omega)
                if k == k_start:
                    break
                k -= 1


def _schedule(k0: int, gamma: int, serial: bool) -> tuple:
    """The cycle's operations on the cell levels above ``k0`` as a static list
    (each a parallel loop, level 0's serial when the particles are few), with
    ``("serial", k0)`` for the rest: (op, level, serialize).  Level 0 is
    visited once; each level 1 .. k0-1 visits the level below it ``gamma``
    times, like the serial state machine (k0 <= L - 2, so that the level
    below is never the coarsest)."""
    ops = []

    def visit(k):
        if k >= k0:
            ops.append(("serial", k, True))
            return
        ser = serial if k == 0 else False
        ops.append(("down", k, ser))
        visit(k + 1)
        if k >= 1 and gamma == 2:
            ops.extend([("correct", k, ser), ("restrict", k, ser)])
            visit(k + 1)
        ops.extend([("correct", k, ser), ("smooth", k, ser)])

    visit(0)
    return tuple(ops)


@ti.kernel
def _scaled_diagonal(l1: ti.template(), n: ti.i32, offsets: ti.types.ndarray(),
                     K: ti.types.ndarray(), D: ti.types.ndarray(), dinv: ti.types.ndarray()):
    """``dinv = 1 / a_ii`` (zero where a_ii = 0), or with ``l1`` ``1 / (sign(a_ii)
    max(|a_ii|, sum_j |a_ij|))``: smaller Jacobi steps on rows far from diagonal
    dominance."""
    for i in range(n):
        den = D[i]
        if ti.static(l1):
            off_abs = 0.0
            for k in range(offsets[i], offsets[i + 1]):
                off_abs += abs(K[k])
            den = ti.math.sign(D[i]) * ti.max(abs(D[i]), off_abs)
        dinv[i] = 1.0 / den if D[i] != 0 else 0.0


@ti.kernel
def _strongest_neighbour(n: ti.i32, weak: float, offsets: ti.types.ndarray(),
                         nbrs: ti.types.ndarray(), K: ti.types.ndarray(),
                         D: ti.types.ndarray(), out: ti.types.ndarray()):
    """out[i]: the neighbour with the largest |a_ij| (the first of equals) of a
    row with ``|a_ii| < weak sum_j |a_ij|``; -1 for every other row."""
    for i in range(n):
        total = 0.0
        best = -1
        top = -1.0
        for k in range(offsets[i], offsets[i + 1]):
            a = abs(K[k])
            total += a
            if a > top:
                top = a
                best = nbrs[k]
        out[i] = best if abs(D[i]) < weak * total else -1


@ti.kernel
def _pair_reach(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                cell_of: ti.types.ndarray(), cix: ti.types.ndarray(),
                ciy: ti.types.ndarray()) -> ti.i32:
    """The largest cell offset (in x or y) between a particle's cell and a
    neighbour's: the half-width of the window a row's columns lie in."""
    reach = 0
    for i in range(n):
        c = cell_of[i]
        for k in range(offsets[i], offsets[i + 1]):
            j = cell_of[nbrs[k]]
            ti.atomic_max(reach, ti.max(abs(cix[j] - cix[c]), abs(ciy[j] - ciy[c])))
    return reach


@ti.kernel
def _csr_galerkin(particles: ti.template(), fill: ti.template(), rows: ti.i32, row0: ti.i32,
                  kid0: ti.i32, kid_start: ti.types.ndarray(), kids: ti.types.ndarray(),
                  f_row0: ti.i32, f_off: ti.types.ndarray(), f_col: ti.types.ndarray(),
                  f_val: ti.types.ndarray(), D: ti.types.ndarray(), dinv: ti.types.ndarray(),
                  up: ti.types.ndarray(), cix: ti.types.ndarray(), ciy: ti.types.ndarray(),
                  reach: ti.i32, chunks: ti.i32, stride: ti.i32, mark: ti.types.ndarray(),
                  where: ti.types.ndarray(), out_off: ti.types.ndarray(),
                  out_col: ti.types.ndarray(), out_val: ti.types.ndarray()):
    """One level's Galerkin operator ``P^T S P`` in CSR, rows ``row0 ..
    row0 + rows`` (global), from the level below (``particles``: the particle
    rows ``D^-1 A``, i.e. the pairs scaled by ``dinv`` and the diagonal; else a
    cell level's CSR ``f_*``): the entries of a row's children, their columns
    mapped up (``up``) and summed.  A row's columns lie within ``reach`` cells
    of its own, so a (2 reach + 1)^2 window of markers (``mark``, ``where``;
    -1 on entry) finds the repeats without sorting.  Two passes: counting
    (``out_off[g + 1]``: global row g's entries) and, with ``fill``, writing at
    the row starts ``out_off[g]``.  The rows are split into ``chunks``
    contiguous runs, in parallel, each run serial with a window of its own
    (``stride`` entries apart: whole cache lines, not shared between threads):
    a row's sums are the same in any split (deterministic)."""
    q, rem = rows // chunks, rows % chunks       # (not t * rows // chunks: i32 overflow)
    for t in range(chunks):
        for C in range(t * q + ti.min(t, rem), (t + 1) * q + ti.min(t + 1, rem)):
            _galerkin_row(particles, fill, row0 + C, t * stride, kid0 + C, kid_start, kids,
                          f_row0, f_off, f_col, f_val, D, dinv, up, cix, ciy, reach, mark,
                          where, out_off, out_col, out_val)


@ti.func
def _galerkin_row(particles: ti.template(), fill: ti.template(), g, slot0, kid_row,
                  kid_start: ti.template(), kids: ti.template(), f_row0,
                  f_off: ti.template(), f_col: ti.template(), f_val: ti.template(),
                  D: ti.template(), dinv: ti.template(), up: ti.template(),
                  cix: ti.template(), ciy: ti.template(), reach, mark: ti.template(),
                  where: ti.template(), out_off: ti.template(), out_col: ti.template(),
                  out_val: ti.template()):
    """Row ``g`` of :func:`_csr_galerkin`, with the window at ``slot0``."""
    w = 2 * reach + 1
    base = 0
    if ti.static(fill):
        base = out_off[g]
    cnt = 0
    for m in range(kid_start[kid_row], kid_start[kid_row + 1]):
        c = kids[m]
        extra = 1 if ti.static(particles) else 0
        for e in range(f_off[c - f_row0], f_off[c - f_row0 + 1] + extra):
            j = c
            v = 0.0
            if ti.static(particles):
                if e < f_off[c + 1]:
                    j = f_col[e]
                    v = dinv[c] * f_val[e]
                else:
                    v = D[c] * dinv[c]
            else:
                j = f_col[e]
                v = f_val[e]
            J = up[j]
            slot = slot0 + (ciy[J] - ciy[g] + reach) * w + cix[J] - cix[g] + reach
            if mark[slot] != g:
                mark[slot] = g
                if ti.static(fill):
                    where[slot] = base + cnt
                    out_col[base + cnt] = J
                    out_val[base + cnt] = v
                cnt += 1
            elif ti.static(fill):
                # not +=: that would be an atomic add in this parallel loop,
                # and no two runs share a row
                out_val[where[slot]] = out_val[where[slot]] + v
    if ti.static(not fill):
        out_off[g + 1] = cnt


@ti.kernel
def _running_sum(off: ti.types.ndarray(), row0: ti.i32, rows: ti.i32, base: ti.i32) -> ti.i32:
    """Row counts in ``off[row0 + 1 .. row0 + rows]`` to row starts from
    ``base``, in place; returns the level's end."""
    off[row0] = base
    ti.loop_config(serialize=True)
    for C in range(rows):
        off[row0 + C + 1] += off[row0 + C]
    return off[row0 + rows]


@ti.kernel
def _copy_prefix(n: ti.i32, src: ti.types.ndarray(), dst: ti.types.ndarray()):
    for i in range(n):
        dst[i] = src[i]


@ti.kernel
def _dense_rows(lo: ti.i32, m: ti.i32, S_off: ti.types.ndarray(), S_col: ti.types.ndarray(),
                S_val: ti.types.ndarray(), out: ti.types.ndarray()):
    """Rows lo .. lo + m of the flat CSR (columns in the same range) as a dense
    m x m matrix: the coarsest level, for its pseudo-inverse."""
    for q in range(m * m):
        out[q] = 0.0
    ti.loop_config(serialize=True)
    for i in range(m):
        for e in range(S_off[lo + i], S_off[lo + i + 1]):
            out[i * m + S_col[e] - lo] += S_val[e]


@ti.kernel
def _diagonal_inverse(rows0: ti.i32, total: ti.i32, S_off: ti.types.ndarray(),
                      S_col: ti.types.ndarray(), S_val: ti.types.ndarray(), eps: float,
                      cdinv: ti.types.ndarray()) -> float:
    """cdinv = 1 / diag on every cell row, zero where the diagonal is below the
    round-off of the first level's entries, ``1e3 eps sum |S_0|`` (returned):
    constants are (nearly) in the null space of every level of a Neumann
    problem, so the coarse entries are sums that cancel."""
    total_abs = 0.0
    ti.loop_config(serialize=True)          # a deterministic sum
    for q in range(S_off[rows0]):
        total_abs += abs(S_val[q])
    noise = 1e3 * eps * total_abs
    for c in range(total):
        d = 0.0
        for e in range(S_off[c], S_off[c + 1]):
            if S_col[e] == c:
                d += S_val[e]
        cdinv[c] = 1.0 / d if abs(d) > noise else 0.0
    return noise


@ti.kernel
def _grid_values(serial: ti.template(), L: ti.i32, eps: float, cell_start: ti.types.ndarray(),
                 offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), K: ti.types.ndarray(),
                 D: ti.types.ndarray(), dims: ti.types.ndarray(), lvl: ti.types.ndarray(),
                 cell_of: ti.types.ndarray(), dinv: ti.types.ndarray(),
                 S_val: ti.types.ndarray(), cdinv: ti.types.ndarray(),
                 small: ti.types.ndarray()):
    """The values of a hierarchy of dense grids (:meth:`MultilevelPreconditioner.
    _setup_grid_levels`): level 0 is the neighbour grid's cells (its particles
    contiguous, every pair within a cell's 3 x 3 block), level k + 1 joins 2 x 2
    cells of level k, every cell's row nine slots (its 3 x 3 block, slot
    ``(dy + 1) 3 + dx + 1``).  Writes the particles' cells and ``D^-1``, the
    Galerkin operators ``P^T D^-1 A P`` of every level, the cells' inverse
    diagonals (zero on empty cells and round-off pivots), and into ``small``:
    the pairs reaching beyond the 3 x 3 block (must be 0), the round-off level
    of the entries, and the coarsest level as a dense matrix."""
    ncell = lvl[0, 1]
    nx = dims[0, 0]
    small[0] = 0.0
    ti.loop_config(serialize=serial)
    for c in range(ncell):
        for i in range(cell_start[c], cell_start[c + 1]):
            cell_of[i] = c
            dinv[i] = 1.0 / D[i] if D[i] != 0 else 0.0
    # level 0: a gather per cell over its particles' pairs (no atomics)
    ti.loop_config(serialize=serial)
    for c in range(ncell):
        row = ti.Vector([0.0] * 9)
        cx = c % nx
        cy = c // nx
        beyond = 0
        for i in range(cell_start[c], cell_start[c + 1]):
            row[4] += D[i] * dinv[i]
            for k in range(offsets[i], offsets[i + 1]):
                cj = cell_of[nbrs[k]]
                dx = cj % nx - cx
                dy = cj // nx - cy
                if abs(dx) <= 1 and abs(dy) <= 1:
                    row[(dy + 1) * 3 + dx + 1] += dinv[i] * K[k]
                else:
                    beyond += 1
        for s in ti.static(range(9)):
            S_val[9 * c + s] = row[s]
        if beyond > 0:
            small[0] += beyond      # rare: an error; its sum order does not matter
    # the cell levels: few cells, one thread
    ti.loop_config(serialize=True)
    for _ in range(1):
        total = 0.0
        for q in range(9 * ncell):
            total += abs(S_val[q])
        # constants are (nearly) in the null space of every level of a Neumann
        # problem: values below the round-off of such a sum are zero, not pivots
        noise = 1e3 * eps * total
        small[1] = noise
        for k in range(1, L):
            f0 = lvl[k - 1, 0]
            nxf = dims[k - 1, 0]
            nyf = dims[k - 1, 1]
            c0 = lvl[k, 0]
            nxc = dims[k, 0]
            for C in range(lvl[k, 1] - c0):
                X = C % nxc
                Y = C // nxc
                acc = ti.Vector([0.0] * 9)
                for b in range(2):
                    for a in range(2):
                        fx = 2 * X + a
                        fy = 2 * Y + b
                        if fx < nxf and fy < nyf:
                            fine = 9 * (f0 + fy * nxf + fx)
                            for s in range(9):
                                gx = fx + s % 3 - 1
                                gy = fy + s // 3 - 1
                                if 0 <= gx < nxf and 0 <= gy < nyf:
                                    acc[(gy // 2 - Y + 1) * 3 + gx // 2 - X + 1] += \
                                        S_val[fine + s]
                for s in ti.static(range(9)):
                    S_val[9 * (c0 + C) + s] = acc[s]
        for c in range(lvl[L - 1, 1]):
            d = S_val[9 * c + 4]
            cdinv[c] = 1.0 / d if abs(d) > noise else 0.0
        lo = lvl[L - 1, 0]
        m = lvl[L - 1, 1] - lo
        nxc = dims[L - 1, 0]
        nyc = dims[L - 1, 1]
        for q in range(m * m):
            small[2 + q] = 0.0
        for i in range(m):
            for s in range(9):
                gx = i % nxc + s % 3 - 1
                gy = i // nxc + s // 3 - 1
                if 0 <= gx < nxc and 0 <= gy < nyc:
                    small[2 + i * m + gy * nxc + gx] = S_val[9 * (lo + i) + s]


@ti.kernel
def _cycle(cols: ti.template(), serial: ti.template(), by_cell: ti.template(), schedule: ti.template(),
           post: ti.template(),
           omega: ti.template(), correction: ti.template(),
           bordered: ti.template(), gamma: ti.template(), L: ti.i32, n: ti.i32,
           pstart: ti.types.ndarray(), porder: ti.types.ndarray(), cell_of: ti.types.ndarray(),
           offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), K: ti.types.ndarray(),
           D: ti.types.ndarray(), dinv: ti.types.ndarray(), lvl: ti.types.ndarray(),
           visits: ti.types.ndarray(), S_off: ti.types.ndarray(), S_col: ti.types.ndarray(),
           S_val: ti.types.ndarray(), parent: ti.types.ndarray(),
           kid_start: ti.types.ndarray(), kids: ti.types.ndarray(), cdinv: ti.types.ndarray(),
           cr: ti.types.ndarray(), cx: ti.types.ndarray(), ctmp: ti.types.ndarray(),
           Minv: ti.types.ndarray(), fx: ti.types.ndarray(), ftmp: ti.types.ndarray(),
           border_c: float, constant_mode: ti.template(), colsum: ti.types.ndarray(),
           const_c: float,
           r: ti.types.ndarray(), z: ti.types.ndarray()):
    """z = M^-1 r: one cycle from zero, in one launch.  The particle level and
    the large cell levels run in parallel loops (``schedule``, a static list of
    operations: :func:`_schedule`); the smaller levels run in one serial loop
    whose level count is a runtime value (one compiled kernel for every
    hierarchy of the same schedule; a parallel loop per small level would cost
    more in thread synchronisation than its work).  ``gamma`` coarse cycles
    per cell level: 1 is a V-cycle, 2 a W-cycle."""
    m0 = lvl[0, 1]
    # particles: pre-smoothing from zero x = omega D^-1 r, stored so that the
    # gather below reads one value per neighbour; the scaled residual
    # D^-1 (r - A x) summed per cell; unless the particles are sorted by cell,
    # first in particle order (ftmp is free until the post-smoothing): read by
    # cell, the rows came out of order, which made this pass twice an apply's
    # time at 200k
    ti.loop_config(serialize=serial)
    for i in range(n):
        fx[i] = omega * dinv[i] * r[i]
    if ti.static(by_cell):
        # the particles are sorted by their cells (the neighbour grid's): one loop
        ti.loop_config(serialize=serial)
        for c in range(m0):
            acc = zeros(cols)
            for s in range(pstart[c], pstart[c + 1]):
                i = porder[s]
                ax = D[i] * fx[i]
                for k in range(offsets[i], offsets[i + 1]):
                    ax += K[k] * fx[nbrs[k]]
                acc += dinv[i] * (r[i] - ax)
            cr[c] = acc
    else:
        ti.loop_config(serialize=serial)
        for i in range(n):
            ax = D[i] * fx[i]
            for k in range(offsets[i], offsets[i + 1]):
                ax += K[k] * fx[nbrs[k]]
            ftmp[i] = dinv[i] * (r[i] - ax)
        ti.loop_config(serialize=serial)
        for c in range(m0):
            acc = zeros(cols)
            for s in range(pstart[c], pstart[c + 1]):
                acc += ftmp[porder[s]]
            cr[c] = acc
    for op in ti.static(schedule):
        if ti.static(op[0] == "down"):
            # pre-smoothing from zero, restriction of the residual
            ti.loop_config(serialize=op[2])
            for c in range(lvl[op[1], 0], lvl[op[1], 1]):
                cx[c] = omega * cdinv[c] * cr[c]
        if ti.static(op[0] == "down" or op[0] == "restrict"):
            ti.loop_config(serialize=op[2])
            for p in range(lvl[op[1] + 1, 0], lvl[op[1] + 1, 1]):
                _restrict_row(cols, S_off, S_col, S_val, kid_start, kids, cr, cx, p)
        if ti.static(op[0] == "correct"):
            ti.loop_config(serialize=op[2])
            for c in range(lvl[op[1], 0], lvl[op[1], 1]):
                cx[c] += correction * cx[parent[c]]
        if ti.static(op[0] == "smooth"):
            for _s in ti.static(range(post)):
                ti.loop_config(serialize=op[2])
                for c in range(lvl[op[1], 0], lvl[op[1], 1]):
                    ctmp[c] = cx[c] + omega * cdinv[c] * (
                        cr[c] - _row_apply(cols, S_off, S_col, S_val, cx, c))
                ti.loop_config(serialize=op[2])
                for c in range(lvl[op[1], 0], lvl[op[1], 1]):
                    cx[c] = ctmp[c]
        if ti.static(op[0] == "serial"):
            ti.loop_config(serialize=True)
            for _ in range(1):
                _serial_levels(cols, op[1], L, gamma, post, omega, correction, lvl, visits, S_off,
                               S_col, S_val, parent, kid_start, kids, cdinv, cr, cx, ctmp, Minv)
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
        rsum = zeros(cols)
        azsum = zeros(cols)
        ti.loop_config(serialize=serial)
        for i in range(n):
            rsum += r[i]
            azsum += colsum[i] * z[i]
        shift = (rsum - azsum) / const_c
        ti.loop_config(serialize=serial)
        for i in range(n):
            z[i] += shift


def _unique_keys(keys: np.ndarray, size: int):
    """``np.unique(keys, return_inverse=True)`` for keys in ``0 .. size - 1``:
    by a presence table when it is not much larger than the keys (no sort)."""
    if size <= 8 * len(keys) + 4096:
        present = np.zeros(size, dtype=bool)
        present[keys] = True
        rank = np.cumsum(present, dtype=np.int64) - 1
        return np.flatnonzero(present), rank[keys]
    uniq, inverse = np.unique(keys, return_inverse=True)
    return uniq, inverse.reshape(-1)


class CellMatrix:
    """A level's Galerkin operator in CSR form, built from (row, column, value)
    entries with the duplicates summed (a piecewise-constant aggregation's
    P^T S P is the entries of S summed by the cells of their row and column),
    columns sorted per row."""

    def __init__(self, rows, cols, values, size: int):
        key = np.asarray(rows, dtype=np.int64) * size + np.asarray(cols, dtype=np.int64)
        order = np.argsort(key, kind="stable")
        key = key[order]
        first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
        self.data = np.add.reduceat(np.asarray(values, dtype=np.float64)[order], first) \
            if len(key) else np.zeros(0)
        unique = key[first]
        self.indices = unique % size
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(unique // size,
                                                                 minlength=size))])
        self.shape = (size, size)

    @property
    def nnz(self) -> int:
        return len(self.data)

    def entries(self):
        """(rows, columns, values)."""
        return np.repeat(np.arange(self.shape[0]), np.diff(self.indptr)), self.indices, self.data

    def diagonal(self) -> np.ndarray:
        r, c, v = self.entries()
        out = np.zeros(self.shape[0])
        on = r == c
        out[r[on]] = v[on]
        return out

    def toarray(self) -> np.ndarray:
        r, c, v = self.entries()
        out = np.zeros(self.shape)
        out[r, c] = v
        return out


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
    omega: Jacobi damping (default 0.7 for W, 0.85 for V);
    correction: coarse-correction scale (default 1.4 for W, 1.8 for V: the
    fastest measured; the V defaults on the flow's pressure rows, levels on the
    neighbour grid);
    l1: scale rows by ``max(|a_ii|, sum_j |a_ij|)`` instead of ``a_ii``
    (smaller Jacobi steps on rows that are not diagonally dominant; it helps
    some systems and hurts others, so off by default);
    cells: side of the first level's cells in units of the particles' median
    kernel support (None: the largest support, the default);
    weak: rows with ``|a_ii| < weak sum_j |a_ij|`` join the cells of their most
    strongly coupled neighbour (0: off, the default).  The measurements
    behind each default: docs/notes/linalg.md.
    reuse: a previous preconditioner no longer needed (the last time step's):
    its Taichi arrays are written over where large enough (the flow builds
    one per step; allocating them cost more than the rest of the set-up).
    """

    name = "multilevel"

    def __init__(self, A, *, cycle: str = "W", post: int | None = None, omega: float | None = None,
                 correction: float | None = None, l1: bool = False, cells: float | None = None,
                 weak: float = 0.0, reuse=None):
        runtime.ensure_init()
        self._arrays = {}
        self._columns_scratch = {}
        self._old_arrays = reuse._arrays if reuse is not None else {}
        self.l1 = bool(l1)
        if cycle not in ("V", "W"):
            raise InputError(f"multilevel: cycle must be 'V' or 'W', got {cycle!r}")
        self.cycle = cycle
        self.gamma = 1 if cycle == "V" else 2
        if omega is None:
            omega = 0.85 if cycle == "V" else 0.7
        if correction is None:
            correction = 1.8 if cycle == "V" else 1.4
        if post is None:
            post = 2 if cycle == "V" else 1
        if not (1 <= post <= 3) or not (0 < omega < 2) or not correction > 0:
            raise InputError("multilevel: need 1 <= post <= 3, 0 < omega < 2, "
                             "correction > 0")
        if not 0 <= weak < math.inf:
            raise InputError(f"multilevel: weak must be a number >= 0, got {weak!r}")
        if cells is not None and not (0 < cells < math.inf):
            raise InputError(f"multilevel: cells must be a positive number or None, got {cells!r}")
        self.post, self.omega, self.correction = int(post), float(omega), float(correction)
        self.cells = cells
        self.weak = float(weak)
        # below SERIAL_MAX_N particles the cycle's loops run on one thread
        self.serial = A.n_particles < SERIAL_MAX_N
        # the rows the cycle reads, not the matrix: the matrix caches this
        # preconditioner (PoissonMatrix.multilevel), and a reference back would
        # make a cycle that keeps both, gigabytes at 1M particles, alive until
        # the garbage collector runs, and the next large call allocates beside
        # them (docs/notes/scattered.md, "What a call leaves behind")
        self._rows = (A.ops.pairs.offsets, A.ops.pairs.neighbours, A.K, A.D)
        ops = A.ops
        n = ops.particles.n
        self.n = n
        self._bordered = bool(getattr(A, "bordered", False))
        self._border_c = float(getattr(A, "border_c", 1.0)) if self._bordered else 1.0
        grid = getattr(ops.pairs, "grid", None)
        # the grid levels' particles are sorted by their level-0 cells
        self._by_cell = cells is None and self.weak == 0 and not self.l1 and grid is not None
        if self._by_cell:
            self._setup_grid_levels(A, n, grid)
        else:
            pos = ops.particles.position.to_numpy()[:n].astype(np.float64)
            lo = pos.min(axis=0)
            extent = pos.max(axis=0) - lo
            if cells is None:
                size = ops.support * CELL_PAD
            else:
                hs = getattr(ops, "supports", None)
                median = ops.support if hs is None else float(np.median(hs.to_numpy()[:n]))
                size = cells * median * CELL_PAD
            if self.weak > 0:
                pos = self._join_weak_rows(A, n, pos)
            self._setup_levels(A, n, *self._aggregates(pos, lo, extent, size))
        self._old_arrays = {}

    def _join_weak_rows(self, A, n: int, pos):
        """Positions for the aggregation in which every particle whose row is far
        from diagonally dominant (``|a_ii| < weak sum_j |a_ij|``) takes the
        position of its most strongly coupled neighbour, so that it shares that
        neighbour's cell on every level: Jacobi barely moves such a row, and a
        cell of its own would leave its error to the Krylov method."""
        strongest = runtime.array(ti.i32, max(n, 1))
        pr = A.ops.pairs
        _strongest_neighbour(n, self.weak, pr.offsets, pr.neighbours, A.K, A.D, strongest)
        partner = strongest.to_numpy()[:n]
        weak = np.flatnonzero(partner >= 0)
        if weak.size == 0:
            return pos
        pos = pos.copy()
        pos[weak] = pos[partner[weak]]
        return pos

    @staticmethod
    def _aggregates(pos, lo, extent, size: float) -> list:
        """The aggregation maps of every cell level: level 0's maps each particle
        to its row, level k >= 1's each row of level k - 1 to its row of level k.

        Level k aggregates the particles by the non-empty cells of side
        ``size 2^k`` of a grid from ``lo`` (nested: level k+1 aggregates 2 x 2
        level-k cells), down to the first grid of at most COARSEST cells (and at
        least two levels).  Also each level's cells: their keys ``iy nx + ix``
        (ascending, as its rows) and ``nx``.  A level's cell indices are its
        finer level's halved (floor(floor(x / s) / 2) = floor(x / 2s), exact in
        floating point: the division by a power of two is), so only level 0
        reads the particles."""
        maps = []
        cells = []
        ij = np.floor((pos - lo) / size).astype(np.int64)
        k = 0
        while True:
            shape = np.floor(extent / (size * 2.0 ** k)).astype(np.int64) + 1
            ij = np.minimum(ij, shape - 1)
            keys, agg = _unique_keys(ij[:, 1] * shape[0] + ij[:, 0], int(shape[0] * shape[1]))
            maps.append(agg)
            cells.append((keys, int(shape[0])))
            k += 1
            if shape[0] * shape[1] <= COARSEST and k >= 2:
                return maps, cells
            ij = np.stack([keys % shape[0], keys // shape[0]], axis=1) // 2

    @staticmethod
    def grid_level_dims(nx: int, ny: int) -> list:
        """The cell counts (nx, ny) of the dense levels from a grid of nx x ny
        cells, each joining 2 x 2 cells of the one before, down to the first of
        at most COARSEST cells (and at least two levels)."""
        dims = [(int(nx), int(ny))]
        while not (dims[-1][0] * dims[-1][1] <= COARSEST and len(dims) >= 2):
            nx, ny = dims[-1]
            dims.append(((nx + 1) // 2, (ny + 1) // 2))
        return dims

    def _setup_grid_levels(self, A, n: int, grid) -> None:
        """Cell levels as dense grids when the particles are sorted by the pair
        list's own grid (cells as wide as the supports; the flow's particles and a
        fixed-support :class:`~taichi_hh.sph.pointset.PointSet`'s are): level 0 is
        that grid's cells, and every level's structure (nine slots a cell: its
        3 x 3 block; empty cells are zero rows) follows from the grid's shape, so
        it is built once and handed on with ``reuse``; the values are one kernel
        launch (:func:`_grid_values`), with no sort and no host copy of the
        pairs.  The operators are those of :meth:`_setup_levels` on the same
        cells (tests/test_multilevel.py)."""
        dims = self.grid_level_dims(grid.spec.nx, grid.spec.ny)
        sizes = [nx * ny for nx, ny in dims]
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        total = int(starts[-1])
        key = ("grid", tuple(dims))
        old = self._old_arrays
        if old.get("structure") == key:
            for name in ("lvl", "dims", "S_off", "S_col", "parent", "kid_start", "kids"):
                self._arrays[name] = old[name]
        else:
            S_col, parent, kid_count, kids = [], [], [np.zeros(sizes[0], np.int64)], []
            for k, (nx, ny) in enumerate(dims):
                iy, ix = np.divmod(np.arange(nx * ny), nx)
                cols = np.empty((nx * ny, 9), dtype=np.int64)
                for s in range(9):
                    jx, jy = ix + s % 3 - 1, iy + s // 3 - 1
                    inside = (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny)
                    # a slot outside the grid points at its own row (its value is 0)
                    cols[:, s] = np.where(inside, jy * nx + jx, iy * nx + ix) + starts[k]
                S_col.append(cols.reshape(-1))
                if k + 1 < len(dims):
                    par = (iy // 2) * dims[k + 1][0] + ix // 2
                    parent.append(par + starts[k + 1])
                    kids.append(np.argsort(par, kind="stable") + starts[k])
                    kid_count.append(np.bincount(par, minlength=sizes[k + 1]))
                else:
                    parent.append(np.full(nx * ny, -1))
            kid_start = np.concatenate([[0], np.cumsum(np.concatenate(kid_count))])
            S_col = np.concatenate(S_col)
            self.lvl = self._array("lvl", ti.i32, (len(dims), 2),
                                   np.c_[starts[:-1], starts[1:]].astype(np.int32))
            self._array("dims", ti.i32, (len(dims), 2), np.asarray(dims, dtype=np.int32))
            self._vector("S_off", ti.i32, 9 * np.arange(total + 1))
            self._vector("S_col", ti.i32, S_col)
            self._vector("parent", ti.i32, np.concatenate(parent))
            self._vector("kid_start", ti.i32, kid_start)
            self._vector("kids", ti.i32, np.concatenate(kids) if kids else [])
        self._arrays["structure"] = key
        for name in ("lvl", "S_off", "S_col", "parent", "kid_start", "kids"):
            setattr(self, name, self._arrays[name])
        # level 0's cells hold their particles in order: the identity permutation
        if old.get("identity_n", 0) >= n:
            self.porder = self._arrays["porder"] = old["porder"]
            self._arrays["identity_n"] = old["identity_n"]
        else:
            self.porder = self._vector("porder", ti.i32, np.arange(n))
            self._arrays["identity_n"] = n
        self.pstart = grid.cell_start
        self.cell_of = self._vector("cell_of", ti.i32, size=n)
        self.dinv = self._vector("dinv", None, size=n)
        self.S_val = self._vector("S_val", None, size=9 * total)
        self.cdinv = self._vector("cdinv", None, size=total)
        m = sizes[-1]
        small = self._array("small", runtime.real_dtype(), (2 + m * m,))
        pr = A.ops.pairs
        _grid_values(self.serial, len(dims), float(np.finfo(runtime.np_real()).eps),
                     grid.cell_start, pr.offsets, pr.neighbours, A.K, A.D,
                     self._arrays["dims"], self.lvl, self.cell_of, self.dinv, self.S_val,
                     self.cdinv, small)
        small = small.to_numpy().astype(np.float64)
        if small[0] > 0:
            raise InputError(f"multilevel: {int(small[0])} pairs reach beyond a cell's 3 x 3 "
                             "block of the neighbour grid")
        self._grid_dims = dims
        self._levels = None                  # CellMatrix views, built on request
        self._parents = None
        self.level_sizes = sizes
        self._finish_setup(A, n, [9 * m for m in sizes], small[2:].reshape(m, m), small[1])

    def _views(self) -> None:
        """Every level as a :class:`CellMatrix` and the aggregation maps, from
        the flat CSR of the cycle (inspection and tests)."""
        if self._levels is not None:
            return
        total = sum(self.level_sizes)
        S_off = self.S_off.to_numpy()[: total + 1].astype(np.int64)
        nnz = int(S_off[-1])
        S = CellMatrix(np.repeat(np.arange(total), np.diff(S_off)), self.S_col.to_numpy()[:nnz],
                       self.S_val.to_numpy()[:nnz].astype(np.float64), total)
        starts = np.concatenate([[0], np.cumsum(self.level_sizes)])
        r, c, v = S.entries()
        self._levels = []
        for k in range(len(self.level_sizes)):
            on = (r >= starts[k]) & (r < starts[k + 1])
            self._levels.append(CellMatrix(r[on] - starts[k], c[on] - starts[k], v[on],
                                           self.level_sizes[k]))
        parent = self.parent.to_numpy()[:total]
        self._parents = [parent[starts[k]:starts[k + 1]] - starts[k + 1]
                         for k in range(len(self.level_sizes) - 1)]
        self.cell_of_np = self.cell_of.to_numpy()[:self.n].astype(np.int64)

    def _setup_levels(self, A, n: int, maps, cells) -> None:
        """The Galerkin operators of every cell level, in kernels (once per
        matrix): B = D^-1 A on the particles, S_0 = P_0^T B P_0, S_k+1 = P_k^T S_k P_k,
        with the piecewise-constant aggregations P (``maps``: particle -> row of
        level 0, then row of level k - 1 -> row of level k; ``cells``: each
        level's cell keys, for the rows' coordinates);
        each level by :func:`_csr_galerkin`, then all in one flat CSR."""
        pr = A.ops.pairs
        self.dinv = self._vector("dinv", None, size=n)
        _scaled_diagonal(self.l1, n, pr.offsets, A.K, A.D, self.dinv)
        cell_of = maps[0]
        ncell = int(cell_of.max()) + 1
        self.porder = self._vector("porder", ti.i32, np.argsort(cell_of, kind="stable"))
        self.pstart = self._vector("pstart", ti.i32, np.concatenate(
            [[0], np.cumsum(np.bincount(cell_of, minlength=ncell))]))
        self.cell_of = self._vector("cell_of", ti.i32, cell_of)
        sizes = [len(keys) for keys, _ in cells]
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        total = int(starts[-1])
        parent = np.full(total, -1, dtype=np.int64)
        kid_count = np.zeros(total, dtype=np.int64)
        kids = []
        for k in range(len(maps) - 1):
            par = maps[k + 1]               # level k's rows -> level k + 1's
            parent[starts[k]:starts[k + 1]] = par + starts[k + 1]
            kid_count[starts[k + 1]:starts[k + 2]] = np.bincount(par, minlength=sizes[k + 1])
            kids.append(np.argsort(par, kind="stable") + starts[k])
        kid_start = np.concatenate([[0], np.cumsum(kid_count)])
        self.lvl = self._array("lvl", ti.i32, (len(sizes), 2),
                               np.c_[starts[:-1], starts[1:]].astype(np.int32))
        self.parent = self._vector("parent", ti.i32, parent)
        self.kid_start = self._vector("kid_start", ti.i32, kid_start)
        self.kids = self._vector("kids", ti.i32, np.concatenate(kids) if kids else [])
        cix = self._vector("cix", ti.i32, np.concatenate([keys % nx for keys, nx in cells]))
        ciy = self._vector("ciy", ti.i32, np.concatenate([keys // nx for keys, nx in cells]))
        reach = _pair_reach(n, pr.offsets, pr.neighbours, self.cell_of, cix, ciy) + 1
        real = runtime.real_dtype()
        dummy = runtime.array(real, 1)
        # every level straight into the cycle's flat CSR: level k's rows read the
        # rows of level k - 1 (global row indices) already written there
        self.S_off = self._vector("S_off", ti.i32, size=total + 1)
        self.S_col = self.S_val = None
        level_nnz = []
        end = 0
        for k, rows in enumerate(sizes):
            if k == 0:       # the particle rows: pairs and diagonal, up by cell_of
                src = (0, self.pstart, self.porder, 0, pr.offsets, pr.neighbours, A.K,
                       self.cell_of)
            else:            # the level below's rows, up by parent
                src = (int(starts[k]), self.kid_start, self.kids, 0, self.S_off, self.S_col,
                       self.S_val, self.parent)
            chunks = max(1, min(rows // GALERKIN_CHUNK_ROWS, GALERKIN_MAX_CHUNKS))
            if k == 0:      # the widest window and the most runs: level 0's, reused above
                stride = -(-(2 * reach + 1) ** 2 // 32) * 32
                mark = runtime.array(ti.i32, chunks * stride)
                where = runtime.array(ti.i32, chunks * stride)
            args = (*src[:7], A.D, self.dinv, src[7], cix, ciy, reach, chunks, stride, mark,
                    where, self.S_off)
            mark.fill(-1)
            _csr_galerkin(k == 0, False, rows, int(starts[k]), *args, mark, dummy)
            base = end
            end = int(_running_sum(self.S_off, int(starts[k]), rows, base))
            level_nnz.append(end - base)
            if self.S_col is None or end > self.S_col.shape[0]:
                # the coarser levels together hold about a third of level 0's
                # entries on the decomposition's cells (13k random points: 27%,
                # 3.6%, 0.7%, ...): 35% more is room for all of them; a regrowth
                # keeps a quarter more, so that it happens once, not per level
                room = max(end + (7 * end // 20 if k == 0 else end // 4), 1)
                S_col = runtime.array(ti.i32, room, zeroed=False)
                S_val = runtime.array(real, room, zeroed=False)
                if self.S_col is not None and base > 0:
                    _copy_prefix(base, self.S_col, S_col)
                    _copy_prefix(base, self.S_val, S_val)
                self.S_col, self.S_val = S_col, S_val
                self._arrays["S_col"], self._arrays["S_val"] = S_col, S_val
                if k > 0:       # the level below's columns moved with them
                    args = (*src[:4], self.S_off, self.S_col, self.S_val, *args[7:])
            mark.fill(-1)
            _csr_galerkin(k == 0, True, rows, int(starts[k]), *args, self.S_col, self.S_val)
            reach = reach // 2 + 1          # the next level's cells are twice as wide
        self.cdinv = self._vector("cdinv", None, size=total)
        noise = _diagonal_inverse(sizes[0], total, self.S_off, self.S_col, self.S_val,
                                  float(np.finfo(runtime.np_real()).eps), self.cdinv)
        m = sizes[-1]
        dense = runtime.array(real, max(m * m, 1))
        _dense_rows(int(starts[-2]), m, self.S_off, self.S_col, self.S_val, dense)
        coarsest = dense.to_numpy()[: m * m].astype(np.float64).reshape(m, m)
        self.level_sizes = sizes
        self._levels = None                  # CellMatrix views, built on request
        self._parents = None
        self.cell_of_np = cell_of
        self._finish_setup(A, n, level_nnz, coarsest, noise)

    def _finish_setup(self, A, n: int, level_nnz: list, coarsest, noise: float) -> None:
        """What both set-ups share: the schedule, the work vectors, the constant
        mode and the coarsest level's (pseudo-)inverse (``coarsest``: dense)."""
        # cell levels 1 .. k0-1 in parallel loops, k0 .. L-1 in the serial machine
        k0 = 1
        if not self.serial:
            # the schedule is unrolled into the kernel, and a W-cycle doubles it
            # per parallel level: at most MAX_SCHEDULE_OPS loops (compile time)
            while (k0 < len(level_nnz) - 2 and level_nnz[k0] >= PARALLEL_MIN_NNZ
                   and len(_schedule(k0 + 1, self.gamma, False)) <= MAX_SCHEDULE_OPS):
                k0 += 1
        self.schedule = _schedule(k0, self.gamma, self.serial)
        total = sum(self.level_sizes)
        self.visits = self._array("visits", ti.i32, (len(self.level_sizes),))
        self.cr = self._vector("cr", None, size=total)
        self.cx = self._vector("cx", None, size=total)
        self.ctmp = self._vector("ctmp", None, size=total)
        self.fx = self._vector("fx", None, size=n)
        self.ftmp = self._vector("ftmp", None, size=n)
        # coarsest level: pseudo-inverse (singular for a Neumann problem)
        U, sv, Vt = np.linalg.svd(coarsest)
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
        self.coarse_inverse = self._array("coarse_inverse", runtime.real_dtype(),
                                          coarsest.shape, Minv.astype(runtime.np_real()))

    def _vector(self, name: str, dtype, values=None, size: int | None = None):
        """A 1-D Taichi array ``name`` holding ``values`` (or ``size`` entries
        uninitialised): the previous preconditioner's when it is large enough
        (its tail then holds zeros: the kernels read within their ranges), else
        a new one with a quarter more room when reusing (the flow's counts grow
        and shrink a little from step to step)."""
        real = dtype is None
        dtype = runtime.real_dtype() if real else dtype
        np_dtype = runtime.np_real() if real else np.int32
        need = max(size if values is None else len(values), 1)
        old = self._old_arrays.get(name)
        if old is not None and old.shape[0] >= need:
            nd = old
        else:
            # not zero-filled: written in full below or, uninitialised, by the
            # set-up's kernels before the cycle reads them (a serial fill of
            # 10-30 ms an array at 1M particles)
            nd = runtime.array(dtype, need + need // 4 if self._old_arrays else need,
                               zeroed=False)
        if values is not None:
            buf = np.zeros(nd.shape[0], dtype=np_dtype)
            buf[:len(values)] = values
            nd.from_numpy(buf)
        self._arrays[name] = nd
        return nd

    def _array(self, name: str, dtype, shape: tuple, values=None):
        """A Taichi array of exactly ``shape``: the previous one when the shape
        is the same."""
        old = self._old_arrays.get(name)
        nd = old if old is not None and tuple(old.shape) == tuple(shape) \
            else runtime.array(dtype, shape)
        if values is not None:
            nd.from_numpy(values)
        self._arrays[name] = nd
        return nd

    def level_matrix(self, k: int) -> "CellMatrix":
        """Cell level k's Galerkin operator (rows = its cells: the non-empty
        ones, or every cell of a dense grid level)."""
        if self._levels is None:
            self._views()
        return self._levels[k]

    def aggregation(self, k: int) -> np.ndarray:
        """The row of level k each row of the level below belongs to: k = 0 maps
        particles to level-0 cells, k >= 1 level k-1 cells to level k cells."""
        if self._levels is None:
            self._views()
        return self.cell_of_np if k == 0 else self._parents[k - 1]

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
        self.colsum = self._vector("colsum", None, size=n)
        self._constant_c = 1.0
        self._constant_mode = False
        if self._bordered or not callable(getattr(A, "apply_transpose", None)):
            return
        ones = runtime.array(real, A.n)
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
        return 1 + len(self.level_sizes)

    def describe(self) -> str:
        sizes = [str(self.n)] + [str(m) for m in self.level_sizes]
        return f"{self.cycle}-cycle, levels " + " > ".join(sizes)

    #: the cycle runs on several columns at once (:mod:`taichi_hh.linalg.columns`)
    accepts_columns = True

    def _scratch(self, cols: int) -> tuple:
        """The cycle's work vectors (cr, cx, ctmp on the cell levels, fx, ftmp on
        the particles) for ``cols`` columns; made on first use for several."""
        if cols == 1:
            return self.cr, self.cx, self.ctmp, self.fx, self.ftmp
        made = self._columns_scratch.get(cols)
        if made is None:
            cells, n = self.cr.shape[0], self.fx.shape[0]
            made = tuple(runtime.array(None, size, vector=cols, zeroed=False)
                         for size in (cells, cells, cells, n, n))
            self._columns_scratch = {cols: made}
        return made

    def apply(self, r, z) -> None:
        """z = M^-1 r (one cycle from zero); r, z hold one column or several
        (vectors: each column cycled independently, the matrix read once)."""
        offsets, neighbours, K, D = self._rows
        cols = columns_of(r)
        cr, cx, ctmp, fx, ftmp = self._scratch(cols)
        _cycle(cols, self.serial, self._by_cell, self.schedule, self.post, self.omega,
               self.correction, self._bordered, self.gamma, len(self.level_sizes), self.n,
               self.pstart, self.porder, self.cell_of, offsets,
               neighbours, K, D, self.dinv, self.lvl, self.visits, self.S_off,
               self.S_col, self.S_val, self.parent, self.kid_start, self.kids, self.cdinv,
               cr, cx, ctmp, self.coarse_inverse, fx, ftmp,
               self._border_c, self._constant_mode, self.colsum, self._constant_c, r, z)
