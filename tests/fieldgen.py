"""Point layouts shared by the tests."""
import numpy as np


def lattice(m: int, jitter: float = 0.0, seed: int = 0, lo=0.0, hi=1.0):
    """m x m cell-centred lattice in [lo, hi]^2, each point moved uniformly by up to
    ``jitter`` spacings in x and y."""
    dx = (hi - lo) / m
    g = lo + (np.arange(m) + 0.5) * dx
    X, Y = np.meshgrid(g, g)
    pts = np.c_[X.ravel(), Y.ravel()]
    if jitter:
        rng = np.random.default_rng(seed)
        pts = pts + rng.uniform(-jitter, jitter, pts.shape) * dx
    return pts, dx


def interior(pts, margin, lo=0.0, hi=1.0):
    x, y = pts[:, 0], pts[:, 1]
    return (x > lo + margin) & (x < hi - margin) & (y > lo + margin) & (y < hi - margin)
