"""Point layouts of the validation studies and benchmarks: lattices, jittered
lattices and the samplings of the stability and speed-accuracy sweeps, from the
most regular (a lattice) to the most disordered (clusters).

The flow scenes start from :func:`lattice_in_box`; the operator benchmark from
:func:`jittered_lattice`; the sweeps name a sampling and call :func:`sample`.
"""
from __future__ import annotations

import math

import numpy as np

#: The samplings :func:`sample` knows (``jitterX`` takes any X).
SAMPLINGS = ("lattice", "jitterX", "poisson", "random", "clustered", "clusters", "gradient")

#: density ratio across x of the ``gradient`` sampling
GRADIENT_RATIO = 10.0

#: Centres of the four Gaussian clusters of the ``clustered`` sampling.
CLUSTER_CENTRES = ((0.3, 0.3), (0.7, 0.35), (0.4, 0.75), (0.75, 0.8))
CLUSTER_WIDTH = 0.05


def lattice_in_box(n_target: int, box):
    """A square lattice of about n_target points filling box = (x0, y0, x1, y1),
    cell-centred; returns (points, spacing)."""
    x0, y0, x1, y1 = box
    area = (x1 - x0) * (y1 - y0)
    nx = max(2, int(round((x1 - x0) / math.sqrt(area / n_target))))
    dx = (x1 - x0) / nx
    ny = max(2, int(round((y1 - y0) / dx)))
    dy = (y1 - y0) / ny
    if abs(dy - dx) > 1e-9 * dx:
        raise ValueError(f"box {box} is not a whole number of square cells at {n_target} "
                         "particles; choose another particle count")
    gx = x0 + (np.arange(nx) + 0.5) * dx
    gy = y0 + (np.arange(ny) + 0.5) * dx
    return np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2), dx


def jittered_lattice(n_target: int, jitter: float = 0.3, seed: int = 12345) -> np.ndarray:
    """An m x m lattice in the unit square (m = round(sqrt(n_target))), every
    coordinate moved by a uniform amount in [-jitter, jitter] spacings, then
    shuffled (seeded) so that binning starts from an arbitrary order."""
    m = max(2, int(round(math.sqrt(n_target))))
    h = 1.0 / m
    g = (np.arange(m) + 0.5) * h
    x, y = np.meshgrid(g, g, indexing="xy")
    rng = np.random.default_rng(seed)
    pts = np.stack([x.ravel(), y.ravel()], axis=1)
    pts += rng.uniform(-jitter, jitter, size=pts.shape) * h
    return pts[rng.permutation(pts.shape[0])]


def sample(domain, n: int, sampling: str, seed: int) -> np.ndarray:
    """About ``n`` points inside ``domain``.  sampling: ``poisson`` (blue noise),
    ``lattice``, ``jitterX`` (lattice, each point moved uniformly in a square of
    side X spacings), ``random`` (uniform), ``clustered`` (half blue noise, half
    in four Gaussian clusters of width 0.05: local density up to ~20x the mean),
    ``clusters`` (the same with a uniformly random half) or ``gradient``
    (uniformly random, density rising 1:10 across x)."""
    if sampling in ("poisson", "random"):
        return domain.sample_interior(n, kind=sampling, seed=seed)
    if sampling == "lattice":
        return domain.sample_interior(n, kind="jittered", jitter=0.0, seed=seed)
    if sampling.startswith("jitter"):
        return domain.sample_interior(n, kind="jittered", jitter=float(sampling[6:]), seed=seed)
    if sampling == "clustered":
        rng = np.random.default_rng(seed)
        bg = domain.sample_interior(n // 2, kind="poisson", seed=seed)
        return np.vstack([bg, _cluster_points(domain, n - len(bg), rng)])
    if sampling == "clusters":
        # scattered data as measured: half uniformly random, half in the clusters
        rng = np.random.default_rng(seed)
        bg = domain.sample_interior(n // 2, kind="random", seed=seed)
        return np.vstack([bg, _cluster_points(domain, n - len(bg), rng)])
    if sampling == "gradient":
        # uniformly random with a density rising linearly 1 : GRADIENT_RATIO across x
        rng = np.random.default_rng(seed)
        (x0, y0), (x1, y1) = np.asarray(domain.bounds, dtype=float).reshape(2, 2)
        out, have = [], 0
        while have < n:
            p = rng.random((2 * n, 2)) * [x1 - x0, y1 - y0] + [x0, y0]
            t = (p[:, 0] - x0) / (x1 - x0)
            keep = rng.random(2 * n) * GRADIENT_RATIO < 1.0 + (GRADIENT_RATIO - 1.0) * t
            p = p[keep & domain.contains(p)]
            out.append(p)
            have += len(p)
        return np.vstack(out)[:n]
    raise ValueError(f"unknown sampling {sampling!r}; choose one of {SAMPLINGS}")


def _cluster_points(domain, need: int, rng) -> np.ndarray:
    centres = np.array(CLUSTER_CENTRES)
    out = []
    while sum(len(o) for o in out) < need:
        c = centres[rng.integers(0, len(centres), size=need)]
        p = c + CLUSTER_WIDTH * rng.standard_normal((need, 2))
        out.append(p[domain.contains(p)])
    return np.vstack(out)[:need]
