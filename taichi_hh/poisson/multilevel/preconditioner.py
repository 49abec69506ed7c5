"""The multilevel preconditioner: options, one set-up, the cycle as ``apply``.

The set-up reads the matrix through its pair rows
(:meth:`~taichi_hh.poisson.matrix.PoissonMatrix.pair_rows`), aggregates them
(:mod:`.levels`: on the pair list's own grid, or on cells of another side),
then, whichever the aggregation, scales every cell row by its inverse
diagonal (zero below the round-off of the first level's entries), inverts
the coarsest level densely and plans the cycle's schedule (:mod:`.cycle`).
The hierarchy the cycle reads is three records of named arrays; on the host
it is a list of :class:`Level` (operator and aggregation), as in pyamg.
"""
import math
from typing import NamedTuple

import numpy as np
import taichi as ti

from ... import runtime
from ...errors import InputError
from ...linalg.columns import columns_of
from . import galerkin
from .cycle import CycleShape, Work, plan_schedule, run_cycle
from .levels import ArrayPool, CellMatrix, aggregates, aggregation_positions, cell_levels, \
    grid_levels

#: below this many particles every loop of the cycle runs on one thread: a
#: cycle has about 15 loops, and waking the thread pool for each costs more
#: than the second core saves on small levels (with the workers bound to
#: their cores, 2.5k particles: serial faster; 10k: parallel faster;
#: docs/notes/flow.md, "Worker threads")
SERIAL_MAX_N = 5_000


class Level(NamedTuple):
    """One cell level on the host: its Galerkin operator (rows = its cells:
    the non-empty ones, or every cell of a dense grid level) and the row of
    this level each row of the level below belongs to (level 0: each
    particle's)."""
    matrix: CellMatrix
    aggregation: np.ndarray


class MultilevelPreconditioner:
    """Aggregation-multigrid cycle approximating ``A^-1`` (module doc).

    A: a :class:`~taichi_hh.poisson.matrix.PoissonMatrix` (rows assembled), read
    through two methods only: ``pair_rows()`` (:class:`~taichi_hh.poisson.matrix.PairRows`:
    the rows, where they live, the border) and ``apply_transpose`` (the
    column sums of a ridge system's constant mode).
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

    #: the cycle runs on several columns at once (:mod:`taichi_hh.linalg.columns`)
    accepts_columns = True

    def __init__(self, A, *, cycle: str = "W", post: int | None = None, omega: float | None = None,
                 correction: float | None = None, l1: bool = False, cells: float | None = None,
                 weak: float = 0.0, reuse=None):
        runtime.ensure_init()
        if cycle not in ("V", "W"):
            raise InputError(f"multilevel: cycle must be 'V' or 'W', got {cycle!r}")
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
        self.cycle = cycle
        self.gamma = 1 if cycle == "V" else 2
        self.post, self.omega, self.correction = int(post), float(omega), float(correction)
        self.l1 = bool(l1)
        self.cells = cells
        self.weak = float(weak)
        # the pair rows the cycle reads, not the matrix: the matrix caches this
        # preconditioner (PoissonMatrix.multilevel), and a reference back would
        # make a cycle that keeps both, gigabytes at 1M particles, alive until
        # the garbage collector runs, and the next large call allocates beside
        # them (docs/notes/scattered.md, "What a call leaves behind")
        rows = A.pair_rows()
        self.n = n = rows.n
        # below SERIAL_MAX_N particles the cycle's loops run on one thread
        # (on the CPU: a GPU's one thread is far slower)
        self.serial = n < SERIAL_MAX_N and not runtime.on_gpu()
        self._bordered = bool(rows.bordered)
        self._border_c = float(rows.border_c) if self._bordered else 1.0
        self.pool = ArrayPool(reuse.pool if reuse is not None else None)
        self._columns_scratch = {}
        self._shapes = {}                    # the cycle kernel's CycleShape by columns
        self._levels = None                  # the host's Level records, built on request
        # the grid levels' particles are sorted by their level-0 cells
        self._by_cell = cells is None and self.weak == 0 and not self.l1 \
            and rows.grid is not None
        if self._by_cell:
            hierarchy = grid_levels(rows, self.pool, self.serial)
        else:
            pos, lo, extent, size = aggregation_positions(rows, cells, self.weak)
            hierarchy = cell_levels(rows, self.pool, *aggregates(pos, lo, extent, size), self.l1)
        self._finish(A, rows, hierarchy)
        self.pool.old = {}

    def _finish(self, A, rows, h) -> None:
        """The set-up after the aggregation, the same for both: the cell rows'
        inverse diagonals, the coarsest level's (pseudo-)inverse, the constant
        mode, the schedule and the work vectors."""
        pool, n, sizes = self.pool, self.n, h.sizes
        total = sum(sizes)
        real = runtime.real_dtype()
        cdinv = pool.vector("cdinv", None, size=total)
        S = h.cells
        noise = galerkin.diagonal_inverse(sizes[0], total, S.offsets, S.cols, S.vals,
                                          float(np.finfo(runtime.np_real()).eps), cdinv)
        m = sizes[-1]
        dense = pool.vector("dense", None, size=m * m)
        galerkin.dense_rows(total - m, m, S.offsets, S.cols, S.vals, dense)
        coarsest = dense.to_numpy()[: m * m].astype(np.float64).reshape(m, m)
        self._constant_mode_setup(A, rows)
        # coarsest level: pseudo-inverse (singular for a Neumann problem)
        U, sv, Vt = np.linalg.svd(coarsest)
        keep = sv > noise
        if (self._bordered or self.constant_mode) and len(sv):
            # the constant is fixed elsewhere: by the border unknown of a
            # bordered system, or by the exact rank-one correction below; the
            # coarse level must not invert its round-off-level image (inverting a
            # small ridge kappa there produced corrections of order 1/kappa:
            # BiCGSTAB diverged on bordered systems, and on a ridge system with a
            # 4 x 4 coarsest level it took twice the iterations)
            keep &= sv > 1e-3 * sv[0]
        Minv = (Vt[keep].T / sv[keep]) @ U[:, keep].T
        coarse_inverse = pool.array("coarse_inverse", real, coarsest.shape,
                                    Minv.astype(runtime.np_real()))
        self.fine_level = h.fine
        self.cell_levels = S._replace(dinv=cdinv, coarse_inverse=coarse_inverse)
        self.level_sizes = sizes
        self.work = Work(pool.array("visits", ti.i32, (len(sizes),)),
                         pool.vector("cr", None, size=total), pool.vector("cx", None, size=total),
                         pool.vector("ctmp", None, size=total), pool.vector("fx", None, size=n),
                         pool.vector("ftmp", None, size=n))
        self.schedule = plan_schedule(h.level_nnz, self.gamma, self.serial)

    def _constant_mode_setup(self, A, rows) -> None:
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
        n = self.n
        self.colsum = self.pool.vector("colsum", None, size=n)
        self._constant_c = 1.0
        self.constant_mode = False
        if self._bordered:
            return
        ones = runtime.array(runtime.real_dtype(), A.n)
        ones.fill(1.0)
        A.apply_transpose(ones, self.colsum)
        colsum = self.colsum.to_numpy()[:n]
        total = float(colsum.sum())                     # 1 . A 1
        off = rows.offsets.to_numpy()[: n + 1].astype(np.int64)
        K = np.abs(rows.values.to_numpy()[: off[-1]])
        row_index = np.repeat(np.arange(n), np.diff(off))
        row_abs = np.bincount(row_index, weights=K, minlength=n) \
            + np.abs(rows.diagonal.to_numpy()[:n])
        eps = float(np.finfo(runtime.np_real()).eps)
        noise = 100.0 * eps * math.sqrt(n) * float(row_abs.max())
        if abs(total) > noise:
            self.constant_mode = True
            self._constant_c = total

    # ---- the hierarchy on the host (inspection and tests) ------------------------
    @property
    def levels(self) -> list:
        """Every cell level as a :class:`Level`, from the flat CSR the cycle
        reads (built on first use)."""
        if self._levels is None:
            cells = self.cell_levels
            total = sum(self.level_sizes)
            S_off = cells.offsets.to_numpy()[: total + 1].astype(np.int64)
            nnz = int(S_off[-1])
            S = CellMatrix(np.repeat(np.arange(total), np.diff(S_off)),
                           cells.cols.to_numpy()[:nnz],
                           cells.vals.to_numpy()[:nnz].astype(np.float64), total)
            starts = np.concatenate([[0], np.cumsum(self.level_sizes)])
            r, c, v = S.entries()
            parent = cells.parent.to_numpy()[:total]
            maps = [self.fine_level.cell_of.to_numpy()[:self.n].astype(np.int64)]
            maps += [parent[starts[k]:starts[k + 1]] - starts[k + 1]
                     for k in range(len(self.level_sizes) - 1)]
            self._levels = []
            for k in range(len(self.level_sizes)):
                on = (r >= starts[k]) & (r < starts[k + 1])
                self._levels.append(Level(CellMatrix(r[on] - starts[k], c[on] - starts[k], v[on],
                                                     self.level_sizes[k]), maps[k]))
        return self._levels

    def level_matrix(self, k: int) -> CellMatrix:
        """Cell level k's Galerkin operator (rows = its cells: the non-empty
        ones, or every cell of a dense grid level)."""
        return self.levels[k].matrix

    def aggregation(self, k: int) -> np.ndarray:
        """The row of level k each row of the level below belongs to: k = 0 maps
        particles to level-0 cells, k >= 1 level k-1 cells to level k cells."""
        return self.levels[k].aggregation

    @property
    def S_col(self):
        """The cell levels' CSR columns, ``cell_levels.cols`` (the name
        tests/test_flow.py checks the handed-on grid structure by)."""
        return self.cell_levels.cols

    @property
    def n_levels(self) -> int:
        return 1 + len(self.level_sizes)

    def describe(self) -> str:
        sizes = [str(self.n)] + [str(m) for m in self.level_sizes]
        return f"{self.cycle}-cycle, levels " + " > ".join(sizes)

    # ---- the cycle ---------------------------------------------------------------
    def _work(self, cols: int) -> Work:
        """The cycle's work vectors for ``cols`` columns; made on first use for
        several (the visit counts are shared)."""
        if cols == 1:
            return self.work
        made = self._columns_scratch.get(cols)
        if made is None:
            cells, n = self.work.cr.shape[0], self.work.fx.shape[0]
            made = Work(self.work.visits, *(runtime.array(None, size, vector=cols, zeroed=False)
                                            for size in (cells, cells, cells, n, n)))
            self._columns_scratch = {cols: made}
        return made

    def apply(self, r, z) -> None:
        """z = M^-1 r (one cycle from zero); r, z hold one column or several
        (vectors: each column cycled independently, the matrix read once)."""
        cols = columns_of(r)
        shape = self._shapes.get(cols)
        if shape is None:
            shape = self._shapes[cols] = CycleShape(
                cols, self.serial, self._by_cell, self.schedule, self.post, self.omega,
                self.correction, self._bordered, self.gamma, self.constant_mode)
        run_cycle(shape, self.n, self.fine_level, self.cell_levels, self._work(cols), self._border_c,
                  self.colsum, self._constant_c, r, z)
