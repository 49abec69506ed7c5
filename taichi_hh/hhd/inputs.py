"""Checks of the user's input to :func:`~taichi_hh.hhd.decompose.decompose`
and :func:`~taichi_hh.hhd.project.project`."""

import warnings

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import AccuracyWarning, InputError
from ..sph.pointset import check_points, check_values

#: fewer points than this are refused by decompose: the components are noise
#: (median error 100-200% on the smoothest test field, docs/notes/app.md)
MIN_POINTS = 10
#: fewer points than this are flagged: nearly every particle's kernel support
#: reaches the boundary (median error 35-70% below, 9-12% from 140 points on)
FEW_POINTS = 100


def validate_input(points, vectors, domain):
    """``(points, vectors, domain)`` checked: (N, 2) finite arrays without
    duplicates, every point inside ``domain`` (a Box, a Polygon, ``(x0, y0, x1,
    y1)``, an (M, 2) vertex array, or ``"bbox"`` / ``"hull"`` / ``"alpha"``:
    the points' bounding box (the default), convex hull or alpha shape).
    Raises :class:`~taichi_hh.errors.InputError`."""
    pts = check_points(points)
    vec = check_values(vectors, len(pts), 2, "vectors")
    if domain is None or isinstance(domain, str):
        from ..geometry.from_points import domain_from_points
        domain = domain_from_points(pts, "bbox" if domain is None else domain)
    else:
        from ..geometry.domain import as_domain
        domain = as_domain(domain)
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


def check_data_reach_boundary(ps, boundary_kind: int, fluid_kind: int) -> None:
    """Boundary particles whose kernel support holds no data point mean that the
    data stop short of the domain's boundary by more than a support (the
    boundary rows would have no data to read).  Raises
    :class:`~taichi_hh.errors.InputError` saying where, and the remedy."""
    p = ps.particles
    first = runtime.array(ti.i32, 1)
    first.fill(ps.n_total)
    n_empty = _rows_without_source(ps.n_total, ps.pairs.offsets, ps.pairs.neighbours, p.kind,
                                   int(boundary_kind), int(fluid_kind), first)
    if n_empty == 0:
        return
    n_boundary = int((p.get("kind") == boundary_kind).sum())
    where = p.get("position")[int(first.to_numpy()[0])]
    raise InputError(
        f"the data do not reach the domain's boundary: {n_empty} of {n_boundary} boundary "
        f"samples (first at ({where[0]:.4g}, {where[1]:.4g})) have no data point within the "
        f"kernel support ({ps.support:.3g} at most). Give the domain the data cover: "
        "domain='bbox' (the points' bounding box), domain='hull' (their convex hull), "
        "domain='alpha' (their alpha shape: concave outlines and gaps followed), or a "
        "Box/Polygon that fits them")
