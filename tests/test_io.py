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
    fast = io._read_field_csv_fast(path)
    checked = io._read_field_csv_checked(path)
    assert fast is not None
    for f, c in zip(fast, checked):
        assert np.array_equal(f, c)
    assert np.array_equal(fast[0], a[:, :2]) and np.array_equal(fast[1], a[:, 2:])


@pytest.mark.parametrize("text, match", [
    ("x,y,u,v\n1,2,3,4\n5,6,oops,8\n", "line 3: column u is not a number"),
    ("x,y,u,v\n1,2,3,4\n5,6,nan,8\n", "line 3: column u is 'nan'"),
    ("1,2,3,4,5\n", "exactly 4 columns"),
    ("x,y,u\n1,2,3\n", "header lacks column"),
])
def test_files_the_fast_reader_refuses_get_the_line_numbered_message(tmp_path, text, match):
    path = _write(tmp_path / "bad.csv", text)
    assert io._read_field_csv_fast(path) is None
    with pytest.raises(InputError, match=match):
        io.read_field(path)
