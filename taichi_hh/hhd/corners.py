"""Re-entrant corners: where the conditions with boundary rows are singular.

At a corner whose interior angle ``alpha`` exceeds 180 degrees (an L-shape's
inner corner, a building's roof corner in a masked PIV grid, every step of a
staircase outline) the Neumann and Dirichlet potentials behave like
``rho^(pi / alpha)``: their gradients, d and r, grow like
``rho^(pi / alpha - 1)`` towards the corner (``rho^(-1/3)`` at 270 degrees)
while d + r, the field's own part, stays bounded.  No discretisation removes
a singularity of the exact answer; the decomposition reports it
(:func:`check_corners`).  The natural condition imposes nothing on the
boundary and has none.  (d + h, not d + r, is what stays bounded at such a
corner under Neumann rows: h = v - d - r takes the opposite spike.)
"""
from __future__ import annotations

import numpy as np

__all__ = ["reentrant_corners", "check_corners", "CORNER_ANGLE", "SPIKE_RATIO"]

#: corners with an interior angle above this (degrees) are reported; d and r
#: grow there at least like rho^(-0.1)
CORNER_ANGLE = 200.0
#: flagged where abs(d) or abs(r) next to such a corner exceeds this times its
#: 99th percentile away from the corners (or where that cannot be measured):
#: 2.1 at an L's corner under Neumann at 12k points, 5-46 on the masked pivpy
#: grids under Neumann, 0.9 on the cavity's under normal-parallel
SPIKE_RATIO = 1.5


def reentrant_corners(domain, min_angle: float = CORNER_ANGLE) -> np.ndarray:
    """(K, 2) vertices of ``domain`` (any ring) whose interior angle exceeds
    ``min_angle`` degrees; empty for a box or a domain without rings."""
    rings = getattr(domain, "rings", None)
    if not rings:
        return np.zeros((0, 2))
    out = []
    for ring in rings:                      # the domain on the left of every ring
        ring = np.asarray(ring, dtype=np.float64)
        incoming = ring - np.roll(ring, 1, axis=0)
        outgoing = np.roll(ring, -1, axis=0) - ring
        cross = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
        dot = (incoming * outgoing).sum(axis=1)
        turn = np.degrees(np.arctan2(cross, dot))      # > 0: left, < 0: right
        interior = 180.0 - turn
        out.append(ring[interior > min_angle])
    return np.concatenate(out) if out else np.zeros((0, 2))


def check_corners(stats: dict, points: np.ndarray, d: np.ndarray, r: np.ndarray, domain,
                  spacing: float, condition: str, to_caller=None) -> None:
    """Flag (``stats["flags"]`` and an AccuracyWarning) the re-entrant corners
    of ``domain`` that data points lie next to (within two spacings) where d
    or r spike (:data:`SPIKE_RATIO`): they are singular there under
    ``condition``.  ``stats["reentrant_corners"]``:
    how many such corners; ``stats["corner_spike"]``: the largest abs(d) or
    abs(r) within two spacings of one over its 99th percentile farther than
    six spacings from all (a measure of what the singularity does to these
    data; 2.1 for the 270-degree corner of an L under Neumann at 12k points).
    ``to_caller``: maps a position to the caller's units for the message."""
    corners = reentrant_corners(domain)
    if len(corners) == 0 or len(points) == 0:
        return
    from ..sph.knn import KNearest
    nearest_corner, which = KNearest(corners).query(points, 1)
    nearest_corner, which = nearest_corner[:, 0], which[:, 0]
    near = nearest_corner < 2.0 * spacing
    if not near.any():
        return
    touched = np.unique(which[near])
    stats["reentrant_corners"] = int(len(touched))
    away = nearest_corner > 6.0 * spacing
    worst, name, where = float("nan"), "d", corners[touched[0]]
    if away.sum() >= 10:
        worst = 0.0
        for label, part in (("d", d), ("r", r)):
            size = np.hypot(part[:, 0], part[:, 1])
            reference = np.percentile(size[away], 99)
            k = np.flatnonzero(near)[np.argmax(size[near])]
            ratio = float(size[k] / reference) if reference > 0 else 0.0
            if ratio > worst:
                worst, name, where = ratio, label, corners[which[k]]
    stats["corner_spike"] = worst
    if worst <= SPIKE_RATIO:
        return
    import warnings
    from ..errors import AccuracyWarning
    if to_caller is not None:
        where = np.asarray(to_caller(where), dtype=np.float64).ravel()
    spike = (f"; the largest abs({name}) next to one, near ({where[0]:.7g}, {where[1]:.7g}), "
             f"is {worst:.2g} times its 99th percentile away from them"
             if np.isfinite(worst) else f", first near ({where[0]:.7g}, {where[1]:.7g})")
    msg = (f"the domain has {len(touched)} re-entrant corner(s) (interior angle above "
           f"{CORNER_ANGLE:g} degrees) next to data points{spike}: with "
           f"boundary_condition={condition!r} d and r are singular there (they grow like "
           "rho^(pi/angle - 1) towards the corner); use boundary_condition='natural', which "
           "imposes no condition on the boundary, or leave out the data next to such corners")
    stats.setdefault("flags", []).append(msg)
    warnings.warn(msg, AccuracyWarning, stacklevel=4)
