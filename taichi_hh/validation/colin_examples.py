"""The five test velocity fields of Colin, Egli & Lin 2006 (Sec. 4, Table 1).

Unit square inside a layer of wall particles at rest; example 1: 2000 inside
particles (a 45 x 45 = 2025 lattice here), support h = 1/9, velocity (0.5, 0)
in the central 0.2 x 0.2 square, zero elsewhere; examples 2-5: 19 x 19 = 361
inside particles, h = 1/5: (2) (0.5, 0) at the centre, (3) (0.2, 0.2) at the
lower-left corner and (0, 0.2) at the upper-right, (4) (0.2, 0) lower-left and
(0, -0.2) upper-right, (5) the rigid rotation (0.25 (y - 0.5), 0.25 (0.5 - x)).
Where the text leaves the extent of "at the centre" or "at the corner" open we
take the central 0.2 x 0.2 square and the 0.2 x 0.2 corner squares, as in
example 1.

Table 1 (max |div| and sum of squared div, initial state then after each of 5
projections) is :data:`TABLE1`; :func:`colin_divergence` is the divergence it
reports (their Eq. 33, wall particles at rest included).

Example 1 reproduces the published initial measures; examples 2-5 do not, so
their published setup differs from the text in some unstated way (the
measurements are in ``benchmarks/colin_table1.py``).
"""
import numpy as np

TABLE1 = {
    1: {"max": [5.32, 1.78, 0.93, 0.63, 0.53, 0.46],
        "sum_sq": [1250.48, 108.01, 33.95, 17.93, 11.13, 7.46]},
    2: {"max": [1.43, 0.59, 0.34, 0.23, 0.17, 0.14],
        "sum_sq": [45.66, 7.44, 2.10, 0.85, 0.48, 0.37]},
    3: {"max": [1.06, 0.49, 0.28, 0.17, 0.14, 0.13],
        "sum_sq": [25.97, 4.04, 1.25, 0.59, 0.38, 0.31]},
    4: {"max": [0.50, 0.32, 0.23, 0.20, 0.22, 0.22],
        "sum_sq": [8.42, 2.71, 1.33, 0.83, 0.59, 0.48]},
    5: {"max": [2.81, 1.37, 0.76, 0.52, 0.39, 0.32],
        "sum_sq": [82.61, 15.47, 5.19, 2.45, 1.53, 1.18]},
}


def example(k: int):
    """(points, velocities, support) of Colin's example k (1-5)."""
    if k not in TABLE1:
        raise ValueError(f"Colin's examples are 1-5, got {k}")
    m, support = (45, 1.0 / 9.0) if k == 1 else (19, 1.0 / 5.0)
    g = (np.arange(m) + 0.5) / m
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    x, y = pts.T
    v = np.zeros_like(pts)
    centre = (np.abs(x - 0.5) <= 0.1) & (np.abs(y - 0.5) <= 0.1)
    lower_left = (x <= 0.2) & (y <= 0.2)
    upper_right = (x >= 0.8) & (y >= 0.8)
    if k in (1, 2):
        v[centre] = (0.5, 0.0)
    elif k == 3:
        v[lower_left] = (0.2, 0.2)
        v[upper_right] = (0.0, 0.2)
    elif k == 4:
        v[lower_left] = (0.2, 0.0)
        v[upper_right] = (0.0, -0.2)
    else:
        v = np.c_[0.25 * (y - 0.5), 0.25 * (0.5 - x)]
    return pts, v, support


def colin_divergence(points, vectors, support, domain=None, spacing=None):
    """Colin's Eq. 33 at ``points``: DGAF (Eq. 13) with poly6 of support
    ``support``, summed over the points and a lattice layer of wall particles at
    rest as wide as the support (Sec. 3.6), i.e. the divergence their Table 1
    reports.  ``domain`` defaults to the unit square; ``spacing`` to
    ``sqrt(area / N)``."""
    import math
    from ..geometry.domain import Box
    from ..sph.particles import BOUNDARY, FLUID
    from ..sph.pointset import PointSet
    from ..hhd.project import wall_layer
    domain = domain or Box((0.0, 0.0), (1.0, 1.0))
    points = np.asarray(points, dtype=np.float64)
    spacing = spacing or math.sqrt(domain.area / len(points))
    walls = wall_layer(domain, spacing, support, points)
    ps = PointSet(points, kernel="poly6", support=support, area=domain.area, boundary=walls)
    st = ps.ops.gradient_coefficients("colin_difference", row_kinds=(FLUID,),
                                      source_kinds=(FLUID, BOUNDARY))
    out = ps.new_array(1)
    ps.ops.divergence(st, ps.upload(vectors), out)     # walls: zero velocity
    return ps.download(out)
