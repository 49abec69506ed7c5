"""The multilevel set-up's kernels: the cell levels' Galerkin operators
``P^T S P`` (from the particle rows or a finer cell level) as CSR rows, or
as the nine-slot rows of a neighbour grid's dense levels; the Jacobi scales
of the particle and cell rows; the coarsest level as a dense matrix.

Every kernel here runs once per matrix (the flow: once per time step)."""
import taichi as ti

#: rows per parallel run of the Galerkin products' set-up (:func:`csr_galerkin`),
#: and the most runs: Taichi's CPU backend hands its threads 512 iterations of a
#: parallel loop at a time (measured: 64 runs stayed on one thread, 1000 used
#: two), so the runs must be many and short
GALERKIN_CHUNK_ROWS = 32
GALERKIN_MAX_CHUNKS = 4096


@ti.kernel
def scaled_diagonal(l1: ti.template(), n: ti.i32, offsets: ti.types.ndarray(),
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
def strongest_neighbour(n: ti.i32, weak: float, offsets: ti.types.ndarray(),
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
def pair_reach(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
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
def csr_galerkin(particles: ti.template(), fill: ti.template(), rows: ti.i32, row0: ti.i32,
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
    """Row ``g`` of :func:`csr_galerkin`, with the window at ``slot0``."""
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
def running_sum(off: ti.types.ndarray(), row0: ti.i32, rows: ti.i32, base: ti.i32) -> ti.i32:
    """Row counts in ``off[row0 + 1 .. row0 + rows]`` to row starts from
    ``base``, in place; returns the level's end."""
    off[row0] = base
    ti.loop_config(serialize=True)
    for C in range(rows):
        off[row0 + C + 1] += off[row0 + C]
    return off[row0 + rows]


@ti.kernel
def copy_prefix(n: ti.i32, src: ti.types.ndarray(), dst: ti.types.ndarray()):
    for i in range(n):
        dst[i] = src[i]


@ti.kernel
def dense_rows(lo: ti.i32, m: ti.i32, S_off: ti.types.ndarray(), S_col: ti.types.ndarray(),
               S_val: ti.types.ndarray(), out: ti.types.ndarray()):
    """Rows lo .. lo + m of the flat CSR (columns in the same range) as a dense
    m x m matrix: the coarsest level, for its pseudo-inverse."""
    for q in range(m * m):
        out[q] = 0.0
    ti.loop_config(serialize=True)
    for i in range(m):
        for e in range(S_off[lo + i], S_off[lo + i + 1]):
            out[i * m + S_col[e] - lo] += S_val[e]


#: rows per block of :func:`diagonal_inverse`'s sum: blocks summed in
#: parallel, their sums in order (deterministic on every arch)
SUM_BLOCK = 256


@ti.kernel
def diagonal_inverse(rows0: ti.i32, total: ti.i32, S_off: ti.types.ndarray(),
                     S_col: ti.types.ndarray(), S_val: ti.types.ndarray(), eps: float,
                     cdinv: ti.types.ndarray()) -> float:
    """cdinv = 1 / diag on every cell row, zero where the diagonal is below the
    round-off of the first level's entries, ``1e3 eps sum |S_0|`` (returned):
    constants are (nearly) in the null space of every level of a Neumann
    problem, so the coarse entries are sums that cancel."""
    for b in range((rows0 + SUM_BLOCK - 1) // SUM_BLOCK):    # each block's sum in its first slot
        part = 0.0
        for c in range(b * SUM_BLOCK, ti.min((b + 1) * SUM_BLOCK, rows0)):
            for e in range(S_off[c], S_off[c + 1]):
                part += abs(S_val[e])
        cdinv[b * SUM_BLOCK] = part
    total_abs = 0.0
    ti.loop_config(serialize=True)      # a deterministic sum
    for b in range((rows0 + SUM_BLOCK - 1) // SUM_BLOCK):
        total_abs += cdinv[b * SUM_BLOCK]
    noise = 1e3 * eps * total_abs
    for c in range(total):
        d = 0.0
        for e in range(S_off[c], S_off[c + 1]):
            if S_col[e] == c:
                d += S_val[e]
        cdinv[c] = 1.0 / d if abs(d) > noise else 0.0
    return noise


@ti.kernel
def grid_values(serial: ti.template(), serial_levels: ti.template(), L: ti.i32, cell_start: ti.types.ndarray(),
                offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(), K: ti.types.ndarray(),
                D: ti.types.ndarray(), dims: ti.types.ndarray(), lvl: ti.types.ndarray(),
                cell_of: ti.types.ndarray(), dinv: ti.types.ndarray(),
                S_val: ti.types.ndarray()) -> ti.i32:
    """The values of a hierarchy of dense grids (:func:`~taichi_hh.linalg.
    multilevel.levels.grid_levels`): level 0 is the neighbour grid's cells (its
    particles contiguous, every pair within a cell's 3 x 3 block), level k + 1
    joins 2 x 2 cells of level k, every cell's row nine slots (its 3 x 3 block,
    slot ``(dy + 1) 3 + dx + 1``; a slot outside the grid stays 0).  Writes the
    particles' cells and ``D^-1`` and the Galerkin operators ``P^T D^-1 A P``
    of every level (the cell levels only with ``serial_levels``: else
    :func:`coarsen_level` for each); returns the number of pairs reaching
    beyond the 3 x 3 block (must be 0)."""
    ncell = lvl[0, 1]
    nx = dims[0, 0]
    beyond_total = 0
    ti.loop_config(serialize=serial)
    for c in range(ncell):
        for i in range(cell_start[c], cell_start[c + 1]):
            cell_of[i] = c
            dinv[i] = 1.0 / D[i] if D[i] != 0 else 0.0
    # level 0: a gather per cell over its particles' pairs (no atomics), summed
    # in the cell's own row of S_val: a local vector indexed at run time fails
    # to compile for SPIR-V (Vulkan) in a kernel of several offloaded tasks
    ti.loop_config(serialize=serial)
    for c in range(ncell):
        cx = c % nx
        cy = c // nx
        beyond = 0
        for s in ti.static(range(9)):
            S_val[9 * c + s] = 0.0
        for i in range(cell_start[c], cell_start[c + 1]):
            S_val[9 * c + 4] += D[i] * dinv[i]
            for k in range(offsets[i], offsets[i + 1]):
                cj = cell_of[nbrs[k]]
                dx = cj % nx - cx
                dy = cj // nx - cy
                if abs(dx) <= 1 and abs(dy) <= 1:
                    S_val[9 * c + (dy + 1) * 3 + dx + 1] += dinv[i] * K[k]
                else:
                    beyond += 1
        if beyond > 0:
            beyond_total += beyond      # rare: an error
    # the cell levels: on the CPU few cells, one thread; on a GPU a launch
    # per level (:func:`coarsen_level`), a GPU's one thread being slow
    if ti.static(serial_levels):
        ti.loop_config(serialize=True)
        for _ in range(1):
            for k in range(1, L):
                for C in range(lvl[k, 1] - lvl[k, 0]):
                    _coarsen_cell(k, C, dims, lvl, S_val)
    return beyond_total


@ti.func
def _coarsen_cell(k, C, dims: ti.template(), lvl: ti.template(), S_val: ti.template()):
    """Row C of cell level k (of :func:`grid_values`' grids): the sum of its
    2 x 2 children's rows of level k - 1, each slot to the coarse slot of its
    column's parent."""
    f0 = lvl[k - 1, 0]
    nxf = dims[k - 1, 0]
    nyf = dims[k - 1, 1]
    nxc = dims[k, 0]
    X = C % nxc
    Y = C // nxc
    row = 9 * (lvl[k, 0] + C)
    for s in ti.static(range(9)):
        S_val[row + s] = 0.0
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
                        S_val[row + (gy // 2 - Y + 1) * 3 + gx // 2 - X + 1] += S_val[fine + s]


@ti.kernel
def coarsen_level(k: ti.i32, dims: ti.types.ndarray(), lvl: ti.types.ndarray(),
                  S_val: ti.types.ndarray()):
    """Cell level k of :func:`grid_values`' grids from level k - 1, a row per
    thread."""
    for C in range(lvl[k, 1] - lvl[k, 0]):
        _coarsen_cell(k, C, dims, lvl, S_val)
