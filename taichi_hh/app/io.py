"""File output that never leaves a half-written file: write to a temporary
name in the same directory, then rename over the target (atomic on POSIX)."""
from __future__ import annotations

import csv
import os
import tempfile
import warnings
from contextlib import contextmanager


_UMASK = None


def _umask() -> int:
    """The process umask (read once; os.umask can only be read by setting it)."""
    global _UMASK
    if _UMASK is None:
        try:
            with open("/proc/self/status") as fh:
                _UMASK = next(int(line.split()[1], 8) for line in fh
                              if line.startswith("Umask:"))
        except (OSError, StopIteration, ValueError, IndexError):
            _UMASK = os.umask(0o022)
            os.umask(_UMASK)
    return _UMASK


#: temporary files are named ``.tmp-<pid>-<random><suffix>``: a process killed
#: mid-write (SIGKILL, power loss) leaves one behind, which
#: :func:`remove_stale_temp_files` recognises by its dead process id
TEMP_PREFIX = ".tmp-"


@contextmanager
def atomic_path(path: str, suffix: str = ""):
    """Yield a temporary path next to ``path``; rename it to ``path`` on success.
    On any exception (or exit) Python sees, the temporary file is removed."""
    directory = os.path.dirname(os.path.abspath(path)) or "."
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f"{TEMP_PREFIX}{os.getpid()}-",
                               suffix=suffix or os.path.splitext(path)[1], dir=directory)
    os.close(fd)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give it the mode a plain open() would
        if os.path.exists(tmp):
            os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True                       # exists (another user's) or cannot tell: keep
    return True


def remove_stale_temp_files(directory: str, *, legacy_age: float = 3600.0) -> list:
    """Remove the temporary files of :func:`atomic_path` that a killed process
    left in ``directory`` (not recursive): those whose process id is no longer
    running, and unnumbered ones (older versions) older than ``legacy_age``
    seconds.  Returns the removed paths.  A missing directory is fine."""
    import time
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    now = time.time()
    for name in names:
        if not name.startswith(TEMP_PREFIX):
            continue
        path = os.path.join(directory, name)
        head = name[len(TEMP_PREFIX):].split("-", 1)[0]
        try:
            if head.isdigit() and "-" in name[len(TEMP_PREFIX):]:
                stale = not _pid_alive(int(head))
            else:
                stale = now - os.path.getmtime(path) > legacy_age
            if stale and os.path.isfile(path):
                os.remove(path)
                removed.append(path)
        except OSError:
            pass
    return removed


def atomic_write_csv(path: str, rows: list[dict]) -> None:
    """Write a list of dicts (same keys) as CSV, atomically."""
    if not rows:
        raise ValueError("no rows to write")
    keys = list(rows[0].keys())
    for r in rows[1:]:
        keys += [k for k in r if k not in keys]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def atomic_savefig(fig, path: str, **kwargs) -> None:
    """Save a matplotlib figure atomically."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)


# --------------------------------------------------------------------------- readers
# (numpy and the standard library only: reading a field needs no Taichi)

FIELD_FORMATS = (".npz", ".csv")
CSV_COLUMNS = ("x", "y", "u", "v")
#: the values of a CSV ``valid`` column
VALID_WORDS = {"1": True, "0": False, "true": True, "false": False, "1.0": True, "0.0": False}


def read_field(path):
    """Read a sampled 2D vector field: ``(points, vectors)``, two (N, 2) float64
    arrays (:func:`read_field_file` with the units and the format)."""
    got = read_field_file(path)
    return got.points, got.vectors


def read_field_file(path):
    """Read a sampled 2D vector field: a
    :class:`~taichi_hh.app.piv_files.VectorFile` (``points``, ``vectors``,
    ``format``, ``length_unit``, ``velocity_unit``).

    ``.npz``: arrays ``points`` (N, 2) and ``vectors`` (N, 2), and optionally
    ``valid`` (N,) (False or 0: an invalid vector).
    ``.csv``: a header naming the columns ``x, y, u, v`` (any order, any case,
    extra columns ignored; an optional ``valid`` column of 1/0 or true/false),
    or no header and exactly four numeric columns in that order.  Blank lines
    and lines starting with ``#`` are skipped.

    Missing vectors (NaN, an empty ``u`` or ``v`` cell, or ``valid`` false)
    come back as NaN rows of ``vectors``: the decomposition leaves them out.

    PIV files and other text (:mod:`taichi_hh.app.piv_files`): TSI Insight
    and Tecplot-style ``.vec``/``.dat``, OpenPIV and DaVis text exports
    (``.txt``, ``.vec``), text with semicolons, tabs or whitespace between
    its columns (``.txt``, ``.dat``, ``.tsv``, and ``.csv`` without commas),
    DaVis ``.vc7`` (lvpyio) and PIVlab ``.mat`` (h5py or scipy), with the
    instrument's invalid vectors as NaN.

    Raises :class:`~taichi_hh.errors.InputError` naming the problem (and the
    line of a CSV file) for a missing or unreadable file, an unknown format,
    missing arrays or columns, wrong shapes, non-numeric or infinite values.
    """
    from ..errors import InputError
    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputError(f"{path}: no such file")
    if os.path.isdir(path):
        raise InputError(f"{path}: is a directory, not a field file")
    from .piv_files import BINARY_EXTENSIONS, TEXT_EXTENSIONS, VectorFile, read_vector_file
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npz":
        return VectorFile(*_read_field_npz(path), format="npz")
    if ext == ".csv" and _commas_first(path):
        return VectorFile(*_read_field_csv(path), format="CSV")
    if ext in TEXT_EXTENSIONS + BINARY_EXTENSIONS:
        return read_vector_file(path)
    raise InputError(f"{path}: unknown field format {ext or '(no extension)'!r}; give a .npz "
                     "(arrays points, vectors), .csv (columns x,y,u,v), PIV text (.txt, .vec, "
                     ".dat, .tsv: Insight, OpenPIV, DaVis or any delimited x y u v), DaVis "
                     ".vc7 or PIVlab .mat file")


def _commas_first(path) -> bool:
    """Whether a .csv file's first line that is not blank or a ``#`` comment
    is comma separated (else it is read as delimited text: semicolons, with
    decimal commas or not, or tabs)."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                # a comment the CSV reader skips: "#..." or a quoted "\"#...\""
                if line.strip() and not line.lstrip().lstrip('"').startswith("#"):
                    return "," in line and ";" not in line and "\t" not in line
    except OSError:
        return True                           # the CSV reader names the problem
    return True


def _read_field_npz(path):
    import numpy as np
    from ..errors import InputError
    problem = npz_problem(path)
    if problem:
        raise InputError(f"{path}: not a readable .npz file ({problem})")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as exc:          # OSError, ValueError, zipfile.BadZipFile, EOFError
        raise InputError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") \
            from None
    missing = [k for k in ("points", "vectors") if k not in arrays]
    if missing:
        raise InputError(f"{path}: missing array(s) {', '.join(missing)}; a field .npz needs "
                         f"'points' (N, 2) and 'vectors' (N, 2) (found: "
                         f"{', '.join(sorted(arrays)) or 'nothing'})")
    out = []
    for name in ("points", "vectors"):
        a = arrays[name]
        if a.dtype.kind not in "biuf":
            raise InputError(f"{path}: array '{name}' must be numeric, got dtype {a.dtype}")
        if a.ndim != 2 or a.shape[1] != 2:
            raise InputError(f"{path}: array '{name}' must have shape (N, 2), got {a.shape}")
        a = a.astype(np.float64)
        bad = np.isinf(a).any(axis=1) if name == "vectors" else ~np.isfinite(a).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            what = "inf" if name == "vectors" else "NaN or inf"
            raise InputError(f"{path}: array '{name}' has {int(bad.sum())} row(s) with {what}, "
                             f"first at index {i}: {a[i].tolist()}"
                             + ("; missing vectors are NaN" if name == "vectors" else ""))
        out.append(a)
    points, vectors = out
    if len(points) != len(vectors):
        raise InputError(f"{path}: 'points' has {len(points)} rows but 'vectors' has "
                         f"{len(vectors)}")
    if len(points) == 0:
        raise InputError(f"{path}: the field has no points")
    if "valid" in arrays:
        valid = arrays["valid"]
        if valid.shape != (len(points),) or valid.dtype.kind not in "biuf" \
                or not np.isin(valid, (0, 1)).all():
            raise InputError(f"{path}: array 'valid' must hold one boolean (or 0/1) per point, "
                             f"shape ({len(points)},); got {valid.dtype} {valid.shape}")
        vectors[~valid.astype(bool)] = np.nan
    return points, vectors


def npz_problem(path) -> str | None:
    """What makes ``path`` unreadable as a .npz archive, in words, or None when
    it is a complete zip archive.  (numpy alone would call garbage "pickled
    data", and a truncated archive a bad zip file.)"""
    import zipfile
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        return f"cannot read it: {exc.strerror or exc}"
    if not head:
        return "the file is empty"
    if head[:2] != b"PK":
        return (f"it is not a zip archive: it starts with bytes {head.hex(' ')}, "
                "a .npz file with 50 4b (PK)")
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        return f"a truncated or damaged zip archive: {exc}"
    if bad is not None:
        return f"a damaged zip archive: member {bad} fails its checksum"
    return None


def _read_field_csv(path):
    fast = read_field_csv_fast(path)
    if fast is not None:
        return fast
    return read_field_csv_checked(path)


def read_field_csv_fast(path):
    """The common case in one vectorised parse (numpy's C reader): a file whose
    rows all parse as numbers with the columns found.  ``None`` for anything
    else, which :func:`read_field_csv_checked` reads line by line and reports
    with the line's number."""
    import numpy as np
    try:
        with open(path, encoding="utf-8-sig") as fh:
            header_rows = 0
            for line in fh:
                if line.strip() and not line.lstrip().startswith("#"):
                    break
                header_rows += 1
            else:
                return None
        cells = [c.strip().lower() for c in line.split(",")]
        try:
            [float(c) for c in cells]
            cols, skip = None, header_rows
        except ValueError:
            if any(cells.count(c) != 1 for c in CSV_COLUMNS) or cells.count("valid") > 1:
                return None
            cols = [cells.index(c) for c in CSV_COLUMNS]
            if "valid" in cells:
                cols.append(cells.index("valid"))
            skip = header_rows + 1
        with warnings.catch_warnings():
            # a file without data rows: the line-by-line reader names that
            # (numpy would also warn "input contained no data")
            warnings.simplefilter("ignore", UserWarning)
            data = np.loadtxt(path, delimiter=",", comments="#", skiprows=skip, usecols=cols,
                              ndmin=2, encoding="utf-8-sig", quotechar='"')
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    width = 4 if cols is None else len(cols)
    if data.ndim != 2 or data.shape[1] != width or len(data) == 0 \
            or not np.isfinite(data[:, :2]).all() or np.isinf(data[:, 2:4]).any():
        return None
    vectors = np.ascontiguousarray(data[:, 2:4])
    if width == 5:
        if not np.isin(data[:, 4], (0.0, 1.0)).all():
            return None
        vectors[data[:, 4] == 0.0] = np.nan
    return np.ascontiguousarray(data[:, :2]), vectors


def read_field_csv_checked(path):
    """The field CSV read line by line: what :func:`read_field_csv_fast` does
    not take, each bad line reported with its number
    (:class:`~taichi_hh.errors.InputError`)."""
    import math
    import numpy as np
    from ..errors import InputError
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = [(k + 1, row) for k, row in enumerate(csv.reader(fh))]
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text CSV file ({exc})") from None
    except (OSError, csv.Error) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    lines = [(n, [c.strip() for c in row]) for n, row in lines
             if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{path}: the file holds no data")

    def number(cell):
        try:
            return float(cell)
        except ValueError:
            return None

    first_line, first = lines[0]
    # no header: x, y, u, v (numbers; an empty cell is a missing value, which a
    # first data row may hold as well as any other)
    if all(number(c) is not None or c == "" for c in first):
        if len(first) != 4:
            raise InputError(f"{path}, line {first_line}: without a header the file must have "
                             f"exactly 4 columns (x, y, u, v), found {len(first)}; or add a "
                             f"header line naming the columns x,y,u,v")
        cols, body, width = [0, 1, 2, 3], lines, 4
    else:
        names = [c.lower() for c in first]
        missing = [c for c in CSV_COLUMNS if c not in names]
        if missing:
            found = ", ".join(c if c.isprintable() else repr(c) for c in first)
            raise InputError(f"{path}, line {first_line}: header lacks column(s) "
                             f"{', '.join(missing)}; need x, y, u, v (found: {found})")
        dup = [c for c in CSV_COLUMNS if names.count(c) > 1]
        if dup:
            raise InputError(f"{path}, line {first_line}: column(s) {', '.join(dup)} appear "
                             f"more than once in the header")
        cols, body, width = [names.index(c) for c in CSV_COLUMNS], lines[1:], len(first)
        if names.count("valid") > 1:
            raise InputError(f"{path}, line {first_line}: column valid appears more than once "
                             "in the header")
        if "valid" in names:
            cols.append(names.index("valid"))
        if not body:
            raise InputError(f"{path}: the file has a header but no data rows")
    data = np.empty((len(body), 4))
    valid = np.ones(len(body), dtype=bool)
    need = max(cols) + 1
    names_of = CSV_COLUMNS + ("valid",)
    for k, (n, row) in enumerate(body):
        if (len(row) != 4) if body is lines else (len(row) < need):
            raise InputError(f"{path}, line {n}: expected {width} columns, found {len(row)}")
        for j, c in enumerate(cols):
            name = names_of[j]
            if name == "valid":
                flag = row[c].lower()
                if flag not in VALID_WORDS:
                    raise InputError(f"{path}, line {n}: column valid is {row[c]!r}; write 1 or "
                                     "0 (true or false)")
                valid[k] = VALID_WORDS[flag]
                continue
            val = float("nan") if row[c] == "" and name in ("u", "v") else number(row[c])
            if val is None:
                raise InputError(f"{path}, line {n}: column {name} is not a number: "
                                 f"{row[c]!r}")
            if math.isinf(val) or (math.isnan(val) and name in ("x", "y")):
                raise InputError(f"{path}, line {n}: column {name} is {row[c]!r}; "
                                 + ("coordinates must be finite" if name in ("x", "y") else
                                    "a missing vector is NaN or an empty cell, not infinite"))
            data[k, j] = val
    vectors = data[:, 2:].copy()
    vectors[~valid] = np.nan
    return data[:, :2].copy(), vectors


def read_domain(spec):
    """A domain from a command-line string: ``"x0,y0,x1,y1"`` gives a
    :class:`~taichi_hh.geometry.domain.Box`; a ``.json`` file ``{"outer": [[x, y], ...],
    "holes": [[[x, y], ...], ...]}`` (holes optional) gives a
    :class:`~taichi_hh.geometry.domain.Polygon`.  ``None`` stays ``None`` (the library
    then uses the points' bounding box).  Raises
    :class:`~taichi_hh.errors.InputError`."""
    import json
    import math
    from ..geometry.domain import Box, Polygon
    from ..errors import InputError
    if spec is None:
        return None
    if not isinstance(spec, str):
        from ..geometry.domain import as_domain
        return as_domain(spec)
    s = spec.strip()
    if s.lower().endswith(".json") or os.path.isfile(s):
        if not os.path.exists(s):
            raise InputError(f"domain file {s}: no such file")
        try:
            with open(s, encoding="utf-8") as fh:
                obj = json.load(fh)
        except json.JSONDecodeError as exc:
            raise InputError(f"domain file {s}: invalid JSON (line {exc.lineno}: {exc.msg})") \
                from None
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"domain file {s}: cannot read ({exc})") from None
        if not isinstance(obj, dict) or "outer" not in obj:
            raise InputError(f'domain file {s}: expected an object {{"outer": [[x, y], ...], '
                             f'"holes": [[[x, y], ...], ...]}}')
        unknown = sorted(set(obj) - {"outer", "holes"})
        if unknown:
            raise InputError(f"domain file {s}: unknown key(s) {', '.join(unknown)}; "
                             f"expected 'outer' and optionally 'holes'")
        holes = obj.get("holes") or []
        if not isinstance(holes, list):
            raise InputError(f"domain file {s}: 'holes' must be a list of rings")
        for name, ring in [("outer", obj["outer"])] + [(f"holes[{k}]", h)
                                                       for k, h in enumerate(holes)]:
            if (not isinstance(ring, list) or
                    not all(isinstance(p, list) and len(p) == 2 and
                            all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                for c in p) for p in ring)):
                raise InputError(f"domain file {s}: '{name}' must be a list of [x, y] "
                                 f"number pairs")
        try:
            return Polygon(obj["outer"], holes=holes)
        except InputError as exc:
            raise InputError(f"domain file {s}: {exc}") from None
    parts = [p.strip() for p in s.split(",")]
    vals = []
    for p in parts:
        try:
            vals.append(float(p))
        except ValueError:
            vals = None
            break
    if vals is None or len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"--domain {spec!r}: give four numbers x0,y0,x1,y1 (a box) or a "
                         f".json polygon file")
    x0, y0, x1, y1 = vals
    if not (x0 < x1 and y0 < y1):
        raise InputError(f"--domain {spec!r}: need x0 < x1 and y0 < y1")
    return Box((x0, y0), (x1, y1))


# --------------------------------------------------------------------------- writers

def _savez(path, arrays) -> None:
    import numpy as np
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def _float64_fields(result, names: dict) -> dict:
    """``{file name: result.<attribute> as a float64 array}`` for ``names``
    (file name -> attribute)."""
    import numpy as np
    return {key: np.asarray(getattr(result, attr), dtype=np.float64)
            for key, attr in names.items()}


def write_components(path, result, critical_points=None, threshold: float = 0.1) -> None:
    """Write a :class:`~taichi_hh.hhd.decompose.HHDResult` as a ``.npz`` file, atomically.

    Arrays: ``points``, ``v`` (the input), ``d`` (curl-free), ``r``
    (divergence-free), ``h`` (harmonic), ``phi``, ``psi``, ``divergence``,
    ``curl`` and the critical points as ``xs``, ``ys`` (float) and ``kinds``
    (strings: source, sink, cw_vortex, ccw_vortex) and ``strengths`` (NaN for
    plain tuples).  critical_points: a list of ``(x, y, kind)`` or
    :class:`~taichi_hh.hhd.critical.CriticalPoint`; default
    ``result.critical_points(threshold)``.
    """
    import numpy as np
    if critical_points is None:
        critical_points = result.critical_points(threshold=threshold)
    cps = list(critical_points)
    _savez(path, {
        **_float64_fields(result, {"points": "points", "v": "vectors", "d": "curl_free",
                                   "r": "div_free", "h": "harmonic", "phi": "phi", "psi": "psi",
                                   "divergence": "divergence", "curl": "curl"}),
        "xs": np.array([c[0] for c in cps], dtype=np.float64),
        "ys": np.array([c[1] for c in cps], dtype=np.float64),
        "kinds": np.array([c[2] for c in cps], dtype="<U10"),
        "strengths": np.array([getattr(c, "strength", np.nan) for c in cps], dtype=np.float64),
    })


def write_projection(path, result) -> None:
    """Write a :class:`~taichi_hh.hhd.project.ProjectionResult` as ``.npz``,
    atomically: ``points``, ``vectors`` (the projected field; the file is again
    a valid field for :func:`read_field`), ``initial``, ``divergence`` (of the
    result), ``max_divergence`` and ``sum_sq_divergence`` (per pass, index 0 =
    before projecting) and ``iterations`` (solver iterations per pass)."""
    import numpy as np
    _savez(path, {
        **_float64_fields(result, {name: name for name in (
            "points", "vectors", "initial", "divergence", "max_divergence",
            "sum_sq_divergence")}),
        "iterations": np.asarray(result.stats.get("iterations", []), dtype=np.int64),
    })
