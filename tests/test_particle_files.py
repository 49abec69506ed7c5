"""Particle data files: npz and VTU read back (the VTU by meshio, the library
that writes it), the .pvd series, bad arrays refused, nothing half-written."""
import os

import meshio
import numpy as np
import pytest

from taichi_hh.app import particle_files as pf


def _data(n=50, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.random((n, 2))
    return pts, {"velocity": rng.normal(size=(n, 2)), "pressure": rng.normal(size=n),
                 "phase": rng.integers(0, 2, n)}


def test_npz_and_vtu_read_back_with_every_array(tmp_path):
    pts, arrays = _data()
    npz, vtu = pf.write_particles(str(tmp_path), 3, 0.25, pts, arrays, vtu=True)
    assert os.path.basename(npz) == "particles_00003.npz" and vtu.endswith("particles_00003.vtu")
    with np.load(npz) as f:
        assert float(f["time"]) == 0.25
        assert np.array_equal(f["points"], pts)
        for k, a in arrays.items():
            assert np.array_equal(f[k], a)
    mesh = meshio.read(vtu)
    assert np.array_equal(mesh.points[:, :2], pts) and not mesh.points[:, 2].any()
    assert mesh.cells[0].type == "vertex" and len(mesh.cells[0].data) == len(pts)
    assert np.array_equal(mesh.point_data["velocity"][:, :2], arrays["velocity"])
    assert not mesh.point_data["velocity"][:, 2].any()
    assert np.array_equal(mesh.point_data["pressure"], arrays["pressure"])
    assert np.array_equal(mesh.point_data["phase"], arrays["phase"])
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp")]


def test_pvd_series_lists_outputs_in_time_and_resumes(tmp_path):
    pts, arrays = _data(10)
    series = pf.PvdSeries(str(tmp_path / "particles.pvd"))
    for k, t in enumerate((0.0, 0.1, 0.2)):
        pf.write_particles(str(tmp_path / "particles"), k, t, pts, arrays, vtu=True, series=series)
    entries = pf.read_pvd(str(tmp_path / "particles.pvd"))
    assert entries == [(0.0, "particles/particles_00000.vtu"), (0.1, "particles/particles_00001.vtu"),
                       (0.2, "particles/particles_00002.vtu")]
    for _, f in entries:                                   # every entry is a readable file
        assert len(meshio.read(tmp_path / f).points) == 10
    resumed = pf.PvdSeries(str(tmp_path / "particles.pvd"), resume_time=0.1)
    assert [t for t, _ in resumed.entries] == [0.0, 0.1]
    assert pf.PvdSeries(str(tmp_path / "particles.pvd")).entries == []   # a fresh run


@pytest.mark.parametrize("bad, match", [
    ({"pressure": np.zeros(3)}, "one entry per particle"),
    ({"name": np.array(["a"] * 50)}, "takes numbers"),
])
def test_bad_arrays_are_refused_and_nothing_is_left(tmp_path, bad, match):
    pts, _ = _data()
    with pytest.raises(ValueError, match=match):
        pf.write_particles(str(tmp_path), 0, 0.0, pts, bad, vtu=True)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".vtu") or p.startswith(".tmp")]
