"""Command line: ``taichi-hh`` (also ``python -m taichi_hh``).

Subcommands are added as features land; each lives in its own function and
only parses arguments, calls the library and writes files.

``decompose FIELD``  Helmholtz-Hodge decomposition -> DIR/components.npz + figures
``project FIELD``    null-divergence projection    -> DIR/projected.npz, measures.csv + figures
``info``             version and Taichi arch
``scene NAME ...``   a two-phase scene (rising-droplet, rayleigh-taylor) -> frames, particles
``worker start|stop|status``  a persistent worker that runs ``decompose`` and
                     ``project`` with Taichi's kernels kept loaded
                     (:mod:`taichi_hh.app.worker`; :func:`main` hands a call to it
                     when one runs, unless ``--no-worker``)

Errors in the input or in the numerics (:class:`~taichi_hh.errors.InputError`,
:class:`~taichi_hh.errors.SolverError`, :class:`~taichi_hh.errors.NeighbourError`,
bad option values, an --out that cannot be written) print one line
``taichi-hh CMD: error: ...`` on stderr and exit with status 2 (as argparse
does for bad usage), leaving no result file of the failed command; an
unexpected error prints one line naming a file with the full report (status
1); set ``TAICHI_HH_DEBUG=1`` to get the traceback instead
(:mod:`taichi_hh.app.errors_report`).
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import textwrap
import time

# numpy, Taichi and the rest load in the functions that need them: a call that
# a persistent worker runs (app/worker_client.py) imports the standard library only

#: HHDOptions fields not on the command line: the multilevel cycle's tuning
#: (a library option: ``decompose(..., multilevel_options={...})``)
LIBRARY_ONLY_OPTIONS = ("multilevel_options",)

#: HHDOptions fields exposed as --options: field -> (metavar/choices source, help)
_OPTION_HELP = {
    "kernel": "SPH smoothing kernel",
    "support_ratio": "kernel support radius divided by the point spacing (the local "
                     "spacing with --adaptive-support, else the mean sqrt(area / N)); "
                     "larger = more neighbours, smoother and slower",
    "adaptive_support": "a support per point from the local spacing (its K nearest "
                        "neighbours): uniformly random, clustered and varying-density "
                        "points keep enough neighbours everywhere",
    "support_neighbours": "K, the nearest neighbours of the local spacing estimate of "
                          "--adaptive-support (1-24)",
    "divergence": "gradient variant used to compute div v and curl v (the right-hand "
                  "sides of the two Poisson equations)",
    "gradient": "gradient variant used for the components d = grad phi and r = J grad psi",
    "laplacian": "Laplacian variant of the Poisson rows",
    "neumann_gradient": "gradient variant of the boundary (Neumann) rows dq/dn = 0",
    "boundary": "boundary treatment: collocation = Neumann rows on particles sampled along "
                "the boundary; petronetto = fake particles outside with the field extended "
                "by Shepard sums (Petronetto 2010); colin = a layer of wall particles with "
                "normals (Colin 2006); none = no boundary condition",
    "kappa": "ridge term added to the Poisson rows (Petronetto Sec. 6a); 0 = none",
    "bordered": "add one unknown for the pure-Neumann compatibility condition (bordered "
                "system); --no-bordered solves the singular system as is",
    "remove_mean": "subtract the volume-weighted means of div v and curl v (the "
                   "compatibility condition of the pure Neumann problems) before solving",
    "tol": "relative residual at which the linear solver stops",
    "solver": "iterative linear solver: bicgstab (BiCGSTAB, see --preconditioner) or "
              "cgnr (CG on the normal equations)",
    "preconditioner": "preconditioner of BiCGSTAB: multilevel (aggregation multigrid "
                      "cycle on the neighbour grid), jacobi (diagonal), auto (multilevel from "
                      "1000 particles on, Jacobi below and for cgnr)",
    "max_iterations": "iteration cap of each linear solve (none = max(1000, unknowns))",
    "positive_rows": "corrected-Laplacian rows with sum |C_ij| above P times sum C_ij (or "
                     "a diagonal of the wrong sign) replaced by positive stencils exact on "
                     "quadratics (P >= 1; off: none replaced)",
    "seed": "random seed of sampled boundary/fake particles",
    "boundary_condition": "boundary condition of the decomposition (decompose only): auto = "
                          "natural, or no-flux where the flow does not cross the boundary (a "
                          "closed container; the summary says which); neumann = dphi/dn = "
                          "dpsi/dn = 0 (Petronetto Eq. 6: d tangent, r normal to the "
                          "boundary; a field with net curl or divergence, e.g. a rigid "
                          "rotation, then lands in h, which is flagged as not harmonic); "
                          "normal-parallel = phi = psi = 0 on the boundary (d normal, r "
                          "tangent to it, all three parts orthogonal); no-flux = dphi/dn = 0 "
                          "and psi = 0 (d and r tangent to the boundary: a closed "
                          "container's split); natural = potentials from the free-space "
                          "Green's function of div v and curl v (Bhatia et al. 2014), no "
                          "condition",
    "natural_evaluation": "how the natural condition's convolution is summed: fft "
                          "(particle-mesh, O(N log N)) or direct (O(N^2), its reference)",
}
_SOLVERS = ("bicgstab", "cgnr")


def _fmt_default(value):
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:g}" if isinstance(value, float) else str(value)


def _method_defaults(name, methods):
    """'default: X (petronetto2010: Y, colin2006: Z)' from the bundles."""
    vals = {m: getattr(o, name) for m, o in methods.items()}
    first = next(iter(vals))
    others = ", ".join(f"{m}: {_fmt_default(v)}" for m, v in vals.items() if m != first)
    return f"default from --method; {first}: {_fmt_default(vals[first])}" + \
        (f", {others}" if others else "")


# --------------------------------------------------------------------------- parser
def _add_common(p, command):
    from ..checks import (at_least_one_or_off, nonnegative_float, nonnegative_int,
                          positive_float, positive_int)
    from ..runtime import ARCHES, default_arch
    from ..hhd.decompose import BOUNDARY_METHODS, METHODS, PRECONDITIONERS, HHDOptions
    from ..hhd.options import BOUNDARY_CONDITIONS, NATURAL_EVALUATIONS
    from ..sph.kernels import KERNELS
    from ..sph.operators import GRADIENT_VARIANTS, LAPLACIAN_VARIANTS
    io = p.add_argument_group("input and output")
    io.add_argument("field", metavar="FIELD", nargs="+" if command == "decompose" else None,
                    help=("the vector field (several files: a series of snapshots on the "
                          "same points, decomposed in one process into DIR/series.npz and, "
                          "with xarray, DIR/series.nc): " if command == "decompose" else
                          "the vector field: ") + "a .npz file with arrays 'points' (N,2) and "
                         "'vectors' (N,2), or a .csv file with columns x,y,u,v (header "
                         "naming them in any order, extra columns ignored; or no header "
                         "and exactly 4 columns); or a PIV file: TSI Insight .vec, "
                         "OpenPIV or DaVis text, any delimited x y u v text (.txt, .dat, "
                         ".tsv), DaVis .vc7 (lvpyio) or PIVlab .mat (h5py/scipy), its "
                         "invalid vectors left out")
    io.add_argument("--domain", metavar="x0,y0,x1,y1|FILE.json|bbox|hull|alpha",
                    help="the domain: a box x0,y0,x1,y1 (write --domain=-1,-1,1,1 when it "
                         "starts with a minus sign), a JSON polygon {\"outer\": [[x,y],...], "
                         "\"holes\": [[[x,y],...],...]}, or from the points: bbox (their "
                         "bounding box, the default), hull (their convex hull) or alpha "
                         "(their alpha shape: a concave outline, with the gaps in the data "
                         "as holes); every point must lie inside.  Without --domain, points "
                         "that are the nodes of a rectilinear grid (PIV, model output) are "
                         "decomposed as a grid: the domain from the valid nodes (masked "
                         "regions cut out), the natural boundary condition by default")
    from ..geometry.from_points import ALPHA
    io.add_argument("--alpha", metavar="A", type=positive_float, default=None,
                    help="with --domain alpha: the alpha shape's radius in local spacings (a "
                         "Delaunay triangle of the points is in the domain while its "
                         "circumradius is below A spacings; larger: gaps in the data filled, "
                         f"pieces joined) (default: {ALPHA:g})")
    io.add_argument("--units", metavar="UNIT", default=None,
                    help="the coordinates' unit for the figures' axis labels (e.g. mm, m, "
                         "km, deg; default: the unit a PIV file's header names)")
    io.add_argument("-o", "--out", metavar="DIR",
                    help=f"output directory, created if needed (default: "
                         f"outputs/<FIELD stem>_{command})")
    io.add_argument("--no-figures", action="store_true",
                    help="no PNG figures (the .npz and .vtu results only)")
    io.add_argument("--vtk", action=argparse.BooleanOptionalAction, default=True,
                    help="also write the results per point as VTU for ParaView")
    io.add_argument("-q", "--quiet", action="store_true",
                    help="no progress messages on stderr (the summary is still printed)")

    num = p.add_argument_group(
        "numerical options",
        "Each defaults to the value in the bundle chosen by --method; only the options "
        "given here override it. Kernels: wendland (Wendland C2), quartic (Petronetto's), "
        "poly6 (Mueller's, Colin's), cubic (cubic spline). Gradient variants: basic (Colin "
        "Eq. 8), difference (Petronetto Eq. 8), colin_difference (DGAF, Colin Eq. 13), "
        "symmetric (SGAF, Colin Eq. 17), corrected (Bonet-Lok, exact on linear fields), "
        "quadratic (moving least squares of order 2, exact on quadratics), cubic (order 3, "
        "exact on cubics). Laplacian "
        "variants: basic (Colin Eq. 9), colin_difference (Colin Eq. 21), brookshaw "
        "(Petronetto Eq. 10), corrected (renormalised, exact on quadratics).")
    num.add_argument("--method", default="default", choices=tuple(METHODS),
                     help="bundle of numerical options: default = most accurate (Wendland "
                          "C2 over 3.5 local spacings, cubic MLS divergence and curl, "
                          "quadratic MLS gradients for d, r and the Neumann rows, corrected "
                          "Laplacian with the rows that lose their sign made positive, "
                          "collocated boundary rows, the boundary condition chosen from the "
                          "data); petronetto2010 = Petronetto et al. 2010 as "
                          "published; colin2006 = Colin et al. 2006's operators "
                          "(default: default)")
    choices = {"kernel": KERNELS, "divergence": GRADIENT_VARIANTS,
               "gradient": GRADIENT_VARIANTS, "laplacian": LAPLACIAN_VARIANTS,
               "neumann_gradient": GRADIENT_VARIANTS, "boundary": BOUNDARY_METHODS,
               "solver": _SOLVERS, "preconditioner": PRECONDITIONERS,
               "boundary_condition": BOUNDARY_CONDITIONS, "natural_evaluation": NATURAL_EVALUATIONS}
    types = {"support_ratio": (positive_float, "R"), "kappa": (nonnegative_float, "K"),
             "tol": (positive_float, "TOL"), "max_iterations": (positive_int, "N"),
             "seed": (nonnegative_int, "SEED"), "support_neighbours": (positive_int, "K"),
             "positive_rows": (at_least_one_or_off, "P")}
    for f in dataclasses.fields(HHDOptions):
        name = f.name
        if name in LIBRARY_ONLY_OPTIONS:
            continue
        flag = "--" + name.replace("_", "-")
        text = f"{_OPTION_HELP.get(name, name)} ({_method_defaults(name, METHODS)})"
        if name in choices:
            num.add_argument(flag, dest=name, default=None, choices=tuple(choices[name]),
                             help=text)
        elif f.type in (bool, "bool"):            # --flag / --no-flag, never a string
            num.add_argument(flag, dest=name, default=None,
                             action=argparse.BooleanOptionalAction, help=text)
        elif name in types:
            typ, metavar = types[name]
            num.add_argument(flag, dest=name, default=None, type=typ, metavar=metavar,
                             help=text)
        else:                                     # a field added later: still exposed
            num.add_argument(flag, dest=name, default=None, help=text)

    rt = p.add_argument_group("runtime")
    rt.add_argument("--arch", default=default_arch(), choices=ARCHES,
                    help="Taichi arch: cpu, cuda, vulkan, gpu (any GPU backend; an error "
                         "where none starts) or auto (a GPU when present) (default: "
                         "$TAICHI_HH_ARCH, else cpu)")
    rt.add_argument("--no-worker", action="store_true",
                    help="run in this process even where a 'taichi-hh worker' runs")
    rt.add_argument("--precision", default="f64", choices=("f32", "f64"),
                    help="floating-point precision of every Taichi kernel; with f32 use a "
                         "looser --tol such as 1e-5 (default: f64)")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    from ..checks import nonnegative_float, positive_int
    from ..runtime import ARCHES
    ap = argparse.ArgumentParser(prog="taichi-hh", description=(
        "Meshless Helmholtz-Hodge decomposition and null-divergence SPH on Taichi."),
        epilog="Run 'taichi-hh COMMAND --help' for the options of a command. "
               "Errors exit with status 2.")
    ap.add_argument("--version", action="version", version=f"taichi-hh {__version__}")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    dec = sub.add_parser(
        "decompose", help="Helmholtz-Hodge decomposition v = d + r + h of a sampled field",
        description=(
            "Decompose a 2D vector field v sampled at scattered points into v = d + r + h: "
            "d = grad phi (curl-free), r = J grad psi (divergence-free), h harmonic "
            "(SPH-HH, Petronetto et al. 2010). Writes DIR/components.npz (points, v, d, r, "
            "h, phi, psi, divergence, curl and the critical points xs, ys, kinds, "
            "strengths), the same "
            "per point as DIR/components.vtu for ParaView (--no-vtk: not), and the "
            "figures DIR/arrows.png and DIR/magnitude.png."),
        epilog="Exit status: 0 on success, 2 on bad input, bad options or a failed solve.")
    _add_common(dec, "decompose")
    dec.add_argument_group("analysis").add_argument("--critical-threshold", type=nonnegative_float, default=0.1,
                     metavar="T",
                     help="critical points (sources, sinks, vortices: extrema of phi and "
                          "psi where d or r vanishes) are kept when their |div d| or |curl r| "
                          "is at least T times the field's largest |div v| or |curl v| and "
                          "well above the data's noise there (default: 0.1)")
    dec.add_argument_group("missing data").add_argument(
        "--invalid", choices=("missing", "error"), default="missing",
        help="rows with NaN vectors (or points), an empty u or v cell, or a false "
             "'valid' column: missing (the default: left out, NaN in the outputs) or "
             "error (refused)")
    dec.add_argument_group("sphere").add_argument(
        "--lonlat", action="store_true",
        help="FIELD.nc holds winds (u eastward, v northward) on longitude and latitude: "
             "decompose them on the sphere into DIR/lonlat.nc (CF streamfunction and "
             "velocity potential) and DIR/lonlat.png (taken without the flag when the "
             "file's coordinates are longitude and latitude)")
    dec.add_argument_group("series").add_argument(
        "--figures", default="first", metavar="WHICH",
        help="with several FIELD files: the snapshots drawn, first, all, none or 0-based "
             "indices N,M (negative from the end) (default: first)")
    dec.set_defaults(func=_cmd_decompose)

    pro = sub.add_parser(
        "project", help="null-divergence projection of a sampled field (Colin et al. 2006)",
        description=(
            "Project a 2D vector field sampled at scattered points onto null divergence, "
            "K times (--iterations) (Colin, Egli & Lin 2006). Default method: a Poisson "
            "step (lap q = div w, dq/dn = 0, w <- w - grad q) then the exact orthogonal "
            "projection onto zero quadratic divergence, so one pass leaves the divergence "
            "at the solver tolerance and further passes change nothing; colin2006: their "
            "formulation, whose divergence decreases pass by pass. Writes DIR/projected.npz (points, vectors = the "
            "projected field, initial, divergence, per-pass max_divergence, "
            "sum_sq_divergence, iterations), DIR/projection.vtu (per point, for ParaView), "
            "DIR/measures.csv and the figures "
            "DIR/projection_arrows.png and DIR/projection_measures.png. Only the "
            "collocation, colin and none boundary treatments apply."),
        epilog="Exit status: 0 on success, 2 on bad input, bad options or a failed solve.")
    _add_common(pro, "project")
    pro.add_argument_group("projection").add_argument("--iterations", type=positive_int, default=1, metavar="K",
                     help="number of projection passes (default: 1)")
    pro.set_defaults(func=_cmd_project)

    info = sub.add_parser("info", help="show the version and the Taichi arch in use")
    info.add_argument("--arch", default="auto", choices=ARCHES,
                      help="Taichi arch: cpu, cuda, vulkan, gpu (an error where no GPU "
                           "backend starts) or auto (default)")
    info.add_argument("--verbose", action="store_true",
                      help="also show Taichi's own start-up messages")
    info.add_argument("--precision", default="f64", choices=("f32", "f64"),
                      help="floating-point precision (default: f64)")
    info.set_defaults(func=_cmd_info)

    sub.add_parser("worker", add_help=False,
                   help="start|stop|status a persistent worker that keeps Taichi's kernels "
                        "loaded between decompose and project calls ('taichi-hh worker "
                        "--help')")
    from .scenes import SCENES
    scene = sub.add_parser(
        "scene", help="run a two-phase scene (the same as the scripts in scenes/)",
        description="Run a two-phase SPH scene headless: PNG frames, particle files, "
                    "diagnostics.csv and a checkpoint in --out. The options after NAME are "
                    "the scene's: 'taichi-hh scene NAME --help' lists them.",
        add_help=True)
    scene.add_argument("name", metavar="NAME", choices=tuple(SCENES),
                       help=f"one of {', '.join(SCENES)}")
    scene.add_argument("scene_args", nargs=argparse.REMAINDER, metavar="...",
                       help="the scene's options")
    scene.set_defaults(func=_cmd_scene)
    return ap


# --------------------------------------------------------------------------- helpers
class _Progress:
    """Stage messages on stderr with the elapsed time."""

    def __init__(self, command, quiet=False):
        self.command = command
        self.quiet = quiet
        self.t0 = time.perf_counter()

    def __call__(self, stage: str) -> None:
        if not self.quiet:
            print(f"taichi-hh {self.command}: [{time.perf_counter() - self.t0:6.1f} s] {stage}",
                  file=sys.stderr, flush=True)

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


def option_overrides(args) -> dict:
    """The decomposition options the command line gave (the others stay the
    method's), by :class:`~taichi_hh.hhd.decompose.HHDOptions` field name."""
    from ..checks import OFF
    from ..hhd.decompose import HHDOptions
    return {f.name: None if getattr(args, f.name) is OFF else getattr(args, f.name)
            for f in dataclasses.fields(HHDOptions) if getattr(args, f.name, None) is not None}


def output_dir(args) -> str:
    """``--out``, else ``outputs/<first field's stem>_<command>``."""
    if args.out:
        return args.out
    field = args.field[0] if isinstance(args.field, list) else args.field   # a series: the first
    stem = os.path.splitext(os.path.basename(os.path.normpath(field)))[0] or "field"
    return os.path.join("outputs", f"{stem}_{args.command}")


def _read_inputs(args, say, *, domain_kind_as_name: bool = False):
    """``(points, vectors, domain)`` from the command line.  A domain made from
    the points (``bbox``, ``hull``, ``alpha``) is made here, or, with
    ``domain_kind_as_name``, passed on by name (``("alpha", A)`` with
    ``--alpha``) for the library to make from the valid points in its unit
    frame (the decomposition).  ``--alpha`` without ``--domain alpha`` is
    refused before the field is read."""
    from . import io
    from ..errors import InputError
    from ..geometry.from_points import ALPHA, DOMAINS_FROM_POINTS, domain_from_points
    kind = args.domain.strip().lower() if args.domain is not None else None
    if args.alpha is not None and kind != "alpha":
        given = "without --domain" if kind is None else f"--domain {args.domain}"
        raise InputError(f"--alpha {args.alpha:g} (the alpha shape's radius) applies only with "
                         f"--domain alpha, not {given}")
    say(f"reading {args.field}")
    got = io.read_field_file(args.field)
    points, vectors = got.points, got.vectors
    if getattr(args, "units", None) is None and got.length_unit:
        args.units = got.length_unit             # the figures' axes in the file's units
    if kind in DOMAINS_FROM_POINTS:
        alpha = ALPHA if args.alpha is None else args.alpha
        if domain_kind_as_name:
            return points, vectors, ("alpha", alpha) if kind == "alpha" else kind
        return points, vectors, domain_from_points(points, kind, alpha)
    domain = io.read_domain(args.domain)
    return points, vectors, domain


def _init(args, say):
    import contextlib
    from .. import runtime
    say(f"starting Taichi ({args.arch}, {args.precision})")
    # ti.init prints "[Taichi] Starting on arch=..." on stdout: keep stdout for the summary
    with contextlib.redirect_stdout(sys.stderr if not args.quiet else open(os.devnull, "w")) \
            as sink:
        try:
            return runtime.init(arch=args.arch, precision=args.precision)
        finally:
            if sink is not sys.stderr:
                sink.close()


def _paragraph(text: str) -> str:
    return textwrap.fill(" ".join(text.split()), width=88)


def _plural(n, word, plural=None):
    return f"{n} {word if n == 1 else (plural or word + 's')}"


# --------------------------------------------------------------------------- commands
def _cmd_info(args) -> int:
    import taichi_hh as thh
    with _captured_output() as captured:     # Taichi's start-up and arch-probing messages
        st = thh.init(arch=args.arch, precision=args.precision)
    device = f", device {st.device}" if st.device else ""
    print(f"taichi_hh {thh.__version__}: Taichi arch={st.arch} (requested {st.requested_arch}{device}), "
          f"precision={st.precision}")
    lines = [ln for ln in captured.text.splitlines() if ln.strip()]
    if args.verbose:
        for ln in lines:
            print(f"  taichi: {ln}")
    elif lines:
        print(f"  ({_plural(len(lines), 'line')} of Taichi start-up messages hidden; "
              "--verbose shows them)")
    return 0


class _captured_output:
    """Collect what is written to the process's stdout and stderr file
    descriptors (Taichi's C++ runtime writes there directly) into ``text``."""

    def __enter__(self):
        import tempfile
        sys.stdout.flush()
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile(mode="w+b")
        self._saved = [os.dup(1), os.dup(2)]
        os.dup2(self._file.fileno(), 1)
        os.dup2(self._file.fileno(), 2)
        self.text = ""
        return self

    def __exit__(self, *exc):
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, saved in zip((1, 2), self._saved):
            os.dup2(saved, fd)
            os.close(saved)
        self._file.seek(0)
        self.text = self._file.read().decode(errors="replace")
        self._file.close()
        return False


def _cmd_scene(args) -> int:
    from .scene import run_scene
    from .scenes import get
    run_scene(get(args.name), args.scene_args)
    return 0


def _cmd_decompose(args) -> int:
    import numpy as np
    from . import io
    from .out_dir import WrittenOnSuccess, prepare_out_dir
    from .series import decompose_field
    from ..hhd.decompose import options_for
    files = list(args.field)
    args.field = files[0]
    say = _Progress("decompose", args.quiet)
    overrides = option_overrides(args)
    options_for(args.method, **overrides)           # bad combinations fail before any work
    if len(files) == 1 and (args.lonlat or _netcdf_on_lonlat(files[0])):
        from .xarray_lonlat import decompose_lonlat_file
        out = output_dir(args)
        prepare_out_dir(out)
        _init(args, say)
        print(_paragraph(decompose_lonlat_file(files[0], out, figures=not args.no_figures,
                                               method=args.method, **overrides)[1]))
        return 0
    if len(files) > 1:
        return _decompose_series(args, files, say, overrides)
    out = output_dir(args)
    prepare_out_dir(out)
    points, vectors, domain = _read_inputs(args, say, domain_kind_as_name=True)
    st = _init(args, say)
    # a field listed node by node on a rectilinear grid (PIV, model output):
    # the domain from its valid nodes, the natural condition by default
    res = decompose_field(points, vectors, domain, method=args.method, invalid=args.invalid,
                          progress=say, overrides=overrides, grid_first=args.domain is None)
    domain = res.domain
    say("critical points")
    critical = res.critical_points(threshold=args.critical_threshold)
    written = [os.path.join(out, "components.npz")]
    say(f"writing {written[0]}")
    with WrittenOnSuccess(out):
        io.write_components(written[0], res, critical_points=critical)
        if args.vtk:
            from .particle_files import write_vtu
            written.append(write_vtu(os.path.join(out, "components.vtu"), res.points, {
                "v": res.vectors, "d": res.curl_free, "r": res.div_free, "h": res.harmonic,
                "phi": res.phi, "psi": res.psi, "divergence": res.divergence,
                "curl": res.curl}))
        if not args.no_figures:
            from .figures import decomposition_figures
            say("drawing figures")
            written += decomposition_figures(res, domain, out, critical=critical,
                                             units=args.units)
    s = res.stats
    mean = {k: float(np.nanmean(np.hypot(a[:, 0], a[:, 1]))) for k, a in
            (("v", res.vectors), ("d", res.curl_free), ("r", res.div_free),
             ("h", res.harmonic))}
    counts = {}
    for _, _, kind in critical:
        counts[kind] = counts.get(kind, 0) + 1
    names = {"source": ("source", "sources"), "sink": ("sink", "sinks"),
             "cw_vortex": ("clockwise vortex", "clockwise vortices"),
             "ccw_vortex": ("counter-clockwise vortex", "counter-clockwise vortices")}
    found = ", ".join(_plural(counts[k], *names[k]) for k in names if k in counts)
    if "iterations_phi" in s:
        solved = (f"the phi and psi solves took {s['iterations_phi']} and "
                  f"{s['iterations_psi']} iterations (relative residuals "
                  f"{s['residual_phi']:.1e}, {s['residual_psi']:.1e})")
    else:
        solved = "free-space potentials on a {} x {} grid".format(*s["natural_grid"])
    solved = f"{_condition_said(s)}; {solved}"
    flags = "".join(f" Warning: {f}" for f in s.get("flags", []))
    print(_paragraph(
        f"Decomposed {len(res.points) - s['n_invalid']} points of {args.field}"
        f"{' (a {1} x {0} grid: its domain from the valid nodes)'.format(*s['grid']) if 'grid' in s else ''}"
        f"{' (' + str(s['n_invalid']) + ' rows missing: NaN or marked invalid, left out)' if s['n_invalid'] else ''}"
        f" (method {args.method}"
        f"{', ' + ', '.join(f'{k}={v}' for k, v in overrides.items()) if overrides else ''}; "
        f"{st.arch}/{st.precision}): {solved}; decomposition {s['seconds']['total']:.2f} s, "
        f"{say.elapsed:.2f} s in all. Mean |v| = {mean['v']:.4g}, |d| = {mean['d']:.4g}, "
        f"|r| = {mean['r']:.4g}, |h| = {mean['h']:.4g}; mean |div h|, |curl h| = "
        f"{s['h_divergence']:.2g}, {s['h_curl']:.2g} of the field's.{flags} "
        f"Critical points: {len(critical)}{' (' + found + ')' if found else ''}. "
        f"Wrote {', '.join(written)}."))
    return 0


#: the file names :func:`~taichi_hh.app.xarray_lonlat.is_lonlat_file` reads
NETCDF_SUFFIXES = (".nc", ".nc4", ".netcdf")


def _netcdf_on_lonlat(path) -> bool:
    """``is_lonlat_file``, its module (and xarray, pandas: a second of
    start-up) imported only for a netCDF name."""
    if not str(path).lower().endswith(NETCDF_SUFFIXES):
        return False
    from .xarray_lonlat import is_lonlat_file
    return is_lonlat_file(path)


def _decompose_series(args, files, say, overrides) -> int:
    """``decompose`` of several files: :mod:`taichi_hh.app.series`."""
    from .out_dir import WrittenOnSuccess, prepare_out_dir
    from .series import FieldSeries, decompose_series, figure_indices
    figure_indices(args.figures, len(files))          # a bad --figures fails before any work
    out = output_dir(args)
    prepare_out_dir(out)
    st = _init(args, say)
    quiet = _Progress("decompose", True)

    def read(path):
        args.field = path
        return _read_inputs(args, quiet, domain_kind_as_name=True)

    # what depends on the points made once for the run (hhd.decomposer)
    decompose_one = FieldSeries(method=args.method, invalid=args.invalid, progress=None,
                                overrides=overrides, grid_first=args.domain is None)

    def draw(res, directory):
        if args.no_figures:
            return []
        from .figures import decomposition_figures
        critical = res.critical_points(threshold=args.critical_threshold)
        return decomposition_figures(res, res.domain, directory, critical=critical,
                                     units=args.units)

    with WrittenOnSuccess(out):
        written, done, interrupted = decompose_series(files, read, decompose_one, draw, out,
                                                      say, args.figures)
    print(_paragraph(
        f"Decomposed {done} of {len(files)} snapshots ({st.arch}/{st.precision}) in "
        f"{say.elapsed:.2f} s{' (interrupted: the snapshots done are written)' if interrupted else ''}. "
        f"Wrote {', '.join(written)}."))
    return 130 if interrupted else 0


def _condition_said(stats: dict) -> str:
    """The boundary condition used, and why where the default chose it."""
    condition = stats.get("boundary_condition", "?")
    flux = stats.get("boundary_flux")
    if flux is None:
        return f"boundary condition {condition}"
    from ..hhd.auto import CLOSED_FLUX
    if condition == "no-flux":
        why = "the flow runs along the boundary without crossing it"
    elif flux < CLOSED_FLUX:        # NaN (no data next to the boundary) compares False
        why = "no flow next to the boundary: no wall in the data"
    else:
        why = "the flow crosses the boundary"
    cancelled = stats.get("natural_energy_ratio")
    if cancelled is not None:
        why += (f", and the natural split's parts cancel (they carry {cancelled:.3g} times "
                "the field's energy): the orthogonal split instead")
    return (f"boundary condition {condition} (chosen by --boundary-condition auto: {why}, "
            f"normal flux {flux:.2g} of |v|)")


def _cmd_project(args) -> int:
    from . import io
    from .out_dir import WrittenOnSuccess, prepare_out_dir
    from ..hhd.decompose import options_for
    from ..hhd.project import project
    say = _Progress("project", args.quiet)
    overrides = option_overrides(args)
    options_for(args.method, **overrides)
    out = output_dir(args)
    prepare_out_dir(out)
    points, vectors, domain = _read_inputs(args, say)
    st = _init(args, say)
    say("setup")
    res = project(points, vectors, domain, iterations=args.iterations, method=args.method,
                  progress=say, **overrides)
    written = [os.path.join(out, "projected.npz"), os.path.join(out, "measures.csv")]
    say(f"writing {written[0]}")
    iters = list(res.stats.get("iterations", []))
    with WrittenOnSuccess(out):
        io.write_projection(written[0], res)
        if args.vtk:
            from .particle_files import write_vtu
            written.append(write_vtu(os.path.join(out, "projection.vtu"), res.points, {
                "vectors": res.vectors, "initial": res.initial, "divergence": res.divergence}))
        io.atomic_write_csv(written[1], [
            {"pass": k, "max_abs_divergence": float(m), "sum_sq_divergence": float(q),
             "solver_iterations": iters[k - 1] if k >= 1 else ""}
            for k, (m, q) in enumerate(zip(res.max_divergence, res.sum_sq_divergence))])
        if not args.no_figures:
            from .figures import projection_figures
            say("drawing figures")
            written += projection_figures(res, domain, out)
    print(_paragraph(
        f"Projected {len(res.points)} points of {args.field} (method {args.method}"
        f"{', ' + ', '.join(f'{k}={v}' for k, v in overrides.items()) if overrides else ''}; "
        f"{st.arch}/{st.precision}) with {_plural(args.iterations, 'pass', 'passes')}: solver iterations {', '.join(map(str, iters))}; "
        f"max |div| {res.max_divergence[0]:.3g} -> {res.max_divergence[-1]:.3g}, sum of "
        f"div^2 {res.sum_sq_divergence[0]:.3g} -> {res.sum_sq_divergence[-1]:.3g}; "
        f"projection {res.stats.get('seconds', float('nan')):.2f} s, {say.elapsed:.2f} s in "
        f"all. Wrote {', '.join(written)}."))
    return 0


# --------------------------------------------------------------------------- entry point
def _solver_hint(exc):
    from ..errors import SolverError
    if isinstance(exc, SolverError):
        return "(try a larger --tol, a larger --max-iterations or another --method)"
    return None


def main(argv=None, worker: bool = True) -> int:
    """The command line; ``worker``: a running ``taichi-hh worker`` may run
    the call (:mod:`taichi_hh.app.worker_client`; False inside the worker)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["worker"]:
        from .worker_client import worker_command
        return worker_command(argv[1:])
    if worker:
        from .worker_client import run_in_worker
        code = run_in_worker(argv)
        if code is not None:
            return code
    # importing taichi (for the option choices) prints a banner on stdout; keep
    # stdout for results unless the user asked for the banner
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
    parser = build_parser()
    args = parser.parse_args(argv)
    from .errors_report import option_rewriter, run_reporting
    return run_reporting(f"taichi-hh {args.command}", lambda: args.func(args),
                         error_hint=_solver_hint, rewrite=option_rewriter(parser))


def entry() -> None:
    """The ``taichi-hh`` command: :func:`main`, then exit with its status.  Where
    a GPU request was refused, at once (``os._exit``, the streams flushed):
    Taichi's teardown after its failed start has crashed the exit
    (:func:`taichi_hh.runtime.gpu_refused`)."""
    code = main()
    from .. import runtime
    if runtime.gpu_refused():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    entry()
