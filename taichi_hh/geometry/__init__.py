"""Geometry layer: domains (:class:`Box`, :class:`Polygon`), point location and
the samplers that fill them (Poisson disk, boundary and ghost particles)."""
from .box import Box
from .domain import as_domain
from .polygon import Polygon

__all__ = ["Box", "Polygon", "as_domain"]
