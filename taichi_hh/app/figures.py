"""Figures of a decomposition or a projection (PNG, headless).

Only matplotlib's object API with the Agg canvas is used (``Figure`` +
``FigureCanvasAgg``): pyplot is never imported, so no interactive backend is
ever selected and no figure is kept in pyplot's registry; every file is written
atomically (:func:`taichi_hh.app.io.atomic_savefig`).

Decomposition (:func:`decomposition_figures`):

``arrows.png``      2x2 quiver panels of v, d, r, h on a spatially even
                    subsample (one point per cell of a coarse grid, ~400-900
                    arrows), one arrow scale for all four panels.
``magnitude.png``   2x2 panels: |v|, |d|, |r|, |h| interpolated linearly on
                    the Delaunay triangulation of the points (triangles outside
                    the domain masked, so holes and concave parts stay empty)
                    onto an image of :data:`IMAGE_PIXELS` pixels across, one
                    colour scale, and streamlets of each component
                    (:mod:`taichi_hh.app.streamlets`: short streamlines from
                    evenly spaced seeds, on a regular grid masked outside the
                    domain).

Critical points are marked on the d and r panels of both figures in
Petronetto et al.'s colours (2010, Fig. 15): sources green, sinks purple,
clockwise vortices blue, counter-clockwise vortices red; the marker's size
grows with the point's strength.

Scales are robust to outliers: the arrow scale and the colour scale stop at
the :data:`SCALE_PERCENTILE` th percentile of the magnitudes (a single spike
does not darken every panel; longer arrows and brighter values are clipped,
which the figure's note says).  Axes carry the coordinates' unit
(``units``, ``--units`` on the command line); a flagged h (not harmonic) is
titled so.

Projection (:func:`projection_figures`): ``projection_arrows.png`` (the field
before and after) and ``projection_measures.png`` (Colin et al.'s measures
per pass: max |div| and the sum of squared div, log scale).
"""
from __future__ import annotations

import math
import os
from collections import namedtuple
from types import SimpleNamespace

import numpy as np

from .io import atomic_savefig

#: Petronetto et al. 2010, Fig. 15
CRITICAL_STYLE = {
    "source": dict(color="#2ca02c", marker="o", label="source"),
    "sink": dict(color="#8e44ad", marker="o", label="sink"),
    "cw_vortex": dict(color="#1f4fd6", marker="s", label="clockwise vortex"),
    "ccw_vortex": dict(color="#d62728", marker="s", label="counter-clockwise vortex"),
}
COMPONENT_TITLES = {
    "v": "v (input)",
    "d": "d = grad phi (curl-free)",
    "r": "r = J grad psi (divergence-free)",
    "h": "h (harmonic)",
}
DPI = 110
#: the magnitude panels' image, pixels along the domain's longer side (an
#: image, not Gouraud-shaded triangles: 4k points' triangles took 0.25 s a
#: panel to render)
IMAGE_PIXELS = 240
#: arrow and colour scales stop at this percentile of the magnitudes shown
SCALE_PERCENTILE = 99.0
#: a critical point as the figures draw it (picklable without the numerical core)
Marker = namedtuple("Marker", "x y kind strength")
#: see :func:`draw_beside`
_beside = None


def draw_beside(helper) -> None:
    """Draw ``arrows.png`` in another process while this one draws
    ``magnitude.png`` (the persistent worker's figure helper,
    :class:`taichi_hh.app.worker.FigureHelper`; None: both here).
    ``helper(job)`` takes :func:`arrows_figure`'s arguments as a dict (plain
    arrays, an absolute path) and returns a function that waits for the file
    and raises its error, or None where it cannot take the job."""
    global _beside
    _beside = helper


def robust_top(values) -> float:
    """The :data:`SCALE_PERCENTILE` th percentile of the finite ``values``
    (0 when there are none)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    return float(np.percentile(v, SCALE_PERCENTILE)) if v.size else 0.0


def component_titles(result) -> dict:
    """The panel titles, h's saying so when the decomposition flagged it."""
    titles = dict(COMPONENT_TITLES)
    flags = (getattr(result, "stats", None) or {}).get("flags", [])
    if any("h is not harmonic" in f for f in flags):
        titles["h"] = "h (NOT harmonic: flagged, see the summary)"
    return titles


def new_figure(width, height):
    """A matplotlib Figure of ``width`` x ``height`` inches on the Agg canvas
    (no display, no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _panels_figure(domain, width: float = 11.0):
    """A figure for 2 x 2 panels of ``domain``, as tall as its aspect needs
    (a 2 x 1 window gets half the height of a square), with room for titles
    and the legend."""
    (x0, y0), (x1, y1) = np.asarray(domain.bounds, dtype=np.float64)
    aspect = min(max((y1 - y0) / max(x1 - x0, 1e-300), 0.25), 4.0)
    panel = (width - 1.2) / 2 * aspect                  # each panel's drawing height
    return new_figure(width, 2 * panel + 2.8)


def _save(fig, path):
    # compress level 1: 0.1-0.2 s less a figure than the default 6, files 0-7% larger
    # (no fig.clear() after: it took 0.1-0.2 s; the figure is freed with its last reference)
    atomic_savefig(fig, path, dpi=DPI, pil_kwargs={"compress_level": 1})


def _domain_of(points, domain):
    if domain is not None:
        return domain
    from ..geometry.domain import Box
    lo, hi = points.min(axis=0), points.max(axis=0)
    return Box(lo, hi)


def even_subsample(points, domain=None, target: int = 600) -> np.ndarray:
    """Indices of a spatially even subsample of about ``target`` points: one
    point (the one closest to the cell centre) per cell of a square grid whose
    cell area is ``domain.area / target``.  All indices when there are fewer
    points than ``target``."""
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n <= target:
        return np.arange(n)
    domain = _domain_of(points, domain)
    (x0, y0), (x1, y1) = np.asarray(domain.bounds, dtype=np.float64)
    cell = math.sqrt(domain.area / target)
    ix = np.clip(((points[:, 0] - x0) / cell).astype(np.int64), 0, None)
    iy = np.clip(((points[:, 1] - y0) / cell).astype(np.int64), 0, None)
    nx = int(ix.max()) + 1
    key = iy * nx + ix
    centre = np.c_[x0 + (ix + 0.5) * cell, y0 + (iy + 0.5) * cell]
    dist = ((points - centre) ** 2).sum(axis=1)
    order = np.lexsort((dist, key))                  # by cell, then closest first
    first = np.r_[True, key[order][1:] != key[order][:-1]]
    return np.sort(order[first])


def _draw_domain(ax, domain):
    for ring in domain.rings:
        ring = np.asarray(ring)
        closed = np.vstack([ring, ring[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="0.25", lw=0.8, zorder=3)


def setup_axes(ax, domain, title, units=None):
    """``ax`` framed on ``domain``'s bounds with a small margin, equal aspect,
    ``title``, the axes labelled with ``units`` where given, the domain's
    outline drawn."""
    (x0, y0), (x1, y1) = np.asarray(domain.bounds, dtype=np.float64)
    pad = 0.02 * max(x1 - x0, y1 - y0)
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y0 - pad, y1 + pad)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=10)
    ax.tick_params(labelsize=8)
    ax.locator_params(nbins=4)         # each tick is costly to draw: a few suffice
    suffix = f" [{units}]" if units else ""
    ax.set_xlabel(f"x{suffix}", fontsize=8)
    ax.set_ylabel(f"y{suffix}", fontsize=8)
    _draw_domain(ax, domain)


def _mark_critical(ax, critical, kinds):
    for c in critical:
        x, y, kind = c[:3]
        if kind in kinds:
            st = CRITICAL_STYLE[kind]
            strength = getattr(c, "strength", float("nan"))
            # strengths are relative to the field's robust derivative scale (its
            # 99th percentile: about 1 for the strongest structures, a peak more)
            size = 40 + 80 * min(strength, 1.5) if math.isfinite(strength) else 70
            ax.scatter([x], [y], s=size, c=st["color"], marker=st["marker"],
                       edgecolors="white", linewidths=1.2, zorder=5)


def _critical_legend(fig, critical):
    from matplotlib.lines import Line2D
    counts = {k: 0 for k in CRITICAL_STYLE}
    for c in critical:
        if c[2] in counts:
            counts[c[2]] += 1
    handles = [Line2D([], [], ls="", marker=st["marker"], color=st["color"], markersize=8,
                      markeredgecolor="white", label=f"{st['label']} ({counts[k]})")
               for k, st in CRITICAL_STYLE.items()]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=9, frameon=False,
               title="critical points (marked on d and r; size: strength)", title_fontsize=9)


def _components(result):
    return {"v": result.vectors, "d": result.curl_free, "r": result.div_free,
            "h": result.harmonic}


def _quiver(ax, pts, vec, scale, color="k"):
    ax.quiver(pts[:, 0], pts[:, 1], vec[:, 0], vec[:, 1], color=color, angles="xy",
              scale_units="xy", scale=scale, width=0.0025, headwidth=3.5, headlength=4,
              headaxislength=3.5, zorder=2)


def _arrow_scale(vectors_list, domain, n_arrows):
    """Quiver ``scale`` (vector units per data unit) so that an arrow at the
    :data:`SCALE_PERCENTILE` th percentile of all panels' lengths spans about
    1.5 sampling cells (longer ones are drawn longer: a spike does not
    shrink every other arrow to a dot)."""
    top = robust_top(np.concatenate([np.hypot(v[:, 0], v[:, 1]) for v in vectors_list]))
    cell = math.sqrt(domain.area / max(n_arrows, 1))
    return top / (1.5 * cell) if top > 0 and math.isfinite(top) else 1.0


def arrows_figure(result, domain, path, critical=(), target: int = 600, units=None) -> str:
    """2x2 quiver panels of v, d, r, h (one arrow scale); returns ``path``."""
    pts = result.points
    domain = _domain_of(pts, domain)
    idx = even_subsample(pts, domain, target)
    comps = _components(result)
    scale = _arrow_scale([c[idx] for c in comps.values()], domain, len(idx))
    fig = _panels_figure(domain)
    axes = fig.subplots(2, 2, sharex=True, sharey=True).ravel()
    titles = component_titles(result)
    for ax, (name, vec) in zip(axes, comps.items()):
        setup_axes(ax, domain, titles[name], units)
        ax.label_outer()                 # shared axes: labels on the outer panels only
        _quiver(ax, pts[idx], vec[idx], scale)
        if name == "d":
            _mark_critical(ax, critical, ("source", "sink"))
        elif name == "r":
            _mark_critical(ax, critical, ("cw_vortex", "ccw_vortex"))
    fig.suptitle(f"Helmholtz-Hodge decomposition: {len(idx)} of {len(pts)} points shown, "
                 f"common arrow scale (1.5 cells at the {SCALE_PERCENTILE:g}th percentile of "
                 f"|v|, |d|, |r|, |h|)", fontsize=11)
    _critical_legend(fig, critical)
    _adjust(fig, right=0.98)
    _save(fig, path)
    return path


def _adjust(fig, right):
    """Margins in inches (titles, labels, the legend) whatever the figure's height."""
    h = fig.get_figheight()
    fig.subplots_adjust(left=0.07, right=right, top=1 - 0.6 / h, bottom=1.1 / h, wspace=0.18,
                        hspace=0.45 / (0.5 * h - 0.85))


def masked_triangulation(points, domain):
    """Delaunay triangulation of ``points`` with the triangles outside ``domain``
    masked (centroid or an edge midpoint outside)."""
    from matplotlib.tri import Triangulation
    tri = Triangulation(points[:, 0], points[:, 1])
    t = tri.triangles
    p = points[t]                                          # (T, 3, 2)
    probes = [p.mean(axis=1)] + [(p[:, k] + p[:, (k + 1) % 3]) / 2 for k in range(3)]
    scale = float(np.max(np.abs(np.asarray(domain.bounds)))) or 1.0
    inside = np.ones(len(t), dtype=bool)
    for q in probes:
        inside &= domain.contains(q, tol=1e-9 * scale)
    tri.set_mask(~inside)
    return tri


def linear_on(tri, X, Y):
    """A function taking values at ``tri``'s points to their linear
    interpolant at the points (X, Y), masked outside the (unmasked)
    triangles: matplotlib's ``LinearTriInterpolator`` with the triangles
    found once for all the fields."""
    where = tri.get_trifinder()(X, Y)
    inside = where >= 0
    corners = tri.triangles[where[inside]]
    x, y = tri.x[corners], tri.y[corners]                     # (M, 3)
    px, py = np.asarray(X, dtype=np.float64)[inside], np.asarray(Y, dtype=np.float64)[inside]
    det = (y[:, 1] - y[:, 2]) * (x[:, 0] - x[:, 2]) + (x[:, 2] - x[:, 1]) * (y[:, 0] - y[:, 2])
    l0 = ((y[:, 1] - y[:, 2]) * (px - x[:, 2]) + (x[:, 2] - x[:, 1]) * (py - y[:, 2])) / det
    l1 = ((y[:, 2] - y[:, 0]) * (px - x[:, 2]) + (x[:, 0] - x[:, 2]) * (py - y[:, 2])) / det
    weights = np.stack([l0, l1, 1.0 - l0 - l1], axis=1)

    def at(values):
        out = np.zeros(np.shape(X))
        out[inside] = (weights * np.asarray(values, dtype=np.float64)[corners]).sum(axis=1)
        return np.ma.masked_array(out, mask=~inside)
    return at


def _grid(domain, n: int = 90):
    (x0, y0), (x1, y1) = np.asarray(domain.bounds, dtype=np.float64)
    span = max(x1 - x0, y1 - y0)
    nx = max(8, int(round(n * (x1 - x0) / span)))
    ny = max(8, int(round(n * (y1 - y0) / span)))
    return np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)


def magnitude_figure(result, domain, path, critical=(), units=None) -> str:
    """2x2 panels of |v|, |d|, |r|, |h| (one colour scale) with streamlets;
    returns ``path``."""
    from . import streamlets
    pts = result.points
    domain = _domain_of(pts, domain)
    tri = masked_triangulation(pts, domain)
    gx, gy = _grid(domain)
    X, Y = np.meshgrid(gx, gy)
    outside = ~domain.contains(np.c_[X.ravel(), Y.ravel()]).reshape(X.shape)
    ix, iy = _grid(domain, IMAGE_PIXELS)
    IX, IY = np.meshgrid(ix, iy)
    image_outside = ~domain.contains(np.c_[IX.ravel(), IY.ravel()]).reshape(IX.shape)
    on_image, on_grid = linear_on(tri, IX, IY), linear_on(tri, X, Y)
    comps = _components(result)
    mags = {k: np.hypot(v[:, 0], v[:, 1]) for k, v in comps.items()}
    vmax = robust_top(np.concatenate(list(mags.values()))) or 1.0
    fig = _panels_figure(domain)
    axes = fig.subplots(2, 2, sharex=True, sharey=True).ravel()
    image = None
    titles = component_titles(result)
    (x0, y0), (x1, y1) = np.asarray(domain.bounds, dtype=np.float64)
    for ax, (name, vec) in zip(axes, comps.items()):
        setup_axes(ax, domain, f"|{name}|, {titles[name]}", units)
        ax.label_outer()                 # shared axes: labels on the outer panels only
        mag = on_image(mags[name])
        mag = np.ma.masked_array(mag, mask=np.ma.getmaskarray(mag) | image_outside)
        image = ax.imshow(mag, origin="lower", extent=(x0, x1, y0, y1), cmap="viridis",
                          vmin=0.0, vmax=vmax, interpolation="bilinear", zorder=1,
                          aspect="auto")
        ax.set_aspect("equal")
        # streamlets need directions only: in units of vmax, nothing squares
        # a field of 1e200 into overflow
        U, V = on_grid(vec[:, 0] / vmax), on_grid(vec[:, 1] / vmax)
        U = np.ma.masked_array(U, mask=np.ma.getmaskarray(U) | outside)
        V = np.ma.masked_array(V, mask=np.ma.getmaskarray(V) | outside)
        streamlets.draw(ax, gx, gy, U, V, color="white", linewidth=0.6, zorder=2)
        if name == "d":
            _mark_critical(ax, critical, ("source", "sink"))
        elif name == "r":
            _mark_critical(ax, critical, ("cw_vortex", "ccw_vortex"))
    _adjust(fig, right=0.88)
    cax = fig.add_axes([0.9, 0.2, 0.02, 0.6])
    fig.colorbar(image, cax=cax, extend="max",
                 label=f"magnitude (clipped at the {SCALE_PERCENTILE:g}th percentile)")
    fig.suptitle("Magnitudes and streamlets", fontsize=11)
    _critical_legend(fig, critical)
    _save(fig, path)
    return path


def decomposition_figures(result, domain, out_dir, critical=None,
                          threshold: float = 0.1, units=None) -> list[str]:
    """Write ``arrows.png`` and ``magnitude.png`` into ``out_dir``; returns the paths.
    critical: ``[(x, y, kind)]``; default ``result.critical_points(threshold)``.
    units: the coordinates' unit, for the axis labels (e.g. ``"mm"``)."""
    if critical is None:
        critical = result.critical_points(threshold=threshold)
    if hasattr(result, "valid_rows"):
        result = result.valid_rows()          # missing rows (NaN) are not drawn
    arrows = os.path.join(out_dir, "arrows.png")
    wait = None if _beside is None else _beside(dict(
        result=SimpleNamespace(points=result.points, vectors=result.vectors,
                               curl_free=result.curl_free, div_free=result.div_free,
                               harmonic=result.harmonic,
                               stats={"flags": list((result.stats or {}).get("flags", []))}),
        domain=domain, path=os.path.abspath(arrows), units=units, umask=_umask(),
        critical=[Marker(c[0], c[1], c[2], getattr(c, "strength", float("nan")))
                  for c in critical]))
    if wait is None:
        arrows_figure(result, domain, arrows, critical, units=units)
    try:
        magnitude = magnitude_figure(result, domain, os.path.join(out_dir, "magnitude.png"),
                                     critical, units=units)
    finally:
        if wait is not None:
            wait()
    return [arrows, magnitude]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def projection_figures(result, domain, out_dir, target: int = 600) -> list[str]:
    """Write ``projection_arrows.png`` (before/after) and ``projection_measures.png``
    (max |div| and sum of squared div per pass, log scale); returns the paths."""
    pts = result.points
    domain = _domain_of(pts, domain)
    idx = even_subsample(pts, domain, target)
    before, after = result.initial[idx], result.vectors[idx]
    scale = _arrow_scale([before, after], domain, len(idx))
    fig = new_figure(11, 5.8)
    axes = fig.subplots(1, 2)
    passes = len(result.max_divergence) - 1
    for ax, vec, title in ((axes[0], before, "before"),
                           (axes[1], after, f"after {passes} projection pass{'' if passes == 1 else 'es'}")):
        setup_axes(ax, domain, title)
        _quiver(ax, pts[idx], vec, scale)
    fig.suptitle(f"Null-divergence projection: {len(idx)} of {len(pts)} points shown, "
                 f"common arrow scale", fontsize=11)
    fig.subplots_adjust(left=0.06, right=0.98, top=0.88, bottom=0.08, wspace=0.15)
    p_arrows = os.path.join(out_dir, "projection_arrows.png")
    _save(fig, p_arrows)

    fig = new_figure(6.5, 4.5)
    ax = fig.subplots()
    k = np.arange(passes + 1)
    for values, label, style in ((result.max_divergence, "max |div|", "o-"),
                                 (result.sum_sq_divergence, "sum of div^2", "s--")):
        values = np.asarray(values, dtype=np.float64)
        ok = values > 0
        ax.semilogy(k[ok], values[ok], style, label=label)
    ax.set_xlabel("projection pass (0 = input)")
    ax.set_ylabel("divergence measure")
    ax.set_xticks(k)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title("Colin et al.'s divergence measures per pass", fontsize=10)
    fig.tight_layout()
    p_measures = os.path.join(out_dir, "projection_measures.png")
    _save(fig, p_measures)
    return [p_arrows, p_measures]
