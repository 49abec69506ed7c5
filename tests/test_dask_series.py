"""Chunks of a series on Dask workers (taichi_hh.app.dask_series): a
2-worker LocalCluster gives the in-process Decomposer's answer."""
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import InputError

distributed = pytest.importorskip("distributed")   # the optional extra 'dask'


def _field(p, t):
    cx = 0.3 + 0.4 * t
    dx, dy = p[:, 0] - cx, p[:, 1] - 0.5
    g = np.exp(-(dx * dx + dy * dy) / 0.03)
    return np.c_[0.4 - dy * g + 0.5 * dx * g, dx * g + 0.5 * dy * g]


@pytest.mark.slow     # two worker processes start and load their kernels (a minute or more)
def test_local_cluster_equals_in_process(monkeypatch, tmp_path):
    from taichi_hh.app.dask_series import decompose_dask
    from conftest import CACHE
    monkeypatch.setenv("TAICHI_HH_CACHE", str(CACHE))     # the workers' compiled kernels
    pts = np.random.default_rng(2).random((400, 2))
    V = np.stack([_field(pts, t) for t in np.linspace(0.0, 1.0, 5)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local = thh.Decomposer(pts, boundary_condition="neumann").decompose(V)
        # chunks of 2, 2 and 1 snapshots over the two workers
        remote = decompose_dask(pts, V, chunk=2, workers=2, boundary_condition="neumann")
    assert len(remote) == 5 and remote.boundary_condition == local.boundary_condition
    for name in ("curl_free", "div_free", "harmonic", "phi", "psi", "divergence", "curl"):
        a, b = getattr(remote, name), getattr(local, name)
        assert np.abs(a - b).max() <= 1e-6 * np.abs(b).max(), name
    assert remote[3].frame is not None and remote[3].pointset is None
    with pytest.raises(InputError, match="vectors"):
        decompose_dask(pts, V[:, :-1], workers=1)
    with pytest.raises(InputError, match="option"):
        decompose_dask(pts, V, workers=1, bogus=True)
