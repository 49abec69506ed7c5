"""Field files: the vectorised CSV reader gives exactly what the line-by-line
reader gives, and hands every file it cannot read cleanly to the latter."""
import numpy as np
import pytest

from taichi_hh.app import io
from taichi_hh.errors import InputError


def _write(path, text):
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("header", ["x,y,u,v\n", "V, u ,Y,x,extra\n", ""])
def test_fast_and_checked_csv_readers_agree_bit_for_bit(tmp_path, header):
    rng = np.random.default_rng(1)
    a = rng.normal(size=(300, 4)) * 10.0 ** rng.integers(-8, 8, (300, 1))
    if header.startswith("V"):
        order = [3, 2, 1, 0]                      # columns v, u, y, x (+ an extra one)
        rows = [",".join(repr(float(r[c])) for c in order) + ",7" for r in a]
    else:
        rows = [",".join(repr(float(x)) for x in r) for r in a]
    path = _write(tmp_path / "f.csv", "# comment\n\n" + header + "\n".join(rows) + "\n")
    fast = io.read_field_csv_fast(path)
    checked = io.read_field_csv_checked(path)
    assert fast is not None
    for f, c in zip(fast, checked):
        assert np.array_equal(f, c)
    assert np.array_equal(fast[0], a[:, :2]) and np.array_equal(fast[1], a[:, 2:])


@pytest.mark.parametrize("text, match", [
    ("x,y,u,v\n1,2,3,4\n5,6,oops,8\n", "line 3: column u is not a number"),
    ("x,y,u,v\n1,2,3,4\n5,6,inf,8\n", "line 3: column u is 'inf'"),
    ("x,y,u,v\n1,2,3,4\nnan,6,1,8\n", "line 3: column x is 'nan'; coordinates must be"),
    ("x,y,u,v,valid\n1,2,3,4,1\n5,6,1,8,maybe\n", "line 3: column valid is 'maybe'"),
    ("1,2,3,4,5\n", "exactly 4 columns"),
    ("x,y,u\n1,2,3\n", "header lacks column"),
])
def test_files_the_fast_reader_refuses_get_the_line_numbered_message(tmp_path, text, match):
    path = _write(tmp_path / "bad.csv", text)
    assert io.read_field_csv_fast(path) is None
    with pytest.raises(InputError, match=match):
        io.read_field(path)


def test_missing_vectors_read_as_nan_rows(tmp_path):
    """NaN, an empty u or v cell, or a false ``valid`` make a row's vector NaN
    (missing: the decomposition leaves it out); both readers agree."""
    text = ("x,y,u,v,valid\n0,0,1,2,1\n1,0,nan,2,1\n0,1,3,,1\n1,1,5,6,0\n"
            "2,1,7,8,true\n")
    path = _write(tmp_path / "gaps.csv", text)
    pts, vec = io.read_field(path)
    assert pts.tolist() == [[0, 0], [1, 0], [0, 1], [1, 1], [2, 1]]
    missing = np.isnan(vec).any(axis=1)
    assert missing.tolist() == [False, True, True, True, False]
    assert vec[0].tolist() == [1, 2] and vec[4].tolist() == [7, 8]
    numeric = _write(tmp_path / "gaps01.csv", "x,y,u,v,valid\n0,0,1,2,1\n1,0,nan,2,1\n"
                                              "1,1,5,6,0\n")
    fast = io.read_field_csv_fast(numeric)
    checked = io.read_field_csv_checked(numeric)
    assert fast is not None
    for f, c in zip(fast, checked):
        np.testing.assert_array_equal(f, c)
    assert np.isnan(fast[1]).any(axis=1).tolist() == [False, True, True]
    npz = tmp_path / "gaps.npz"
    np.savez(npz, points=pts[:3], vectors=np.array([[1.0, 2], [np.nan, 1], [3, 4]]),
             valid=np.array([True, True, False]))
    _, v = io.read_field(npz)
    assert np.isnan(v).any(axis=1).tolist() == [False, True, True]
