"""The decomposition through the SPH operators at the points, of one field
or of many on the same points: :class:`OperatorSplit`.

The conditions with Poisson rows (``neumann``, ``normal-parallel``,
``no-flux``: two systems, phi's Neumann rows and psi's Dirichlet rows) and
the natural condition with operator options other than the default's (the
SPH div v and curl v convolved, :func:`~taichi_hh.hhd.natural.natural_potentials`).
The set-up (:func:`~taichi_hh.hhd.poisson_setup.unit_setup`: particles,
neighbours, stencils, matrix, preconditioner) is made once per system; the
fields' right-hand sides are solved together as the columns of one BiCGSTAB
(:meth:`~taichi_hh.poisson.matrix.PoissonMatrix.solve_columns`: the matrix
and the preconditioner read once per iteration for all), at most
``max_columns`` at a time (:data:`MAX_COLUMNS`, and the memory: the solver
holds about a dozen vectors per column).  Each column runs its own iteration and stopping test, so a
field's answer is the one a call for it alone gives, to the solver's
tolerance.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .. import runtime
from ..errors import InputError
from .component_checks import check_energy, check_harmonic
from .corners import check_corners
from .inputs import Data, check_point_count
from .natural import natural_potentials
from .options import HHDOptions
from .poisson_setup import PoissonSetup, right_hand_sides, unit_setup
from .rotation import J

__all__ = ["OperatorSplit", "NO_FLUX_PARTS", "solve_potentials", "factorise", "COLUMN_BYTES",
           "MAX_COLUMNS"]

#: ``no-flux``: each potential under its own condition, one system each
#: (phi's Neumann rows, psi's Dirichlet rows)
NO_FLUX_PARTS = (("phi", "neumann"), ("psi", "normal-parallel"))
#: the memory of the joint solve's columns at most (bytes): about a dozen
#: vectors of the system's length per column (BiCGSTAB's and the
#: multilevel cycle's work vectors)
COLUMN_BYTES = 512 * 2 ** 20
#: vectors the joint solve holds per column
VECTORS_PER_COLUMN = 16
#: columns in one joint solve at most: on the CPU wider joint solves ran
#: slower per column at 13k and at 100k points (docs/notes/series.md)
MAX_COLUMNS = 4


def solve_potentials(setup: PoissonSetup, columns: list, seconds: dict, say) -> list:
    """Step (d): the solutions of ``setup.A`` for the right-hand sides
    ``columns`` (per slot), as ``(x, stats)`` pairs (stats: iterations,
    relative residual, the bordered compatibility unknown).  With BiCGSTAB
    (the default) the columns are solved together
    (:meth:`~taichi_hh.poisson.matrix.PoissonMatrix.solve_columns`).
    ``seconds["preconditioner"]``: its set-up (once per matrix);
    ``seconds["solve"]``: the iterations."""
    opts, A = setup.opts, setup.A
    if setup.factor is not None:              # a series' factorisation: triangular solves
        t = time.perf_counter()
        out = _direct_columns(setup, columns)
        seconds["preconditioner"] = seconds.get("preconditioner", 0.0)
        seconds["solve"] = seconds.get("solve", 0.0) + time.perf_counter() - t
        return out
    say("preconditioner")
    t = time.perf_counter()
    preconditioner = A.preconditioner_for(opts.preconditioner, opts.solver,
                                          dict(opts.multilevel_options))
    seconds["preconditioner"] = seconds.get("preconditioner", 0.0) + time.perf_counter() - t
    say("solve phi and psi")
    t = time.perf_counter()
    if opts.solver == "bicgstab":
        results = A.solve_columns(np.stack(columns, axis=1), tol=opts.tol,
                                  max_iterations=opts.max_iterations,
                                  preconditioner=preconditioner)
    else:
        # Colin's stacked boundary system is overdetermined and inconsistent in
        # general: CGNR then seeks its least-squares solution (Colin Sec. 3.5)
        extra = {"least_squares": True} if opts.solver == "cgnr" else {}
        results = [A.solve(b, method=opts.solver, tol=opts.tol,
                           max_iterations=opts.max_iterations, preconditioner=preconditioner,
                           **extra) for b in columns]
    seconds["solve"] = seconds.get("solve", 0.0) + time.perf_counter() - t
    return [(res.x, {"iterations": res.iterations, "residual": res.relative_residual,
                     "compatibility": res.border}) for res in results]


def factorise(setup: PoissonSetup) -> None:
    """``setup.factor``: scipy's SuperLU of the assembled matrix (bordered
    row and column included), for many right-hand sides by triangular solves
    (:func:`_direct_columns`).  scipy is optional: InputError without it."""
    try:
        import scipy.sparse.linalg as sla
    except ImportError:
        raise InputError("factorize=True needs scipy (pip install scipy); the default "
                         "(factorize=False) solves by BiCGSTAB without it") from None
    S = setup.A.to_scipy().tocsc()
    setup.factor = (S, sla.splu(S))


def _direct_columns(setup: PoissonSetup, columns: list) -> list:
    """The columns solved by the kept factorisation: ``(x, stats)`` pairs as
    :func:`solve_potentials` gives them (no iterations; the relative
    residual of the assembled system measured)."""
    A = setup.A
    S, lu = setup.factor
    B = np.stack(columns, axis=1)
    if A.bordered:
        B = np.vstack([B, np.zeros((1, B.shape[1]))])
    X = lu.solve(B)
    R = S @ X - B
    out = []
    for c in range(B.shape[1]):
        norm = float(np.linalg.norm(B[:, c]))
        residual = float(np.linalg.norm(R[:, c]) / norm) if norm > 0 else 0.0
        out.append((X[:A.n_particles, c].copy(),
                    {"iterations": 0, "residual": residual,
                     "compatibility": float(X[A.n_particles, c]) if A.bordered else 0.0}))
    return out


class _Problems:
    """What :func:`~taichi_hh.hhd.component_checks.check_harmonic` reads of a
    field's problems (duck-typed :class:`~taichi_hh.hhd.decompose.PoissonProblems`)."""

    def __init__(self, setup: PoissonSetup, rhs: dict, vectors):
        self.ps, self.opts, self.rhs, self.vectors = setup.ps, setup.opts, rhs, vectors
        self.divergence_stencil = setup.divergence_stencil


class OperatorSplit:
    """The decomposition of fields on the points of ``data`` (unit frame) under
    ``opts`` (its condition one of ``neumann``, ``normal-parallel``,
    ``no-flux``, or ``natural`` with the SPH operator: module doc).

    ``keep``: the systems' set-up kept for the next :meth:`split` (a series);
    without it each system is built when first needed and dropped after its
    solve (one field: no-flux's first system freed before the second is
    made, as the single call always did)."""

    def __init__(self, data: Data, opts: HHDOptions, *, keep: bool = True,
                 max_columns: int | None = None, factorize: bool = False):
        if factorize and opts.solver != "bicgstab":
            raise InputError(f"factorize=True solves the square systems of solver='bicgstab'; "
                             f"solver={opts.solver!r} seeks a least-squares solution")
        self.data, self.opts, self.keep, self.factorize = data, opts, keep, factorize
        self.parts = (NO_FLUX_PARTS if opts.boundary_condition == "no-flux"
                      else (("phi psi", opts.boundary_condition),))
        self._setups = {}
        self.max_columns = max_columns
        self.seconds = {}

    def setup(self, condition: str, progress=None) -> tuple:
        """``(setup, built_now)``: the system of ``condition``, made once while kept."""
        if condition in self._setups:
            return self._setups[condition], False
        d = self.data
        s = unit_setup(d.unit_points, d.unit_domain,
                       replace(self.opts, boundary_condition=condition), progress, d)
        if self.factorize and s.A is not None:
            t = time.perf_counter()
            factorise(s)
            s.seconds["factorise"] = time.perf_counter() - t
        if self.keep:
            self._setups[condition] = s
        return s, True

    def build(self, progress=None) -> None:
        """Every system made now (and its preconditioner), not at the first field."""
        for _, condition in self.parts:
            s, _ = self.setup(condition, progress)
            if s.A is not None and s.factor is None:
                t = time.perf_counter()
                s.A.preconditioner_for(s.opts.preconditioner, s.opts.solver,
                                       dict(s.opts.multilevel_options))
                s.seconds["preconditioner"] = time.perf_counter() - t
        for s in self._setups.values():
            for k, v in s.seconds.items():
                self.seconds[k] = self.seconds.get(k, 0.0) + v

    def _columns(self, n_slots: int) -> int:
        cap = MAX_COLUMNS if self.max_columns is None else max(1, int(self.max_columns))
        return max(1, min(cap, COLUMN_BYTES // (VECTORS_PER_COLUMN * 8 * max(n_slots, 1))))

    def split(self, fields: list, progress=None) -> list:
        """The unit-frame :class:`~taichi_hh.hhd.decompose.HHDResult` of each of
        ``fields`` (:class:`~taichi_hh.hhd.inputs.Data` on this split's points,
        their ``unit_vectors`` the field), in order."""
        from .decompose import HHDResult
        say = progress or (lambda stage: None)
        t_start = time.perf_counter()
        count = len(fields)
        seconds = [dict() for _ in range(count)]
        stats = [None] * count
        solved = [dict() for _ in range(count)]       # name -> (potential, gradient)
        rhs = [None] * count
        for names, condition in self.parts:
            names = names.split()
            setup, built = self.setup(condition, progress)
            if built and count:
                for k, v in setup.seconds.items():
                    seconds[0][k] = seconds[0].get(k, 0.0) + v
            if names[0] == "phi":          # the first system: too few points refused or flagged
                counted = {}
                check_point_count(len(setup.points), counted, stacklevel=6)
            for i, data in enumerate(fields):
                t = time.perf_counter()
                say("divergence and curl")
                rhs[i] = right_hand_sides(setup, data.unit_vectors)
                seconds[i]["divergence"] = (seconds[i].get("divergence", 0.0)
                                            + time.perf_counter() - t)
                if stats[i] is None or names == ["psi"]:
                    first = stats[i]
                    stats[i] = dict(setup.stats)
                    if names[0] == "phi":
                        stats[i]["flags"] = list(counted["flags"])
                    if first is not None:          # no-flux: phi's solve stats kept
                        stats[i].update({k: v for k, v in first.items()
                                         if k.endswith("_phi") or k == "flags"})
            if setup.A is None:
                self._natural(setup, names, rhs, solved, stats, seconds, say)
            else:
                self._solve(setup, names, rhs, solved, stats, seconds, say)
        results = []
        for i, data in enumerate(fields):
            t = time.perf_counter()
            phi, d = solved[i]["phi"]
            psi, grad_psi = solved[i]["psi"]
            vec, pts, ps = data.unit_vectors, setup.points, setup.ps
            r = J(grad_psi)
            h = vec - d - r
            st = stats[i]
            st["seconds"] = seconds[i]
            check_energy(st, vec, d, r, h, ps.particles.get("volume")[ps.slot_of], self.opts,
                         stacklevel=6)
            check_harmonic(st, _Problems(setup, rhs[i], vec), h, stacklevel=7)
            if self.opts.boundary_condition != "natural":
                check_corners(st, pts, d, r, setup.domain, st["spacing"],
                              self.opts.boundary_condition, data.frame.points_from_unit)
            seconds[i]["checks"] = time.perf_counter() - t
            results.append(HHDResult(points=pts, vectors=vec, curl_free=d, div_free=r,
                                     harmonic=h, phi=phi, psi=psi,
                                     divergence=rhs[i]["phi"][ps.slot_of],
                                     curl=-rhs[i]["psi"][ps.slot_of], stats=st,
                                     options=self.opts, pointset=ps, domain=setup.domain))
        if count:
            seconds[0]["total"] = time.perf_counter() - t_start
        runtime.release_launch_arguments(setup.ps.n_total)
        return results

    def _solve(self, setup, names, rhs, solved, stats, seconds, say) -> None:
        """Step (d) and (e) for the potentials ``names`` of every field: the
        right-hand sides in joint solves of at most ``max_columns`` columns
        (zero columns padding each batch to a power-of-two width: a few compiled
        widths), then each field's gradients."""
        ps = setup.ps
        columns = [(i, name) for i in range(len(rhs)) for name in names]
        width = max(min(self._columns(ps.n_total), len(columns)), len(names))
        if len(columns) > width and len(names) > 1:
            width -= width % len(names)        # a field's columns in one batch
        # joint solves of a power-of-two width, zero columns padding the rest:
        # each width compiles its kernels once (tens of seconds), so a series
        # meets a few of them, not one per batch length
        padded = 1 << (width - 1).bit_length()
        zero = np.zeros(ps.n_total)
        out = {}
        for start in range(0, len(columns), width):
            batch = columns[start:start + width]
            B = [rhs[i][name] for i, name in batch]
            B += [zero] * (padded - len(B))
            timing = {}
            answers = solve_potentials(setup, B, timing, say)
            for (i, name), (x, s) in zip(batch, answers):
                out[i, name] = x
                for key, value in s.items():
                    stats[i][f"{key}_{name}"] = value
            # the batch's iterations shared by its columns; the preconditioner
            # (made at the first solve, then kept by the matrix) charged to its first
            for i in dict.fromkeys(i for i, _ in batch):
                share = sum(1 for j, _ in batch if j == i) / len(batch)
                seconds[i]["solve"] = seconds[i].get("solve", 0.0) + timing["solve"] * share
            first = seconds[batch[0][0]]
            first["preconditioner"] = first.get("preconditioner", 0.0) + timing["preconditioner"]
        say("components")
        st_grad = setup.gradient_stencil()
        for i in range(len(rhs)):
            t = time.perf_counter()
            a = out.get((i, "phi"))
            b = out.get((i, "psi"))
            a = np.zeros_like(b) if a is None else np.asarray(a)
            b = np.zeros_like(a) if b is None else np.asarray(b)
            ga, gb = _gradients(ps, st_grad, a, b)
            for name, x, g in (("phi", a, ga), ("psi", b, gb)):
                if name in names:
                    solved[i][name] = (x[ps.slot_of], g)
            seconds[i]["components"] = (seconds[i].get("components", 0.0)
                                        + time.perf_counter() - t)

    def _natural(self, setup, names, rhs, solved, stats, seconds, say) -> None:
        """The natural condition with the SPH operator's div v and curl v
        (:func:`~taichi_hh.hhd.natural.natural_potentials`), field by field."""
        ps = setup.ps
        say("natural potentials")
        for i in range(len(rhs)):
            t = time.perf_counter()
            nat = natural_potentials(setup.points, setup.domain,
                                     {k: rhs[i][k][ps.slot_of] for k in ("phi", "psi")},
                                     stats[i]["spacing"], evaluation=self.opts.natural_evaluation)
            solved[i]["phi"], solved[i]["psi"] = nat["phi"], nat["psi"]
            stats[i]["natural_grid"] = nat["grid"].shape
            seconds[i]["natural"] = time.perf_counter() - t
            seconds[i].update({f"natural_{k}": v for k, v in nat.get("seconds", {}).items()})


def _gradients(ps, st_grad, a, b) -> tuple:
    """Step (e): the gradients (stencil ``st_grad``) of two per-slot fields at the
    data points, one pass over the pairs."""
    f_nd = ps.new_array(2, zeroed=False)
    f_nd.from_numpy(np.stack([a, b], axis=1).astype(runtime.np_real()))
    ga, gb = ps.new_array(2, zeroed=False), ps.new_array(2, zeroed=False)
    ps.ops.gradients(st_grad, f_nd, ga, gb)
    return ps.download(ga), ps.download(gb)
