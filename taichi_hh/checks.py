"""Input validation shared by every layer: point arrays, per-point values, real
parameters, random seeds, option values (:class:`OptionSpec`, one per option of
a table: :data:`taichi_hh.hhd.options.OPTION_SPECS`) and option names, and the
argparse value types of the command lines.

Every check either returns the value in canonical form (float64 arrays, a
float, a numpy Generator) or raises :class:`~taichi_hh.errors.InputError`
(``argparse.ArgumentTypeError`` for the argparse types) with a message that
names the argument and the problem.  This module sits at the bottom of the
package next to :mod:`taichi_hh.errors`: it imports nothing else from it.
"""
from __future__ import annotations

import argparse
import difflib
import math
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Callable, Union

import numpy as np

from .arrays import column_mean, rows_all_finite
from .errors import InputError

__all__ = ["as_real_array", "check_spread", "check_points", "check_values", "check_real", "check_int", "check_bool",
           "check_choice", "check_names", "check_option", "did_you_mean", "OptionSpec",
           "check_seed",
           "positive_float", "nonnegative_float", "positive_int", "nonnegative_int",
           "at_least_one_or_off", "OFF"]


# --------------------------------------------------------------------------- arrays
#: dtype kinds refused before the conversion to float64: complex (numpy would
#: drop the imaginary part with a mere warning), object, strings, bytes,
#: records, dates and durations
_NOT_REAL_KINDS = {"c": "complex", "O": "object", "U": "string", "S": "bytes",
                   "V": "record", "M": "datetime", "m": "timedelta",
                   # True and False are no coordinates or velocities (a mask
                   # passed where the values belong)
                   "b": "boolean"}


def as_real_array(data, name: str, what: str) -> np.ndarray:
    """``data`` as a float64 array, or InputError '{name} must be {what}: ...'.
    Complex, object and string arrays are refused by their dtype, not converted."""
    try:
        raw = np.asarray(data)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be {what}: {exc}") from None
    kind = raw.dtype.kind
    if kind == "c":
        raise InputError(f"{name} must be real, got a complex array (dtype {raw.dtype}); "
                         "pass its .real or .imag part explicitly")
    if kind in _NOT_REAL_KINDS:
        raise InputError(f"{name} must be {what}, got an array of {_NOT_REAL_KINDS[kind]} "
                         f"entries (dtype {raw.dtype})")
    try:
        return np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be {what}: {exc}") from None


def check_points(points, name: str = "points", *, allow_empty: bool = False) -> np.ndarray:
    """Validate an (N, 2) array of finite coordinates; returns it as float64.

    ``allow_empty``: accept N = 0 (queries on no points); by default an empty
    array is refused, since a point set needs at least one point."""
    arr = as_real_array(points, name, "a numeric (N, 2) array")
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must have shape (N, 2), got {arr.shape}")
    if arr.shape[0] == 0 and not allow_empty:
        raise InputError(f"{name} is empty: at least one point is needed")
    finite = rows_all_finite(arr)
    if finite is not None:
        idx = np.flatnonzero(~finite)
        raise InputError(f"{name} contains {idx.size} non-finite (NaN or inf) entries, "
                         f"first at index {idx[0]}: {arr[idx[0]].tolist()}")
    return arr


def check_values(values, n: int, ncomp: int, name: str = "values") -> np.ndarray:
    """Validate per-point values: shape (n,) for ncomp = 1 or (n, ncomp); finite."""
    arr = as_real_array(values, name, "numeric")
    want = (n,) if ncomp == 1 else (n, ncomp)
    if arr.shape != want:
        raise InputError(f"{name} must have shape {want} (one per point), got {arr.shape}")
    finite = rows_all_finite(arr.reshape(n, -1))
    if finite is not None:
        idx = np.flatnonzero(~finite)
        raise InputError(f"{name} contains {idx.size} non-finite (NaN or inf) entries, "
                         f"first at point {idx[0]}")
    return arr


#: points count as lying on a line when their spread across their principal
#: line is less than this many times their mean gap along it (length / N): they
#: then cannot form even two rows, and no 2D operator has neighbours off the
#: line (a line computed in floating point spreads ~1e-16 of its length)
LINE_ROWS = 1.0

#: what every refusal of a point set that spans no area ends with
NEEDS_AREA = ("a 2D field needs points spread over an area (at least two rows of "
               "points, not one line)")


def check_spread(points, name: str = "points") -> None:
    """Refuse (:class:`~taichi_hh.errors.InputError`) points that span no area:
    all one point, all on one line (x all equal, y all equal, or any other
    line, also to rounding), or so close to a line that they cannot form two
    rows (spread across their principal line less than :data:`LINE_ROWS`
    times their mean gap along it).  O(N), numpy float64: meant to run before
    any domain, boundary or neighbour is made from the points.  The message
    names no coordinates (they may be in a re-centred frame) but the ratio."""
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n == 0:
        return
    centre = column_mean(pts)
    cx, cy = pts[:, 0] - centre[0], pts[:, 1] - centre[1]
    size = max(float(np.abs(cx).max()), float(np.abs(cy).max()))
    if size > 0:
        cx, cy = cx / size, cy / size   # the scatter below squares: no overflow at 1e200
    # principal axes of the points (the eigenvectors of their 2 x 2 scatter);
    # elementwise sums, not c.T @ c: a BLAS call this long leaves OpenBLAS's
    # threads spinning on the cores Taichi's workers use (docs/notes/series.md)
    sxy = float((cx * cy).sum())
    scatter = np.array([[float((cx * cx).sum()), sxy], [sxy, float((cy * cy).sum())]])
    _, axes = np.linalg.eigh(scatter)              # ascending: axes[:, 1] the major
    along = cx * axes[0, 1] + cy * axes[1, 1]
    length = float(np.ptp(along))
    if not length > 0:
        raise InputError(f"all {n} {name} are the same point: {NEEDS_AREA}")
    across = float(np.ptp(cx * axes[0, 0] + cy * axes[1, 0]))
    if across * n >= LINE_ROWS * length:
        return
    if across <= 1e-9 * length:
        raise InputError(f"the {n} {name} lie on a line and span no area: {NEEDS_AREA}")
    raise InputError(
        f"the {n} {name} lie on a line, or nearly, and span no area: they spread "
        f"{across / length:.3g} of their length across the line, less than their mean "
        f"gap along it (1/{n} of the length), so they form a single row: {NEEDS_AREA}")


# --------------------------------------------------------------------------- scalars
def check_real(value, name: str, *, positive: bool = True, allow_zero: bool = False) -> float:
    """A finite real number (not a bool) as float; ``positive``: also > 0
    (>= 0 with ``allow_zero``)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise InputError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name} must be finite, got {v}")
    if positive and (v < 0 or (v == 0 and not allow_zero)):
        raise InputError(f"{name} must be {'non-negative' if allow_zero else 'positive'}, got {v}")
    return v


def _is_bool(value) -> bool:
    return isinstance(value, (bool, np.bool_))


def _got(value) -> str:
    """'got VALUE', with its type where the repr does not tell it apart from a
    number (True is a bool, '1e-6' a str, (1+0j) a complex); long reprs cut."""
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    if _is_bool(value):
        return f"got {text} (a bool)"
    if value is None or isinstance(value, Real):
        return f"got {text}"
    return f"got {text} (a {type(value).__name__})"


def _range_text(low, high, low_open: bool, high_open: bool) -> str:
    """' > 0', ' >= 1', ' in [1, 24]', ' in (0, 2)' or ''."""
    if low is not None and high is not None:
        return f" in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    if low is not None:
        return f" {'>' if low_open else '>='} {low:g}"
    if high is not None:
        return f" {'<' if high_open else '<='} {high:g}"
    return ""


def _in_range(v, low, high, low_open: bool, high_open: bool) -> bool:
    return ((low is None or (v > low if low_open else v >= low))
            and (high is None or (v < high if high_open else v <= high)))


def _integer(value):
    """int(value) for a Python or numpy int or a float with an integral value
    (1e4); None for anything else, a bool included."""
    if _is_bool(value):
        return None
    if isinstance(value, Integral):
        return int(value)
    if isinstance(value, Real):
        f = float(value)
        if math.isfinite(f) and f.is_integer():
            return int(f)
    return None


def check_int(value, name: str, *, low=None, high=None) -> int:
    """An integer (a Python or numpy int, or a float with an integral value such
    as 1e4; never a bool) in ``[low, high]`` as int."""
    return check_option(value, name, OptionSpec("int", low=low, high=high))


def check_bool(value, name: str) -> bool:
    """True or False (or a numpy bool); 0, 1 and strings such as "no" are refused."""
    return check_option(value, name, OptionSpec("bool"))


def did_you_mean(word, valid) -> str:
    """' (did you mean 'x'?)' for close spellings of ``word`` among ``valid``
    (difflib, or a name that one of the two starts with), else ''."""
    if not isinstance(word, str):
        return ""
    names = [str(v) for v in valid]
    close = difflib.get_close_matches(word, names, n=3, cutoff=0.6)
    close += [v for v in names if v not in close and min(len(v), len(word)) >= 3
              and (word.startswith(v) or v.startswith(word))]
    return f" (did you mean {' or '.join(repr(c) for c in close[:3])}?)" if close else ""


def check_choice(value, name: str, choices) -> str:
    """One of the strings ``choices``; the message lists them (and the close ones)."""
    return check_option(value, name, OptionSpec("choice", choices=tuple(choices)))


def check_names(names, valid, *, what: str = "option") -> None:
    """Every name in ``names`` among ``valid``; else InputError naming the unknown
    ones, their close spellings and the valid names."""
    valid = tuple(valid)
    unknown = [n for n in names if n not in valid]
    if unknown:
        listed = ", ".join(f"{n!r}{did_you_mean(n, valid)}" for n in unknown)
        raise InputError(f"unknown {what}{'s' if len(unknown) > 1 else ''} {listed}; "
                         f"valid names: {', '.join(map(str, valid))}")


@dataclass(frozen=True)
class OptionSpec:
    """How the value of one option is checked (:func:`check_option`).

    kind: ``"real"`` (a finite real number: not a bool, a string or a complex;
    numpy scalars and ints accepted, returned as float), ``"int"``
    (:func:`check_int`), ``"bool"`` (:func:`check_bool`), ``"choice"``
    (:func:`check_choice`) or ``"options"`` (named sub-options: a dict or
    (name, value) pairs, each checked by its spec in ``fields``; returned as
    pairs sorted by name).  low, high: bounds of reals and ints (``low_open``,
    ``high_open``: the bound itself excluded).  choices: the valid strings, or
    a function returning them (for lists defined in modules imported late).
    none: None is accepted, and kept."""
    kind: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: Union[tuple, Callable[[], tuple]] = ()
    none: bool = False
    fields: dict | None = None

    KINDS = ("real", "int", "bool", "choice", "options")

    def __post_init__(self):
        if self.kind not in self.KINDS:
            raise ValueError(f"OptionSpec kind must be one of {self.KINDS}, got {self.kind!r}")

    def valid_choices(self) -> tuple:
        return tuple(self.choices() if callable(self.choices) else self.choices)

    def describe(self) -> str:
        """What a valid value is, in words ('a finite real number > 0 or None')."""
        rng = _range_text(self.low, self.high, self.low_open, self.high_open)
        text = {"real": "a finite real number" + rng,
                "int": "an integer" + rng,
                "bool": "True or False",
                "choice": f"one of {self.valid_choices()}",
                "options": "a dict or (name, value) pairs"}[self.kind]
        return text + (" or None" if self.none else "")


def check_option(value, name: str, spec: OptionSpec):
    """``value`` of option ``name`` checked against ``spec``, in canonical form
    (float, int, bool, str, or sorted (name, value) pairs); else InputError
    '{name} must be ..., got ...'."""
    if value is None:
        if spec.none:
            return None
        raise InputError(f"{name} must be {spec.describe()}, got None")
    if spec.kind == "real":
        if _is_bool(value) or not isinstance(value, Real):
            raise InputError(f"{name} must be {spec.describe()}, {_got(value)}")
        v = float(value)
        if not math.isfinite(v) or not _in_range(v, spec.low, spec.high, spec.low_open,
                                                 spec.high_open):
            raise InputError(f"{name} must be {spec.describe()}, got {v!r}")
        return v
    if spec.kind == "int":
        v = _integer(value)
        if v is None:
            raise InputError(f"{name} must be {spec.describe()}, {_got(value)}")
        if not _in_range(v, spec.low, spec.high, spec.low_open, spec.high_open):
            raise InputError(f"{name} must be {spec.describe()}, got {v}")
        return v
    if spec.kind == "bool":
        if not _is_bool(value):
            raise InputError(f"{name} must be {spec.describe()}, {_got(value)}")
        return bool(value)
    if spec.kind == "choice":
        choices = spec.valid_choices()
        if not isinstance(value, str) or value not in choices:
            got = f"got {value!r}" if isinstance(value, str) else _got(value)
            raise InputError(f"{name} must be {spec.describe()}, {got}"
                             f"{did_you_mean(value, choices)}")
        return str(value)
    return _check_sub_options(value, name, spec)


def _check_sub_options(value, name: str, spec: OptionSpec) -> tuple:
    """Named sub-options (a dict or (name, value) pairs), each name among
    ``spec.fields`` and each value checked by its spec, as pairs sorted by name."""
    if isinstance(value, dict):
        items = list(value.items())
    elif isinstance(value, (tuple, list)) and all(
            isinstance(item, (tuple, list)) and len(item) == 2 for item in value):
        items = [tuple(item) for item in value]
    else:
        raise InputError(f"{name} must be {spec.describe()}, {_got(value)}")
    keys = [k for k, _ in items]
    bad = [k for k in keys if not isinstance(k, str)]
    if bad:
        raise InputError(f"{name}: option names must be strings, got {bad[0]!r}")
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise InputError(f"{name} names {', '.join(map(repr, twice))} more than once")
    fields = spec.fields or {}
    check_names(keys, fields, what=f"{name} entry")
    return tuple(sorted(((k, check_option(v, f"{name}[{k!r}]", fields[k])) for k, v in items),
                        key=lambda kv: kv[0]))


def check_seed(seed) -> np.random.Generator:
    """A numpy Generator from a seed: None, a non-negative integer, a
    SeedSequence or a Generator (used as is, so its stream continues)."""
    if seed is None or isinstance(seed, (np.random.SeedSequence, np.random.Generator)):
        return np.random.default_rng(seed)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer (or None), got {seed!r}")
    return np.random.default_rng(int(seed))


# --------------------------------------------------------------------------- argparse types
def _argparse_number(name: str, convert, noun: str, accept, requirement: str, doc: str):
    """The argparse type ``name``: ``convert(text)`` (else "not {noun}") that
    ``accept`` takes (else "must be {requirement}")."""
    def parse(text: str):
        try:
            v = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {noun}: {text!r}") from None
        if not accept(v):
            raise argparse.ArgumentTypeError(f"must be {requirement}, got {text!r}")
        return v
    parse.__name__ = parse.__qualname__ = name
    parse.__doc__ = f"argparse type: {doc}."
    return parse


positive_float = _argparse_number("positive_float", float, "a number",
                                  lambda v: math.isfinite(v) and v > 0,
                                  "a positive number", "a finite number > 0")
nonnegative_float = _argparse_number("nonnegative_float", float, "a number",
                                     lambda v: math.isfinite(v) and v >= 0,
                                     "a non-negative number", "a finite number >= 0")
positive_int = _argparse_number("positive_int", int, "an integer", lambda v: v >= 1,
                                "a positive integer", "an integer >= 1")
nonnegative_int = _argparse_number("nonnegative_int", int, "an integer", lambda v: v >= 0,
                                   "a non-negative integer", "an integer >= 0")


#: what :func:`at_least_one_or_off` gives for ``off`` (an option's None, which
#: an option not given on the command line cannot say)
OFF = "off"


def at_least_one_or_off(text: str):
    """argparse type: a number >= 1, or ``off`` (:data:`OFF`)."""
    if text.strip().lower() == OFF:
        return OFF
    v = positive_float(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a number >= 1 or 'off', got {text!r}")
    return v
