"""Geometry layer: domains (:class:`Box`, :class:`Polygon`), point location and
the samplers that fill them (Poisson disk, boundary and ghost particles)."""
from .domain import Box, Polygon, as_domain

__all__ = ["Box", "Polygon", "as_domain"]
