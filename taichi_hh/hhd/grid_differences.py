"""Finite differences over the available nodes of a uniform grid: the
stencils of :mod:`taichi_hh.hhd.natural_grid` (fourth order where two nodes
are available on each side, one-sided fourth order next to the outline and
holes, lower order only where a line of available nodes is shorter than
five), their choice per node (:func:`stencil_codes`), the numpy reference
(:func:`axis_derivative`) and the Taichi kernels the decomposition runs.

The decomposition's differences take two kernel launches in all (at 161 x 81
nodes a launch's fixed cost is about what its arithmetic costs):
:func:`codes_div_curl` picks every node's stencils from the runs of
available nodes next to it and takes div v and curl v in the same pass (the
codes kept for the next call on the same nodes, which then only
differentiates);
:func:`components_checks` takes d = grad phi, r = J grad psi, h = v - d - r
and then, in a second loop of the same launch, div h and curl h.  The
stencils' weights are compile-time constants of the kernels.
"""
import numpy as np
import taichi as ti

from .. import runtime

__all__ = ["STENCILS", "PAD", "NO_STENCIL", "UNAVAILABLE", "CODE_OF_RUNS", "DATA_CODE_OF_RUNS",
           "stencil_codes", "axis_derivative", "div_curl", "codes_div_curl", "forget_codes",
           "components_checks"]

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
    table = CODE_OF_RUNS if table is None else table
    codes = table[runs[0] * (PAD + 1) + runs[1]]
    codes[~a] = UNAVAILABLE
    return np.moveaxis(codes, 0, axis)


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




#: each stencil's (offset, weight) terms, offsets increasing: compile-time
#: constants of the kernels (the sums in the order of the numpy reference's)
_TERMS = [[(o, float(STENCILS[c, o + PAD])) for o in range(-PAD, PAD + 1)
           if STENCILS[c, o + PAD] != 0.0] for c in range(NO_STENCIL)]


@ti.func
def _at(F: ti.template(), layer: ti.template(), j, i, comp: ti.template()):
    """F[j, i, comp], or F[layer, j, i, comp] for a ``layer`` >= 0."""
    value = ti.f64(0.0)
    if ti.static(layer < 0):
        value = F[j, i, comp]
    else:
        value = F[layer, j, i, comp]
    return value


@ti.func
def _derivative(F: ti.template(), layer: ti.template(), c, comp: ti.template(), j, i,
                dj: ti.template(), di: ti.template()):
    """sum_o w_o F[(j, i) + o (dj, di), comp] (of ``layer``: :func:`_at`) for
    the stencil ``c`` (times 1 / step): the central one (code 0, nearly every
    node) first, the others by their constant terms; 0 for
    :data:`NO_STENCIL`."""
    acc = ti.f64(0.0)
    if c == 0:
        acc = ((_at(F, layer, j - 2 * dj, i - 2 * di, comp)
                - _at(F, layer, j + 2 * dj, i + 2 * di, comp))
               + 8.0 * (_at(F, layer, j + dj, i + di, comp)
                        - _at(F, layer, j - dj, i - di, comp))) / 12.0
    else:
        for code in ti.static(range(1, NO_STENCIL)):
            if c == code:
                for t in ti.static(_TERMS[code]):
                    acc += t[1] * _at(F, layer, j + dj * t[0], i + di * t[0], comp)
    return acc


@ti.func
def _div_curl_at(F: ti.template(), layer: ti.template(), a, b, j, i, hx, hy):
    """(div F, curl F) (of ``layer``: :func:`_at`) at node (j, i) by the
    stencils ``a`` along x and ``b`` along y."""
    dudx = _derivative(F, layer, a, 0, j, i, 0, 1) / hx
    dvdx = _derivative(F, layer, a, 1, j, i, 0, 1) / hx
    dudy = _derivative(F, layer, b, 0, j, i, 1, 0) / hy
    dvdy = _derivative(F, layer, b, 1, j, i, 1, 0) / hy
    return dudx + dvdy, dvdx - dudy


@ti.func
def _run(avail: ti.template(), j, i, dj: ti.template(), di: ti.template()):
    """The number of available nodes next to (j, i) in the direction (dj, di)
    before the first one not available or the grid's edge, up to PAD."""
    ny, nx = avail.shape[0], avail.shape[1]
    run = 0
    going = 1
    for k in ti.static(range(1, PAD + 1)):
        if going == 1:
            going = 0
            jj, ii = j + k * dj, i + k * di
            if jj >= 0 and jj < ny and ii >= 0 and ii < nx:
                if avail[jj, ii] != 0:
                    going = 1
                    run += 1
    return run


@ti.func
def _code(left, right):
    """:data:`CODE_OF_RUNS` of the runs ``left``, ``right``: the first stencil
    in the order of preference that they carry."""
    code = NO_STENCIL
    for c in ti.static(range(NO_STENCIL - 1, -1, -1)):
        if left >= _REACH[c][0] and right >= _REACH[c][1]:
            code = c
    return code


@ti.func
def _data_code(code):
    """:data:`DATA_CODE_OF_RUNS`'s replacement of a stencil code."""
    out = code
    for c in ti.static(range(1, 5)):
        if code == c:
            out = int(_DATA_CODE[c])
    return out


@ti.kernel
def _div_curl(F: ti.types.ndarray(), cx: ti.types.ndarray(), cy: ti.types.ndarray(),
              hx: ti.f64, hy: ti.f64, out: ti.types.ndarray()):
    """out[j, i] = (div F, curl F) by the stencils ``cx``, ``cy``
    (:func:`stencil_codes`; (0, 0) at the nodes not available)."""
    for j, i in ti.ndrange(F.shape[0], F.shape[1]):
        div = ti.f64(0.0)
        curl = ti.f64(0.0)
        a = ti.cast(cx[j, i], ti.i32)
        if a != UNAVAILABLE:
            div, curl = _div_curl_at(F, -1, a, ti.cast(cy[j, i], ti.i32), j, i, hx, hy)
        out[j, i, 0] = div
        out[j, i, 1] = curl


@ti.kernel
def _codes_div_curl(avail: ti.types.ndarray(), F: ti.types.ndarray(), hx: ti.f64, hy: ti.f64,
                    codes: ti.types.ndarray(), out: ti.types.ndarray()):
    """codes[0..3, j, i]: the stencils along x and y, then those of the data
    along x and y (:func:`stencil_codes` with :data:`CODE_OF_RUNS` and
    :data:`DATA_CODE_OF_RUNS`); out[j, i] = (div F, curl F) by the data's
    ((0, 0) at the nodes not available)."""
    for j, i in ti.ndrange(F.shape[0], F.shape[1]):
        div = ti.f64(0.0)
        curl = ti.f64(0.0)
        if avail[j, i] != 0:
            a = _code(_run(avail, j, i, 0, -1), _run(avail, j, i, 0, 1))
            b = _code(_run(avail, j, i, -1, 0), _run(avail, j, i, 1, 0))
            da, db = _data_code(a), _data_code(b)
            codes[0, j, i] = ti.cast(a, ti.i8)
            codes[1, j, i] = ti.cast(b, ti.i8)
            codes[2, j, i] = ti.cast(da, ti.i8)
            codes[3, j, i] = ti.cast(db, ti.i8)
            div, curl = _div_curl_at(F, -1, da, db, j, i, hx, hy)
        else:
            for k in ti.static(range(4)):
                codes[k, j, i] = ti.i8(UNAVAILABLE)
        out[j, i, 0] = div
        out[j, i, 1] = curl


@ti.kernel
def _components_checks(P: ti.types.ndarray(), V: ti.types.ndarray(),
                       codes: ti.types.ndarray(), hx: ti.f64, hy: ti.f64,
                       out: ti.types.ndarray()):
    """out[0], out[1], out[2]: d = grad P[..., 0], r = J grad P[..., 1] =
    (dpsi/dy, -dpsi/dx), h = V - d - r by the stencils codes[0], codes[1]
    (NaN at the nodes not available); then out[3] = (div h, curl h) by the
    data's stencils codes[2], codes[3] (0 at the nodes not available)."""
    for j, i in ti.ndrange(P.shape[0], P.shape[1]):
        a = ti.cast(codes[0, j, i], ti.i32)
        b = ti.cast(codes[1, j, i], ti.i32)
        if a != UNAVAILABLE:
            px = _derivative(P, -1, a, 0, j, i, 0, 1) / hx
            py = _derivative(P, -1, b, 0, j, i, 1, 0) / hy
            sx = _derivative(P, -1, a, 1, j, i, 0, 1) / hx
            sy = _derivative(P, -1, b, 1, j, i, 1, 0) / hy
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
    for j, i in ti.ndrange(P.shape[0], P.shape[1]):
        div = ti.f64(0.0)
        curl = ti.f64(0.0)
        a = ti.cast(codes[2, j, i], ti.i32)
        if a != UNAVAILABLE:
            div, curl = _div_curl_at(out, 2, a, ti.cast(codes[3, j, i], ti.i32), j, i, hx,
                                     hy)
        out[3, j, i, 0] = div
        out[3, j, i, 1] = curl


def div_curl(F: np.ndarray, avail: np.ndarray, hx: float, hy: float, codes=None) -> np.ndarray:
    """(ny, nx, 2): div F and curl F of ``F`` (ny, nx, 2) at the nodes ``avail``
    (0 elsewhere) by the differences over them (fourth order where two nodes
    are available on each side, :func:`stencil_codes`; ``codes``: those of x
    and y if made already): one Taichi kernel."""
    runtime.ensure_init()
    cx, cy = codes if codes is not None else (stencil_codes(avail, 1), stencil_codes(avail, 0))
    out = np.empty(F.shape[:2] + (2,))
    _div_curl(np.ascontiguousarray(F, dtype=np.float64), np.ascontiguousarray(cx),
              np.ascontiguousarray(cy), float(hx), float(hy), out)
    return out


#: the stencil codes of the last few sets of available nodes (a field
#: decomposed again, the frames of a run with a fixed mask)
KEPT_CODES = 4
_CODES: dict = {}


def forget_codes() -> None:
    """Drop the kept stencil codes (:func:`codes_div_curl`)."""
    _CODES.clear()


def codes_div_curl(avail: np.ndarray, F: np.ndarray, hx: float, hy: float) -> tuple:
    """``(codes, dc)``: codes (4, ny, nx) int8 (read-only), the stencils of
    the nodes ``avail`` along x and y (:func:`stencil_codes`), then those of
    measured vectors (:data:`DATA_CODE_OF_RUNS`); dc (ny, nx, 2): div F and
    curl F of ``F`` (ny, nx, 2) by the latter (0 off ``avail``).  One kernel
    launch: the codes picked in it, or those of the same ``avail`` kept from
    the last few calls (the launch then only differentiates)."""
    runtime.ensure_init()
    ny, nx = avail.shape
    F = np.ascontiguousarray(F, dtype=np.float64)
    dc = np.empty((ny, nx, 2))
    key = (avail.shape, avail.tobytes())
    codes = _CODES.pop(key, None)
    if codes is None:
        codes = np.empty((4, ny, nx), dtype=np.int8)
        _codes_div_curl(np.ascontiguousarray(avail, dtype=np.uint8), F, float(hx), float(hy),
                        codes, dc)
        codes.setflags(write=False)
    else:
        _div_curl(F, codes[2], codes[3], float(hx), float(hy), dc)
    _CODES[key] = codes                                  # the most recent last
    while len(_CODES) > KEPT_CODES:
        _CODES.pop(next(iter(_CODES)))
    return codes, dc


def components_checks(P: np.ndarray, V: np.ndarray, codes: np.ndarray, hx: float,
                      hy: float) -> np.ndarray:
    """(4, ny, nx, 2): d = grad P[..., 0], r = J grad P[..., 1] and h = V - d
    - r at the nodes the stencils ``codes`` (:func:`codes_div_curl`) reach
    (NaN elsewhere), then (div h, curl h) by the data's stencils (0 off
    them).  One kernel launch."""
    runtime.ensure_init()
    out = np.empty((4,) + P.shape[:2] + (2,))
    _components_checks(np.ascontiguousarray(P, dtype=np.float64),
                       np.ascontiguousarray(V, dtype=np.float64), codes, float(hx), float(hy),
                       out)
    return out
