"""Vector fields as PIV software and other tools write them.

:func:`read_vector_file` reads one snapshot into points, vectors (NaN where
the instrument marks a vector invalid), the units its header names and the
format it recognised.  The format is recognised from the content, the
extension deciding only between binary kinds:

* **TSI Insight** ``.vec`` (and other Tecplot-style text): a ``TITLE=`` /
  ``VARIABLES="X mm", "Y mm", "U m/s", "V m/s", "CHC"`` header, comma
  separated rows.  Insight's CHC is positive for a valid vector, zero or
  negative for one removed by validation (-1) or not computed at the frame's
  edge (-3).
* **DaVis text export** (``#DaVis 8.1.6 2D-vector ... "mm" ... "m/s"``): tab
  separated, decimal commas where the locale wrote them.  DaVis writes
  disabled and masked vectors as exact zeros and has no flag column, so
  ``u == v == 0`` exactly is invalid there.
* **OpenPIV text** (``.txt``, ``.vec``): whitespace separated ``x y u v``
  and a fifth column (signal-to-noise ratio, or with a ``# x y u v flags
  mask`` header the outlier flags and the mask: non-zero is invalid), NaN
  where OpenPIV replaced an outlier.
* **Delimited text** of any kind: a header line (commented with ``#`` or
  not) naming the columns ``x, y, u, v`` in any order and case (``x [mm]``,
  ``U (m/s)``, ``X mm``: the bracketed or trailing unit is read), or no
  header and ``x y u v`` first; comma, semicolon, tab or whitespace
  separated (sniffed from the first data row; with semicolons or tabs a
  comma is a decimal comma).  A validity column among ``valid`` (1/0,
  true/false), ``flags`` and ``mask`` (non-zero: invalid), ``chc`` (positive:
  valid), ``typevector`` (PIVlab: 0 masked).
* **DaVis** ``.vc7`` through LaVision's own reader, ``lvpyio`` (the ``piv``
  extra): the active choice of each vector, scaled, with the axes' signs,
  invalid where disabled or masked; positions at the centres of the
  interrogation windows (offset + (j + 1/2) slope step, as DaVis places them).
* **PIVlab** ``.mat``: the session export (HDF5, MATLAB 7.3: ``x_N``,
  ``y_N``, ``u_N``, ``v_N``, ``typevector_N``, the first frame N) through
  ``h5py``, or PIVlab's "export all frames" file (MATLAB 5: cells
  ``x``, ``y``, ``u_filtered`` or ``u_original``, ``typevector_...``, the
  first frame) through ``scipy.io``; typevector 0 is a masked vector.

Every failure is an :class:`~taichi_hh.errors.InputError` that names the
file, the line where one applies, and what was expected.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["VectorFile", "read_vector_file", "TEXT_EXTENSIONS", "BINARY_EXTENSIONS"]

#: extensions read as text (the content says which text format)
TEXT_EXTENSIONS = (".txt", ".vec", ".dat", ".tsv", ".csv")
#: extensions read by a binary reader
BINARY_EXTENSIONS = (".vc7", ".mat")
#: column names of the coordinates and components
COLUMNS = ("x", "y", "u", "v")
#: validity columns and what makes a row valid
VALIDITY = {
    "valid": lambda a: a != 0,
    "flags": lambda a: a == 0,
    "mask": lambda a: a == 0,
    "chc": lambda a: a > 0,
    "typevector": lambda a: a != 0,
}


@dataclass(frozen=True)
class VectorFile:
    """One snapshot read from a file: ``points`` and ``vectors`` (N, 2)
    float64, NaN rows of ``vectors`` where the file marks a vector invalid;
    ``length_unit`` and ``velocity_unit`` as the header names them (None when
    it names none); ``format``: what was recognised, in words."""
    points: np.ndarray
    vectors: np.ndarray
    format: str
    length_unit: str | None = None
    velocity_unit: str | None = None


def read_vector_file(path) -> VectorFile:
    """Read ``path`` (module doc).  The caller has checked that it exists."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".vc7":
        return _read_vc7(path)
    if ext == ".mat":
        return _read_pivlab(path)
    lines = _text_lines(path)
    first = next((line for _, line in lines if line.strip()), "")
    if first.lstrip().upper().startswith(("TITLE", "VARIABLES")):
        return _read_tecplot(path, lines)
    if first.lstrip().startswith("#DaVis"):
        return _read_davis_text(path, lines)
    return _read_delimited(path, lines)


# ---- text


def _text_lines(path) -> list:
    try:
        with open(path, encoding="utf-8-sig", errors="strict") as fh:
            text = fh.read()
    except UnicodeDecodeError:
        try:
            with open(path, encoding="latin-1") as fh:      # Insight writes Windows paths
                text = fh.read()
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    if "\x00" in text:
        raise InputError(f"{path}: a binary file, not vector text (it holds NUL bytes); "
                         "text formats: delimited x y u v, Insight .vec, OpenPIV, DaVis text; "
                         "binary: DaVis .vc7, PIVlab .mat")
    return list(enumerate(text.splitlines(), start=1))


def _name_and_unit(label: str) -> tuple:
    """``"x [mm]"``, ``"U (m/s)"``, ``"X mm"``, ``"u"`` -> ``("x", "mm")`` ..."""
    label = label.strip().strip('"').strip()
    m = re.fullmatch(r"([A-Za-z_]\w*)\s*(?:[\[(](.*?)[\])]|\s+(\S.*))?", label)
    if not m:
        return label.lower(), None
    unit = m.group(2) or m.group(3)
    return m.group(1).lower(), (unit.strip() if unit else None)


def _split(line: str, delimiter: str | None) -> list:
    cells = line.split(delimiter) if delimiter else line.split()
    return [c.strip().strip('"') for c in cells]


def _sniff(line: str) -> tuple:
    """``(delimiter, decimal comma)`` of a data row: comma, semicolon, tab or
    whitespace; with semicolons or tabs a comma is a decimal comma."""
    for delimiter in (";", "\t"):
        if delimiter in line:
            return delimiter, "," in line
    if "," in line:
        return ",", False
    return None, False


def _numbers(path, rows, delimiter, decimal_comma, width) -> np.ndarray:
    """(rows, width) float64 of the data rows ``[(line number, text)]``; the
    first bad row named."""
    out = np.empty((len(rows), width))
    for k, (n, line) in enumerate(rows):
        cells = _split(line, delimiter)
        if len(cells) < width:
            raise InputError(f"{path}, line {n}: expected {width} columns, found {len(cells)}")
        for j in range(width):
            cell = cells[j].replace(",", ".") if decimal_comma else cells[j]
            try:
                out[k, j] = float(cell) if cell else np.nan
            except ValueError:
                raise InputError(f"{path}, line {n}: column {j + 1} is not a number: "
                                 f"{cells[j]!r}") from None
    return out


def _columns_of(path, n, names) -> dict:
    """name -> column index of x, y, u, v and a validity column."""
    found = {}
    for j, name in enumerate(names):
        if name in COLUMNS or name in VALIDITY:
            if name in found:
                raise InputError(f"{path}, line {n}: column {name} appears more than once")
            found[name] = j
    missing = [c for c in COLUMNS if c not in found]
    if missing:
        raise InputError(f"{path}, line {n}: the header lacks column(s) {', '.join(missing)}; "
                         f"need x, y, u, v (found: {_shown(names)})")
    return found


def _field(path, data, cols, fmt, units, validity_note=None) -> VectorFile:
    points = np.ascontiguousarray(data[:, [cols["x"], cols["y"]]])
    vectors = np.ascontiguousarray(data[:, [cols["u"], cols["v"]]])
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise InputError(f"{path}: {int(bad.sum())} row(s) with a coordinate that is not a "
                         f"finite number, first at data row {int(np.flatnonzero(bad)[0]) + 1}")
    if np.isinf(vectors).any():
        raise InputError(f"{path}: infinite vector components; a missing vector is NaN")
    for name, valid_when in VALIDITY.items():       # every validity column the file has
        if name in cols:
            flag = data[:, cols[name]]
            vectors[~(valid_when(flag) & np.isfinite(flag))] = np.nan
    if len(points) == 0:
        raise InputError(f"{path}: the file holds no data rows")
    length = units.get("x") or units.get("y")
    velocity = units.get("u") or units.get("v")
    return VectorFile(points, vectors, fmt, length, velocity)


def _data_rows(lines, start: int) -> list:
    return [(n, line) for n, line in lines[start:]
            if line.strip() and not line.lstrip().startswith("#")]


def _read_tecplot(path, lines) -> VectorFile:
    """Insight .vec and Tecplot-style point files: VARIABLES= in the header."""
    header = []
    start = 0
    for k, (n, line) in enumerate(lines):
        s = line.strip()
        if s and (s[0].isdigit() or s[0] in "+-."):
            start = k
            break
        header.append(s)
    else:
        raise InputError(f"{path}: a Tecplot-style header but no data rows")
    text = " ".join(header)
    m = re.search(r"VARIABLES\s*=\s*((?:\"[^\"]*\"\s*,?\s*)+)", text, re.IGNORECASE)
    if not m:
        raise InputError(f"{path}, line 1: a TITLE= header without VARIABLES=\"...\"; "
                         "cannot tell the columns")
    labels = re.findall(r"\"([^\"]*)\"", m.group(1))
    parsed = [_name_and_unit(label) for label in labels]
    names = [name for name, _ in parsed]
    cols = _columns_of(path, lines[0][0], names)
    rows = _data_rows(lines, start)
    delimiter, decimal_comma = _sniff(rows[0][1]) if rows else (None, False)
    data = _numbers(path, rows, delimiter, decimal_comma, len(names))
    units = {name: unit for name, unit in parsed}
    insight = "insight" in text.lower() or "chc" in names
    return _field(path, data, cols, "TSI Insight .vec" if insight else "Tecplot point text",
                  units)


def _read_davis_text(path, lines) -> VectorFile:
    """DaVis's text export: ``#DaVis <version> 2D-vector <step> <ny> <nx>
    "position" "mm" "position" "mm" "velocity" "m/s"``."""
    header = lines[0][1]
    quoted = re.findall(r"\"([^\"]*)\"", header)
    units = {}
    if len(quoted) >= 6:
        units = {"x": quoted[1], "y": quoted[3], "u": quoted[5]}
    rows = _data_rows(lines, 1)
    if not rows:
        raise InputError(f"{path}: a DaVis header but no data rows")
    delimiter, decimal_comma = _sniff(rows[0][1])
    data = _numbers(path, rows, delimiter, decimal_comma, 4)
    # DaVis writes disabled and masked vectors as exact zeros (no flag column)
    data[(data[:, 2] == 0) & (data[:, 3] == 0), 2:4] = np.nan
    return _field(path, data, dict(zip(COLUMNS, range(4))), "DaVis text export", units)


def _read_delimited(path, lines) -> VectorFile:
    """Delimited or whitespace text, a header line (commented or not) naming
    the columns, or none and x y u v first (OpenPIV, spreadsheets)."""
    header, header_line, start, header_delimiter = None, None, None, None
    for k, (n, line) in enumerate(lines):
        s = line.strip()
        if not s:
            continue
        body = s.lstrip("#").strip()
        if not body:
            continue
        delimiter, _ = _sniff(body)
        cells = _header_cells(body, delimiter)
        numeric = all(_is_number(c) for c in cells if c)
        if numeric and not s.startswith("#"):
            start = k
            break
        if not numeric:
            names = [_name_and_unit(c)[0] for c in cells]
            if all(c in names for c in COLUMNS):
                header, header_line = [_name_and_unit(c) for c in cells], n
                header_delimiter = delimiter
            elif not s.startswith("#"):
                found = _shown(cells[:8])
                raise InputError(f"{path}, line {n}: not a header naming x, y, u, v, nor a row "
                                 f"of numbers (found: {found})")
    if start is None:
        raise InputError(f"{path}: the file holds no data rows")
    rows = _data_rows(lines, start)
    delimiter, decimal_comma = _sniff(rows[0][1])
    width = len(_split(rows[0][1], delimiter))
    if header is None:
        if width < 4:
            raise InputError(f"{path}, line {rows[0][0]}: without a header the rows must start "
                             f"with x, y, u, v; found {width} column(s)")
        data = _numbers(path, rows, delimiter, decimal_comma, 4)
        return _field(path, data, dict(zip(COLUMNS, range(4))),
                      "OpenPIV text" if width in (5, 6) and delimiter in (None, "\t")
                      else "delimited text (x y u v)", {})
    words = {",": "commas", ";": "semicolons", "\t": "tabs", None: "spaces"}
    if header_delimiter != delimiter and {header_delimiter, delimiter} & {",", ";"}:
        raise InputError(f"{path}, line {header_line}: the header separates its columns by "
                         f"{words[header_delimiter]}, the data rows (line {rows[0][0]}) by "
                         f"{words[delimiter]}; use one separator throughout")
    names = [name for name, _ in header]
    cols = _columns_of(path, header_line, names)
    data = _numbers(path, rows, delimiter, decimal_comma, max(cols.values()) + 1)
    units = {name: unit for name, unit in header}
    openpiv = names[:6] == ["x", "y", "u", "v", "flags", "mask"]
    return _field(path, data, cols, "OpenPIV text" if openpiv else "delimited text", units)


def _shown(cells) -> str:
    """Cells for a message: an unprintable one (a binary file's bytes) as its
    repr, so that the message prints on one clean line."""
    return ", ".join(c if c.isprintable() else repr(c) for c in cells)


def _header_cells(line: str, delimiter) -> list:
    """A header's cells; between whitespace-separated names a bracketed unit
    (``u (m/s)``, ``x [mm]``) stays with its name."""
    cells = _split(line, delimiter)
    if delimiter is not None:
        return cells
    out = []
    for cell in cells:
        if out and cell[:1] in "([" and not _is_number(cell):
            out[-1] = f"{out[-1]} {cell}"
        else:
            out.append(cell)
    return out


def _is_number(cell: str) -> bool:
    try:
        float(cell.replace(",", ".") if cell.count(",") == 1 and "." not in cell else cell)
        return True
    except ValueError:
        return False


# ---- binary


def _optional(module: str, what: str, path):
    import importlib
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(f"{path}: reading {what} needs the {module} package: "
                         f"pip install \"taichi-hh[piv]\" (or pip install {module})") from None


def _read_vc7(path) -> VectorFile:
    lvpyio = _optional("lvpyio", "DaVis .vc7 files", path)
    try:
        frame = lvpyio.read_buffer(path)[0]
        arr = frame.as_masked_array()
        scales, grid = frame.scales, frame.grid
    except Exception as exc:          # the reader's own errors, whatever their type
        raise InputError(f"{path}: not a readable DaVis vector file ({type(exc).__name__}: "
                         f"{exc})") from None
    u = np.asarray(arr["u"].data, dtype=np.float64)
    v = np.asarray(arr["v"].data, dtype=np.float64)
    mask = np.ma.getmaskarray(arr)
    invalid = (mask["u"] | mask["v"]) if mask.dtype.names else mask
    ny, nx = u.shape
    x = scales.x.offset + (np.arange(nx) + 0.5) * scales.x.slope * grid.x
    y = scales.y.offset + (np.arange(ny) + 0.5) * scales.y.slope * grid.y
    X, Y = np.meshgrid(x, y)
    vectors = np.c_[u.ravel(), v.ravel()]
    vectors[invalid.ravel()] = np.nan
    return VectorFile(np.c_[X.ravel(), Y.ravel()], vectors, "DaVis .vc7",
                      scales.x.unit or None, scales.i.unit or None)


def _read_pivlab(path) -> VectorFile:
    with open(path, "rb") as fh:
        head = fh.read(128)
    if head.startswith(b"\x89HDF") or b"MATLAB 7.3" in head:
        return _read_pivlab_hdf5(path)
    if not head.startswith(b"MATLAB 5.0"):
        raise InputError(f"{path}: not a MATLAB .mat file (its header is {head[:20]!r})")
    sio = _optional("scipy.io", "MATLAB 5 .mat files", path)
    try:
        mat = sio.loadmat(path)
    except Exception as exc:
        raise InputError(f"{path}: not a readable .mat file ({type(exc).__name__}: {exc})") \
            from None

    def first(name):
        a = mat[name]
        if a.dtype == object:               # a cell array of frames: the first
            a = a.ravel()[0]
        return np.asarray(a, dtype=np.float64)

    for suffix in ("filtered", "original"):
        u_key = f"u_{suffix}"
        if u_key in mat and first(u_key).size:
            break
    else:
        raise InputError(f"{path}: no PIVlab vectors (u_filtered or u_original) in it; "
                         f"found {', '.join(k for k in mat if not k.startswith('__'))}")
    arrays = {"x": first("x"), "y": first("y"), "u": first(u_key), "v": first(f"v_{suffix}")}
    type_key = f"typevector_{suffix}"
    typevector = first(type_key) if type_key in mat else None
    return _pivlab_field(path, arrays, typevector, "PIVlab .mat (MATLAB 5)")


def _read_pivlab_hdf5(path) -> VectorFile:
    h5py = _optional("h5py", "PIVlab .mat (MATLAB 7.3) files", path)
    try:
        with h5py.File(path, "r") as f:
            frames = sorted(int(m.group(1)) for k in f.keys()
                            for m in [re.fullmatch(r"u_(\d+)", k)] if m)
            if not frames:
                raise InputError(f"{path}: no PIVlab vectors (u_<frame>) in it; found "
                                 f"{', '.join(list(f.keys())[:10])}")
            k = frames[0]
            arrays = {}
            for name in COLUMNS:
                key = f"{name}_{k}"
                if key not in f:
                    raise InputError(f"{path}: frame {k} lacks {key}")
                arrays[name] = np.asarray(f[key], dtype=np.float64)
            tv = f.get(f"typevector_{k}")
            typevector = None if tv is None else np.asarray(tv, dtype=np.float64)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"{path}: not a readable HDF5 .mat file ({type(exc).__name__}: "
                         f"{exc})") from None
    return _pivlab_field(path, arrays, typevector, "PIVlab .mat (MATLAB 7.3)")


def _pivlab_field(path, arrays, typevector, fmt) -> VectorFile:
    shapes = {name: a.shape for name, a in arrays.items()}
    if len(set(shapes.values())) != 1 or (typevector is not None
                                          and typevector.shape != shapes["u"]):
        raise InputError(f"{path}: PIVlab arrays of different shapes: {shapes}")
    points = np.c_[arrays["x"].ravel(), arrays["y"].ravel()]
    vectors = np.c_[arrays["u"].ravel(), arrays["v"].ravel()]
    if typevector is not None:
        vectors[typevector.ravel() == 0] = np.nan
    if not np.isfinite(points).all():
        raise InputError(f"{path}: PIVlab coordinates that are not finite numbers")
    return VectorFile(points, vectors, fmt)
