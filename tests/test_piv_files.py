"""PIV files and other vector text (taichi_hh.app.piv_files, through
io.read_field_file): each format written here as the software writes it,
read back with its invalid vectors as NaN and its units; the samples pivpy
ships read the same as pivpy reads them."""
import os
import sys
import types

import numpy as np
import pytest

from taichi_hh.app import io
from taichi_hh.errors import InputError

X = np.array([0.5, 1.0, 1.5])
Y = np.array([-0.5, -1.0])


def _grid():
    xx, yy = np.meshgrid(X, Y)
    u = np.round(np.sin(xx) + yy, 6)
    v = np.round(np.cos(yy) - xx, 6)
    return xx.ravel(), yy.ravel(), u.ravel(), v.ravel()


def _write(path, text):
    path.write_text(text)
    return str(path)


def test_insight_vec(tmp_path):
    x, y, u, v = _grid()
    chc = np.array([1, -1, 1, -3, 0, 2])
    rows = "\n".join(f"{a:.6f}, {b:.6f}, {c:.6f}, {d:.6f}, {k}"
                     for a, b, c, d, k in zip(x, y, u, v, chc))
    path = _write(tmp_path / "Run01.vec",
                  'TITLE="E:\\Run01.vec" VARIABLES="X mm", "Y mm", "U m/s", "V m/s", "CHC", '
                  'DATASETAUXDATA Application="PIV"\n' + rows + "\n")
    got = io.read_field_file(path)
    assert got.format == "TSI Insight .vec"
    assert (got.length_unit, got.velocity_unit) == ("mm", "m/s")
    assert np.array_equal(got.points, np.c_[x, y])
    valid = chc > 0                     # Insight's CHC: positive is a valid vector
    assert np.array_equal(np.isnan(got.vectors[:, 0]), ~valid)
    assert np.array_equal(got.vectors[valid], np.c_[u, v][valid])


def test_davis_text_export_with_decimal_commas(tmp_path):
    x, y, u, v = _grid()
    u[2] = v[2] = 0.0                       # DaVis writes a disabled vector as 0 0
    rows = "\n".join("\t".join(f"{c:.4f}".replace(".", ",") for c in row)
                     for row in zip(x, y, u, v))
    path = _write(tmp_path / "B00001.txt", '#DaVis 8.1.6 2D-vector 32 2 3 "position" "mm" '
                  '"position" "mm" "velocity" "m/s"\n' + rows + "\n")
    got = io.read_field_file(path)
    assert got.format == "DaVis text export"
    assert (got.length_unit, got.velocity_unit) == ("mm", "m/s")
    assert np.allclose(got.points, np.c_[x, y], atol=5e-5)
    assert np.flatnonzero(np.isnan(got.vectors[:, 0])).tolist() == [2]
    keep = np.arange(6) != 2
    assert np.allclose(got.vectors[keep], np.c_[u, v][keep], atol=5e-5)


@pytest.mark.parametrize("header", [True, False])
def test_openpiv_text(tmp_path, header):
    x, y, u, v = _grid()
    u[1] = np.nan                                   # an outlier OpenPIV replaced by NaN
    flags = np.array([0, 0, 1, 0, 0, 0])
    mask = np.array([0, 0, 0, 0, 1, 0])
    rows = "\n".join("\t".join(f"{c:.4e}" for c in row) for row in zip(x, y, u, v, flags, mask))
    text = ("# x\ty\tu\tv\tflags\tmask\n" if header else "") + rows + "\n"
    got = io.read_field_file(_write(tmp_path / "field.txt", text))
    assert got.format == "OpenPIV text"
    invalid = np.isnan(got.vectors[:, 0])
    # with the header the flags and the mask mark vectors invalid; without
    # it the fifth column is a signal-to-noise ratio and only NaN does
    assert invalid.tolist() == ([False, True, True, False, True, False] if header
                                else [False, True, False, False, False, False])
    assert np.allclose(got.points, np.c_[x, y], rtol=1e-4)


@pytest.mark.parametrize("delimiter, decimal", [(";", ","), ("\t", "."), (" ", "."),
                                                (";", ".")])
def test_delimited_text_with_a_header_and_units(tmp_path, delimiter, decimal):
    x, y, u, v = _grid()
    valid = np.array([1, 1, 0, 1, 1, 1])
    rows = "\n".join(delimiter.join(f"{c:.5f}".replace(".", decimal) for c in row[:4])
                     + f"{delimiter}{int(row[4])}" for row in zip(u, x, v, y, valid))
    header = delimiter.join(["U (m/s)", "x [mm]", "V (m/s)", "y [mm]", "valid"])
    text = "# exported by hand\n# " + header + "\n" + rows + "\n"
    got = io.read_field_file(_write(tmp_path / "field.csv" if delimiter == ";" else
                                    tmp_path / "field.dat", text))
    assert got.format == "delimited text"
    assert (got.length_unit, got.velocity_unit) == ("mm", "m/s")
    assert np.allclose(got.points, np.c_[x, y], atol=1e-5)
    assert np.isnan(got.vectors[2]).all() and np.isfinite(np.delete(got.vectors, 2, 0)).all()
    assert np.allclose(np.delete(got.vectors, 2, 0), np.delete(np.c_[u, v], 2, 0), atol=1e-5)


def test_comma_csv_keeps_its_reader(tmp_path):
    path = _write(tmp_path / "f.csv", "x,y,u,v,valid\n0,0,1,2,true\n1,0,,2,true\n0,1,1,2,false\n")
    got = io.read_field_file(path)
    assert got.format == "CSV"
    assert np.isnan(got.vectors[1:, 0]).all() and got.vectors[0].tolist() == [1.0, 2.0]


def test_pivlab_mat_v73(tmp_path):
    h5py = pytest.importorskip("h5py")
    xx, yy = np.meshgrid(X, Y)
    path = tmp_path / "session.mat"
    tv = np.array([[1, 1, 0], [1, 2, 1]], dtype=float)         # 0: masked
    with h5py.File(path, "w") as f:
        for k, shift in ((3, 0.0), (4, 10.0)):                  # two frames: the first read
            f[f"x_{k}"], f[f"y_{k}"] = xx, yy
            f[f"u_{k}"], f[f"v_{k}"] = xx + shift, -yy
            f[f"typevector_{k}"] = tv
    got = io.read_field_file(path)
    assert got.format == "PIVlab .mat (MATLAB 7.3)"
    assert np.array_equal(got.points, np.c_[xx.ravel(), yy.ravel()])
    assert np.isnan(got.vectors[2]).all()
    assert np.array_equal(np.delete(got.vectors, 2, 0),
                          np.delete(np.c_[xx.ravel(), -yy.ravel()], 2, 0))


def test_pivlab_mat_v5(tmp_path):
    sio = pytest.importorskip("scipy.io")
    xx, yy = np.meshgrid(X, Y)

    def cells(*frames):
        out = np.empty((1, len(frames)), dtype=object)
        for k, a in enumerate(frames):
            out[0, k] = a
        return out

    path = tmp_path / "PIVlab_export.mat"
    sio.savemat(path, {"x": cells(xx, xx), "y": cells(yy, yy),
                       "u_original": cells(xx, xx), "v_original": cells(yy, yy),
                       "u_filtered": cells(2 * xx, xx), "v_filtered": cells(2 * yy, yy),
                       "typevector_filtered": cells(np.ones_like(xx) - (xx > 1.2) * (yy < -0.7),
                                                    np.ones_like(xx))})
    got = io.read_field_file(path)
    assert got.format == "PIVlab .mat (MATLAB 5)"
    invalid = ((xx > 1.2) & (yy < -0.7)).ravel()
    assert np.array_equal(np.isnan(got.vectors[:, 0]), invalid)
    assert np.array_equal(got.vectors[~invalid], np.c_[2 * xx.ravel(), 2 * yy.ravel()][~invalid])


def test_vc7_through_lvpyio(tmp_path, monkeypatch):
    """The DaVis reader's use of lvpyio (a stand-in with lvpyio's interface:
    the active choice as a masked array, scales, the interrogation step):
    positions at the windows' centres, masked vectors NaN, units."""
    Scale = types.SimpleNamespace
    u = np.ma.masked_array(np.arange(6.0).reshape(2, 3), mask=[[0, 1, 0], [0, 0, 0]])
    v = np.ma.masked_array(-np.arange(6.0).reshape(2, 3), mask=[[0, 1, 0], [1, 0, 0]])
    arr = np.ma.empty((2, 3), dtype=[("u", "f4"), ("v", "f4")])
    arr["u"], arr["v"] = u, v
    frame = types.SimpleNamespace(
        as_masked_array=lambda: arr, grid=types.SimpleNamespace(x=16, y=16, z=16),
        scales=types.SimpleNamespace(x=Scale(slope=0.1, offset=-5.0, unit="mm"),
                                     y=Scale(slope=-0.1, offset=7.0, unit="mm"),
                                     i=Scale(slope=1.0, offset=0.0, unit="m/s")))
    monkeypatch.setitem(sys.modules, "lvpyio",
                        types.SimpleNamespace(read_buffer=lambda path: [frame]))
    path = tmp_path / "B00001.vc7"
    path.write_bytes(b"stand-in")
    got = io.read_field_file(path)
    assert got.format == "DaVis .vc7" and (got.length_unit, got.velocity_unit) == ("mm", "m/s")
    x = -5.0 + (np.arange(3) + 0.5) * 0.1 * 16
    y = 7.0 - (np.arange(2) + 0.5) * 0.1 * 16
    assert np.allclose(got.points, np.c_[np.tile(x, 2), np.repeat(y, 3)])
    assert np.flatnonzero(np.isnan(got.vectors[:, 0])).tolist() == [1, 3]
    assert got.vectors[5].tolist() == [5.0, -5.0]


def test_optional_readers_name_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "lvpyio", None)          # import fails
    path = tmp_path / "B.vc7"
    path.write_bytes(b"x")
    with pytest.raises(InputError, match=r"lvpyio.*taichi-hh\[piv\]"):
        io.read_field_file(path)


@pytest.mark.parametrize("text, match", [
    ("TITLE=\"t\"\n1, 2, 3, 4\n", "without VARIABLES"),
    ('VARIABLES="X mm", "Y mm", "U m/s"\n1, 2, 3\n', r"lacks column\(s\) v"),
    ("# x;y;u;v\n1;2;3;4\n1;2;x;4\n", r"line 3: column 3 is not a number: 'x'"),
    ("a b c d\n1 2 3 4\n", "line 1: not a header naming x, y, u, v"),
    ("1 2 3\n", "without a header the rows must start with x, y, u, v"),
    ("# only comments\n", "no data rows"),
    ("x y u v\n1 2 inf 4\n", "infinite"),
    ("#DaVis 8 2D-vector\n", "no data rows"),
])
def test_bad_text_is_named(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        io.read_field_file(_write(tmp_path / "bad.txt", text))


def test_unknown_and_binary_files_are_named(tmp_path):
    with pytest.raises(InputError, match="unknown field format '.xyz'.*PIVlab .mat"):
        io.read_field_file(_write(tmp_path / "f.xyz", "1 2 3 4\n"))
    path = tmp_path / "f.txt"
    path.write_bytes(b"\x00\x01binary")
    with pytest.raises(InputError, match="binary file"):
        io.read_field_file(path)
    path = tmp_path / "f.mat"
    path.write_bytes(b"not matlab at all")
    with pytest.raises(InputError, match="not a MATLAB .mat file"):
        io.read_field_file(path)


def _pivpy_samples():
    pytest.importorskip("pivpy")
    pytest.importorskip("lvpyio")
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks"))
    import real_data
    return real_data


def test_pivpys_samples_read_as_pivpy_reads_them():
    """Each of the seven samples real_data.py decomposes: the same grid, the
    same invalid vectors and the same values as its pivpy/lvpyio reading."""
    real_data = _pivpy_samples()
    for spec in real_data.DATASETS:
        x, y, u, v = real_data.read(spec)
        got = io.read_field_file(os.path.join(real_data.data_dir(), spec.path))
        xx, yy = np.meshgrid(x, y)
        assert np.array_equal(got.points, np.c_[xx.ravel(), yy.ravel()]), spec.name
        want = np.c_[u.ravel(), v.ravel()]
        assert np.array_equal(np.isnan(got.vectors), np.isnan(want)), spec.name
        assert np.array_equal(got.vectors[~np.isnan(want)], want[~np.isnan(want)]), spec.name


def test_a_header_and_rows_with_different_separators_are_refused(tmp_path):
    path = _write(tmp_path / "mixed.csv", "x;y;u;v\n0,0,1,2\n1,0,1,2\n0,1,1,2\n")
    with pytest.raises(InputError, match="line 1: the header separates its columns by "
                                         "semicolons, the data rows \\(line 2\\) by commas"):
        io.read_field_file(path)
    # a whitespace header over tab-separated rows is one kind of separator
    got = io.read_field_file(_write(tmp_path / "tabs.txt", "# x y u v\n0\t0\t1\t2\n"))
    assert got.vectors.tolist() == [[1.0, 2.0]]
