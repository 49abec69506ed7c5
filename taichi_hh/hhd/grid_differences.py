"""Finite differences over the available nodes of a uniform grid: the
stencils of :mod:`taichi_hh.hhd.natural_grid` (fourth order where two nodes
are available on each side, one-sided fourth order next to the outline and
holes, lower order only where a line of available nodes is shorter than
five), their choice per node (:func:`stencil_codes`), the numpy reference
(:func:`axis_derivative`) and the Taichi kernels the decomposition runs.

The decomposition's differences take two kernel launches (at 161 x 81 nodes
a launch's fixed cost is about what its arithmetic costs):
:func:`codes_div_curl` takes div v and curl v by the stencils each node
picks from the runs of available nodes next to it (:func:`node_codes`,
kept for the next calls on the same nodes);
:func:`components_checks` takes d = grad phi, r = J grad psi, h = v - d - r
and then, in a second loop of the same launch, div h and curl h.  Every
array they differentiate is read as (layer, ny, nx, 2), so one function
serves the potentials, the vectors and h, and the stencils next to the
outline loop over their row of :data:`STENCILS` rather than being unrolled:
Taichi transforms each call site's syntax tree in every process, before its
offline cache is looked up (the first call's cost).
"""
import numpy as np
import taichi as ti

from .. import runtime
from .recent import Recent

__all__ = ["STENCILS", "PAD", "NO_STENCIL", "UNAVAILABLE", "CODE_OF_RUNS", "DATA_CODE_OF_RUNS",
           "stencil_codes", "node_codes", "axis_derivative", "div_curl", "codes_div_curl",
           "forget_codes", "components_checks"]

#: first-derivative stencils on offsets -4 .. 4 (times 1 / step), in order of
#: preference: the first whose nodes are all available is used at a node.
#: 0: central, 4th order; 1, 2: one node on one side, 4th order; 3, 4: one-sided
#: 4th order; 5: central 2nd order; 6, 7: one-sided 2nd order; 8, 9: 1st order
STENCILS = np.zeros((12, 9))
for _code, (_offsets, _coefs) in enumerate((
        ((-2, -1, 1, 2), (1 / 12, -8 / 12, 8 / 12, -1 / 12)),
        ((-1, 0, 1, 2, 3), (-3 / 12, -10 / 12, 18 / 12, -6 / 12, 1 / 12)),
        ((-3, -2, -1, 0, 1), (-1 / 12, 6 / 12, -18 / 12, 10 / 12, 3 / 12)),
        ((0, 1, 2, 3, 4), (-25 / 12, 48 / 12, -36 / 12, 16 / 12, -3 / 12)),
        ((-4, -3, -2, -1, 0), (3 / 12, -16 / 12, 36 / 12, -48 / 12, 25 / 12)),
        ((-1, 1), (-0.5, 0.5)),
        ((0, 1, 2), (-1.5, 2.0, -0.5)),
        ((-2, -1, 0), (0.5, -2.0, 1.5)),
        ((0, 1), (-1.0, 1.0)),
        ((-1, 0), (-1.0, 1.0)))):
    for _o, _c in zip(_offsets, _coefs):
        STENCILS[_code, _o + 4] = _c
#: the nodes each stencil needs (its own node always): offsets -4 .. 4
_NEEDS = [np.flatnonzero(STENCILS[c] != 0) - 4 for c in range(10)]
_NEEDS[0] = np.array([-2, -1, 1, 2])
#: code of a node without a neighbour along the axis: derivative 0
NO_STENCIL = 10
#: code of a node not available (no derivative there)
UNAVAILABLE = 11
#: the stencils' reach: offsets -PAD .. PAD
PAD = 4


#: a stencil's reach on each side: (left, right) available nodes it needs
_REACH = [(max(0, -int(n.min())), max(0, int(n.max()))) for n in _NEEDS]


def stencil_codes(avail: np.ndarray, axis: int, table=None) -> np.ndarray:
    """Per node, the index into the stencil table of the derivative along
    ``axis`` (0: y, rows; 1: x, columns) over the nodes ``avail`` (bool
    (ny, nx)): the first stencil of the order of preference whose nodes are
    all available (from the runs of available nodes on each side, up to 4);
    :data:`NO_STENCIL` where none is (derivative 0), :data:`UNAVAILABLE` where
    the node itself is not available."""
    return _codes(_runs(avail, axis), CODE_OF_RUNS if table is None else table, axis)


def _runs(avail: np.ndarray, axis: int) -> tuple:
    """``(index, a)``: per node, its runs (left, right) of available nodes
    along ``axis`` (up to PAD each) as ``left * (PAD + 1) + right``, and the
    available nodes, both with ``axis`` first."""
    a = np.moveaxis(np.asarray(avail, dtype=bool), axis, 0)
    n = a.shape[0]
    pad = np.zeros((n + 2 * PAD,) + a.shape[1:], dtype=bool)
    pad[PAD:PAD + n] = a
    runs = []
    for sign in (-1, 1):
        run = np.zeros(a.shape, dtype=np.int8)
        cur = a.copy()
        for k in range(1, PAD + 1):
            cur &= pad[PAD + sign * k:PAD + sign * k + n]
            run += cur
        runs.append(run)
    return runs[0] * (PAD + 1) + runs[1], a


def _codes(runs: tuple, table: np.ndarray, axis: int) -> np.ndarray:
    """The codes of ``table`` for the runs of :func:`_runs`, ``axis`` back in
    its place."""
    index, a = runs
    codes = table[index]
    codes[~a] = UNAVAILABLE
    return np.moveaxis(codes, 0, axis)


def node_codes(avail: np.ndarray) -> np.ndarray:
    """(4, ny, nx) int8: :func:`stencil_codes` of the nodes ``avail`` along x
    and y, then those of measured vectors (:data:`DATA_CODE_OF_RUNS`) along x
    and y (the runs found once per axis)."""
    x, y = _runs(avail, 1), _runs(avail, 0)
    return np.stack([_codes(x, CODE_OF_RUNS, 1), _codes(y, CODE_OF_RUNS, 0),
                     _codes(x, DATA_CODE_OF_RUNS, 1), _codes(y, DATA_CODE_OF_RUNS, 0)])


def _code_of_runs() -> np.ndarray:
    """The stencil code for each pair of runs (left, right) of available nodes
    next to a node, flattened ``left * (PAD + 1) + right``."""
    table = np.full((PAD + 1) * (PAD + 1), NO_STENCIL, dtype=np.int8)
    for left in range(PAD + 1):
        for right in range(PAD + 1):
            for code in range(10):
                if _REACH[code][0] <= left and _REACH[code][1] <= right:
                    table[left * (PAD + 1) + right] = code
                    break
    return table


#: the stencil code of each pair of runs of available nodes (left, right),
#: flattened ``left * (PAD + 1) + right``
CODE_OF_RUNS = _code_of_runs()
#: the derivatives of measured vectors: next to the outline (fewer than two
#: available nodes on a side) second order, not the one-sided fourth-order
#: stencils, whose coefficients (up to 25/12) amplify the data's noise 3 to 6
#: times where the central ones' do not; each code's replacement
_DATA_CODE = np.array([0, 5, 5, 6, 7, 5, 6, 7, 8, 9, NO_STENCIL, UNAVAILABLE], dtype=np.int8)
#: :data:`CODE_OF_RUNS` for the derivatives of measured vectors
DATA_CODE_OF_RUNS = _DATA_CODE[CODE_OF_RUNS]


def axis_derivative(F: np.ndarray, avail: np.ndarray, axis: int, h: float,
                    table=None) -> np.ndarray:
    """The derivative along ``axis`` (0: rows, y; 1: columns, x) of ``F``
    (ny, nx[, k]) with step ``h`` over the nodes ``avail`` by the stencils
    :func:`stencil_codes` picks (0 where none; ``table``: its table, e.g.
    :data:`DATA_CODE_OF_RUNS`): numpy, node by stencil; the reference of the
    Taichi kernels (:func:`codes_div_curl`, :func:`components_checks`)."""
    F = np.asarray(F, dtype=np.float64)
    codes = stencil_codes(avail, axis, table)
    Fm = np.moveaxis(F, axis, 0)
    n = Fm.shape[0]
    pad = np.zeros((n + 2 * PAD,) + Fm.shape[1:])
    pad[PAD:PAD + n] = np.where(np.moveaxis(avail, axis, 0).reshape(
        (n,) + Fm.shape[1:2] + (1,) * (Fm.ndim - 2)), Fm, 0.0)
    cm = np.moveaxis(codes, axis, 0)
    out = np.zeros_like(Fm)
    for o in range(-PAD, PAD + 1):
        w = STENCILS[cm.astype(np.intp), o + PAD]
        out += w.reshape(w.shape + (1,) * (Fm.ndim - 2)) * pad[PAD + o:PAD + o + n]
    return np.moveaxis(out / h, 0, axis)




@ti.func
def _derivative(F: ti.template(), layer: ti.template(), c, comp: ti.template(), j, i,
                dj: ti.template(), di: ti.template(), table: ti.template()):
    """sum_o w_o F[layer, (j, i) + o (dj, di), comp] for the stencil ``c`` of
    ``table`` (:data:`STENCILS`; times 1 / step): the central one (code 0,
    nearly every node) unrolled, the others (next to the outline) by a loop
    over the table's row; 0 for :data:`NO_STENCIL`."""
    acc = ti.f64(0.0)
    if c == 0:
        acc = ((F[layer, j - 2 * dj, i - 2 * di, comp] - F[layer, j + 2 * dj, i + 2 * di, comp])
               + 8.0 * (F[layer, j + dj, i + di, comp] - F[layer, j - dj, i - di, comp])) / 12.0
    else:
        for k in range(2 * PAD + 1):
            w = table[c, k]
            if w != 0.0:
                o = k - PAD
                acc += w * F[layer, j + dj * o, i + di * o, comp]
    return acc


@ti.func
def _div_curl_at(F: ti.template(), layer: ti.template(), a, b, j, i, hx, hy,
                 table: ti.template()):
    """(div F, curl F) of F[layer] at node (j, i) by the stencils ``a`` along
    x and ``b`` along y."""
    dudx = _derivative(F, layer, a, 0, j, i, 0, 1, table) / hx
    dvdx = _derivative(F, layer, a, 1, j, i, 0, 1, table) / hx
    dudy = _derivative(F, layer, b, 0, j, i, 1, 0, table) / hy
    dvdy = _derivative(F, layer, b, 1, j, i, 1, 0, table) / hy
    return dudx + dvdy, dvdx - dudy


@ti.kernel
def _div_curl(F: ti.types.ndarray(), codes: ti.types.ndarray(), x: ti.i32,
              table: ti.types.ndarray(), hx: ti.f64, hy: ti.f64, out: ti.types.ndarray()):
    """out[j, i] = (div F[0], curl F[0]) by the stencils codes[x] along x and
    codes[x + 1] along y (:func:`stencil_codes`; (0, 0) at the nodes not
    available)."""
    for j, i in ti.ndrange(F.shape[1], F.shape[2]):
        div = ti.f64(0.0)
        curl = ti.f64(0.0)
        a = ti.cast(codes[x, j, i], ti.i32)
        if a != UNAVAILABLE:
            div, curl = _div_curl_at(F, 0, a, ti.cast(codes[x + 1, j, i], ti.i32), j, i, hx,
                                     hy, table)
        out[j, i, 0] = div
        out[j, i, 1] = curl


@ti.kernel
def _components_checks(P: ti.types.ndarray(), V: ti.types.ndarray(),
                       codes: ti.types.ndarray(), table: ti.types.ndarray(), hx: ti.f64,
                       hy: ti.f64, out: ti.types.ndarray()):
    """out[0], out[1], out[2]: d = grad P[0, ..., 0], r = J grad P[0, ..., 1] =
    (dpsi/dy, -dpsi/dx), h = V - d - r by the stencils codes[0], codes[1]
    (NaN at the nodes not available); then out[3] = (div h, curl h) by the
    data's stencils codes[2], codes[3] and out[4] = (div d, curl r) by
    codes[0], codes[1] (0 at the nodes not available)."""
    for j, i in ti.ndrange(P.shape[1], P.shape[2]):
        a = ti.cast(codes[0, j, i], ti.i32)
        b = ti.cast(codes[1, j, i], ti.i32)
        if a != UNAVAILABLE:
            px = _derivative(P, 0, a, 0, j, i, 0, 1, table) / hx
            py = _derivative(P, 0, b, 0, j, i, 1, 0, table) / hy
            sx = _derivative(P, 0, a, 1, j, i, 0, 1, table) / hx
            sy = _derivative(P, 0, b, 1, j, i, 1, 0, table) / hy
            out[0, j, i, 0] = px
            out[0, j, i, 1] = py
            out[1, j, i, 0] = sy
            out[1, j, i, 1] = -sx
            out[2, j, i, 0] = V[j, i, 0] - px - sy
            out[2, j, i, 1] = V[j, i, 1] - py + sx
        else:
            for k, c in ti.static(ti.ndrange(3, 2)):
                out[k, j, i, c] = ti.math.nan
    # the second loop runs after the first (a kernel's top-level loops in turn)
    for j, i in ti.ndrange(P.shape[1], P.shape[2]):
        div = ti.f64(0.0)
        curl = ti.f64(0.0)
        a = ti.cast(codes[2, j, i], ti.i32)
        if a != UNAVAILABLE:
            div, curl = _div_curl_at(out, 2, a, ti.cast(codes[3, j, i], ti.i32), j, i, hx,
                                     hy, table)
        out[3, j, i, 0] = div
        out[3, j, i, 1] = curl
        div_d = ti.f64(0.0)
        curl_r = ti.f64(0.0)
        a = ti.cast(codes[0, j, i], ti.i32)
        if a != UNAVAILABLE:
            b = ti.cast(codes[1, j, i], ti.i32)
            div_d = _derivative(out, 0, a, 0, j, i, 0, 1, table) / hx + \
                _derivative(out, 0, b, 1, j, i, 1, 0, table) / hy
            curl_r = _derivative(out, 1, a, 1, j, i, 0, 1, table) / hx - \
                _derivative(out, 1, b, 0, j, i, 1, 0, table) / hy
        out[4, j, i, 0] = div_d
        out[4, j, i, 1] = curl_r


def _layered(F: np.ndarray) -> np.ndarray:
    """``F`` (ny, nx, 2) as the kernels read it: float64, contiguous, (1, ny,
    nx, 2)."""
    return np.ascontiguousarray(F, dtype=np.float64)[None]


def div_curl(F: np.ndarray, avail: np.ndarray, hx: float, hy: float, codes=None) -> np.ndarray:
    """(ny, nx, 2): div F and curl F of ``F`` (ny, nx, 2) at the nodes ``avail``
    (0 elsewhere) by the differences over them (fourth order where two nodes
    are available on each side, :func:`stencil_codes`; ``codes``: those of x
    and y if made already): one Taichi kernel."""
    runtime.ensure_init()
    cx, cy = codes if codes is not None else (stencil_codes(avail, 1), stencil_codes(avail, 0))
    out = np.empty(F.shape[:2] + (2,))
    _div_curl(_layered(F), np.stack([cx, cy]).astype(np.int8, copy=False), 0, STENCILS,
              float(hx), float(hy), out)
    return out


#: the stencil codes of the last few sets of available nodes (a field
#: decomposed again, the frames of a run with a fixed mask)
KEPT_CODES = 4
#: grids of more nodes keep none (the codes' memory, 4 bytes a node, and
#: their key's)
KEPT_CODES_NODES = 1_000_000
_CODES = Recent(KEPT_CODES)


def forget_codes() -> None:
    """Drop the kept stencil codes (:func:`codes_div_curl`)."""
    _CODES.clear()


def codes_div_curl(avail: np.ndarray, F: np.ndarray, hx: float, hy: float) -> tuple:
    """``(codes, dc)``: codes (4, ny, nx) int8 (read-only), the stencils of
    the nodes ``avail`` along x and y (:func:`stencil_codes`), then those of
    measured vectors (:data:`DATA_CODE_OF_RUNS`); dc (ny, nx, 2): div F and
    curl F of ``F`` (ny, nx, 2) by the latter (0 off ``avail``): one kernel
    launch, the codes (:func:`node_codes`) kept from the last few calls on
    the same ``avail``."""
    runtime.ensure_init()
    ny, nx = avail.shape
    kept = avail.size <= KEPT_CODES_NODES
    key = (avail.shape, avail.tobytes()) if kept else None
    codes = _CODES.get(key) if kept else None
    if codes is None:
        codes = node_codes(avail)
        codes.setflags(write=False)
    if kept:
        _CODES.put(key, codes)
    dc = np.empty((ny, nx, 2))
    _div_curl(_layered(F), codes, 2, STENCILS, float(hx), float(hy), dc)
    return codes, dc


def components_checks(P: np.ndarray, V: np.ndarray, codes: np.ndarray, hx: float,
                      hy: float) -> np.ndarray:
    """(5, ny, nx, 2): d = grad P[..., 0], r = J grad P[..., 1] and h = V - d
    - r at the nodes the stencils ``codes`` (:func:`codes_div_curl`) reach
    (NaN elsewhere), then (div h, curl h) by the data's stencils and (div d,
    curl r) by the potentials' (0 off them; what the critical points read).
    One kernel launch."""
    runtime.ensure_init()
    out = np.empty((5,) + P.shape[:2] + (2,))
    _components_checks(_layered(P), np.ascontiguousarray(V, dtype=np.float64), codes,
                       STENCILS, float(hx), float(hy), out)
    return out
