"""The decomposition of gridded data (PIV, model output): :func:`decompose_grid`.

A PIV or model field comes on a rectilinear grid with invalid vectors (NaN,
or a mask): dropouts scattered through the field, masked obstacles, unlit
corners.  The domain comes from the valid nodes, not from an alpha shape:

* an invalid region that holds a block of ``hole_size`` x ``hole_size``
  nodes (the grid's outside counts as invalid) is cut out: an obstacle
  becomes a hole, an unlit corner or edge is cut off;
* smaller gaps (dropouts, thin lines) stay inside the domain: their nodes are
  left out of the operators, which bridge them (a gap of a node or two is
  well inside the kernel support);
* a valid node with fewer than ``min_neighbours`` valid nodes among its 8
  neighbours (on an edge or corner: the same share of its 5 or 3) is left
  out too: islands and
  one-node strips in a region the instrument mostly rejected are the least
  reliable vectors of a field (measured on an Insight cavity flow whose
  bottom rows lost 80-90% of their vectors: the nodes with the largest
  volumes there carried the whole excess of its energy ratio, 1.30 -> 1.17
  without them; benchmarks/real_data.py);
* the outline runs half way between the nodes kept and those cut out,
  corners cut at 45 degrees (:mod:`taichi_hh.geometry.raster`).

If the nodes kept fall into several pieces, the piece with the most valid
nodes is decomposed and the others are left out (counted and warned).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..checks import as_real_array
from ..errors import AccuracyWarning, InputError
from ..geometry.polygon import Polygon
from ..geometry.raster import cell_outlines, check_axis
from .auto import ORTHOGONAL_CONDITION, energy_closer, natural_cancels
from .component_checks import Components
from .recent import Recent

__all__ = ["decompose_grid", "GridResult", "GridLayout", "grid_components", "forget_layouts",
           "HOLE_SIZE", "KEPT_LAYOUTS"]

#: invalid regions holding a block of this many x this many nodes are cut out
#: of the domain (holes, cut-off corners); smaller gaps are bridged
HOLE_SIZE = 3
#: valid nodes with fewer valid neighbours (of 8; the same share of 5 or 3 on
#: edges and corners) are left out as isolated
MIN_NEIGHBOURS = 4
#: the options the grid-native natural path takes (the others are the
#: scattered operators' and solvers': decompose() on the nodes)
GRID_NATIVE_OPTIONS = frozenset({"boundary_condition", "natural_evaluation"})


@dataclass
class GridResult(Components):
    """A decomposition of gridded data: arrays on the input's grid.

    ``curl_free`` (d), ``div_free`` (r), ``harmonic`` (h): (ny, nx, 2);
    ``phi``, ``psi``, ``divergence``, ``curl``: (ny, nx); NaN where no vector
    was decomposed.  ``used``: the nodes decomposed; ``inside``: the nodes
    inside ``domain`` (used nodes and bridged gaps).  ``scattered``: the
    decomposition of the used nodes as
    :func:`~taichi_hh.hhd.decompose.decompose` returns one
    (:class:`~taichi_hh.hhd.decompose.HHDResult`, made on first use where the
    grid-native path ran)."""
    x: np.ndarray
    y: np.ndarray
    used: np.ndarray
    inside: np.ndarray
    domain: Polygon
    stats: dict
    lattice: object = field(repr=False, default=None)     # NodeFields of the grid-native path
    _scattered: object = field(repr=False, default=None)

    @property
    def scattered(self):
        if self._scattered is None and self.lattice is not None:
            self._scattered = self.lattice.result()
        return self._scattered

    def critical_points(self, threshold: float = 0.1, radius: float | None = None,
                        **filters):
        """Sources, sinks and vortices: see
        :meth:`~taichi_hh.hhd.decompose.HHDResult.critical_points` (on the
        grid's nodes where the grid-native path ran:
        :func:`~taichi_hh.hhd.critical_grid.find_grid_critical_points`)."""
        from .critical import critical_points
        return critical_points(self, threshold, radius, **filters)


def _component(values, name: str, shape) -> tuple:
    """``(array, masked)``: a (ny, nx) float64 array and the nodes a numpy mask
    hides (or None)."""
    masked = None
    if np.ma.isMaskedArray(values):
        masked = np.ma.getmaskarray(values)
        values = np.ma.getdata(values)
    arr = as_real_array(values, name, "a numeric (ny, nx) array")
    if arr.shape != shape:
        raise InputError(f"{name} must have shape (ny, nx) = {shape} (y along the rows, x "
                         f"along the columns), got {arr.shape}")
    if np.isinf(arr).any():
        j, i = np.argwhere(np.isinf(arr))[0]
        raise InputError(f"{name} has infinite values, first at row {j}, column {i} (missing "
                         f"values are NaN or masked)")
    return arr, masked


def cut_out(invalid: np.ndarray, hole_size: int = HOLE_SIZE) -> np.ndarray:
    """The invalid nodes cut out of the domain: the morphological opening of
    ``invalid`` by a ``hole_size`` square, the grid's outside counted invalid,
    i.e. every invalid node that lies in some all-invalid ``hole_size`` x
    ``hole_size`` block."""
    if not invalid.any():
        return np.zeros_like(invalid)
    k = hole_size - 1
    core = np.pad(invalid, k, constant_values=True)
    for _ in range(k):           # erosion: (j, i) stays if its 2 x 2 block upwards is all set
        core = core[:-1, :-1] & core[1:, :-1] & core[:-1, 1:] & core[1:, 1:]
        core = np.pad(core, ((0, 1), (0, 1)), constant_values=False)
    grown = core
    for _ in range(k):           # dilation back: the blocks those corners anchor
        grown = np.pad(grown, ((1, 0), (1, 0)), constant_values=False)
        grown = grown[1:, 1:] | grown[:-1, 1:] | grown[1:, :-1] | grown[:-1, :-1]
    return grown[k:-k, k:-k] & invalid


def isolated_nodes(invalid: np.ndarray, min_neighbours: int = MIN_NEIGHBOURS) -> np.ndarray:
    """The valid nodes with fewer than ``min_neighbours`` valid nodes among
    their 8 neighbours, or on the grid's edges and corners (5 and 3
    neighbours) fewer than the same share of them (4 of 8: 3 of 5, 2 of 3): a
    full grid's corner is no island, an edge node amid rejected ones is."""
    ny, nx = invalid.shape
    if not invalid.any():          # a full grid: each node has its share of neighbours
        return np.zeros_like(invalid)

    def neighbours(a):               # the 3 x 3 box's sum by rows then columns, less a
        pad = np.pad(a.astype(np.int8), 1)
        rows = pad[:, :-2] + pad[:, 1:-1] + pad[:, 2:]
        return rows[:-2] + rows[1:-1] + rows[2:] - pad[1:-1, 1:-1]
    valid = neighbours(~invalid)
    on_grid = neighbours(np.ones_like(invalid))
    # the same share of the neighbours the node has: 4 of 8, 3 of 5, 2 of 3
    need = np.ceil(min_neighbours * on_grid / 8.0)
    return ~invalid & (valid < need)


def decompose_grid(x, y, u, v, mask=None, *, hole_size: int = HOLE_SIZE,
                   min_neighbours: int = MIN_NEIGHBOURS, method: str = "default",
                   progress=None, _path: str = "auto", **options) -> GridResult:
    """Helmholtz-Hodge decomposition of a field on a rectilinear grid.

    x: (nx,) and y: (ny,) node coordinates (strictly monotonic, any spacing);
    u, v: (ny, nx) components (rows along y, columns along x), NaN or masked
    where invalid; mask: optional (ny, nx) booleans, True where invalid (the
    numpy.ma convention).  hole_size: invalid regions holding a block of
    ``hole_size`` x ``hole_size`` nodes are cut out of the domain (module
    doc); smaller gaps are bridged.  min_neighbours: valid nodes with fewer
    valid neighbours are left out as isolated (0: none).  Other arguments as
    :func:`~taichi_hh.hhd.decompose.decompose` (``domain`` is made here),
    and the default condition alike (``auto``): a grid of measurements is a
    window of a larger flow, which gets ``"natural"`` (d, r: what the sources
    and vortices inside induce; h: the rest; on windows it errs 10 to 500
    times less than ``"neumann"``: benchmarks/windows.py, docs/notes/hhd.md),
    a closed container (v.n = 0 along the outline of the nodes' cells: a
    cell-centred simulation with walls) ``"no-flux"``.

    A uniform grid (equal steps along x, and along y) under the natural
    condition (chosen or asked for; the default method, ``natural_evaluation``
    the only numerical option given) is decomposed on its own nodes
    (:mod:`taichi_hh.hhd.natural_grid`: finite differences and the FFT over the
    nodes' cells, no neighbour search; ``stats["grid_native"]``), every other
    case through :func:`~taichi_hh.hhd.decompose.decompose` on the used nodes.
    ``_path="scattered"`` (internal: tests and benchmarks) takes the second
    way always.

    Returns a :class:`GridResult`; ``stats`` adds ``n_invalid`` (nodes
    without a vector), ``n_cut_out`` (invalid nodes outside the domain),
    ``n_left_out`` (valid nodes of smaller pieces, not decomposed)."""
    if _path not in ("auto", "scattered"):
        raise InputError(f"_path must be 'auto' or 'scattered', got {_path!r}")
    check_grid_options(options, hole_size, min_neighbours)
    x_in, y_in = check_axis(x, "x"), check_axis(y, "y")
    u_arr, v_arr, invalid = grid_components(x_in, y_in, u, v, mask)
    layout = GridLayout.of(x_in, y_in, invalid, int(hole_size), int(min_neighbours))
    res = layout.split(u_arr, v_arr, method, progress, options, scattered_only=_path != "auto")
    return layout.result(res)


def check_grid_options(options: dict, hole_size, min_neighbours) -> None:
    """:func:`decompose_grid`'s own arguments checked (InputError)."""
    if "domain" in options:
        raise InputError("decompose_grid makes its domain from the valid nodes: give "
                         "mask= (True where invalid) to cut regions out, or use "
                         "decompose() with a domain")
    check_outline_rules(hole_size, min_neighbours)


def check_outline_rules(hole_size, min_neighbours) -> None:
    """The rules of a grid's outline (:func:`cut_out`, :func:`isolated_nodes`)
    checked (InputError)."""
    if isinstance(hole_size, bool) or not isinstance(hole_size, (int, np.integer)) \
            or hole_size < 2:
        raise InputError(f"hole_size must be an integer >= 2 (nodes), got {hole_size!r}")
    if isinstance(min_neighbours, bool) or not isinstance(min_neighbours, (int, np.integer)) \
            or not 0 <= min_neighbours <= 8:
        raise InputError(f"min_neighbours must be an integer 0..8, got {min_neighbours!r}")


def grid_components(x_in, y_in, u, v, mask=None) -> tuple:
    """``(u, v, invalid)``: the components as (ny, nx) float64 arrays and the
    nodes without a vector (NaN, masked, or ``mask`` True)."""
    shape = (len(y_in), len(x_in))
    u_arr, u_mask = _component(u, "u", shape)
    v_arr, v_mask = _component(v, "v", shape)
    invalid = np.isnan(u_arr) | np.isnan(v_arr)
    for m in (u_mask, v_mask):
        if m is not None:
            invalid |= m
    if mask is not None:
        m = np.asarray(mask)
        if m.shape != shape or m.dtype.kind not in "bui":
            raise InputError(f"mask must be booleans of shape (ny, nx) = {shape}, True where "
                             f"invalid; got {m.dtype} {m.shape}")
        invalid |= m.astype(bool)
    return u_arr, v_arr, invalid


#: the layouts :meth:`GridLayout.of` keeps, and the outlines :func:`_outline` keeps
KEPT_LAYOUTS = 4
#: grids of more nodes are not kept (their arrays' memory; their set-up is a
#: small part of their decomposition)
KEPT_NODES = 1_000_000
_LAYOUTS = Recent(KEPT_LAYOUTS)
_OUTLINES = Recent(KEPT_LAYOUTS)


def forget_layouts() -> None:
    """Drop the layouts, outlines, stencil codes and critical points'
    geometries :func:`decompose_grid` and its results keep (their memory; or
    to time a call on a grid seen for the first time)."""
    from .critical_grid import forget_geometries
    from .grid_differences import forget_codes
    _LAYOUTS.clear()
    _OUTLINES.clear()
    forget_codes()
    forget_geometries()


def _outline(xs, ys, outside) -> tuple:
    """``(domain, holes, n_pieces, inside)``: the outline of the nodes not
    ``outside`` (:func:`~taichi_hh.geometry.raster.cell_outlines`; its largest
    piece) and the nodes inside it, kept for the last few ``outside`` (dropouts
    that change from frame to frame leave the regions cut out as they are)."""
    key = (xs.tobytes(), ys.tobytes(), outside.shape, outside.tobytes())
    found = _OUTLINES.get(key) if outside.size <= KEPT_NODES else None
    if found is None:
        pieces = cell_outlines(xs, ys, ~outside)
        outer, holes = pieces[0]
        domain = Polygon(outer, holes)
        if len(pieces) == 1:             # every node not cut out is inside the one outline
            inside = ~outside
        else:
            X, Y = np.meshgrid(xs, ys)
            inside = domain.contains(np.c_[X.ravel(), Y.ravel()]).reshape(outside.shape) \
                & ~outside
        inside.setflags(write=False)
        found = (domain, holes, len(pieces), inside)
    if outside.size <= KEPT_NODES:
        _OUTLINES.put(key, found)
    return found


class GridLayout:
    """What a gridded decomposition takes from the axes and the invalid nodes
    alone (module doc): the nodes left out as isolated, the regions cut out,
    the domain's outline, the nodes inside and those decomposed (``used``),
    on increasing axes (``sl`` the slices back to the input's order).  A
    series whose snapshots miss the same nodes shares one."""

    def __init__(self, x_in, y_in, invalid, hole_size: int, min_neighbours: int):
        self.x_in, self.y_in, self.hole_size = x_in, y_in, hole_size
        self.shape = (len(y_in), len(x_in))
        self.missing = invalid.copy()
        self.isolated = isolated_nodes(invalid, min_neighbours)
        invalid = invalid | self.isolated
        # work on increasing axes; the results go back to the input's order
        flip_x, flip_y = x_in[1] < x_in[0], y_in[1] < y_in[0]
        self.sl = (slice(None, None, -1 if flip_y else 1), slice(None, None, -1 if flip_x else 1))
        self.xs, self.ys = x_in[self.sl[1]], y_in[self.sl[0]]
        self.invalid_s = invalid_s = invalid[self.sl]
        if invalid_s.all():
            raise InputError(f"all {invalid.size} nodes are invalid: there is no field to "
                             "decompose")
        self.outside = cut_out(invalid_s, hole_size)
        self.domain, self.holes, self.n_pieces, self.inside = _outline(self.xs, self.ys,
                                                                       self.outside)
        self.used = self.inside & ~invalid_s
        self.left_out = int((~invalid_s & ~self.inside).sum())
        from .natural_grid import uniform_steps
        self.steps = uniform_steps(self.xs, self.ys)
        self._band = None
        for name in ("missing", "isolated", "invalid_s", "outside", "used"):
            getattr(self, name).setflags(write=False)      # shared by calls (GridLayout.of)

    @classmethod
    def of(cls, x_in, y_in, invalid, hole_size: int, min_neighbours: int) -> "GridLayout":
        """The layout of these axes and invalid nodes: one of the last
        :data:`KEPT_LAYOUTS` made, where it is the same (a field decomposed
        again, the frames of a run with a fixed mask), else a new one (kept
        up to :data:`KEPT_NODES` nodes)."""
        if invalid.size > KEPT_NODES:
            return cls(x_in, y_in, invalid, hole_size, min_neighbours)
        key = (x_in.tobytes(), y_in.tobytes(), invalid.shape, invalid.tobytes(), hole_size,
               min_neighbours)
        layout = _LAYOUTS.get(key)
        if layout is None:
            layout = cls(x_in, y_in, invalid, hole_size, min_neighbours)
        _LAYOUTS.put(key, layout)
        return layout

    def flux_band(self) -> tuple:
        """``(rows, cols, normal)``: the used nodes within auto's band of the
        outline (:data:`~taichi_hh.hhd.auto.FLUX_BAND` times the spacing,
        sqrt(area / nodes used)) and the outward normals there, from the grid
        (:func:`~taichi_hh.hhd.natural_grid.outline_distance`; made once)."""
        if self._band is None:
            from .auto import FLUX_BAND
            from .natural_grid import outline_distance
            hx, hy = self.steps
            n = int(self.used.sum())
            reach = FLUX_BAND * math.sqrt(self.domain.area / max(n, 1))
            jj, ii, best, normal = outline_distance(self.used, self.inside, hx, hy, reach)
            keep = best < reach
            self._band = (jj[keep], ii[keep], normal[keep])
        return self._band

    def nodes(self) -> np.ndarray:
        """(ny * nx, 2) every node, on the increasing axes."""
        X, Y = np.meshgrid(self.xs, self.ys)
        return np.c_[X.ravel(), Y.ravel()]

    def used_points(self) -> np.ndarray:
        return self.nodes()[self.used.ravel()]

    def native(self, method: str, options: dict) -> bool:
        """Whether the grid-native natural path may serve these options."""
        return (self.steps is not None and method == "default"
                and set(options) <= GRID_NATIVE_OPTIONS)

    def split(self, u_arr, v_arr, method: str, progress, options: dict, *,
              scattered_only: bool = False, scattered=None, orthogonal=None):
        """The decomposition of one snapshot (u, v in the input's order) on
        this layout: the grid-native natural path where it applies, else the
        scattered one on the used nodes.  ``scattered(points, vectors)`` and
        ``orthogonal(points, vectors)`` (auto's fallback): how the scattered
        decompositions are made (default: a :func:`decompose` call each;
        :class:`~taichi_hh.hhd.decomposer.GridDecomposer` passes its kept ones)."""
        from .decompose import decompose
        from .natural_grid import decompose_nodes
        u_s, v_s = u_arr[self.sl], v_arr[self.sl]
        used, inside = self.used, self.inside
        res = None
        if not scattered_only and self.native(method, options):
            # a uniform grid under the natural condition: on its own nodes
            # (hhd.natural_grid); the default condition (auto) measured alike
            opts, natural = _native_options(method, options)
            chosen = {"boundary_condition": opts.boundary_condition}
            if opts.boundary_condition == "auto":
                chosen = _auto_condition(self, u_s, v_s, opts.boundary)
            if chosen["boundary_condition"] == "natural":
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    res = decompose_nodes(self.xs, self.ys, self.steps, u_s, v_s, inside, used,
                                          self.domain, natural, chosen, progress)
                if "boundary_flux" in chosen and natural_cancels(res.stats["energy_ratio"]):
                    # auto's window split whose parts cancel: the orthogonal one if
                    # its energy is closer to the field's (hhd/auto.py)
                    attempt = orthogonal or (lambda p, w: _orthogonal_attempt(
                        p, w, self.domain, method, progress, options))
                    orth, orthogonal_warnings = attempt(self.used_points(),
                                                        np.c_[u_s[used], v_s[used]])
                    if energy_closer(orth.stats["energy_ratio"], res.stats["energy_ratio"]):
                        orth.stats.update(
                            boundary_condition=ORTHOGONAL_CONDITION,
                            boundary_flux=chosen["boundary_flux"],
                            boundary_along=chosen["boundary_along"],
                            natural_energy_ratio=res.stats["energy_ratio"])
                        res, caught = orth, orthogonal_warnings
                    else:
                        res.stats["orthogonal_energy_ratio"] = orth.stats["energy_ratio"]
                for w in caught:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if res is None:
            # the default condition as decompose()'s (auto): natural for a window, which
            # every measured PIV field is, no-flux where the flow does not cross the outline
            if scattered is not None:
                res = scattered(self.used_points(), np.c_[u_s[used], v_s[used]])
            else:
                res = decompose(self.used_points(), np.c_[u_s[used], v_s[used]], self.domain,
                                method=method, progress=progress, **options)
        return res

    def result(self, res, *, stacklevel: int = 3) -> GridResult:
        """The :class:`GridResult` of a decomposition ``res`` on this layout."""
        from .natural_grid import NodeFields
        sl, shape, used, inside = self.sl, self.shape, self.used, self.inside
        stats = dict(res.stats)
        stats.update(n_invalid=int(self.missing.sum()), n_isolated=int(self.isolated.sum()),
                     n_cut_out=int((self.outside & self.invalid_s).sum()),
                     n_left_out=self.left_out, n_holes=len(self.holes),
                     hole_size=self.hole_size)
        if self.left_out:
            msg = (f"{self.left_out} valid vectors lie in {self.n_pieces - 1} separate piece(s) "
                   f"of the grid, cut off from the largest by invalid regions of "
                   f"{self.hole_size} x {self.hole_size} nodes or more: left out (NaN); a "
                   "larger hole_size bridges the gaps")
            stats["flags"] = list(stats.get("flags", [])) + [msg]
            warnings.warn(msg, AccuracyWarning, stacklevel=stacklevel)
        lattice = res if isinstance(res, NodeFields) else None
        gaps = inside & ~used

        def on_grid(name):
            if lattice is not None:         # on the grid already, NaN off the inside nodes
                out = np.array(getattr(lattice, name))
                if gaps.any():
                    out[gaps] = np.nan
                return out[sl]
            values = np.asarray(getattr(res, name))
            out = np.full(shape + values.shape[1:], np.nan)
            out[used] = values
            return out[sl]                      # the input's order again
        return GridResult(x=self.x_in, y=self.y_in, curl_free=on_grid("curl_free"),
                          div_free=on_grid("div_free"), harmonic=on_grid("harmonic"),
                          phi=on_grid("phi"), psi=on_grid("psi"),
                          divergence=on_grid("divergence"), curl=on_grid("curl"),
                          used=used[sl].copy(), inside=inside[sl].copy(), domain=self.domain,
                          stats=stats,
                          lattice=lattice, _scattered=None if lattice is not None else res)


_NATIVE_OPTIONS: dict = {}


def _native_options(method: str, options: dict) -> tuple:
    """``(opts, natural)``: the options of ``method`` with ``options``
    (:func:`~taichi_hh.hhd.options.options_for`: checked) and those with the
    natural condition, which the grid-native path runs; kept per options
    given (a few names, string values: each check costs as much as the
    decomposition's smallest stages)."""
    from .options import options_for
    try:
        key = (method, tuple(sorted(options.items())))
        found = _NATIVE_OPTIONS.get(key)
    except TypeError:                       # an unhashable value: options_for names it
        key, found = None, None
    if found is None:
        opts = options_for(method, **options)
        found = (opts, replace(opts, boundary_condition="natural"))
        if key is not None and len(_NATIVE_OPTIONS) < 64:
            _NATIVE_OPTIONS[key] = found
    return found


def _orthogonal_attempt(points, vectors, domain, method, progress, options):
    """``(result, warnings)``: the scattered decomposition under ``auto``'s
    orthogonal condition, its warnings kept back (it is an attempt: the
    caller may drop it)."""
    from .decompose import decompose
    options = dict(options, boundary_condition=ORTHOGONAL_CONDITION)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = decompose(points, vectors, domain, method=method, progress=progress, **options)
    return res, caught


def _auto_condition(layout: GridLayout, u, v, boundary: str) -> dict:
    """``auto``'s choice on a uniform grid's used nodes, as
    :func:`~taichi_hh.hhd.auto.choose_boundary_condition` makes it:
    ``{"boundary_condition", "boundary_flux", "boundary_along"}``.  The flux
    (:func:`~taichi_hh.hhd.auto.boundary_flux`: RMS of v.n over the nodes
    within its band of the outline over the RMS of abs(v)) with the
    distances and normals from the grid rather than the domain's locator
    (:meth:`GridLayout.flux_band`)."""
    from .auto import band_flow, is_closed
    jj, ii, normal = layout.flux_band()
    used = layout.used
    uu, vv = u[used], v[used]
    size = float(np.mean(uu * uu + vv * vv))
    band = np.stack([u[jj, ii], v[jj, ii]], axis=-1)
    flux, along = band_flow(band, normal, size)
    closed = is_closed(flux, along, boundary)
    return {"boundary_condition": "no-flux" if closed else "natural", "boundary_flux": flux,
            "boundary_along": along}


def grid_of(points) -> tuple | None:
    """``(x, y, rows, cols)`` when ``points`` (N, 2) are the nodes of a
    rectilinear grid, each once (``points[k] == (x[cols[k]], y[rows[k]])``,
    ``x``, ``y`` increasing, at least 4 nodes each way): how PIV software and
    gridded model output list a field.  None otherwise."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
        return None
    x, cols = np.unique(pts[:, 0], return_inverse=True)
    y, rows = np.unique(pts[:, 1], return_inverse=True)
    if len(x) < 4 or len(y) < 4 or len(x) * len(y) != len(pts):
        return None
    flat = rows * len(x) + cols
    if np.unique(flat).size != len(pts):
        return None
    return x, y, rows.ravel(), cols.ravel()


def decompose_grid_rows(points, vectors, *, method: str = "default", progress=None,
                        **options):
    """:func:`decompose_grid` of a field listed row by row (``points`` (N, 2)
    the nodes of a rectilinear grid, :func:`grid_of`; ``vectors`` (N, 2), NaN
    where invalid), returned as :func:`~taichi_hh.hhd.decompose.decompose`
    returns it: an :class:`~taichi_hh.hhd.decompose.HHDResult` in the rows'
    order (NaN on the rows not decomposed), ``stats["grid"]`` the grid's shape.
    None when the points are not such a grid."""
    found = grid_of(points)
    if found is None:
        return None
    x, y, rows, cols = found
    u, v = on_nodes(found, vectors)
    g = decompose_grid(x, y, u, v, method=method, progress=progress, **options)
    return as_rows(g, found, points, vectors)


def on_nodes(found: tuple, vectors) -> tuple:
    """``(u, v)`` (ny, nx): the rows' ``vectors`` on the grid ``found``
    (:func:`grid_of`), NaN on nodes no row gives."""
    x, y, rows, cols = found
    vec = np.asarray(vectors, dtype=np.float64)
    u = np.full((len(y), len(x)), np.nan)
    v = np.full((len(y), len(x)), np.nan)
    u[rows, cols], v[rows, cols] = vec[:, 0], vec[:, 1]
    return u, v


def as_rows(g: GridResult, found: tuple, points, vectors):
    """The :class:`GridResult` ``g`` of a row-listed field (:func:`grid_of`'s
    ``found``) in the rows' order, as :func:`decompose_grid_rows` returns it."""
    x, y, rows, cols = found
    vec = np.asarray(vectors, dtype=np.float64)
    stats = dict(g.stats, grid=(len(y), len(x)))
    used = g.used[rows, cols]
    stats["n_invalid"] = int((~used).sum())
    return replace(g.scattered, points=np.asarray(points, dtype=np.float64),
                   vectors=np.where(used[:, None], vec, np.nan),
                   curl_free=g.curl_free[rows, cols], div_free=g.div_free[rows, cols],
                   harmonic=g.harmonic[rows, cols], phi=g.phi[rows, cols],
                   psi=g.psi[rows, cols], divergence=g.divergence[rows, cols],
                   curl=g.curl[rows, cols], stats=stats, valid=used, domain=g.domain)
