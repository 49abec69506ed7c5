"""Several snapshots in one CLI call (taichi_hh.app.series): each the same
decomposition as a call of its own, one file for the run, figures where
asked, Ctrl-C keeps what is done."""
import os

import numpy as np
import pytest

from taichi_hh.app import cli, series
from taichi_hh.errors import InputError


def _snapshots(tmp_path, count=3):
    x = np.linspace(0.0, 1.0, 21)
    y = np.linspace(0.0, 0.5, 11)
    X, Y = np.meshgrid(x, y)
    files = []
    for t in range(count):
        cx = 0.3 + 0.2 * t
        swirl = np.exp(-((X - cx) ** 2 + (Y - 0.25) ** 2) / 0.01)
        u = -(Y - 0.25) * swirl + 0.2
        v = (X - cx) * swirl
        path = tmp_path / f"snap_{t:03d}.csv"
        rows = "\n".join(f"{a:.17g},{b:.17g},{c:.17g},{d:.17g}" for a, b, c, d in
                         zip(X.ravel(), Y.ravel(), u.ravel(), v.ravel()))
        path.write_text("x,y,u,v\n" + rows + "\n")
        files.append(str(path))
    return files


def test_a_series_equals_one_call_per_file(tmp_path, capsys):
    files = _snapshots(tmp_path)
    out = tmp_path / "run"
    assert cli.main(["decompose", *files, "-o", str(out), "--quiet", "--no-vtk",
                     "--figures", "0,-1"]) == 0
    got = np.load(out / "series.npz")
    assert got["d"].shape == (3, 231, 2) and list(got["files"]) == files
    for t, path in enumerate(files):
        one = tmp_path / f"one_{t}"
        assert cli.main(["decompose", path, "-o", str(one), "--quiet", "--no-vtk",
                         "--no-figures"]) == 0
        ref = np.load(one / "components.npz")
        for name in ("d", "r", "h", "phi", "psi"):
            np.testing.assert_array_equal(got[name][t], ref[name])
    # figures for the first and the last snapshot only
    assert sorted(p for p in os.listdir(out) if os.path.isdir(out / p)) == \
        ["snap_000", "snap_002"]
    assert "Decomposed 3 of 3 snapshots" in capsys.readouterr().out


def test_a_series_on_different_points_is_refused(tmp_path):
    files = _snapshots(tmp_path, 2)
    other = tmp_path / "other.csv"
    other.write_text("x,y,u,v\n0,0,1,1\n1,0,1,1\n0,1,1,1\n1,1,1,1\n0.5,0.5,1,1\n")
    with pytest.raises(InputError, match="points differ"):
        series.decompose_series(files + [str(other)], lambda p: _read(p), _decompose,
                                lambda r, d: [], str(tmp_path), lambda s: None, "none")


def _read(path):
    from taichi_hh.app import io
    points, vectors = io.read_field(path)
    return points, vectors, None


def _decompose(points, vectors, domain):
    return series.decompose_field(points, vectors, domain, method="default", invalid="missing",
                                  progress=None, overrides={}, grid_first=True)


def test_ctrl_c_keeps_the_snapshots_done(tmp_path):
    files = _snapshots(tmp_path, 3)
    calls = []

    def read(path):
        calls.append(path)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return _read(path)

    written, done, interrupted = series.decompose_series(
        files, read, _decompose, lambda r, d: [], str(tmp_path), lambda s: None, "none")
    assert (done, interrupted) == (2, True)
    got = np.load(written[0])
    assert got["v"].shape[0] == 2 and list(got["files"]) == files[:2]
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp-")]


@pytest.mark.parametrize("spec, want", [("first", [0]), ("all", [0, 1, 2, 3]), ("none", []),
                                        ("2,0,-1", [0, 2, 3])])
def test_figure_indices(spec, want):
    assert series.figure_indices(spec, 4) == want


@pytest.mark.parametrize("spec", ["4", "x", "-5"])
def test_bad_figure_indices_are_named(spec):
    with pytest.raises(InputError, match="--figures"):
        series.figure_indices(spec, 4)
