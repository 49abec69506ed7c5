"""Streamlets: short streamlines from evenly spaced seeds, traced all at once.

matplotlib's ``streamplot`` traces one streamline at a time in Python (with a
mask that keeps them apart): 0.4-0.6 s a panel at its default density, most of
a decomposition's figures.  Here every seed moves together, one numpy step for
all of them (the midpoint rule on the unit direction field, bilinear on the
grid), a fixed arc length forward and backward; the lines are drawn as one
``LineCollection`` with one arrowhead each (a ``PolyCollection``).  Lines from
neighbouring seeds may run close where the flow converges: the seeds, not a
mask, keep them apart.
"""
from __future__ import annotations

import numpy as np

#: seeds along the longer side of the grid
SEEDS = 22
#: each streamlet's arc length forward and backward, in seed spacings
HALF_LENGTH = 0.8
#: steps of each half
STEPS = 12


def _bilinear(gx, gy, field, x, y):
    """``field`` (ny, nx) at the points (x, y) of the grid's box, bilinear."""
    fx = np.clip((x - gx[0]) / (gx[-1] - gx[0]) * (len(gx) - 1), 0.0, len(gx) - 1.000001)
    fy = np.clip((y - gy[0]) / (gy[-1] - gy[0]) * (len(gy) - 1), 0.0, len(gy) - 1.000001)
    i, j = fx.astype(np.int64), fy.astype(np.int64)
    a, b = fx - i, fy - j
    return ((1 - a) * (1 - b) * field[j, i] + a * (1 - b) * field[j, i + 1]
            + (1 - a) * b * field[j + 1, i] + a * b * field[j + 1, i + 1])


def trace(gx, gy, U, V, seeds: int = SEEDS, half_length: float = HALF_LENGTH,
          steps: int = STEPS):
    """Streamlets of the field (U, V) on the regular grid ``gx`` x ``gy``
    (masked arrays, shape (ny, nx); masked nodes are outside the data).

    Returns ``(lines, heads)``: ``lines`` (S, 2 * steps + 1, 2), each seed's
    path from its backward end through the seed to its forward end (a path
    that leaves the data or reaches a node without flow stops there: its
    remaining points repeat the last); ``heads`` (S, 2, 2), each forward end
    and the unit direction there.  Only seeds inside the data where the
    field is not nil are traced."""
    gx, gy = np.asarray(gx, dtype=np.float64), np.asarray(gy, dtype=np.float64)
    mask = np.ma.getmaskarray(U) | np.ma.getmaskarray(V)
    u = np.where(mask, 0.0, np.ma.getdata(U)).astype(np.float64)
    v = np.where(mask, 0.0, np.ma.getdata(V)).astype(np.float64)
    speed = np.hypot(u, v)
    top = float(speed.max()) if speed.size else 0.0
    if not np.isfinite(top) or top <= 0:
        return np.empty((0, 2 * steps + 1, 2)), np.empty((0, 2, 2))
    # unit directions; a node without flow (or outside) stops a streamlet
    still = mask | (speed <= 1e-6 * top) | ~np.isfinite(speed)
    with np.errstate(invalid="ignore", divide="ignore"):
        du = np.where(still, 0.0, u / np.where(still, 1.0, speed))
        dv = np.where(still, 0.0, v / np.where(still, 1.0, speed))
    inside = (~still).astype(np.float64)
    width, height = gx[-1] - gx[0], gy[-1] - gy[0]
    spacing = max(width, height) / seeds
    nsx, nsy = max(1, int(round(width / spacing))), max(1, int(round(height / spacing)))
    sx = gx[0] + (np.arange(nsx) + 0.5) * width / nsx
    sy = gy[0] + (np.arange(nsy) + 0.5) * height / nsy
    SX, SY = np.meshgrid(sx, sy)
    x0, y0 = SX.ravel(), SY.ravel()
    keep = _bilinear(gx, gy, inside, x0, y0) > 0.999       # all four nodes in the data
    x0, y0 = x0[keep], y0[keep]
    h = half_length * spacing / steps

    def half(sign):
        x, y = x0.copy(), y0.copy()
        alive = np.ones(len(x), dtype=bool)
        path = [np.c_[x, y]]
        last = np.c_[np.zeros_like(x), np.zeros_like(y)]
        for _ in range(steps):
            ax_, ay_ = _bilinear(gx, gy, du, x, y), _bilinear(gx, gy, dv, x, y)
            mx, my = x + 0.5 * sign * h * ax_, y + 0.5 * sign * h * ay_
            bx, by = _bilinear(gx, gy, du, mx, my), _bilinear(gx, gy, dv, mx, my)
            norm = np.hypot(bx, by)
            nx_, ny_ = x + sign * h * bx / np.where(norm > 0, norm, 1.0), \
                y + sign * h * by / np.where(norm > 0, norm, 1.0)
            ok = alive & (norm > 0.5) & (_bilinear(gx, gy, inside, nx_, ny_) > 0.999) \
                & (nx_ >= gx[0]) & (nx_ <= gx[-1]) & (ny_ >= gy[0]) & (ny_ <= gy[-1])
            x, y = np.where(ok, nx_, x), np.where(ok, ny_, y)
            last = np.where(ok[:, None], np.c_[sign * bx, sign * by] /
                            np.where(norm > 0, norm, 1.0)[:, None], last)
            alive = ok
            path.append(np.c_[x, y])
        return np.stack(path, axis=1), last

    back, _ = half(-1.0)
    fore, direction = half(1.0)
    lines = np.concatenate([back[:, ::-1], fore[:, 1:]], axis=1)
    moved = np.hypot(*(fore[:, -1] - fore[:, 0]).T) > 0.25 * h
    heads = np.stack([fore[:, -1], direction], axis=1)[moved]
    return lines, heads


def draw(ax, gx, gy, U, V, color="white", linewidth=0.6, zorder=2, **options) -> int:
    """Streamlets of (U, V) on ``ax`` (:func:`trace`'s options); returns how
    many were drawn."""
    from matplotlib.collections import LineCollection, PolyCollection
    lines, heads = trace(gx, gy, U, V, **options)
    if not len(lines):
        return 0
    ax.add_collection(LineCollection(lines, colors=color, linewidths=linewidth,
                                     zorder=zorder, capstyle="round"))
    if len(heads):
        width, height = gx[-1] - gx[0], gy[-1] - gy[0]
        size = 0.22 * max(width, height) / options.get("seeds", SEEDS)
        tip, d = heads[:, 0], heads[:, 1]
        n = np.c_[-d[:, 1], d[:, 0]]
        base = tip - size * d
        tri = np.stack([tip, base + 0.45 * size * n, base - 0.45 * size * n], axis=1)
        ax.add_collection(PolyCollection(tri, facecolors=color, edgecolors="none",
                                         zorder=zorder))
    return len(lines)
