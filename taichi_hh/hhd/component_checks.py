"""The components every decomposition returns (:class:`Components`, the
arrays its result records share) and the checks it makes of them: the energy
of the parts against the field's (Petronetto Eq. 16) and how harmonic h is.
Both flag what they find in ``stats["flags"]`` and by an
:class:`~taichi_hh.errors.AccuracyWarning`."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import AccuracyWarning
from .options import METHODS, HHDOptions

__all__ = ["Components", "HARMONIC_LIMIT", "ENERGY_LIMIT", "flag_harmonic", "check_energy",
           "check_harmonic", "divergence_curl"]


@dataclass(kw_only=True)
class Components:
    """The arrays every decomposition result holds
    (:class:`~taichi_hh.hhd.decompose.HHDResult`,
    :class:`~taichi_hh.hhd.decomposer.SeriesResult`,
    :class:`~taichi_hh.hhd.grid.GridResult`: the shapes are theirs);
    keyword-only."""
    curl_free: np.ndarray      # d = grad phi
    div_free: np.ndarray       # r = J grad psi
    harmonic: np.ndarray       # h = v - d - r
    phi: np.ndarray
    psi: np.ndarray
    divergence: np.ndarray     # SPH div v at the points (the right-hand side of Eq. 5)
    curl: np.ndarray


#: h with mean |div h| or |curl h| above this fraction of the field's mean
#: sqrt(div v^2 + curl v^2) is not harmonic: flagged.  Measured (docs/notes/hhd.md):
#: 0.02-0.16 for the default method on the analytic fields at 13k-1k points,
#: up to 0.29 for petronetto2010, 0.47 for the natural HHD of pure 1% noise
#: (finer than its grid), 1.0 for a rigid rotation under Neumann
HARMONIC_LIMIT = 0.5

#: components with more than this many times the field's energy are flagged
ENERGY_LIMIT = 4.0


def divergence_curl(ps, st, w):
    """div w and curl w at the data points by the stencil ``st``."""
    out = ps.new_array(2)
    ps.ops.divergence_and_curl(st, ps.upload(w), out)
    dc = ps.download(out)
    return dc[:, 0], dc[:, 1]


def check_harmonic(stats, problems, h, *, stacklevel: int = 5) -> None:
    """How harmonic h is: ``stats["h_divergence"]``, ``stats["h_curl"]`` (mean |div h|
    and |curl h| over the mean of sqrt(div v^2 + curl v^2), the divergence operator
    over the data points); above :data:`HARMONIC_LIMIT` flagged as check_energy does.
    ``problems``: the :class:`~taichi_hh.hhd.decompose.PoissonProblems` (point set,
    options, right-hand sides, vectors, divergence stencil) h came from."""
    ps, opts = problems.ps, problems.opts
    if opts.boundary == "petronetto" or opts.remove_mean:
        # the right-hand sides are not div v and curl v over the data alone there
        st = ps.gradient_stencil(opts.divergence)
        div_v, curl_v = divergence_curl(ps, st, problems.vectors)
    else:                                   # the same operator as the right-hand sides'
        st = problems.divergence_stencil
        div_v = problems.rhs["phi"][ps.slot_of]
        curl_v = -problems.rhs["psi"][ps.slot_of]
    scale = float(np.hypot(div_v, curl_v).mean())
    ratios = {}
    for name, values in zip(("divergence", "curl"), divergence_curl(ps, st, h)):
        mean = float(np.abs(values).mean())
        ratios[name] = mean / scale if scale > 0 else (0.0 if mean == 0 else math.inf)
    flag_harmonic(stats, ratios, opts, stacklevel=stacklevel)


def flag_harmonic(stats, ratios: dict, opts: HHDOptions, *, stacklevel: int = 5) -> None:
    """``stats["h_divergence"]``, ``stats["h_curl"]`` from ``ratios`` (by
    ``divergence``, ``curl``); above :data:`HARMONIC_LIMIT` flagged (stats and
    an AccuracyWarning)."""
    for name in ("divergence", "curl"):
        stats[f"h_{name}"] = ratios[name]
    stats.setdefault("flags", [])
    worst = max(ratios, key=ratios.get)
    if not ratios[worst] <= HARMONIC_LIMIT:
        msg = (f"h is not harmonic: mean |{'div' if worst == 'divergence' else 'curl'} h| is "
               f"{ratios[worst]:.3g} of the field's mean derivative (limit {HARMONIC_LIMIT:g}); "
               f"with boundary_condition={opts.boundary_condition!r}")
        if not stats.get("energy_ratio", 1.0) <= ENERGY_LIMIT:
            msg += "; the operators are inconsistent on these points (see the energy flag)"
        elif opts.boundary_condition == "neumann":
            msg += ("; the usual cause: the field has net curl or divergence, which the "
                    "Neumann condition cannot put into d or r (boundary_condition="
                    "'normal-parallel' or 'natural' can)")
        stats["flags"].append(msg)
        warnings.warn(msg, AccuracyWarning, stacklevel=stacklevel)


def check_energy(stats, v, d, r, h, vol, opts, *, stacklevel: int = 4,
                 energies=None) -> None:
    """The decomposition is L2-orthogonal (Petronetto Eq. 16), so
    |d|^2 + |r|^2 + |h|^2 = |v|^2 (volume-weighted sums) for an exact one; an
    accurate discrete one stays within a few percent (docs/notes/hhd.md).
    Components carrying several times the field's energy cancel each other: the
    operators are inconsistent on these points (e.g. the symmetric gradient on
    random points).  ``stats["energy_ratio"]``; above :data:`ENERGY_LIMIT`
    flagged.  ``energies``: the four volume-weighted sums (v, d, r, h) made
    already (a batch of natural splits: :class:`~.natural.NaturalSplit`)."""
    def energy(x):
        # one pass of einsum, no temporaries (numpy's sum over an axis of two
        # is slow); no np.dot: a BLAS call this long wakes OpenBLAS's threads,
        # which then spin beside Taichi's pinned workers (docs/notes/series.md)
        return float(np.einsum("i,ij,ij->", vol, x, x))

    total, ed, er, eh = energies if energies is not None else map(energy, (v, d, r, h))
    ratio = (ed + er + eh) / total if total > 0 else 1.0
    stats["energy_ratio"] = ratio
    stats.setdefault("flags", [])
    if not np.isfinite(ratio) or ratio > ENERGY_LIMIT:
        default = METHODS["default"]
        if (opts.gradient, opts.divergence, opts.laplacian) != \
                (default.gradient, default.divergence, default.laplacian):
            why = (f"the operators (gradient {opts.gradient!r}, divergence "
                   f"{opts.divergence!r}, Laplacian {opts.laplacian!r}) are not consistent "
                   "on these points; the default method's are")
        else:
            why = ("the components cancel each other: the data are too few or too noisy "
                   "for the operators at this resolution, or the boundary condition "
                   f"({opts.boundary_condition!r}) forces large opposite parts near the "
                   "boundary (boundary_condition='natural' imposes none)")
        msg = (f"decomposition components carry {ratio:.3g} times the field's energy "
               f"(|d|^2 + |r|^2 + |h|^2 over |v|^2; 1 for an exact decomposition): {why}; "
               "the components are unreliable")
        stats["flags"].append(msg)
        warnings.warn(msg, AccuracyWarning, stacklevel=stacklevel)
