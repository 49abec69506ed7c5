"""Checks of the user's input to :func:`~taichi_hh.hhd.decompose.decompose`
and :func:`~taichi_hh.hhd.project.project`."""

import functools
import warnings
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from .. import runtime
from ..arrays import bounds, rows_any
from ..checks import as_real_array
from ..errors import AccuracyWarning, InputError
from ..sph.pointset import check_points, check_values
from .units import Frame, speeds_of

#: how decompose() treats rows whose point or vector is NaN or masked
INVALID_MODES = ("missing", "error")
#: exactly zero vectors in at least this many rows and this fraction of them
#: are named in a warning: DaVis text and Insight .vec files write invalid
#: vectors as zeros, which the decomposition would take for still fluid
ZERO_ROWS = 4
ZERO_FRACTION = 0.002

#: fewer points than this are refused by decompose: the components are noise
#: (median error 100-200% on the smoothest test field, docs/notes/app.md)
MIN_POINTS = 10
#: fewer points than this are flagged: nearly every particle's kernel support
#: reaches the boundary (median error 35-70% below, 9-12% from 140 points on)
FEW_POINTS = 100


def validate_input(points, vectors, domain, *, holds_points: bool = False):
    """``(points, vectors, domain)`` checked: (N, 2) finite arrays without
    duplicates, every point inside ``domain`` (a Box, a Polygon, ``(x0, y0, x1,
    y1)``, an (M, 2) vertex array, or ``"bbox"`` / ``"hull"`` / ``"alpha"`` /
    ``("alpha", A)``: the points' bounding box (the default), convex hull or
    alpha shape, :func:`~taichi_hh.geometry.from_points.domain_spec`).
    ``holds_points``: the caller has checked that ``domain`` holds the points
    (:func:`prepare_data`, in the caller's coordinates).  Raises
    :class:`~taichi_hh.errors.InputError`."""
    from ..geometry.from_points import domain_from_points, domain_spec
    pts = check_points(points)
    vec = check_values(vectors, len(pts), 2, "vectors")
    spec = domain_spec(domain)
    if spec is not None:
        domain = domain_from_points(pts, *spec)
    else:
        from ..geometry.domain import as_domain
        domain = as_domain(domain)
    if holds_points:
        return pts, vec, domain
    scale = float(np.max(np.abs(np.asarray(domain.bounds)))) or 1.0
    inside = domain.contains(pts, tol=1e-9 * scale)
    if not inside.all():
        bad = np.flatnonzero(~inside)
        raise InputError(f"{bad.size} point(s) lie outside the domain {domain!r}, first index "
                         f"{bad[0]} at {pts[bad[0]].tolist()}")
    return pts, vec, domain


def refuse_too_few(n: int) -> None:
    """Refuse a decomposition of fewer than :data:`MIN_POINTS` points
    (:class:`~taichi_hh.errors.InputError`), before any particle is built."""
    if n < MIN_POINTS:
        raise InputError(f"{n} point(s) are too few to decompose: at least {MIN_POINTS} are "
                         f"needed, and below {FEW_POINTS} the result is unreliable")


def check_point_count(n: int, stats: dict, *, stacklevel: int = 3) -> None:
    """Refuse a decomposition of fewer than :data:`MIN_POINTS` points
    (:func:`refuse_too_few`); flag one of fewer than :data:`FEW_POINTS` in
    ``stats["flags"]`` and by an :class:`~taichi_hh.errors.AccuracyWarning`."""
    refuse_too_few(n)
    stats.setdefault("flags", [])
    if n < FEW_POINTS:
        msg = (f"only {n} points: below {FEW_POINTS} nearly every particle's kernel support "
               f"reaches the boundary and the components are unreliable (errors of 35% "
               f"and more against exact answers); sample the field more densely")
        stats["flags"].append(msg)
        warnings.warn(msg, AccuracyWarning, stacklevel=stacklevel)


@ti.kernel
def _rows_without_source(n: ti.i32, offsets: ti.types.ndarray(), nbrs: ti.types.ndarray(),
                         kind: ti.types.ndarray(), row_kind: ti.i32, source_kind: ti.i32,
                         first: ti.types.ndarray()) -> ti.i32:
    """How many rows of kind ``row_kind`` have no neighbour of kind ``source_kind``;
    ``first[0]``: the lowest such slot (left as it was when there is none)."""
    count = 0
    for i in range(n):
        if kind[i] == row_kind:
            found = 0
            for k in range(offsets[i], offsets[i + 1]):
                if kind[nbrs[k]] == source_kind:
                    found = 1
                    break
            if found == 0:
                count += 1
                ti.atomic_min(first[0], i)
    return count


def check_data_reach_boundary(ps, boundary_kind: int, fluid_kind: int,
                              data: "Data | None" = None) -> None:
    """Boundary particles whose kernel support holds no data point mean that the
    data stop short of the domain's boundary by more than a support (the
    boundary rows would have no data to read).  Raises
    :class:`~taichi_hh.errors.InputError` saying where (in the caller's
    coordinates: ``data.frame``), and the remedy (one other than the domain
    the caller asked for, ``data.made_from``)."""
    p = ps.particles
    first = runtime.array(ti.i32, 1)
    first.fill(ps.n_total)
    n_empty = _rows_without_source(ps.n_total, ps.pairs.offsets, ps.pairs.neighbours, p.kind,
                                   int(boundary_kind), int(fluid_kind), first)
    if n_empty == 0:
        return
    n_boundary = int((p.get("kind") == boundary_kind).sum())
    where = p.get("position")[int(first.to_numpy()[0])]
    _refuse_gap(n_empty, n_boundary, where, ps.support, data)


def check_data_near_boundary(points: np.ndarray, domain, spacing: float, reach: float,
                             data: "Data | None" = None) -> None:
    """:func:`check_data_reach_boundary` for a decomposition without boundary
    particles (the natural condition): samples of the boundary ``spacing``
    apart, each with a data point within ``reach`` (the kernel support), or
    the same :class:`~taichi_hh.errors.InputError`.  Data short of the
    boundary would leave part of the domain's area to no point (their volumes,
    and so the convolution's weights, wrong: the components then carried 6
    times the field's energy on data covering the middle 36% of the domain)."""
    from ..sph.knn import KNearest
    samples = domain.sample_boundary(spacing)[0]
    # a point within reach of a boundary sample is within reach of the boundary:
    # only those are searched (the locator's cells place the rest deeper)
    near = points[domain.classify_discs(points, 0.0, -np.inf, -reach) != 1]
    if len(near) == 0:
        far = np.ones(len(samples), dtype=bool)
    else:
        far = KNearest(near).query(samples, 1)[0][:, 0] > reach
    if far.any():
        _refuse_gap(int(far.sum()), len(samples), samples[np.argmax(far)], reach, data)


def _refuse_gap(n_empty: int, n_boundary: int, where, reach: float,
                data: "Data | None" = None) -> None:
    """The refusal of data short of the boundary (``where``, ``reach``: unit
    frame when ``data`` is given); its remedies the domains drawn closer to
    the data than the one ``data.made_from`` names (None: the caller's own)."""
    if data is not None:
        where, reach = data.frame.points_from_unit(where), reach * data.frame.length
    kind, alpha = (data.made_from if data is not None else None) or (None, None)
    remedies = {
        "bbox": "domain='bbox' (the points' bounding box)",
        "hull": "domain='hull' (the points' convex hull)",
        "alpha": "domain='alpha' (the points' alpha shape: concave outlines and gaps followed)"}
    if kind is None:
        offer = list(remedies.values())
    elif kind == "alpha":
        # a boundary edge spans up to twice the radius: a smaller one keeps the
        # outline closer to the data (below 2, random data fall into pieces)
        offer = [f"domain=('alpha', {max(2.0, round(2.0 * alpha / 3.0, 1)):g}) (a smaller "
                 "alpha-shape radius: the outline closer to the data)"] if alpha > 2.0 else []
    else:                       # the hull and the alpha shape lie inside the bounding box
        offer = [remedies[k] for k in ("hull", "alpha") if k != kind]
    raise InputError(
        f"the data do not reach the domain's boundary: {n_empty} of {n_boundary} boundary "
        f"samples (first at ({where[0]:.4g}, {where[1]:.4g})) have no data point within the "
        f"kernel support ({reach:.3g} at most). Give the domain the data cover: "
        f"{''.join(o + ', ' for o in offer)}{'or ' if offer else ''}a Box/Polygon that fits them")


# --------------------------------------------------------------------------- measured data
@dataclass
class Data:
    """A field as the caller gave it and as the numerical core sees it.

    ``points``, ``vectors``: every row as given (float64; NaN where missing);
    ``valid``: the rows the decomposition uses; ``frame``: the unit frame
    (:mod:`taichi_hh.hhd.units`); ``unit_points``, ``unit_vectors``,
    ``unit_domain``: the valid rows and the domain in it.  ``flags``: what the
    checks found (warned already)."""
    points: np.ndarray
    vectors: np.ndarray
    valid: np.ndarray
    frame: Frame
    unit_points: np.ndarray
    unit_vectors: np.ndarray
    unit_domain: object
    flags: list = field(default_factory=list)
    domain: object = None        # the caller's Box or Polygon; None: made from the points
    made_from: tuple | None = None   # (kind, alpha) of a domain made from the points

    @functools.cached_property
    def n_invalid(self) -> int:
        return int(self.valid.size - np.count_nonzero(self.valid))

    @property
    def all_valid(self) -> bool:
        """Whether every row is valid (no missing row)."""
        return self.n_invalid == 0

    def rows(self, values, scale: float = 1.0) -> np.ndarray:
        """Per-valid-row ``values`` (unit frame) times ``scale`` on every row of
        the input, NaN on the missing ones."""
        values = np.asarray(values, dtype=np.float64)
        if self.all_valid:
            return values * scale
        out = np.full((self.valid.size,) + values.shape[1:], np.nan)
        out[self.valid] = values * scale
        return out


def _real_rows(values, name: str, n: int | None):
    """``(array, masked_rows, finite)``: ``values`` as an (n, 2) float64 array,
    the rows a numpy mask hides (None without a mask), and whether every
    value is finite (else some are NaN: infinite ones are refused).  Complex, object and string
    arrays are refused (:func:`~taichi_hh.checks.as_real_array`): a cast would
    drop an imaginary part or invent numbers."""
    masked = None
    if np.ma.isMaskedArray(values):
        mask = np.ma.getmaskarray(values)
        masked = mask.reshape(mask.shape[0], -1).any(axis=1) if mask.ndim else None
        values = np.ma.getdata(values)
    arr = as_real_array(values, name, "a numeric (N, 2) array")
    want = (n, 2) if n is not None else None
    if arr.ndim != 2 or arr.shape[1] != 2 or (want is not None and arr.shape != want):
        expect = f"({n}, 2), one row per point" if n is not None else "(N, 2)"
        raise InputError(f"{name} must have shape {expect}, got {arr.shape}")
    if arr.shape[0] == 0:
        raise InputError(f"{name} is empty: at least one point is needed")
    # a finite sum: every value finite (one pass; an overflowing sum of
    # finite values takes the values' own check)
    with np.errstate(over="ignore", invalid="ignore"):
        finite = bool(np.isfinite(arr.sum()))
    if not finite and np.isinf(arr).any():
        i = int(np.flatnonzero(np.isinf(arr).any(axis=1))[0])
        raise InputError(f"{name} contain infinite values, first in row {i}: "
                         f"{arr[i].tolist()} (missing values are NaN)")
    return arr, masked, finite


def prepare_data(points, vectors, domain, *, invalid: str = "missing", valid=None,
                 caller: str = "decompose") -> Data:
    """The caller's ``(points, vectors, domain)`` checked and moved into the unit
    frame (:class:`Data`).

    A row is missing when its point or vector holds a NaN, a numpy mask hides
    it, or ``valid`` (a boolean array, one per row) is False there.  With
    ``invalid="missing"`` (the default) missing rows are left out and the
    results are NaN there; with ``invalid="error"`` they are refused.  The
    domain (a Box, a Polygon, ``(x0, y0, x1, y1)``, an (M, 2) vertex array, or
    ``"bbox"``, ``"hull"``, ``"alpha"``, ``("alpha", A)``: one made from the
    valid points, :func:`~taichi_hh.geometry.from_points.domain_spec`) must
    hold every valid point.  ``caller``: ``"decompose"``, or ``"project"``,
    which needs a velocity on every particle (missing rows refused) and whose
    zero vectors are fluid at rest.  Raises :class:`~taichi_hh.errors.InputError`."""
    if invalid not in INVALID_MODES:
        raise InputError(f"invalid must be one of {INVALID_MODES}, got {invalid!r}")
    pts, masked_p, finite_p = _real_rows(points, "points", None)
    vec, masked_v, finite_v = _real_rows(vectors, "vectors", len(pts))
    missing = np.zeros(len(pts), dtype=bool)
    if not (finite_p and finite_v):
        missing = rows_any(np.isnan(pts)) | rows_any(np.isnan(vec))
    for m in (masked_p, masked_v):
        if m is not None:
            missing |= m
    if valid is not None:
        flags = np.asarray(valid)
        if flags.shape != (len(pts),) or flags.dtype.kind not in "bui":
            raise InputError(f"valid must be a boolean array of shape ({len(pts)},), one per "
                             f"row, got {flags.dtype} {flags.shape}")
        if flags.dtype.kind != "b" and not np.isin(flags, (0, 1)).all():
            raise InputError("valid must hold booleans (or 0 and 1)")
        missing |= ~flags.astype(bool)
    if missing.any() and (invalid == "error" or caller == "project"):
        first = int(np.flatnonzero(missing)[0])
        remedy = ("invalid='missing' (the default) leaves them out and returns NaN there"
                  if caller == "decompose" else "a projection needs a velocity on every "
                  "particle")
        raise InputError(f"{int(missing.sum())} of {len(pts)} rows are missing (NaN, masked or "
                         f"marked invalid), first row {first}; {remedy}")
    ok = ~missing
    n_valid = int(ok.sum())
    if n_valid == 0:
        raise InputError(f"all {len(pts)} rows are missing (NaN, masked or marked invalid): "
                         "there is no field to decompose")
    every = n_valid == len(pts)
    pts_ok, vec_ok = (pts, vec) if every else (pts[ok], vec[ok])
    # in the caller's coordinates and row numbers, before any re-centring
    from ..checks import check_spread
    from ..sph.pointset import check_distinct
    check_spread(pts_ok)
    check_distinct(pts_ok, rows=None if every else np.flatnonzero(ok))
    from ..geometry.from_points import domain_from_points, domain_spec
    made_from = domain_spec(domain)
    if made_from is not None:
        lo, hi = bounds(pts_ok)
        frame = Frame.of((lo, hi), vec_ok)
        unit_in = frame.points_to_unit(pts_ok)
        # made in the unit frame, its messages in the caller's coordinates
        unit_domain = domain_from_points(unit_in, *made_from, to_caller=frame.points_from_unit)
    else:
        from ..geometry.domain import as_domain
        user_domain = as_domain(domain)
        frame = Frame.of(user_domain.bounds, vec_ok)
        unit_domain = frame.domain_to_unit(user_domain)
        unit_in = frame.points_to_unit(pts_ok)
        # asked once, in the unit frame (its tolerance is the tighter one),
        # answered in the caller's rows and coordinates
        scale = float(np.max(np.abs(np.asarray(unit_domain.bounds)))) or 1.0
        inside = unit_domain.contains(unit_in, tol=1e-9 * scale)
        if not inside.all():
            bad = np.flatnonzero(ok)[~inside]
            raise InputError(f"{bad.size} point(s) lie outside the domain {user_domain!r}, "
                             f"first row {bad[0]} at {pts[bad[0]].tolist()}")
    unit_pts, unit_vec, unit_domain = validate_input(unit_in, vec_ok / frame.speed, unit_domain,
                                                     holds_points=made_from is None)
    vec_out = vec.copy()
    vec_out[missing] = np.nan
    data = Data(pts, vec_out, ok, frame, unit_pts, unit_vec, unit_domain,
                domain=None if made_from is not None else user_domain, made_from=made_from)
    if caller == "decompose":
        check_zero_rows(data)
    return data


def fields_on(data: Data, snapshots, *, stacklevel: int = 5) -> tuple:
    """``(datas, units)``: other fields ``snapshots`` (a sequence of (N, 2)
    arrays) on the points of ``data`` (:func:`prepare_data`'s), one Data
    each in ``datas``, and ``units`` (k, n, 2) the unit vectors of the k of
    them that are not None, in order (their Data's ``unit_vectors`` are
    views of it; None if there is none).  Each Data holds the same points,
    valid rows, domain and unit coordinates, each field's own speed
    (:class:`~taichi_hh.hhd.units.Frame`) and zero-row check; None for a
    field that misses (NaN, masked) a row that ``data`` holds: its valid
    points differ, the caller prepares them anew.  Raises
    :class:`~taichi_hh.errors.InputError` for a bad array.  The passes over
    the fields are taken once for all of them: one copy of the fields
    stacked (the ``vectors`` each Data holds are views of it), their speeds,
    unit vectors and zero components over the stack (a series paid each
    pass per snapshot, 0.3 ms of a 13k-point one)."""
    n, every = data.valid.size, data.all_valid
    out = [None] * len(snapshots)
    kept = []
    for i, vectors in enumerate(snapshots):
        vec, masked, finite = _real_rows(vectors, "vectors", n)
        if masked is not None or not finite:
            # by columns: numpy's reductions over an axis of two cost more than the work
            missing = np.isnan(vec[:, 0]) | np.isnan(vec[:, 1])
            if masked is not None:
                missing |= masked
            if (missing if every else missing[data.valid]).any():   # a row the points hold
                continue
        kept.append((i, vec))
    if not kept:
        return out, None
    stack = np.stack([vec for _, vec in kept])              # (k, N, 2), a copy
    if every:
        ok = stack
    else:
        stack[:, ~data.valid] = np.nan
        ok = stack[:, data.valid]
    speeds = speeds_of(ok)
    unit = ok / speeds[:, None, None]
    least = zero_rows_named(unit.shape[1])
    # a zero row is two zero components: counted per field only where the
    # batch has enough of them (a count along axes is 2.5x the plain one)
    zeros = np.zeros(len(kept), dtype=np.int64)
    if np.count_nonzero(unit == 0.0) >= 2 * least:
        zeros = np.count_nonzero(unit == 0.0, axis=(1, 2))
    base = data.frame
    for j, (i, _) in enumerate(kept):
        one = Data(data.points, stack[j], data.valid,
                   Frame(base.centre, base.length, float(speeds[j])), data.unit_points,
                   unit[j], data.unit_domain, domain=data.domain, made_from=data.made_from)
        if zeros[j] >= 2 * least:        # else too few zero components for zero rows
            check_zero_rows(one, stacklevel=stacklevel)
        out[i] = one
    return out, unit


def zero_rows_named(n: int) -> float:
    """The zero rows of n that :func:`check_zero_rows` names at least."""
    return max(ZERO_ROWS, ZERO_FRACTION * n)


def check_zero_rows(data: Data, *, stacklevel: int = 4) -> None:
    """Name exactly zero vectors when there are enough of them to be an
    instrument's mark for invalid ones rather than still fluid."""
    u = data.unit_vectors
    least = zero_rows_named(len(u))
    # a zero row is two zero components: too few of those, no rows to name
    if np.count_nonzero(u == 0.0) < 2 * least:
        return
    zero = (u[:, 0] == 0.0) & (u[:, 1] == 0.0)
    count = int(np.count_nonzero(zero))
    if count < least or count == zero.size:
        return
    where = np.flatnonzero(data.valid)[zero]
    lo, hi = data.points[where].min(axis=0), data.points[where].max(axis=0)
    msg = (f"{count} of {zero.size} vectors are exactly zero (rows {where[0]}"
           f"{', ' + str(where[1]) if count > 1 else ''}, ...; within x {lo[0]:.6g}..{hi[0]:.6g},"
           f" y {lo[1]:.6g}..{hi[1]:.6g}): they are decomposed as still fluid. PIV software "
           "(DaVis text, Insight .vec) writes invalid vectors as zeros; if these are invalid, "
           "mark them missing (NaN, or False in valid)")
    data.flags.append(msg)
    warnings.warn(msg, AccuracyWarning, stacklevel=stacklevel)
