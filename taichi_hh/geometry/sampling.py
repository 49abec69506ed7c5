"""Samplers that fill a domain and its surroundings with particles.

* :func:`sample_boundary`: boundary particles with outward normals, equally
  spaced by arc length between sharp corners (Colin et al. 2006, Sec. 3.4-3.6);
* :func:`sample_ghosts`: Poisson-disk "fake" particles in a band outside the
  domain (Petronetto et al. 2010, Sec. 5b);
* :func:`mirror_across_segments`: mirror ghosts of interior particles;
* :func:`sample_interior`: interior points as blue noise, a jittered lattice
  or uniform random points, for a spacing or a wanted count.

They work on any domain through its public geometry: ``area``,
``perimeter``, ``bounds``, ``rings``, ``boundary_tolerance``,
``segment_table``, ``closest_boundary``, ``contains``, ``classify_discs`` and
``locator`` (see :class:`~taichi_hh.geometry.polygon.Polygon`).  Every sampler
is deterministic for a given seed.
"""
from __future__ import annotations

import math
from numbers import Integral

import numpy as np

from ..checks import check_points, check_real, check_seed
from ..errors import InputError
from .poisson_disk import MAX_CELLS, poisson_disk

__all__ = ["sample_boundary", "sample_ghosts", "mirror_across_segments", "mirror_points",
           "sample_interior", "DEFAULT_CORNER_ANGLE", "POISSON_ALPHA", "POISSON_BETA",
           "MAX_POINTS"]

#: boundary vertices turning by more than this (degrees) are always sampled
DEFAULT_CORNER_ANGLE = 10.0
#: blue-noise density: a maximal Poisson-disk sample of radius r in a region of
#: area A and perimeter P holds about ALPHA * (A + BETA * P * r) / r**2 points
#: (points can sit right at the edge, so the boundary adds a little); measured,
#: see docs/notes/geometry.md
POISSON_ALPHA = 0.633
POISSON_BETA = 0.18
#: refuse samples larger than this many points
MAX_POINTS = 5e7
#: a local spacing (``spacing_at`` of :func:`sample_boundary`) is evaluated at
#: most this many times along a boundary: every quarter spacing up to 2^18
#: samples at the mean spacing (a square holding 4e9 points), coarser beyond.
#: A boundary far longer than the spacing (a domain as thin as a line) once
#: asked for 2.6e7 evaluations, each a k-nearest search: minutes to hours
MAX_SPACING_EVALUATIONS = 2 ** 20


# --------------------------------------------------------------------------- boundary
def sample_boundary(domain, spacing: float, corner_angle: float = DEFAULT_CORNER_ANGLE,
                    spacing_at=None):
    """``(points, normals, piece)`` along every ring of ``domain`` (see
    :meth:`Polygon.sample_boundary <taichi_hh.geometry.polygon.Polygon.sample_boundary>`).
    spacing_at: optional ``f(points) -> spacings`` (M, 2) -> (M,): the samples
    follow that local spacing instead, evaluated every ``spacing / 4`` along
    the boundary (so ``spacing`` is the finest resolved), or at most
    :data:`MAX_SPACING_EVALUATIONS` times (evenly) along all of it."""
    spacing = check_real(spacing, "spacing")
    corner_angle = check_real(corner_angle, "corner_angle", allow_zero=True)
    if corner_angle >= 180.0:
        raise InputError(f"corner_angle must be below 180 degrees, got {corner_angle}")
    fine = spacing
    if spacing_at is not None:
        fine = max(spacing / 4, domain.perimeter / MAX_SPACING_EVALUATIONS)
    if domain.perimeter / fine > MAX_POINTS:
        raise InputError(f"spacing {spacing:g} is too small for a boundary {domain.perimeter:g} "
                         f"long: it would give more than 5e7 boundary points")
    segs = domain.segment_table
    pts, nrm, pieces = [], [], []
    thresh = math.radians(corner_angle)
    for k in range(len(domain.rings)):
        s0, s1 = segs.ring_start[k], segs.ring_start[k + 1]
        m = s1 - s0
        seglen = np.sqrt(1.0 / segs.inv_len2[s0:s1])
        cum = np.concatenate([[0.0], np.cumsum(seglen)])     # arc length at vertex j
        total = cum[-1]
        corners = np.flatnonzero(segs.turn[s0:s1] > thresh) if corner_angle > 0 \
            else np.arange(m)
        if corners.size == 0:
            corners = np.array([0])
        # arcs between consecutive corners (cyclic)
        a_start = cum[corners]
        a_len = np.diff(np.concatenate([a_start, [a_start[0] + total]]))

        def on_ring(arc):
            """points, normals and "at a vertex" at arc positions of this ring"""
            arc = np.where(arc >= total, arc - total, arc)
            seg = np.clip(np.searchsorted(cum, arc, side="right") - 1, 0, m - 1)
            t = (arc - cum[seg]) / seglen[seg]
            g = s0 + seg
            return segs.starts[g] + t[:, None] * segs.direction[g], seg, t

        if spacing_at is None:
            nsub = np.maximum(1, np.ceil(a_len / spacing * (1 - 1e-12)).astype(np.int64))
            owner = np.repeat(np.arange(corners.size), nsub)
            j = np.arange(nsub.sum()) - np.repeat(np.cumsum(nsub) - nsub, nsub)
            arc = a_start[owner] + a_len[owner] * j / nsub[owner]
        else:
            # per arc: the number of local spacings it spans, cumulated at fine
            # steps (trapezoids of 1 / spacing_at); samples where it crosses
            # equal shares of its total
            # (1 - 1e-12): an arc a whole number of fine steps long (a lattice's
            # bounding box) keeps its count under rounding, as nsub below does
            nfine = np.maximum(1, np.ceil(a_len / fine * (1 - 1e-12))).astype(np.int64)
            owner_f = np.repeat(np.arange(corners.size), nfine + 1)
            i_f = np.arange(owner_f.size) - np.repeat(np.cumsum(nfine + 1) - (nfine + 1), nfine + 1)
            arc_f = a_start[owner_f] + a_len[owner_f] * i_f / nfine[owner_f]
            local = np.asarray(spacing_at(on_ring(arc_f)[0]), dtype=np.float64)
            if local.shape != arc_f.shape or not (np.isfinite(local) & (local > 0)).all():
                # (the decomposition's spacing_at refuses copies of a point, where
                # the data's local spacing is zero, itself: hhd.boundary)
                raise InputError(f"spacing_at must give one positive finite spacing per "
                                 f"position along the boundary: {arc_f.shape} wanted, got "
                                 f"shape {local.shape}, smallest {np.min(local, initial=np.inf):g}")
            rate = 1.0 / np.maximum(local, fine)
            # the count cumulated along the whole ring (no increment across an
            # arc's end, where the next arc starts at the same position): one
            # interpolation places every arc's samples, no loop over arcs
            same = owner_f[1:] == owner_f[:-1]
            step = np.where(same, 0.5 * (rate[1:] + rate[:-1]) * np.diff(arc_f), 0.0)
            count = np.concatenate([[0.0], np.cumsum(step)])
            first = np.cumsum(nfine + 1) - (nfine + 1)
            base = count[first]
            total_a = count[first + nfine] - base
            nsub = np.maximum(1, np.ceil(total_a * (1 - 1e-12)).astype(np.int64))
            owner = np.repeat(np.arange(corners.size), nsub)
            j = np.arange(nsub.sum()) - np.repeat(np.cumsum(nsub) - nsub, nsub)
            want = base[owner] + total_a[owner] * j / nsub[owner]
            # within arc a, interpolate on its own fine points only (the join's
            # duplicate count value belongs to both neighbours)
            pos = np.searchsorted(count, want, side="right") - 1
            pos = np.clip(pos, first[owner], first[owner] + nfine[owner] - 1)
            c0, c1 = count[pos], count[pos + 1]
            frac = np.where(c1 > c0, (want - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.0)
            arc = arc_f[pos] + frac * (arc_f[pos + 1] - arc_f[pos])
        p, seg, t = on_ring(arc)
        # snap to vertices where the arc position is (numerically) one
        at_start = (j == 0) | (t <= 1e-12)
        at_end = ~at_start & (t >= 1 - 1e-12)
        g = s0 + seg
        n = segs.normal[g].copy()
        p[at_start] = segs.starts[g[at_start]]
        n[at_start] = segs.vertex_normal_start[g[at_start]]
        p[at_end] = segs.ends[g[at_end]]
        n[at_end] = segs.vertex_normal_end[g[at_end]]
        pts.append(p)
        nrm.append(n)
        pieces.append(np.full(len(p), k, dtype=np.int64))
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(pieces)


# --------------------------------------------------------------------------- ghosts
def sample_ghosts(domain, spacing: float, width: float, seed=0, avoid=None) -> np.ndarray:
    """(G, 2) Poisson-disk points with ``0 < signed_distance <= width`` (see
    :meth:`Polygon.sample_ghosts <taichi_hh.geometry.polygon.Polygon.sample_ghosts>`)."""
    spacing = check_real(spacing, "spacing")
    width = check_real(width, "width")
    rng = check_seed(seed)
    av = None if avoid is None else check_points(avoid, "avoid", allow_empty=True)
    return poisson_disk(domain, spacing, domain.boundary_tolerance, width, rng, avoid=av)


def mirror_points(domain, points, width):
    """Validated ``(points, width)`` for a mirror sampler: the points must lie in
    the domain (or on its boundary)."""
    p = check_points(points, allow_empty=True)
    width = check_real(width, "width")
    outside = ~domain.contains(p)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise InputError(f"points must lie in the domain to be mirrored: {int(outside.sum())} "
                         f"do not, first at index {k}: {p[k].tolist()}")
    return p, width


def mirror_across_segments(domain, points, width: float):
    """``(ghosts, source)``: interior points within ``width`` of the boundary
    reflected across the line of their closest segment, keeping the images
    that land strictly outside the domain."""
    p, width = mirror_points(domain, points, width)
    eps = domain.boundary_tolerance
    segs = domain.segment_table
    dist, _, _, seg = domain.closest_boundary(p)
    sel = np.flatnonzero((dist <= width) & (dist > eps))
    s = segs.starts[seg[sel]]
    n = segs.normal[seg[sel]]
    off = np.einsum("ij,ij->i", p[sel] - s, n)
    g = p[sel] - 2.0 * off[:, None] * n
    keep = domain.classify_discs(g, 0.0, eps, np.inf) == 1
    return g[keep], sel[keep]


# --------------------------------------------------------------------------- interior
def sample_interior(domain, n_or_spacing, kind: str = "poisson", seed=0, *,
                    jitter: float = 0.5, margin: float = 0.0) -> np.ndarray:
    """(N, 2) points strictly inside ``domain`` (see
    :meth:`Polygon.sample_interior <taichi_hh.geometry.polygon.Polygon.sample_interior>`)."""
    if kind not in ("poisson", "jittered", "random"):
        raise InputError(f"kind must be 'poisson', 'jittered' or 'random', got {kind!r}")
    rng = check_seed(seed)
    jitter = check_real(jitter, "jitter", allow_zero=True)
    if jitter > 1.0:
        raise InputError(f"jitter must be in [0, 1], got {jitter}")
    margin = check_real(margin, "margin", allow_zero=True)
    count, spacing = _count_or_spacing(n_or_spacing)
    hi = -max(margin, domain.boundary_tolerance)
    avail = _available_area(domain, margin)
    if kind == "random":
        if count is None:
            count = max(1, int(round(avail / spacing ** 2)))
            if count > MAX_POINTS:
                raise InputError(f"spacing {spacing:g} is too small: it would give {count:.3g} "
                                 f"points (limit 5e7)")
        return _random_inside(domain, count, hi, rng)
    if kind == "jittered":
        if count is not None:
            state = rng.bit_generator.state
            return _calibrate(lambda h: _jittered(domain, h, jitter, hi, _rng_from(state)),
                              math.sqrt(avail / count), count)
        return _jittered(domain, spacing, jitter, hi, _rng_from(rng.bit_generator.state))
    # poisson
    if count is not None:
        # solve count = ALPHA (avail + BETA P r) / r^2 for x = 1 / r
        qa, qb = POISSON_ALPHA * avail, POISSON_ALPHA * POISSON_BETA * domain.perimeter
        r0 = 2.0 * qa / (-qb + math.sqrt(qb * qb + 4.0 * qa * count))
        state = rng.bit_generator.state
        return _calibrate(lambda r: poisson_disk(domain, r, -np.inf, hi, _rng_from(state)),
                          r0, count)
    return poisson_disk(domain, spacing, -np.inf, hi, rng)


def _count_or_spacing(n_or_spacing):
    """``(count, None)`` for an integer, ``(None, spacing)`` for a real number."""
    if isinstance(n_or_spacing, (bool, np.bool_)):
        raise InputError(f"n_or_spacing must be a point count (int) or a spacing (float), "
                         f"got {n_or_spacing!r}")
    if isinstance(n_or_spacing, Integral):
        count = int(n_or_spacing)
        if count < 1:
            raise InputError(f"the number of points must be at least 1, got {count}")
        if count > MAX_POINTS:
            raise InputError(f"{count} points is more than this sampler supports (5e7)")
        return count, None
    return None, check_real(n_or_spacing, "spacing")


def _available_area(domain, margin: float) -> float:
    """Area left to the points: the domain minus a ``margin`` strip along the
    boundary (at least 1e-3 of the area); refuses margins deeper than the domain."""
    avail = domain.area - margin * domain.perimeter
    if margin > 0:
        loc = domain.locator()
        depth = -float(loc.sd.min()) + loc.half_diag     # upper bound on the inradius
        if margin >= depth:
            raise InputError(f"margin {margin:g} leaves no room inside the domain "
                             f"(no point is farther than {depth:.6g} from the boundary)")
    return max(avail, 1e-3 * domain.area)


def _rng_from(state):
    """A fresh Generator in the given bit-generator state (to replay a stream)."""
    g = np.random.default_rng()
    g.bit_generator.state = state
    return g


def _calibrate(make, size0: float, count: int):
    """Run ``make(size)`` and rescale size until the point count is near ``count``."""
    size = size0
    best = None
    for _ in range(3):
        pts = make(size)
        if best is None or abs(len(pts) - count) < abs(len(best) - count):
            best = pts
        if len(pts) == 0:
            size *= 0.5
            continue
        ratio = len(pts) / count
        if abs(ratio - 1.0) <= 0.03:
            break
        size *= math.sqrt(ratio)
    return best


def _random_inside(domain, count: int, hi: float, rng) -> np.ndarray:
    """``count`` uniform points with signed distance <= ``hi`` (rejection sampling)."""
    lo_b, hi_b = (np.array(b) for b in domain.bounds)
    frac = max(domain.area / float(np.prod(hi_b - lo_b)), 1e-6)
    out, have = [], 0
    for _ in range(1000):
        m = int(1.2 * (count - have) / frac) + 16
        cand = lo_b + rng.random((m, 2)) * (hi_b - lo_b)
        cand = cand[domain.classify_discs(cand, 0.0, -np.inf, hi) == 1]
        out.append(cand[: count - have])
        have += len(out[-1])
        if have >= count:
            return np.concatenate(out)
    raise InputError("could not place the random points: the domain (minus the margin) "
                     "is too thin")


def _jittered(domain, h: float, jitter: float, hi: float, rng) -> np.ndarray:
    """Square lattice of step ``h`` centred in the bounds, each point moved
    uniformly within ``jitter * h``; the points with signed distance <= ``hi``."""
    lo_b, hi_b = (np.array(b) for b in domain.bounds)
    ncell = float(np.prod(hi_b - lo_b)) / (h * h)
    if ncell > MAX_CELLS:
        raise InputError(f"the lattice step is too small for this domain: sampling would need "
                         f"{ncell:.3g} grid cells (limit {MAX_CELLS:.0e})")
    span = hi_b - lo_b
    nxy = np.maximum(1, np.floor(span / h + 1e-9).astype(np.int64))
    off = lo_b + 0.5 * (span - (nxy - 1) * h)        # lattice centred in the bounds
    ix, iy = np.meshgrid(np.arange(nxy[0]), np.arange(nxy[1]))
    pts = off + h * np.stack([ix.ravel(), iy.ravel()], axis=1).astype(np.float64)
    if jitter > 0:
        pts += jitter * h * (rng.random(pts.shape) - 0.5)
    return pts[domain.classify_discs(pts, 0.0, -np.inf, hi) == 1]
