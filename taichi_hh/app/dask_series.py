"""Many snapshots past one process: chunks of a series on Dask workers.

    from taichi_hh.app.dask_series import decompose_dask
    series = decompose_dask(points, vectors)                    # a 2-worker LocalCluster
    series = decompose_dask(points, vectors, address="tcp://scheduler:8786")
    series = decompose_dask(points, vectors, client=client)     # a Client of your own

The snapshots (T, N, 2) are cut into chunks along T, each chunk one task;
each worker process builds one :class:`~taichi_hh.hhd.decomposer.Decomposer`
for the points and options and keeps it for every chunk it gets (Taichi
initialised in the worker on first use, CPU and f64 unless the worker's
``TAICHI_HH_ARCH`` says otherwise: :func:`taichi_hh.runtime.ensure_init`).
The answer equals the in-process ``Decomposer(points).decompose(vectors)``'s
to the solver's tolerance (tests/test_dask_series.py).  Without Dask nothing
here is imported: the default is the Decomposer in-process.

A worker runs one chunk at a time (Taichi's runtime is one per process):
the LocalCluster made here has one thread per worker, and on a cluster of
your own a lock keeps a multi-threaded worker's chunks in turn.  The
results come back without the point set (a Taichi object stays in its
process): ``series[t].critical_points()`` builds what it needs again.

Dask is an optional extra: ``pip install taichi-hh[dask]`` (dask, distributed).
"""
from __future__ import annotations

import math
import threading

import numpy as np

from ..errors import InputError

__all__ = ["decompose_dask", "DEFAULT_WORKERS"]

#: workers of the LocalCluster made when neither a client nor an address is given
DEFAULT_WORKERS = 2

#: per worker process: the Decomposer of the last points and options it served
_KEPT: dict = {}
_LOCK = threading.Lock()


def _distributed():
    try:
        import distributed
    except ImportError:
        raise InputError("decompose_dask needs Dask's distributed scheduler: pip install "
                         "'taichi-hh[dask]' (or dask distributed); without it use "
                         "taichi_hh.Decomposer in-process") from None
    return distributed


def _decompose_chunk(key: str, points, domain, method: str, options: dict, vectors) -> dict:
    """On a worker: the chunk ``vectors`` (t, N, 2) through the worker's kept
    Decomposer (made on its first chunk of these points and options), as
    plain arrays and stats."""
    from ..hhd.decomposer import SERIES_FIELDS, Decomposer
    with _LOCK:
        dec = _KEPT.get(key)
        if dec is None:
            _KEPT.clear()
            dec = _KEPT[key] = Decomposer(points, domain, method=method, **options)
        series = dec.decompose(vectors)
    out = {name: getattr(series, name) for name in SERIES_FIELDS}
    out["stats"] = series.stats
    out["meta"] = [{k: v for k, v in m.items() if k != "pointset"} for m in series.meta]
    return out


def decompose_dask(points, vectors, domain=None, *, client=None, address: str | None = None,
                   chunk: int | None = None, workers: int = DEFAULT_WORKERS,
                   method: str = "default", **options):
    """The decompositions of ``vectors`` (T, N, 2) on ``points`` (N, 2) over
    Dask workers (module doc): ``client`` (a ``distributed.Client``), or
    ``address`` (a scheduler's), or neither (a ``LocalCluster`` of
    ``workers`` processes, closed afterwards).  ``chunk``: snapshots per
    task (default: T over twice the workers, at least one).  ``domain``,
    ``method``, ``options``: as :class:`~taichi_hh.hhd.decomposer.Decomposer`.
    Returns a :class:`~taichi_hh.hhd.decomposer.SeriesResult`."""
    from ..hhd.decomposer import SERIES_FIELDS, SeriesResult
    from ..hhd.options import options_for
    distributed = _distributed()
    options_for(method, **options)                      # bad options fail here, not remotely
    pts = np.asarray(points, dtype=np.float64)
    V = np.asarray(vectors, dtype=np.float64)
    if V.ndim == 2:
        V = V[None]
    if V.ndim != 3 or V.shape[1:] != (len(pts), 2) or len(V) == 0:
        raise InputError(f"vectors must have shape (T, {len(pts)}, 2) with T >= 1, got "
                         f"{np.shape(vectors)}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers must be a positive integer, got {workers!r}")
    own = None
    if client is None:
        if address is not None:
            client = own = distributed.Client(address)
        else:
            cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                               processes=True, dashboard_address=None)
            client = own = distributed.Client(cluster)
    try:
        count = max(1, len(client.scheduler_info().get("workers", {})) or workers)
        size = int(chunk) if chunk is not None else max(1, math.ceil(len(V) / (2 * count)))
        if size < 1:
            raise InputError(f"chunk must be a positive integer, got {chunk!r}")
        import hashlib
        key = hashlib.sha1(pts.tobytes() + repr((domain, method, sorted(options.items())))
                           .encode()).hexdigest()
        remote_points = client.scatter(pts, broadcast=True)
        futures = [client.submit(_decompose_chunk, key, remote_points, domain, method, options,
                                 V[a:a + size], pure=False)
                   for a in range(0, len(V), size)]
        chunks = client.gather(futures)
    finally:
        if own is not None:
            cluster = getattr(own, "cluster", None)
            own.close()
            if cluster is not None and address is None:
                cluster.close()
    arrays = {name: np.concatenate([c[name] for c in chunks]) for name in SERIES_FIELDS}
    stats = [s for c in chunks for s in c["stats"]]
    meta = [dict(m, pointset=None) for c in chunks for m in c["meta"]]
    return SeriesResult(points=pts, **arrays, stats=stats, meta=meta)
