"""Many snapshots in one process: ``taichi-hh decompose run/*.vec``.

Each file is one snapshot on the same points (a PIV run, a model's output
steps).  One process reads and decomposes them in turn (the kernels compiled
once), prints a line per snapshot, and writes one file for the run:
``DIR/series.npz`` (``points`` (N, 2), ``files`` (T,), ``v``, ``d``, ``r``,
``h`` (T, N, 2), ``phi``, ``psi``, ``divergence``, ``curl`` (T, N),
``boundary_condition``, ``energy_ratio``, ``seconds`` (T,)), and with xarray
installed the same as ``DIR/series.nc`` (dimensions ``time``, ``point``);
figures for the snapshots ``--figures`` names (``first``, ``all``,
``none``, or 0-based indices ``N,M``) in ``DIR/<file stem>/``.

Ctrl-C stops after the snapshot in progress is abandoned: the snapshots done
are written (the files named as the run's, complete, never half-written) and
the command exits with status 130.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputError

__all__ = ["decompose_field", "FieldSeries", "decompose_series", "figure_indices",
           "SERIES_ARRAYS"]

#: per-snapshot arrays of the run's file and the result attribute each comes from
SERIES_ARRAYS = {"v": "vectors", "d": "curl_free", "r": "div_free", "h": "harmonic",
                 "phi": "phi", "psi": "psi", "divergence": "divergence", "curl": "curl"}


def decompose_field(points, vectors, domain, *, method: str, invalid: str, progress,
                    overrides: dict, grid_first: bool):
    """One snapshot as the CLI decomposes it: a field listed node by node on a
    rectilinear grid through the grid path (``grid_first``: no --domain
    given), anything else through :func:`~taichi_hh.hhd.decompose.decompose`."""
    from ..hhd.decompose import decompose
    from ..hhd.grid import decompose_grid_rows
    res = None
    if grid_first and not (invalid == "error" and np.isnan(vectors).any()):
        # (with --invalid error the scattered path refuses NaN rows by row)
        res = decompose_grid_rows(points, vectors, method=method, progress=progress,
                                  **overrides)
    if res is None:
        res = decompose(points, vectors, domain, method=method, progress=progress,
                        invalid=invalid, **overrides)
    return res


class FieldSeries:
    """:func:`decompose_field` for the snapshots of a series: a callable
    ``(points, vectors, domain) -> HHDResult`` that keeps what depends on the
    points between calls (:class:`~taichi_hh.hhd.decomposer.Decomposer`, or
    :class:`~taichi_hh.hhd.decomposer.GridDecomposer` for a field listed
    node by node on a grid): the particles, the systems and their
    preconditioners are made once for the run, each snapshot's answer the
    same as :func:`decompose_field` gives (to the solver's tolerance).  New
    points or another domain start a new one."""

    def __init__(self, *, method: str, invalid: str, progress, overrides: dict,
                 grid_first: bool):
        self.method, self.invalid, self.progress = method, invalid, progress
        self.overrides, self.grid_first = dict(overrides), grid_first
        self._key = self._kept = None

    @property
    def decomposer(self):
        """The set-up kept for the current points (a
        :class:`~taichi_hh.hhd.decomposer.Decomposer` or
        :class:`~taichi_hh.hhd.decomposer.GridDecomposer`; None before the
        first call)."""
        return None if self._kept is None else self._kept[2]

    def __call__(self, points, vectors, domain):
        from ..hhd.decomposer import Decomposer, GridDecomposer
        from ..hhd.grid import as_rows, grid_of, on_nodes
        points = np.asarray(points, dtype=np.float64)
        key = (points.shape, points.tobytes(), repr(domain))
        if key != self._key:
            self._key, self._kept = key, None
            found = grid_of(points) if self.grid_first else None
            if found is not None:
                self._kept = ("grid", found, GridDecomposer(
                    found[0], found[1], method=self.method, progress=self.progress,
                    batch=1, **self.overrides))
            else:
                self._kept = ("points", None, Decomposer(
                    points, domain, method=self.method, progress=self.progress,
                    invalid=self.invalid, batch=1, **self.overrides))
        kind, found, dec = self._kept
        if kind == "grid" and not (self.invalid == "error" and np.isnan(vectors).any()):
            g = next(dec.stream([on_nodes(found, vectors)]))
            return as_rows(g, found, points, vectors)
        if kind == "grid":     # --invalid error refuses NaN rows by row (the scattered path)
            return decompose_field(points, vectors, domain, method=self.method,
                                   invalid=self.invalid, progress=self.progress,
                                   overrides=self.overrides, grid_first=False)
        return next(dec.stream([vectors]))


def figure_indices(spec: str, count: int) -> list:
    """The snapshots ``--figures`` names among ``count``: ``first``, ``all``,
    ``none`` or comma-separated 0-based indices (negative from the end)."""
    spec = spec.strip().lower()
    if spec == "none":
        return []
    if spec == "first":
        return [0] if count else []
    if spec == "all":
        return list(range(count))
    out = []
    for cell in spec.split(","):
        try:
            k = int(cell)
        except ValueError:
            raise InputError(f"--figures {spec}: write first, all, none or snapshot indices "
                             "such as 0,10,-1") from None
        if not -count <= k < count:
            raise InputError(f"--figures: snapshot {k} of {count} does not exist "
                             f"(0..{count - 1}, or negative from the end)")
        out.append(k % count)
    return sorted(set(out))


def decompose_series(files, read, decompose_one, draw, out: str, say, figures: str = "first"):
    """Decompose every file of ``files`` (module doc).  ``read(path)`` ->
    ``(points, vectors, domain)``; ``decompose_one(points, vectors, domain)``
    -> an :class:`~taichi_hh.hhd.decompose.HHDResult`; ``draw(result,
    directory)`` -> the figure paths written.  Returns ``(written paths,
    snapshots done, interrupted)``."""
    import time
    from . import io
    wanted = set(figure_indices(figures, len(files)))
    points0 = None
    rows = {name: [] for name in SERIES_ARRAYS}
    meta = {"boundary_condition": [], "energy_ratio": [], "seconds": []}
    written, interrupted, done = [], False, 0
    try:
        for k, path in enumerate(files):
            t0 = time.perf_counter()
            points, vectors, domain = read(path)
            if points0 is None:
                points0 = points
            elif points.shape != points0.shape or not np.array_equal(points, points0):
                raise InputError(f"{path}: its points differ from {files[0]}'s ("
                                 f"{len(points)} against {len(points0)} points"
                                 f"{'' if points.shape != points0.shape else ', same count'}"
                                 "); a series is snapshots on the same points")
            res = decompose_one(points, vectors, domain)
            for name, attr in SERIES_ARRAYS.items():
                rows[name].append(np.asarray(getattr(res, attr), dtype=np.float64))
            s = res.stats
            meta["boundary_condition"].append(str(s.get("boundary_condition", "")))
            meta["energy_ratio"].append(float(s.get("energy_ratio", np.nan)))
            meta["seconds"].append(time.perf_counter() - t0)
            done = k + 1
            if k in wanted:
                stem = os.path.splitext(os.path.basename(path))[0] or f"snapshot_{k}"
                target = os.path.join(out, stem)
                os.makedirs(target, exist_ok=True)
                written += draw(res, target)
            say(f"[{done}/{len(files)}] {os.path.basename(path)}: "
                f"{meta['boundary_condition'][-1]}, energy ratio "
                f"{meta['energy_ratio'][-1]:.3g}, {meta['seconds'][-1]:.2f} s")
    except KeyboardInterrupt:
        interrupted = True
    if done == 0:
        if interrupted:
            raise KeyboardInterrupt
        raise InputError("no snapshot to decompose")
    arrays = {name: np.stack(values) for name, values in rows.items()}
    arrays.update({"points": points0, "files": np.asarray(files[:done]),
                   "boundary_condition": np.asarray(meta["boundary_condition"]),
                   "energy_ratio": np.asarray(meta["energy_ratio"]),
                   "seconds": np.asarray(meta["seconds"])})
    npz = os.path.join(out, "series.npz")
    with io.atomic_path(npz, ".npz") as tmp:
        np.savez(tmp, **arrays)
    written.insert(0, npz)
    nc = _write_netcdf(os.path.join(out, "series.nc"), arrays)
    if nc:
        written.insert(1, nc)
    return written, done, interrupted


def _write_netcdf(path, arrays):
    """``series.nc`` through xarray (any engine it has), or None without one."""
    try:
        import xarray as xr
    except ImportError:
        return None
    from . import io
    ds = xr.Dataset(coords={"time": np.arange(len(arrays["files"])),
                            "x": ("point", arrays["points"][:, 0]),
                            "y": ("point", arrays["points"][:, 1])})
    for name in SERIES_ARRAYS:
        a = arrays[name]
        if a.ndim == 3:
            ds[f"{name}_u"] = (("time", "point"), a[..., 0])
            ds[f"{name}_v"] = (("time", "point"), a[..., 1])
        else:
            ds[name] = (("time", "point"), a)
    for name in ("files", "boundary_condition", "energy_ratio", "seconds"):
        ds[name] = ("time", arrays[name])
    ds.attrs["source"] = "taichi-hh decompose (series)"
    try:
        with io.atomic_path(path, ".nc") as tmp:
            ds.to_netcdf(tmp)
    except (ValueError, ImportError, OSError):
        return None                          # no netCDF engine installed: the .npz holds it
    return path
