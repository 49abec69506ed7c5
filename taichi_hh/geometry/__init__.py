"""Geometry layer: domains (:class:`Box`, :class:`Polygon`), point location and
the samplers that fill them (Poisson disk, boundary and ghost particles), and
domains made from the data (:mod:`.from_points`: bounding box, convex hull,
alpha shape over a Delaunay triangulation, :mod:`.delaunay`)."""
from .box import Box
from .domain import as_domain
from .polygon import Polygon

__all__ = ["Box", "Polygon", "as_domain"]
