"""Sums and maxima over many entries on a GPU, without contended atomics.

On the CPU a kernel-scope accumulator in a parallel loop is a per-thread
partial (Taichi's thread-local reduction): cheap.  On CUDA a float64
accumulator becomes one atomic per entry on a single address (Taichi 1.7
reduces only i32 and f32 within a warp): a 160k-entry dot product took 1.9 ms
on an H200, three quarters of the droplet's step (docs/arch.md).  On a GPU
arch the reducing loops therefore run in ``LANES`` threads, thread t taking
entries t, t + LANES, t + 2 LANES, ... (neighbouring threads read
neighbouring entries), each writing its partial to ``part[t]``; then
:func:`lane_total` folds the partials in ``GROUPS`` threads and finally in
one, in a fixed order: no atomics, and the same result on every run.

A kernel writes each entry's work once, as a ``ti.func`` ``entry(i, *args)``
that returns the entry's contribution (a real, or several packed with
:func:`pack2` / :func:`pack3`), and sums with :func:`fold_entries`, which
loops over the entries the CPU's way or in lanes (``in_lanes``: :func:`on`,
a compile-time setting of the kernel).
"""
import taichi as ti

from .. import runtime

__all__ = ["LANES", "GROUPS", "on", "partials", "fold_entries", "lane_total", "pack2", "pack3",
           "unpack", "ADD", "MAX"]

#: threads of a GPU reduction's first pass (the partials it leaves)
LANES = 4096
#: threads of the second pass; the last pass, one thread, folds their results
GROUPS = 64
#: how a component of the partials is folded
ADD, MAX = 0, 1

_cache: dict = {}


def on() -> bool:
    """Whether reductions run in lanes: under the GPU's schedule
    (:func:`taichi_hh.runtime.on_gpu`)."""
    return runtime.on_gpu()


def partials(values: int = 1, cols: int = 1):
    """The scratch of one reduction of ``values`` sums per column over
    ``cols`` columns: ``LANES`` entries of the packed partial's type (a real,
    a vector of ``cols`` or of ``values``, or a ``values x cols`` matrix:
    :func:`pack2`, :func:`pack3`), shared by every kernel of that type
    (kernels run one after the other on one stream)."""
    key = (values, cols, runtime.generation(), runtime.state().precision)
    array = _cache.get(key)
    if array is None:
        if any(k[2:] != key[2:] for k in _cache):
            _cache.clear()              # made under another runtime: gone
        real = runtime.real_dtype()
        if values == 1 and cols == 1:
            array = ti.ndarray(real, LANES)
        elif values == 1 or cols == 1:
            array = ti.Vector.ndarray(max(values, cols), real, LANES)
        else:
            array = ti.Matrix.ndarray(values, cols, real, LANES)
        _cache[key] = array
    return array


@ti.func
def _fold(a, b, ops: ti.template()):
    """a and b folded component by component: ``ops`` a tuple (one per
    component of a vector, or per row of a matrix) of ADD / MAX, or one of
    them for a scalar."""
    if ti.static(isinstance(ops, int)):
        if ti.static(ops == MAX):
            a = ti.max(a, b)
        else:
            a = a + b
    else:
        for q in ti.static(range(len(ops))):
            if ti.static(ops[q] == MAX):
                a[q] = ti.max(a[q], b[q])
            else:
                a[q] = a[q] + b[q]
    return a


@ti.func
def fold(a, b, ops: ti.template()):
    """One entry's contribution ``b`` folded into the lane's partial ``a``."""
    return _fold(a, b, ops)


@ti.func
def pack2(cols: ti.template(), p, q):
    """Two per-column values as one partial (as :func:`pack3`)."""
    if ti.static(cols == 1):
        return ti.Vector([p, q])
    else:
        return ti.Matrix.rows([p, q])


@ti.func
def pack3(cols: ti.template(), p, q, r):
    """Three per-column values as one partial: a 3-vector for one column, a
    3 x cols matrix (a row each) for several."""
    if ti.static(cols == 1):
        return ti.Vector([p, q, r])
    else:
        return ti.Matrix.rows([p, q, r])


@ti.func
def unpack(cols: ti.template(), total, row: ti.template()):
    """Value ``row`` of a :func:`pack3` partial."""
    if ti.static(cols == 1):
        return total[row]
    else:
        return ti.Vector([total[row, j] for j in ti.static(range(cols))])


@ti.func
def lane_total(part: ti.template(), ops: ti.template()):
    """The partials ``part[0 .. LANES)`` folded, in a fixed order: GROUPS
    threads each fold the lanes g, g + GROUPS, ... into ``part[g]`` (only
    thread g reads them), then one thread folds ``part[0 .. GROUPS)`` into
    ``part[0]``, which is returned.  (The running value lives inside the
    loops: a kernel-scope vector that a loop reads faults on CUDA, Taichi
    1.7, docs/arch.md.)"""
    for g in range(GROUPS):
        s = part[g]
        t = g + GROUPS
        while t < LANES:
            s = _fold(s, part[t], ops)
            t += GROUPS
        part[g] = s
    ti.loop_config(serialize=True)
    for _ in range(1):
        total = part[0]
        for g in range(1, GROUPS):
            total = _fold(total, part[g], ops)
        part[0] = total
    return part[0]


@ti.func
def zero(values: ti.template(), cols: ti.template()):
    """The zero partial of ``values`` sums per column over ``cols`` columns."""
    if ti.static(values == 1 and cols == 1):
        return 0.0
    elif ti.static(values == 1 or cols == 1):
        return ti.Vector.zero(float, max(values, cols))
    else:
        return ti.Matrix.zero(float, values, cols)


@ti.func
def _reduce_into(acc: ti.template(), value, ops: ti.template()):
    """acc (a kernel-scope accumulator: Taichi's per-thread partials on the
    CPU) takes ``value``, component by component as ``ops`` says."""
    if ti.static(isinstance(ops, int)):
        if ti.static(ops == MAX):
            ti.atomic_max(acc, value)
        else:
            acc += value
    else:
        for q in ti.static(range(len(ops))):
            if ti.static(ops[q] == MAX):
                ti.atomic_max(acc[q], value[q])
            else:
                acc[q] += value[q]


@ti.func
def fold_entries(n, entry: ti.template(), args: ti.template(), values: ti.template(),
                 cols: ti.template(), ops: ti.template(), in_lanes: ti.template(),
                 serial: ti.template(), part: ti.template()):
    """``entry(i, *args)`` for i < n (it may also write the entry's outputs),
    its returns folded by ``ops`` (ADD, MAX, or a tuple of them per packed
    value; the MAX values are >= 0, folded from 0): on the CPU one loop into a
    kernel-scope accumulator (serially with ``serial``); on a GPU
    (``in_lanes``) in lanes through ``part`` (:func:`partials` of ``values``
    and ``cols``) and :func:`lane_total`."""
    if ti.static(in_lanes):
        for t in range(LANES):
            lane = zero(values, cols)
            i = t
            while i < n:
                lane = _fold(lane, entry(i, *args), ops)
                i += LANES
            part[t] = lane
        return lane_total(part, ops)
    else:
        acc = zero(values, cols)
        ti.loop_config(serialize=serial)
        for i in range(n):
            _reduce_into(acc, entry(i, *args), ops)
        return acc
