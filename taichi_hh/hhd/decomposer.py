"""Many fields on the same points: :class:`Decomposer` (a PIV run, a radar
archive, a model's output steps).

    dec = taichi_hh.Decomposer(points, domain=None, **options)   # set-up once
    series = dec.decompose(vectors)          # (T, N, 2) or (N, 2)
    series.curl_free, series.div_free, series.harmonic          # (T, N, 2)
    series.phi, series.psi, series.divergence, series.curl      # (T, N)
    series.stats[t], series.boundary_condition[t], series[t]    # per snapshot
    for res in dec.stream(snapshots): ...    # one HHDResult per snapshot, memory flat

What depends only on the points and the options is made once, the first
time a snapshot needs it, and kept: the checked points, the domain and the
unit frame's geometry, ``auto``'s band of points next to the boundary (and
their normals), the natural condition's check that the points reach the
boundary; for each condition with Poisson rows the particles,
boundary samples, neighbour pairs, stencils, the assembled matrix and its
multilevel preconditioner (:class:`~taichi_hh.hhd.operator_split.OperatorSplit`).
The snapshots of a batch are solved together, their right-hand sides the
columns of one BiCGSTAB (the matrix and the preconditioner read once per
iteration for all of them); each column iterates and stops on its own, so
every snapshot's answer is the one ``decompose(points, vectors[t], ...)``
gives, to the solver's tolerance (tests/test_decomposer.py).

Per snapshot, as in a call of its own:

* the unit frame's speed (the field's largest component) and the zero-rows
  check;
* ``boundary_condition="auto"`` (the default) chooses from the snapshot's
  data (:mod:`taichi_hh.hhd.auto`): its boundary flux says window
  (``natural``) or closed container (``no-flux``), and a window whose
  natural parts cancel is split again under ``normal-parallel`` (through
  the kept system of that condition).  A series can so mix conditions;
  ``series.boundary_condition`` says which each snapshot got, and each
  condition's system is made once, when a snapshot first needs it;
* the natural decomposition with the default operators (the usual answer
  for a window) has no system to keep: its node fits and convolution run
  per snapshot, on a set-up of the points made once
  (:class:`~taichi_hh.hhd.natural.NaturalSetup`: the grid and its cut cells,
  the bins, the node fits kept as weights, one gather per field) and the
  grid's kernel spectrum reused;
* missing data: a snapshot whose NaN (or masked) rows are not among the
  points' own missing rows has other valid points, so no shared set-up: it
  is decomposed on its own (a one-off :func:`~taichi_hh.hhd.decompose.decompose`),
  ``stats["shared_setup"]`` False.  The points' own NaN rows are missing in
  every snapshot.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import runtime
from ..errors import InputError
from .auto import boundary_flows, flux_band
from .component_checks import Components
from .decompose import (HHDResult, check_natural_reach, decompose, decompose_unit,
                        in_caller_units, natural_at_nodes, resolved_options, unit_spacing)
from .inputs import fields_on, prepare_data
from .natural import NaturalSetup
from .operator_split import COLUMN_BYTES, VECTORS_PER_COLUMN, OperatorSplit
from .options import options_for

__all__ = ["Decomposer", "SeriesResult", "GridDecomposer", "GridSeries", "SERIES_FIELDS"]

#: per-snapshot arrays of a :class:`SeriesResult`, the HHDResult attribute each stacks
SERIES_FIELDS = ("vectors", "curl_free", "div_free", "harmonic", "phi", "psi", "divergence",
                 "curl")
#: snapshots in one joint solve at most (the columns also bounded in memory:
#: :data:`~taichi_hh.hhd.operator_split.COLUMN_BYTES`)
MAX_BATCH = 16
#: natural snapshots split together
#: (:meth:`~taichi_hh.hhd.natural.NaturalSetup.split_many`): between these,
#: as many as keep NATURAL_POINT_SNAPSHOTS points x snapshots (a batch's
#: columns in the caches; the kept fits' weights are read once a batch, so
#: wider batches read them less often: at 13k points 8 ran 10% faster a
#: snapshot than 4, at 100k the same, with twice the work arrays)
NATURAL_BATCH = (4, 8)
NATURAL_POINT_SNAPSHOTS = 2 ** 18


def natural_batch(n_points: int) -> int:
    """Natural snapshots split together on ``n_points`` points (NATURAL_BATCH)."""
    low, high = NATURAL_BATCH
    return max(low, min(high, NATURAL_POINT_SNAPSHOTS // max(n_points, 1)))


@dataclass
class SeriesResult(Components):
    """The decompositions of T snapshots on the same points, stacked:
    ``vectors``, ``curl_free`` (d), ``div_free`` (r), ``harmonic`` (h):
    (T, N, 2); ``phi``, ``psi``, ``divergence``, ``curl``: (T, N), in the
    caller's units and row order, NaN on missing rows.  ``stats``: one dict
    per snapshot (as :attr:`HHDResult.stats`); ``series[t]``: snapshot t as
    an :class:`~taichi_hh.hhd.decompose.HHDResult` (critical points,
    figures)."""
    points: np.ndarray
    vectors: np.ndarray
    stats: list
    # per snapshot: its options, frame, valid rows, point set and domain (HHDResult's)
    meta: list = field(repr=False, default_factory=list)

    def __len__(self) -> int:
        return len(self.stats)

    @property
    def boundary_condition(self) -> list:
        """The condition each snapshot was decomposed under."""
        return [s.get("boundary_condition", "") for s in self.stats]

    @property
    def energy_ratio(self) -> np.ndarray:
        """(T,) |d|^2 + |r|^2 + |h|^2 over |v|^2 per snapshot."""
        return np.array([s.get("energy_ratio", np.nan) for s in self.stats])

    def __getitem__(self, t: int) -> HHDResult:
        t = range(len(self))[t]
        meta = self.meta[t]
        return HHDResult(points=self.points, **{k: getattr(self, k)[t] for k in SERIES_FIELDS},
                         stats=self.stats[t], **meta)

    @classmethod
    def stacked(cls, points, results: list) -> "SeriesResult":
        """The results (HHDResult per snapshot, on ``points``) stacked."""
        arrays = {k: np.stack([np.asarray(getattr(r, k), dtype=np.float64) for r in results])
                  for k in SERIES_FIELDS}
        meta = [{"options": r.options, "pointset": r.pointset, "valid": r.valid,
                 "frame": r.frame, "domain": r.domain} for r in results]
        return cls(points=np.asarray(points, dtype=np.float64), **arrays,
                   stats=[r.stats for r in results], meta=meta)


class Decomposer:
    """Helmholtz-Hodge decompositions of many fields on the fixed ``points``
    (module doc).  ``points``, ``domain``, ``method``, ``options``: as
    :func:`~taichi_hh.hhd.decompose.decompose` takes them (NaN rows of the
    points are missing in every snapshot); ``invalid``: alike, per snapshot.
    ``batch``: snapshots taken in at a time (default: as many as
    :data:`MAX_BATCH` and the columns' memory,
    :data:`~taichi_hh.hhd.operator_split.COLUMN_BYTES`, allow); ``columns``:
    right-hand sides in one joint solve at most (default
    :data:`~taichi_hh.hhd.operator_split.MAX_COLUMNS`: two snapshots' phi and psi).
    ``factorize``: each Poisson system factorised once by scipy's SuperLU
    (scipy needed) and every snapshot solved by triangular solves instead of
    BiCGSTAB: for long series where the factorisation's cost (seconds at
    13k points, growing faster than N) is repaid (benchmarks/timeseries.py
    ``--direct``; docs/notes/series.md).  ``seconds``: what the set-up took,
    made on first use (each condition's system by its name, ``natural``,
    ``auto_band``, ``natural_reach``), and ``last_batch``."""

    def __init__(self, points, domain=None, *, method: str = "default", progress=None,
                 invalid: str = "missing", batch: int | None = None,
                 columns: int | None = None, factorize: bool = False, **options):
        self.opts = options_for(method, **options)
        self.method, self.options, self.invalid = method, dict(options), invalid
        self.domain_spec, self.progress = domain, progress
        runtime.ensure_init()
        pts = np.asarray(points, dtype=np.float64) if not np.ma.isMaskedArray(points) \
            else points
        # the points checked once (a unit field: the frame's speed is per snapshot)
        self.data = prepare_data(pts, np.ones((len(pts), 2)), domain, invalid=invalid)
        self.points = self.data.points
        n = len(self.data.unit_points)
        if batch is None:
            columns = COLUMN_BYTES // (VECTORS_PER_COLUMN * 8 * max(2 * n, 1))
            batch = max(1, min(MAX_BATCH, columns // 2))
        if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
            raise InputError(f"batch must be a positive integer (snapshots), got {batch!r}")
        self.batch = int(batch)
        if columns is not None and (isinstance(columns, bool) or not isinstance(
                columns, (int, np.integer)) or columns < 1):
            raise InputError(f"columns must be a positive integer, got {columns!r}")
        self.columns = columns
        if not isinstance(factorize, (bool, np.bool_)):
            raise InputError(f"factorize must be True or False, got {factorize!r}")
        self.factorize = bool(factorize)
        self._splits = {}
        self.seconds = {}
        self._near = None              # auto's band of points next to the boundary
        self._reach_checked = False    # the natural condition's reach of the boundary
        self._natural = None           # the natural decomposition's set-up (NaturalSetup)
        self._natural_width = 0        # the fields its splits take (_split_width)
        self._caller_domain = None     # (unit domain, the same in the caller's units)

    def __repr__(self) -> str:
        return (f"Decomposer({len(self.points)} points, method={self.method!r}, "
                f"batch={self.batch}, systems={sorted(self._splits)})")

    def split_for(self, condition: str) -> OperatorSplit:
        """The kept system (:class:`~taichi_hh.hhd.operator_split.OperatorSplit`)
        of ``condition``, made on first use."""
        from dataclasses import replace
        s = self._splits.get(condition)
        if s is None:
            t = time.perf_counter()
            s = OperatorSplit(self.data, replace(self.opts, boundary_condition=condition),
                              keep=True, max_columns=self.columns, factorize=self.factorize)
            s.build(self.progress)
            self._splits[condition] = s
            self.seconds[condition] = time.perf_counter() - t
        return s

    def natural_setup(self, data, opts) -> NaturalSetup:
        """The natural decomposition's set-up of the points
        (:class:`~taichi_hh.hhd.natural.NaturalSetup`: grid, bins, the node
        fits kept as weights), made on first use."""
        if self._natural is None:
            t = time.perf_counter()
            self._natural = NaturalSetup(data.unit_points, data.unit_domain, unit_spacing(data),
                                         evaluation=opts.natural_evaluation, reuse_fits=True)
            self.seconds["natural"] = time.perf_counter() - t
        return self._natural

    def _one(self, data, opts):
        # the orthogonal attempt of auto's window split, through the kept system
        return self.split_for(opts.boundary_condition).split([data], self.progress)[0]

    def decompose(self, vectors) -> SeriesResult:
        """The decompositions of ``vectors``: (T, N, 2), or (N, 2) for one
        snapshot (T = 1).  Returns a :class:`SeriesResult`."""
        arr = vectors if np.ma.isMaskedArray(vectors) else np.asarray(vectors)
        if arr.ndim == 2:
            arr = arr[None]
        n = len(self.points)
        if arr.ndim != 3 or arr.shape[1:] != (n, 2):
            raise InputError(f"vectors must have shape (T, {n}, 2) or ({n}, 2), one row per "
                             f"point, got {np.shape(vectors)}")
        if len(arr) == 0:
            raise InputError("vectors hold no snapshot (T = 0)")
        return SeriesResult.stacked(self.points, list(self.stream(arr)))

    def stream(self, snapshots):
        """One :class:`~taichi_hh.hhd.decompose.HHDResult` per snapshot of
        ``snapshots`` (any iterable of (N, 2) arrays, e.g. a generator reading
        files), in order, :attr:`batch` at a time: the memory holds one batch,
        whatever the series' length."""
        pending = []
        for vec in snapshots:
            pending.append(vec)
            if len(pending) == self.batch:
                yield from self._batch(pending)
                pending = []
        if pending:
            yield from self._batch(pending)

    def _batch(self, snapshots: list) -> list:
        """The results of a batch of snapshots, in order (module doc): the
        natural ones at the nodes split together
        (:meth:`~taichi_hh.hhd.natural.NaturalSetup.split_many`), each
        condition with Poisson rows solved jointly."""
        t0 = time.perf_counter()
        out = [None] * len(snapshots)
        natural = []                       # [(index, data, opts, chosen)]
        groups = {}                        # condition -> [(index, data, chosen)]
        datas, units = fields_on(self.data, snapshots, stacklevel=6)
        shared = [data for data in datas if data is not None]
        unit_of = {id(data): j for j, data in enumerate(shared)}      # its row of units
        flows = None
        if shared and self.opts.boundary_condition == "auto":
            # auto's measure of the flow next to the boundary, the batch's at once
            if self._near is None:
                t = time.perf_counter()
                data = shared[0]
                self._near = flux_band(data.unit_points, data.unit_domain, unit_spacing(data))
                self.seconds["auto_band"] = time.perf_counter() - t
            flows = iter(zip(*(a.tolist() for a in boundary_flows(
                [d.unit_vectors for d in shared], self._near))))
        for k, (vec, data) in enumerate(zip(snapshots, datas)):
            if data is None:               # other valid rows: a call of its own
                res = decompose(self.points, vec, self.domain_spec, method=self.method,
                                progress=self.progress, invalid=self.invalid, **self.options)
                res.stats["shared_setup"] = False
                out[k] = res
                continue
            flow = next(flows) if flows is not None else None
            opts, chosen = resolved_options(self.opts, data, near=self._near, flow=flow)
            if natural_at_nodes(opts) or "boundary_flux" in chosen \
                    and opts.boundary_condition == "natural":
                natural.append((k, data, opts, chosen))
            else:
                groups.setdefault(opts.boundary_condition, []).append((k, data, chosen))
        at_nodes = [m for m in natural if natural_at_nodes(m[2])]
        if at_nodes and not self._reach_checked:
            _, data, opts, _ = at_nodes[0]
            t = time.perf_counter()
            check_natural_reach(data.unit_points, data.unit_domain, unit_spacing(data), opts,
                                data)
            self._reach_checked = True
            self.seconds["natural_reach"] = time.perf_counter() - t
        t = time.perf_counter()
        splits = {}
        if at_nodes:
            setup = self.natural_setup(at_nodes[0][1], at_nodes[0][2])
            width = natural_batch(len(self.data.unit_points))
            for a in range(0, len(at_nodes), width):
                part = at_nodes[a:a + width]
                # the fields' rows of units (a slice of it as a rule: no copy),
                # the first again up to the split's width
                rows = [unit_of[id(data)] for _, data, _, _ in part]
                rows += [rows[0]] * (self._split_width(len(rows), width) - len(rows))
                made = setup.split_many(units[rows[0]:rows[-1] + 1]
                                        if rows == list(range(rows[0], rows[-1] + 1))
                                        else units[rows])
                splits.update({k: split for (k, _, _, _), split in zip(part, made)})
        share = (time.perf_counter() - t) / max(len(at_nodes), 1)
        for k, data, opts, chosen in natural:
            t = time.perf_counter()
            unit = decompose_unit(data, opts, chosen, self.progress, split=self._one,
                                  reach_checked=self._reach_checked,
                                  natural=_Made(splits[k]) if k in splits else None)
            unit.stats["seconds"]["total"] = time.perf_counter() - t + (share if k in splits
                                                                        else 0.0)
            out[k] = self._finish(unit, data)
        for condition, members in groups.items():
            t = time.perf_counter()
            units = self.split_for(condition).split([d for _, d, _ in members], self.progress)
            share = (time.perf_counter() - t) / len(members)
            for (k, data, chosen), unit in zip(members, units):
                unit.stats.update(chosen)
                unit.stats["seconds"]["total"] = share
                out[k] = self._finish(unit, data)
        self.seconds["last_batch"] = time.perf_counter() - t0
        return out

    def _split_width(self, k: int, width: int) -> int:
        """The fields a natural split of ``k`` snapshots takes (the rest
        copies of the first, their results dropped): the split's kernels
        compile once per width (their strides known at compile time), and a
        width's first split in a process loads them (0.3 s at 13k points;
        2 s where never compiled), so a series' short last batch takes the
        width of the batches before it, and a first split the next power of
        two (at most ``width``: four widths in all)."""
        if k >= self._natural_width:
            self._natural_width = min(width, 1 << max(k - 1, 0).bit_length())
        return max(k, self._natural_width)

    def _finish(self, unit, data) -> HHDResult:
        # the domain in the caller's units: the same for every snapshot on
        # the kept unit frame (made once: a Box or Polygon rescaled)
        kept = self._caller_domain
        res = in_caller_units(unit, data, kept[1] if kept and kept[0] is unit.domain else None)
        if not kept or kept[0] is not unit.domain:
            self._caller_domain = (unit.domain, res.domain)
        res.stats["shared_setup"] = True
        return res


class _Made:
    """The natural set-up's stand-in for one snapshot of a batch: its split
    made already, with the batch's
    (:meth:`~taichi_hh.hhd.natural.NaturalSetup.split_many`)."""

    def __init__(self, split):
        self._split = split

    def split(self, vectors):
        return self._split


#: the layouts (missing-node patterns) a GridDecomposer keeps, with their systems
KEPT_LAYOUTS = 2


class GridSeries:
    """The decompositions of T gridded snapshots
    (:class:`GridDecomposer`): ``series[t]`` a
    :class:`~taichi_hh.hhd.grid.GridResult`; the arrays stacked on first
    read, ``curl_free``, ``div_free``, ``harmonic`` (T, ny, nx, 2), ``phi``,
    ``psi``, ``divergence``, ``curl``, ``used`` (T, ny, nx); ``stats`` one
    dict per snapshot."""

    def __init__(self, x, y, results: list):
        self.x, self.y, self.results = x, y, results
        self.stats = [r.stats for r in results]

    def __len__(self) -> int:
        return len(self.results)

    def __getitem__(self, t: int):
        return self.results[t]

    def __getattr__(self, name):
        if name in SERIES_FIELDS[1:] + ("used", "inside"):
            value = np.stack([getattr(r, name) for r in self.results])
            setattr(self, name, value)
            return value
        raise AttributeError(name)

    boundary_condition = SeriesResult.boundary_condition
    energy_ratio = SeriesResult.energy_ratio


class GridDecomposer:
    """:func:`~taichi_hh.hhd.grid.decompose_grid` of many snapshots on the
    same grid: ``x`` (nx,), ``y`` (ny,), ``mask`` (ny, nx, True where
    invalid in every snapshot) and the options as ``decompose_grid`` takes
    them; ``decompose(u, v)`` with (T, ny, nx) or (ny, nx) components,
    ``stream(pairs)`` over ``(u, v)`` pairs.

    The layout (isolated nodes, regions cut out, the outline, the nodes
    decomposed) comes from each snapshot's missing nodes; snapshots missing
    the same nodes share it, and with it the scattered path's kept systems
    (a :class:`Decomposer` on the used nodes; auto's orthogonal fallback
    through another).  A snapshot whose missing nodes differ gets its own
    layout: the last :data:`KEPT_LAYOUTS` are kept (a PIV run whose masks
    change each frame pays a one-off call per frame).  The grid-native
    natural path (a uniform grid, the default method) runs per snapshot:
    its finite differences and FFT have nothing of size to keep."""

    def __init__(self, x, y, mask=None, *, hole_size: int = None, min_neighbours: int = None,
                 method: str = "default", progress=None, batch: int | None = None, **options):
        from ..geometry.raster import check_axis
        from .grid import HOLE_SIZE, MIN_NEIGHBOURS, check_grid_options
        self.hole_size = HOLE_SIZE if hole_size is None else hole_size
        self.min_neighbours = MIN_NEIGHBOURS if min_neighbours is None else min_neighbours
        check_grid_options(options, self.hole_size, self.min_neighbours)
        options_for(method, **options)
        self.x, self.y = check_axis(x, "x"), check_axis(y, "y")
        self.mask, self.method, self.progress = mask, method, progress
        self.options, self.batch = dict(options), batch
        self._layouts = {}

    def _layout(self, invalid):
        from .grid import GridLayout
        key = invalid.tobytes()
        kept = self._layouts.pop(key, None)
        if kept is None:
            kept = {"layout": GridLayout(self.x, self.y, invalid, int(self.hole_size),
                                         int(self.min_neighbours))}
        self._layouts[key] = kept                       # the most recent last
        while len(self._layouts) > KEPT_LAYOUTS:
            self._layouts.pop(next(iter(self._layouts)))
        return kept

    def _decomposer(self, kept, name: str, **extra) -> Decomposer:
        if name not in kept:
            layout = kept["layout"]
            kept[name] = Decomposer(layout.used_points(), layout.domain, method=self.method,
                                    progress=self.progress, batch=self.batch,
                                    **dict(self.options, **extra))
        return kept[name]

    def decompose(self, u, v) -> GridSeries:
        """The decompositions of the snapshots ``u``, ``v`` ((T, ny, nx) or
        (ny, nx)): a :class:`GridSeries`."""
        U = u if np.ma.isMaskedArray(u) else np.asarray(u)
        V = v if np.ma.isMaskedArray(v) else np.asarray(v)
        shape = (len(self.y), len(self.x))
        if U.ndim == 2 and V.ndim == 2:
            U, V = U[None], V[None]
        if U.ndim != 3 or U.shape != V.shape or U.shape[1:] != shape or len(U) == 0:
            raise InputError(f"u and v must both have shape (T, ny, nx) = (T, {shape[0]}, "
                             f"{shape[1]}) with T >= 1, or (ny, nx); got {np.shape(u)} and "
                             f"{np.shape(v)}")
        return GridSeries(self.x, self.y, list(self.stream(zip(U, V))))

    def stream(self, pairs):
        """One :class:`~taichi_hh.hhd.grid.GridResult` per ``(u, v)`` of
        ``pairs`` (any iterable), in order; the scattered path's snapshots
        that share a layout solved together in batches."""
        from .auto import ORTHOGONAL_CONDITION
        from .grid import grid_components
        pending = []
        size = self.batch or MAX_BATCH

        def flush():
            out = [None] * len(pending)
            scattered = {}                  # id(kept) -> [(k, vectors)]
            for k, (kept, u_arr, v_arr) in enumerate(pending):
                layout = kept["layout"]
                if layout.native(self.method, self.options):
                    def one(points, vectors, kept=kept):
                        return next(self._decomposer(kept, "scattered").stream([vectors]))

                    def orthogonal(points, vectors, kept=kept):
                        with warnings.catch_warnings(record=True) as caught:
                            warnings.simplefilter("always")
                            dec = self._decomposer(kept, "orthogonal",
                                                   boundary_condition=ORTHOGONAL_CONDITION)
                            res = next(dec.stream([vectors]))
                        return res, caught
                    res = layout.split(u_arr, v_arr, self.method, self.progress, self.options,
                                       scattered=one, orthogonal=orthogonal)
                    out[k] = layout.result(res, stacklevel=5)
                else:
                    sl, used = layout.sl, layout.used
                    vec = np.c_[u_arr[sl][used], v_arr[sl][used]]
                    scattered.setdefault(id(kept), (kept, []))[1].append((k, vec))
            for kept, members in scattered.values():
                dec = self._decomposer(kept, "scattered")
                for (k, _), res in zip(members, dec.stream([w for _, w in members])):
                    out[k] = kept["layout"].result(res, stacklevel=5)
            pending.clear()
            return out

        for u, v in pairs:
            u_arr, v_arr, invalid = grid_components(self.x, self.y, u, v, self.mask)
            pending.append((self._layout(invalid), u_arr, v_arr))
            if len(pending) == size:
                yield from flush()
        if pending:
            yield from flush()
