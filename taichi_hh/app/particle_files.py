"""Particle data per output: ``.npz`` always, ``.vtu`` for ParaView, and a
``.pvd`` collection that lists the ``.vtu`` files of a run with their times.

VTU files are written by meshio (each particle a VTK vertex cell, every array
a point-data array: scalars as is, 2D vectors padded to 3 components as VTK
expects), the library ParaView users already know; it reads them back, which
the tests use.  The collection is plain XML rewritten atomically after every
output, so an interrupted run leaves a valid series of what it wrote.
"""
from __future__ import annotations

import os
from xml.sax.saxutils import quoteattr

import numpy as np

from .io import atomic_path

#: what :func:`write_particles` writes: ``"npz"`` always, ``"vtu"`` on request
FORMATS = ("npz", "vtu")


def _columns(points, arrays: dict) -> dict:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (n, 2), got {pts.shape}")
    out = {}
    for name, a in arrays.items():
        a = np.asarray(a)
        if a.shape[:1] != (len(pts),):
            raise ValueError(f"array {name!r} must have one entry per particle ({len(pts)}), "
                             f"got shape {a.shape}")
        out[name] = a
    return out


def write_npz(path: str, points, arrays: dict, time: float | None = None) -> str:
    """``points`` (n, 2) and per-particle ``arrays`` as a compressed ``.npz``
    (keys ``points``, the array names, and ``time`` when given), atomically."""
    data = {"points": np.asarray(points, dtype=np.float64), **_columns(points, arrays)}
    if time is not None:
        data["time"] = np.float64(time)
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **data)
    return path


def write_vtu(path: str, points, arrays: dict) -> str:
    """``points`` (n, 2) and per-particle ``arrays`` as a VTK unstructured grid
    of vertices (``.vtu``, binary, zlib-compressed), atomically."""
    import meshio
    cols = _columns(points, arrays)
    pts = np.asarray(points, dtype=np.float64)
    xyz = np.c_[pts, np.zeros(len(pts))]
    point_data = {}
    for name, a in cols.items():
        if a.dtype.kind in "biu":
            a = a.astype(np.int32)
        elif a.dtype.kind == "f":
            a = a.astype(np.float64)
        else:
            raise ValueError(f"array {name!r}: VTK takes numbers, got dtype {a.dtype}")
        if a.ndim == 2 and a.shape[1] == 2:        # 2D vectors: VTK vectors have 3 components
            a = np.c_[a, np.zeros(len(a), dtype=a.dtype)]
        point_data[name] = a
    mesh = meshio.Mesh(xyz, [("vertex", np.arange(len(pts), dtype=np.int64)[:, None])],
                       point_data=point_data)
    with atomic_path(path, suffix=".vtu") as tmp:
        meshio.write(tmp, mesh, file_format="vtu")
    return path


class PvdSeries:
    """A ParaView collection (``.pvd``) of time steps: :meth:`add` a written
    file with its time; the XML is rewritten atomically each time.  Files are
    referenced relative to the collection's folder.  ``resume_time``: keep
    only entries up to that time from an existing collection (a resumed run),
    else start empty."""

    def __init__(self, path: str, resume_time: float | None = None):
        self.path = path
        self.entries: list[tuple[float, str]] = []
        if resume_time is not None and os.path.exists(path):
            self.entries = [(t, f) for t, f in read_pvd(path) if t <= resume_time + 1e-12]

    def add(self, time: float, file: str) -> None:
        rel = os.path.relpath(os.path.abspath(file), os.path.dirname(os.path.abspath(self.path)))
        self.entries = [(t, f) for t, f in self.entries if f != rel] + [(float(time), rel)]
        lines = ['<?xml version="1.0"?>',
                 '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
                 "  <Collection>"]
        lines += [f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>'
                  for t, f in self.entries]
        lines += ["  </Collection>", "</VTKFile>", ""]
        with atomic_path(self.path, suffix=".pvd") as tmp, open(tmp, "w") as fh:
            fh.write("\n".join(lines))


def read_pvd(path: str) -> list[tuple[float, str]]:
    """The ``(time, file)`` entries of a ``.pvd`` collection, in file order."""
    import xml.etree.ElementTree as ET
    root = ET.parse(path).getroot()
    return [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]


def write_particles(directory: str, index: int, time: float, points, arrays: dict, *,
                    vtu: bool = False, series: PvdSeries | None = None) -> list[str]:
    """One output: ``directory/particles_{index:05d}.npz`` and, with ``vtu``,
    the ``.vtu`` twin, added to ``series``.  Returns the paths written."""
    base = os.path.join(directory, f"particles_{int(index):05d}")
    written = [write_npz(base + ".npz", points, arrays, time)]
    if vtu:
        written.append(write_vtu(base + ".vtu", points, arrays))
        if series is not None:
            series.add(time, written[-1])
    return written
