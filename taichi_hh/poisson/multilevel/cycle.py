"""The multilevel cycle: ``z = M^-1 r`` in one kernel launch (package doc).

The hierarchy reaches the kernel as three records of named Taichi arrays
(:class:`FineLevel`, :class:`CellLevels`, :class:`Work`; a kernel takes its
arrays one by one, so :func:`run_cycle` spreads them and the kernel gathers
them again under their names) and one compile-time record of the cycle's
shape (:class:`CycleShape`).  On the particle level the pre-smoothing from
zero, the residual and the restriction are one gather loop over cells (a
cell's particles are listed contiguously); the prolongation and the first
post-smoothing sweep are another.  The cell levels above ``k0`` run as
parallel loops in a static schedule (:func:`plan_schedule`); the rest in one
serial loop driven as a state machine (kernels cannot recurse).
"""
from dataclasses import dataclass
from typing import NamedTuple

import taichi as ti

from ... import runtime
from ...linalg.columns import zeros

#: parallel loops of the cycle's unrolled schedule at most (a W-cycle's
#: doubles per parallel level: 4, 10, 22, 46, ...; Taichi warns beyond 32)
MAX_SCHEDULE_OPS = 32

#: cell levels below the first with at least this many entries run in parallel
#: loops (with the particles, from SERIAL_MAX_N on); smaller ones in the serial
#: state machine.  A parallel loop needs about 1000 rows to reach the second
#: thread (Taichi's 512-iteration tasks), some 30k-50k entries; with the
#: worker threads bound to cores 50k beat 400k: 13k random points 0.41 against
#: 0.44-0.51 s a call, 200k 5.7 against 6.8 s (docs/notes/scattered.md)
PARALLEL_MIN_NNZ = 50_000

#: the same on a GPU: every cell level but the two coarsest in parallel loops
#: (as far as MAX_SCHEDULE_OPS allows), a GPU's one thread being slow
GPU_PARALLEL_MIN_NNZ = 0


class FineLevel(NamedTuple):
    """The particle level: its rows ``diagonal[i] x_i + sum_k values[k]
    x[neighbours[k]]`` (k in ``offsets[i] .. offsets[i + 1]``), their inverse
    diagonal ``dinv`` and the aggregation into level 0's cells: ``cell_of[i]``,
    and each cell's particles ``porder[pstart[c] .. pstart[c + 1]]``."""
    offsets: object
    neighbours: object
    values: object
    diagonal: object
    dinv: object
    pstart: object
    porder: object
    cell_of: object


class CellLevels(NamedTuple):
    """Every cell level in one flat CSR matrix: level k owns the rows
    ``bounds[k, 0] .. bounds[k, 1]``; a row's columns (``cols``) are global row
    indices of the same level.  ``parent[c]``: the row of c's cell on the next
    level (-1 on the coarsest); the children of a row are
    ``kids[kid_start[c] .. kid_start[c + 1]]`` (rows of the level below);
    ``dinv``: the rows' inverse diagonals; ``coarse_inverse``: the coarsest
    level's dense (pseudo-)inverse."""
    bounds: object
    offsets: object
    cols: object
    vals: object
    parent: object
    kid_start: object
    kids: object
    dinv: object
    coarse_inverse: object


class Work(NamedTuple):
    """The cycle's scratch: per-level visit counts of the serial machine, the
    cell levels' residual, solution and sweep buffer, the particles' solution
    and sweep buffer."""
    visits: object
    cr: object
    cx: object
    ctmp: object
    fx: object
    ftmp: object


@dataclass(frozen=True)
class CycleShape:
    """What the cycle kernel is compiled for (one compiled kernel per shape):
    columns, one thread or many on the particles, particles sorted by cell,
    the static schedule, post-sweeps, Jacobi damping, coarse-correction scale,
    a border unknown, coarse cycles per level (1: V, 2: W), the rank-one
    constant correction."""
    cols: int
    serial: bool
    by_cell: bool
    schedule: tuple
    post: int
    omega: float
    correction: float
    bordered: bool
    gamma: int
    constant_mode: bool


@ti.func
def _row_apply(cols: ti.template(), cells: ti.template(), x: ti.template(), c):
    acc = zeros(cols)
    for k in range(cells.offsets[c], cells.offsets[c + 1]):
        acc += cells.vals[k] * x[cells.cols[k]]
    return acc


@ti.func
def _restrict_row(cols: ti.template(), cells: ti.template(), cr: ti.template(),
                  cx: ti.template(), p):
    """Coarse row p: the sum over its children c of r_c - (S x)_c."""
    acc = zeros(cols)
    for m in range(cells.kid_start[p], cells.kid_start[p + 1]):
        c = cells.kids[m]
        acc += cr[c] - _row_apply(cols, cells, cx, c)
    cr[p] = acc


@ti.func
def _smooth_level(shape: ti.template(), cells: ti.template(), work: ti.template(), lo, hi):
    """``post`` damped-Jacobi sweeps on the rows lo .. hi of a cell level (serial)."""
    for _s in range(shape.post):
        for c in range(lo, hi):
            work.ctmp[c] = work.cx[c] + shape.omega * cells.dinv[c] * (
                work.cr[c] - _row_apply(shape.cols, cells, work.cx, c))
        for c in range(lo, hi):
            work.cx[c] = work.ctmp[c]


@ti.func
def _serial_levels(shape: ti.template(), k_start, L, cells: ti.template(), work: ti.template()):
    """The cycle of levels k_start .. L-1 (their residual in cr on level k_start),
    serially, as a state machine (kernels cannot recurse); ``gamma`` coarse
    cycles per level below k_start's parent."""
    cols = ti.static(shape.cols)
    cr, cx, visits = ti.static(work.cr, work.cx, work.visits)
    k = k_start
    going_down = 1
    while True:
        lo, hi = cells.bounds[k, 0], cells.bounds[k, 1]
        if k == L - 1:
            # coarsest: (pseudo-)inverse, from zero
            for i in range(hi - lo):
                acc = zeros(cols)
                for j in range(hi - lo):
                    acc += cells.coarse_inverse[i, j] * cr[lo + j]
                cx[lo + i] = acc
            if k == k_start:
                break
            going_down = 0
            k -= 1
        elif going_down == 1:
            for c in range(lo, hi):
                cx[c] = shape.omega * cells.dinv[c] * cr[c]
            for p in range(cells.bounds[k + 1, 0], cells.bounds[k + 1, 1]):
                _restrict_row(cols, cells, cr, cx, p)
            visits[k] = 1
            k += 1
        else:
            for c in range(lo, hi):
                cx[c] += shape.correction * cx[cells.parent[c]]
            if visits[k] < shape.gamma and k + 1 < L - 1:
                # another coarse cycle on the new residual (the coarsest
                # level is solved exactly: once is enough)
                visits[k] += 1
                for p in range(cells.bounds[k + 1, 0], cells.bounds[k + 1, 1]):
                    _restrict_row(cols, cells, cr, cx, p)
                k += 1
                going_down = 1
            else:
                _smooth_level(shape, cells, work, lo, hi)
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


def plan_schedule(level_nnz: list, gamma: int, serial: bool) -> tuple:
    """The static schedule for cell levels of ``level_nnz`` entries: levels
    1 .. k0-1 in parallel loops, k0 .. L-1 in the serial machine.  The
    schedule is unrolled into the kernel, and a W-cycle doubles it per
    parallel level: at most MAX_SCHEDULE_OPS loops (compile time)."""
    k0 = 1
    min_nnz = GPU_PARALLEL_MIN_NNZ if runtime.on_gpu() else PARALLEL_MIN_NNZ
    if not serial:
        while (k0 < len(level_nnz) - 2 and level_nnz[k0] >= min_nnz
               and len(_schedule(k0 + 1, gamma, False)) <= MAX_SCHEDULE_OPS):
            k0 += 1
    return _schedule(k0, gamma, serial)


def run_cycle(shape: CycleShape, n: int, fine: FineLevel, cells: CellLevels, work: Work,
              border_c: float, colsum, const_c: float, r, z) -> None:
    """z = M^-1 r for the hierarchy's records (one launch)."""
    _cycle(shape, n, cells.bounds.shape[0], *fine, *cells, *work, border_c, colsum, const_c,
           r, z)


@ti.kernel
def _cycle(shape: ti.template(), n: ti.i32, L: ti.i32,
           offsets: ti.types.ndarray(), neighbours: ti.types.ndarray(),
           values: ti.types.ndarray(), diagonal: ti.types.ndarray(), dinv: ti.types.ndarray(),
           pstart: ti.types.ndarray(), porder: ti.types.ndarray(), cell_of: ti.types.ndarray(),
           bounds: ti.types.ndarray(), S_off: ti.types.ndarray(), S_col: ti.types.ndarray(),
           S_val: ti.types.ndarray(), parent: ti.types.ndarray(),
           kid_start: ti.types.ndarray(), kids: ti.types.ndarray(), cdinv: ti.types.ndarray(),
           Minv: ti.types.ndarray(),
           visits: ti.types.ndarray(), cr: ti.types.ndarray(), cx: ti.types.ndarray(),
           ctmp: ti.types.ndarray(), fx: ti.types.ndarray(), ftmp: ti.types.ndarray(),
           border_c: float, colsum: ti.types.ndarray(), const_c: float,
           r: ti.types.ndarray(), z: ti.types.ndarray()):
    """z = M^-1 r: one cycle from zero, in one launch (the arguments are the
    fields of :class:`FineLevel`, :class:`CellLevels` and :class:`Work` in
    order).  The particle level and the large cell levels run in parallel
    loops (``shape.schedule``, a static list of operations:
    :func:`plan_schedule`); the smaller levels run in one serial loop whose
    level count is a runtime value (one compiled kernel for every hierarchy
    of the same schedule; a parallel loop per small level would cost more in
    thread synchronisation than its work).  ``shape.gamma`` coarse cycles per
    cell level: 1 is a V-cycle, 2 a W-cycle."""
    cells = ti.static(CellLevels(bounds, S_off, S_col, S_val, parent, kid_start, kids, cdinv,
                                 Minv))
    work = ti.static(Work(visits, cr, cx, ctmp, fx, ftmp))
    cols, serial, post = ti.static(shape.cols, shape.serial, shape.post)
    omega, correction = ti.static(shape.omega, shape.correction)
    K, D = ti.static(values, diagonal)
    m0 = bounds[0, 1]
    # particles: pre-smoothing from zero x = omega D^-1 r, stored so that the
    # gather below reads one value per neighbour; the scaled residual
    # D^-1 (r - A x) summed per cell; unless the particles are sorted by cell,
    # first in particle order (ftmp is free until the post-smoothing): read by
    # cell, the rows came out of order, which made this pass twice an apply's
    # time at 200k
    ti.loop_config(serialize=serial)
    for i in range(n):
        fx[i] = omega * dinv[i] * r[i]
    if ti.static(shape.by_cell):
        # the particles are sorted by their cells (the neighbour grid's): one loop
        ti.loop_config(serialize=serial)
        for c in range(m0):
            acc = zeros(cols)
            for s in range(pstart[c], pstart[c + 1]):
                i = porder[s]
                ax = D[i] * fx[i]
                for k in range(offsets[i], offsets[i + 1]):
                    ax += K[k] * fx[neighbours[k]]
                acc += dinv[i] * (r[i] - ax)
            cr[c] = acc
    else:
        ti.loop_config(serialize=serial)
        for i in range(n):
            ax = D[i] * fx[i]
            for k in range(offsets[i], offsets[i + 1]):
                ax += K[k] * fx[neighbours[k]]
            ftmp[i] = dinv[i] * (r[i] - ax)
        ti.loop_config(serialize=serial)
        for c in range(m0):
            acc = zeros(cols)
            for s in range(pstart[c], pstart[c + 1]):
                acc += ftmp[porder[s]]
            cr[c] = acc
    for op in ti.static(shape.schedule):
        if ti.static(op[0] == "down"):
            # pre-smoothing from zero, restriction of the residual
            ti.loop_config(serialize=op[2])
            for c in range(bounds[op[1], 0], bounds[op[1], 1]):
                cx[c] = omega * cdinv[c] * cr[c]
        if ti.static(op[0] == "down" or op[0] == "restrict"):
            ti.loop_config(serialize=op[2])
            for p in range(bounds[op[1] + 1, 0], bounds[op[1] + 1, 1]):
                _restrict_row(cols, cells, cr, cx, p)
        if ti.static(op[0] == "correct"):
            ti.loop_config(serialize=op[2])
            for c in range(bounds[op[1], 0], bounds[op[1], 1]):
                cx[c] += correction * cx[parent[c]]
        if ti.static(op[0] == "smooth"):
            for _s in ti.static(range(post)):
                ti.loop_config(serialize=op[2])
                for c in range(bounds[op[1], 0], bounds[op[1], 1]):
                    ctmp[c] = cx[c] + omega * cdinv[c] * (
                        cr[c] - _row_apply(cols, cells, cx, c))
                ti.loop_config(serialize=op[2])
                for c in range(bounds[op[1], 0], bounds[op[1], 1]):
                    cx[c] = ctmp[c]
        if ti.static(op[0] == "serial"):
            ti.loop_config(serialize=True)
            for _ in range(1):
                _serial_levels(shape, op[1], L, cells, work)
    # particles, up: x += correction P x_0, then post-smoothing
    ti.loop_config(serialize=serial)
    for i in range(n):
        fx[i] += correction * cx[cell_of[i]]
    ti.loop_config(serialize=serial)
    for i in range(n):
        xi = fx[i]
        ax = D[i] * xi
        for k in range(offsets[i], offsets[i + 1]):
            ax += K[k] * fx[neighbours[k]]
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
                ax += K[k] * ftmp[neighbours[k]]
            z[i] = ftmp[i] + omega * dinv[i] * (r[i] - ax)
        if ti.static(post > 2):
            ti.loop_config(serialize=serial)
            for i in range(n):
                ftmp[i] = z[i]
    if ti.static(shape.bordered):
        z[n] = r[n] / border_c
    if ti.static(shape.constant_mode):
        # Petrov-Galerkin correction along the constants (the near-null vector
        # of L + kappa I): z += 1 (1.(r - A z)) / (1.A 1), with 1.A z = colsum.z
        rsum = zeros(cols)
        azsum = zeros(cols)
        ti.loop_config(serialize=serial)
        for i in range(n):
            rsum += r[i]
            azsum += colsum[i] * z[i]
        # the shift through cr[0] (free now): a kernel-scope vector read by a
        # loop faults on CUDA (Taichi 1.7; docs/arch.md)
        cr[0] = (rsum - azsum) / const_c
        ti.loop_config(serialize=serial)
        for i in range(n):
            z[i] += cr[0]
