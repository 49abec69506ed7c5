"""Wall particles on a lattice around a box (Colin et al. 2006 Sec. 3.6, Fig. 4)."""
import math

import numpy as np


def box_wall_lattice(lo, hi, spacing: float, width: float, *, closed: bool = False) -> np.ndarray:
    """(M, 2) points of the box's particle lattice continued outward: the cell
    centres ``lo + (i + 1/2) (hi - lo) / n`` (n = the box size over ``spacing``,
    rounded) that lie outside the box ``[lo, hi]`` within distance ``width`` of
    it (``< width``, or ``<= width`` when ``closed``), row by row from the
    bottom (y outer, x inner).  A wall layer as wide as the kernel support keeps
    the fluid rows' neighbourhoods full (Colin Sec. 3.6)."""
    x0, y0 = (float(c) for c in lo)
    x1, y1 = (float(c) for c in hi)
    k = int(math.ceil(width / spacing)) + 1
    nx = max(int(round((x1 - x0) / spacing)), 1)
    ny = max(int(round((y1 - y0) / spacing)), 1)
    gx = x0 + (np.arange(-k, nx + k) + 0.5) * (x1 - x0) / nx
    gy = y0 + (np.arange(-k, ny + k) + 0.5) * (y1 - y0) / ny
    P = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    inside = (P[:, 0] > x0) & (P[:, 0] < x1) & (P[:, 1] > y0) & (P[:, 1] < y1)
    P = P[~inside]
    d = np.linalg.norm(P - np.clip(P, [x0, y0], [x1, y1]), axis=1)
    return P[d <= width] if closed else P[d < width]
