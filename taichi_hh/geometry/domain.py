"""Domains: :class:`Box` and :class:`Polygon` (with holes), and :func:`as_domain`,
which makes one from the shorthand forms the public functions accept.

The pieces live in one module per job: :mod:`.rings` (validation),
:mod:`.segments` (the oriented boundary and exact distance queries),
:mod:`.locator` (the acceleration grid), :mod:`.polygon` and :mod:`.box` (the
domain classes), :mod:`.sampling` and :mod:`.poisson_disk` (the samplers).
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .box import Box
from .polygon import Polygon

__all__ = ["Polygon", "Box", "as_domain"]


def as_domain(domain):
    """A Box or Polygon from a domain, a 4-sequence ``(x0, y0, x1, y1)`` (a Box) or an
    (M, 2) vertex array (a Polygon without holes)."""
    if isinstance(domain, Polygon):
        return domain
    try:
        arr = np.asarray(domain, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is not None and arr.shape == (4,):
        return Box(arr[:2], arr[2:])
    if arr is not None and arr.ndim == 2 and arr.shape[1] == 2:
        return Polygon(arr)
    raise InputError(f"cannot make a domain from {domain!r}: give a Box, a Polygon, "
                     f"(x0, y0, x1, y1) or an (M, 2) array of vertices")
