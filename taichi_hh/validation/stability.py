"""The status of one cell of the stability map (``benchmarks/stability_map.py``):
did a method finish accurately, lose accuracy, report its failure, or return
garbage silently?

Statuses: ``ok``; ``inaccurate`` (err > :data:`ERR_ABS`, or more than
:data:`ERR_REL` times the same row's reference cell); ``flagged`` (returned,
but flagged by the library's own consistency check: ``AccuracyWarning``,
``stats["flags"]``); ``error`` (raised one of this package's exceptions, naming
the cause); ``garbage`` (returned NaN/inf or absurd values without an error:
a component above :data:`ABSURD_RATIO` times max |v|, a flow speed above
:data:`ABSURD_SPEED`); ``crash`` (the worker died, or raised an exception that
is not the package's).  The map's job is to show that ``garbage`` and
``crash`` never happen.
"""
from __future__ import annotations

import math
import re

from .measures import as_float

ERR_ABS = 0.25            # inaccurate above this error
ERR_REL = 4.0             # ... or above this factor times the row's reference cell
ABSURD_RATIO = 100.0      # garbage: a component above this times max |v|
ABSURD_SPEED = 10.0       # garbage: a flow speed above this (box 1 x 2, g = 1: five
#                           times the free-fall speed over the box height)
PACKAGE_ERRORS = ("InputError", "NeighbourError", "SolverError", "BlowUpError", "BlowUp",
                  "TaichiHHError")
STATUSES = ("ok", "inaccurate", "error", "flagged", "garbage", "crash")


def classify(row: dict, ref_err: float) -> tuple[str, str]:
    """(status, note) of one cell: ``row`` is a sweep row
    (:data:`~taichi_hh.validation.sweep.CSV_FIELDS`), ``ref_err`` the error of
    its row's reference cell (NaN when there is none); see the module doc."""
    st = row.get("status")
    if st == "crash":
        return "crash", f"worker died: {row.get('message', '')[:60]}"
    if st == "error":
        if row.get("error") not in PACKAGE_ERRORS:
            return "crash", f"{row.get('error')}: {row.get('message', '')[:60]}"
        why = row.get("reason") or ""
        return "error", f"{row['error']}{': ' + why if why else ''}"
    if row.get("flags"):
        # returned, but flagged by the library's own consistency check
        # (AccuracyWarning, stats["flags"]): reported, not silent
        m = re.search(r"carry ([0-9.e+]+) times", row["flags"])
        return "flagged", f"AccuracyWarning\nenergy x{m.group(1) if m else '?'}"
    err = as_float(row.get("err"))
    absurd = as_float(row.get("max_abs_ratio"))
    if row.get("task") == "rt":
        speed = as_float(row.get("max_speed"))
        if not row.get("finite") or not math.isfinite(err) or not (speed <= ABSURD_SPEED):
            return "garbage", f"max speed {speed:.2g}\nerr {err:.2g}"
    elif not row.get("finite") or not math.isfinite(err) or not (absurd <= ABSURD_RATIO):
        return "garbage", ("non-finite" if not row.get("finite") else
                           f"|out| {absurd:.1e}\nx max|v|")
    note = f"err {err:.2g}"
    if row.get("task") == "hhd" and row.get("iterations_phi") not in (None, ""):
        note += f"\nit {row['iterations_phi']}/{row['iterations_psi']}"
    if err > ERR_ABS:
        return "inaccurate", note
    if math.isfinite(ref_err) and ref_err > 0 and err > ERR_REL * ref_err:
        return "inaccurate", note + f" ({err / ref_err:.0f}x ref)"
    return "ok", note
