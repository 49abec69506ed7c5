"""Petronetto et al. 2010 (SPH-HH) analyses redone: Fig. 10-12 and Eq. 16.

    python benchmarks/petronetto_analysis.py [--quick] [--out DIR] [--tol 1e-8]
                                             [--sizes 1600,3300,...] [--seed 1]

Every analysis runs twice on the same points: the paper configuration
(``method="petronetto2010"``: quartic kernel, difference gradient, Brookshaw
Laplacian, fake particles, ridge kappa 1e-3, Jacobi BiCGSTAB to 1e-6) and our
default (``method="default"``).  Points are blue noise (Poisson disk) in the
unit square from ``taichi_hh.validation.fields``; errors are against the fields' exact
components.

(a) Fig. 10  div r and curl d, computed at the data points with each
             configuration's own divergence operator (the one that made the
             right-hand sides), should vanish: histogram and statistics,
             relative to the mean |div v| and |curl v| of the input.  The
             operator floor (the same operator on the exact r0, d0) is listed
             beside them.
(b) Fig. 11  a field with a constant harmonic part of magnitude 0.1 (the
             ``trig`` potentials scaled by 0.1, so d, r and h are of similar
             size; 10k points like the paper's Figs. 10-11): histogram of |h|.
             (a) and (d) use this field too.
(c) Fig. 12  error table on the ``gaussian`` field (two sources, two
             vortices, a constant harmonic part) at about 13k points: max,
             mean, variance and median of |d - d0|, |r - r0|, |h - h0| and
             of the same over mean |v0|, beside the published values.
(d) Eq. 16   L2 orthogonality sum_j V_j <d_j, r_j> and its normalised form
             <d, r> / (|d| |r|) (V_j = m_j / rho_j), with the value of the exact
             components for reference.
(e)          mean errors of d, r, h (over mean |v0|) against the particle count
             on the ``gaussian`` and ``trig`` fields, with the fitted order p
             of err ~ spacing^p (least squares over all sizes).
(f)          critical points on the ``gaussian`` field (``res.critical_points()``
             with its default threshold): each true centre's nearest found point
             of the same kind, the distance in particle spacings
             sqrt(area / N), and found points matching no centre (spurious).

Solver workaround.  ``--tol`` (default 1e-8, the library default) is the
tolerance of the default configuration.  Should its solve fail (SolverError)
the run is repeated with each looser ``--fallback-tols`` value in turn, and the
tolerance used is reported in the tables and the CSV.  The paper configuration
keeps its published tolerance (1e-6, ``--paper-tol``); if its Jacobi-
preconditioned BiCGSTAB fails (it stagnates near 5e-3 at 13k points), the
same system is solved with the multilevel preconditioner instead and this is
reported too: it changes how the system is solved, not the discretisation.
A point sample on which a configuration cannot build its operators
(NeighbourError) is reported and replaced by the next seed.

``--quick``: sizes 1600 and 3300, the error table at 3300 points, the
histograms at 2000 (a smoke test of 10-20 s; give it another ``--out``).

Writes to ``--out`` (default outputs/benchmarks/), atomically:
``petronetto_runs.csv`` (one row per field, size, configuration: every
scalar measure), ``petronetto_fig12.csv`` (the error table, long format),
``petronetto_properties.csv`` ((a), (b), (d)), ``petronetto_convergence.csv``
(fitted orders), ``petronetto_critical_points.csv``, ``petronetto_summary.md``
(the tables in markdown), and ``petronetto_histograms.png``,
``petronetto_convergence.png``, ``petronetto_critical_points.png``.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (REPO_ROOT, add_repo_to_path, format_table, parse_list,  # noqa: E402
                     save_figure_atomic, write_bytes_atomic, write_csv_atomic)

add_repo_to_path()
from taichi_hh.validation.measures import loglog_slope, summary_stats  # noqa: E402

CONFIGS = ("petronetto2010", "default")
LABEL = {"petronetto2010": "paper", "default": "default"}
DEFAULT_SIZES = (1600, 3300, 6500, 13000, 26000, 53000)
QUICK_SIZES = (1600, 3300)
TABLE_N = 13000           # Fig. 12: 13287 particles
QUICK_TABLE_N = 3300
HIST_N = 10000            # Figs. 10-11: 10000 points
QUICK_HIST_N = 2000
H_MAGNITUDE = 0.1         # Fig. 11: ||h|| = 0.1
H_ANGLE = math.radians(30.0)
TRIG_SCALE = 0.1          # potentials of the constant-harmonic field
MAX_SEED_TRIES = 3

# Petronetto Fig. 12 (13287 particles): max, mean, var, median
PAPER_FIG12 = {
    "|d-d0|": (2.88e-2, 6.27e-3, 1.99e-5, 5.18e-3),
    "|d-d0|/|v0|": (6.31e-1, 8.92e-2, 4.90e-3, 7.21e-2),
    "|r-r0|": (2.89e-2, 5.92e-3, 2.12e-5, 4.59e-3),
    "|r-r0|/|v0|": (4.38e-1, 8.06e-2, 4.22e-3, 6.34e-2),
    "|h|": (3.85e-2, 8.88e-3, 3.84e-5, 7.35e-3),
    "|cos(r,d)|": (5.05e-1, 3.50e-2, 1.38e-3, 2.73e-2),
    # printed as "div d" and "curl r" in the paper's table; the median above the mean
    # says the values are signed.  We read them as curl d and div r.
    "curl d (signed)": (1.00e-1, 3.83e-5, 3.28e-4, 3.29e-4),
    "div r (signed)": (1.00e-1, 3.66e-5, 3.29e-4, 2.17e-4),
    "|v0|": (1.52e-1, 7.55e-2, 5.60e-4, 7.20e-2),
}
PAPER_EQ16 = 2.13e-6
# issue 4 targets (default configuration, ~13k blue-noise points)
TARGET_MEAN_ERROR = 0.01

RUN_FIELDS = ["field", "n", "seed", "method", "tol", "preconditioner", "solve_note",
              "iterations_phi", "iterations_psi", "residual_phi", "residual_psi", "seconds",
              "spacing", "support", "mean_v0",
              "err_d", "err_r", "err_h", "err_d_max", "err_r_max", "err_h_max",
              "div_r_rel", "curl_d_rel", "div_r0_rel", "curl_d0_rel",
              "eq16", "eq16_normalized", "eq16_exact", "eq16_exact_normalized",
              "h_mag_mean", "h_mag_std",
              "cp_true", "cp_found", "cp_matched", "cp_spurious", "cp_max_dist_spacings"]


# ---------------------------------------------------------------------------
# fields

def constant_harmonic_field(fields):
    """``trig`` potentials scaled by TRIG_SCALE plus a constant harmonic part of
    magnitude H_MAGNITUDE (the Fig. 11 set-up: ||h|| = 0.1)."""
    base = fields.get("trig")
    h0 = H_MAGNITUDE * np.array([math.cos(H_ANGLE), math.sin(H_ANGLE)])

    def scaled(f):
        def g(p):
            v, grad = f(p)
            return TRIG_SCALE * v, TRIG_SCALE * grad
        return g

    return dataclasses.replace(base, name="trig_h0.1", phi=scaled(base.phi),
                               psi=scaled(base.psi),
                               h=lambda p: np.broadcast_to(h0, (len(p), 2)).copy())


# ---------------------------------------------------------------------------
# one decomposition with the solver workaround

class Runner:
    def __init__(self, args, log):
        self.args = args
        self.log = log
        self.notes = []          # human-readable workaround notes, in order

    def attempts(self, method):
        a = self.args
        if method == "default":
            first = {"tol": a.tol}
            return [first] + [{"tol": t} for t in a.fallback_tols if t > a.tol]
        first = {"tol": a.paper_tol} if a.paper_tol is not None else {}
        return [first, dict(first, preconditioner="multilevel")]

    def decompose(self, thh, pts, v, domain, method, where):
        """(result, solve_note); raises NeighbourError (bad sample) or the last
        SolverError."""
        last = None
        failures = []
        for opts in self.attempts(method):
            try:
                # the analysis is of Petronetto's Neumann problem (Eq. 6): the
                # default method under it, not under the condition auto would choose
                res = thh.decompose(pts, v, domain, method=method,
                                    **{"boundary_condition": "neumann", **opts})
            except thh.SolverError as exc:
                last = exc
                desc = ", ".join(f"{k}={val:g}" if isinstance(val, float) else f"{k}={val}"
                                 for k, val in opts.items()) or "published options"
                failures.append(f"{desc}: {exc.reason} at iteration {exc.iteration} "
                                f"(residual {exc.residual:.1e})")
                self.log(f"  {where} {method}: SolverError with {desc}: {exc}")
                continue
            note = ""
            if failures:
                used = ", ".join(f"{k}={val:g}" if isinstance(val, float) else f"{k}={val}"
                                 for k, val in opts.items())
                note = "failed with " + "; ".join(failures) + f"; solved with {used}"
                self.notes.append(f"{where}, {method}: {note}")
            return res, note
        self.notes.append(f"{where}, {method}: every attempt failed: " + "; ".join(failures))
        raise last


# ---------------------------------------------------------------------------
# measures

def _norm(a):
    return np.linalg.norm(a, axis=1)


def measure(res, exact, F):
    """Every scalar measure of one decomposition and the arrays behind (a)-(d)."""
    ps = res.pointset
    opts = res.options
    d, r, h = res.curl_free, res.div_free, res.harmonic
    v0 = _norm(exact.v)
    vm = float(v0.mean())
    e_d, e_r, e_h = _norm(d - exact.d), _norm(r - exact.r), _norm(h - exact.h)
    variant = opts.divergence
    div_r = ps.divergence(r, variant=variant)
    curl_d = ps.curl(d, variant=variant)
    div_r0 = ps.divergence(exact.r, variant=variant)
    curl_d0 = ps.curl(exact.d, variant=variant)
    div_scale = float(np.abs(res.divergence).mean())
    curl_scale = float(np.abs(res.curl).mean())
    vol = ps.volume()

    def eq16(a, b):
        dot = float((vol * (a * b).sum(axis=1)).sum())
        na = math.sqrt(float((vol * (a * a).sum(axis=1)).sum()))
        nb = math.sqrt(float((vol * (b * b).sum(axis=1)).sum()))
        return dot, dot / (na * nb) if na > 0 and nb > 0 else float("nan")

    dot, dot_n = eq16(d, r)
    dot0, dot0_n = eq16(exact.d, exact.r)
    nd, nr = _norm(d), _norm(r)
    both = (nd > 0) & (nr > 0)
    cos_rd = np.abs((d * r).sum(axis=1)[both]) / (nd[both] * nr[both])
    h_mag = _norm(h)
    s = res.stats
    row = {
        "n": len(res.points), "spacing": s["spacing"], "support": s["support"],
        "iterations_phi": s["iterations_phi"], "iterations_psi": s["iterations_psi"],
        "residual_phi": s["residual_phi"], "residual_psi": s["residual_psi"],
        "seconds": s["seconds"]["total"], "tol": opts.tol,
        "preconditioner": opts.preconditioner, "mean_v0": vm,
        "err_d": e_d.mean() / vm, "err_r": e_r.mean() / vm, "err_h": e_h.mean() / vm,
        "err_d_max": e_d.max() / vm, "err_r_max": e_r.max() / vm, "err_h_max": e_h.max() / vm,
        "div_r_rel": np.abs(div_r).mean() / div_scale,
        "curl_d_rel": np.abs(curl_d).mean() / curl_scale,
        "div_r0_rel": np.abs(div_r0).mean() / div_scale,
        "curl_d0_rel": np.abs(curl_d0).mean() / curl_scale,
        "eq16": dot, "eq16_normalized": dot_n, "eq16_exact": dot0,
        "eq16_exact_normalized": dot0_n,
        "h_mag_mean": float(h_mag.mean()), "h_mag_std": float(h_mag.std()),
    }
    fig12 = {
        "|d-d0|": summary_stats(e_d), "|d-d0|/|v0|": summary_stats(e_d / vm),
        "|r-r0|": summary_stats(e_r), "|r-r0|/|v0|": summary_stats(e_r / vm),
        "|h-h0|": summary_stats(e_h), "|h-h0|/|v0|": summary_stats(e_h / vm),
        "|h|": summary_stats(h_mag), "|cos(r,d)|": summary_stats(cos_rd),
        "|curl d|": summary_stats(np.abs(curl_d)), "|div r|": summary_stats(np.abs(div_r)),
        "curl d (signed)": summary_stats(curl_d), "div r (signed)": summary_stats(div_r),
        "|v0|": summary_stats(v0),
    }
    n0d, n0r = _norm(exact.d), _norm(exact.r)
    both0 = (n0d > 0) & (n0r > 0)
    fig12_exact = {"|cos(r,d)|": summary_stats(np.abs((exact.d * exact.r).sum(axis=1)[both0])
                                        / (n0d[both0] * n0r[both0])),
                   "|curl d|": summary_stats(np.abs(curl_d0)),
                   "|div r|": summary_stats(np.abs(div_r0)),
                   "curl d (signed)": summary_stats(curl_d0),
                   "div r (signed)": summary_stats(div_r0),
                   "|v0|": summary_stats(v0)}
    arrays = {"div_r": div_r, "curl_d": curl_d, "div_r0": div_r0, "curl_d0": curl_d0,
              "h_mag": h_mag, "div_scale": div_scale, "curl_scale": curl_scale}
    return row, fig12, fig12_exact, arrays


def match_critical_points(found, true, spacing):
    """Nearest found point of the same kind for each true centre (each found
    point used once); found points left over are spurious."""
    used = set()
    rows = []
    for x, y, kind in true:
        cands = [(math.hypot(fx - x, fy - y), k) for k, (fx, fy, fk) in enumerate(found)
                 if fk == kind and k not in used]
        if cands:
            dist, k = min(cands)
            matched = dist <= spacing
            if matched:
                used.add(k)
            rows.append({"kind": kind, "true_x": x, "true_y": y, "found_x": found[k][0],
                         "found_y": found[k][1], "dist_spacings": dist / spacing,
                         "matched": int(matched)})
        else:
            rows.append({"kind": kind, "true_x": x, "true_y": y, "found_x": "", "found_y": "",
                         "dist_spacings": "", "matched": 0})
    for k, (fx, fy, fk) in enumerate(found):
        if k not in used:
            rows.append({"kind": fk, "true_x": "", "true_y": "", "found_x": fx, "found_y": fy,
                         "dist_spacings": "", "matched": 0, "spurious": 1})
    return rows


# ---------------------------------------------------------------------------
# the runs

class Study:
    """Runs every configuration on a point sample and caches the measures by
    (field, n): the 13k row of the table and of the convergence sweep is one run."""

    def __init__(self, thh, fields, runner, args, log):
        self.thh, self.fields, self.runner, self.args, self.log = thh, fields, runner, args, log
        self.cache = {}

    def run(self, F, n, *, keep_arrays=False, critical=False):
        key = (F.name, n)
        if key in self.cache and (not keep_arrays or self.cache[key]["arrays"]):
            return self.cache[key]
        thh = self.thh
        for attempt in range(MAX_SEED_TRIES):
            seed = self.args.seed + attempt
            pts = F.sample(n, "poisson", seed=seed)
            exact = F.evaluate(pts)
            out = {"rows": {}, "fig12": {}, "arrays": {}, "cps": {}, "seed": seed}
            try:
                for method in CONFIGS:
                    t0 = time.perf_counter()
                    res, note = self.runner.decompose(thh, pts, exact.v, F.domain, method,
                                                      f"{F.name} N={len(pts)}")
                    row, fig12, fig12_x, arrays = measure(res, exact, F)
                    row.update(field=F.name, seed=seed, method=method, solve_note=note)
                    if critical and F.critical_points:
                        found = res.critical_points()
                        cps = match_critical_points(found, F.critical_points,
                                                    res.stats["spacing"])
                        dists = [c["dist_spacings"] for c in cps if c.get("true_x", "") != ""
                                 and c["dist_spacings"] != ""]
                        row.update(cp_true=len(F.critical_points), cp_found=len(found),
                                   cp_matched=sum(c["matched"] for c in cps),
                                   cp_spurious=sum(c.get("spurious", 0) for c in cps),
                                   cp_max_dist_spacings=max(dists) if dists else "")
                        out["cps"][method] = cps
                    out["rows"][method] = row
                    out["fig12"][method] = fig12
                    if method == "default":
                        out["fig12_exact"] = fig12_x
                    if keep_arrays:
                        out["arrays"][method] = arrays
                    del res
                    self.log(f"  {F.name:9s} N={len(pts):6d} {LABEL[method]:7s} "
                             f"err d {row['err_d']:.2e} r {row['err_r']:.2e} "
                             f"h {row['err_h']:.2e}  its {row['iterations_phi']}/"
                             f"{row['iterations_psi']}  {time.perf_counter() - t0:.1f} s"
                             + (f"  [{note}]" if note else ""))
            except thh.NeighbourError as exc:
                msg = (f"{F.name} N~{n} seed {seed}, {method}: NeighbourError ({exc}); "
                       f"sample replaced by seed {seed + 1}")
                self.runner.notes.append(msg)
                self.log("  " + msg)
                continue
            self.cache[key] = out
            return out
        raise RuntimeError(f"no usable sample for {F.name} N~{n} in {MAX_SEED_TRIES} seeds")


# ---------------------------------------------------------------------------
# output

def g(x, digits=3):
    if x == "" or x is None:
        return ""
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return f"{x:.{digits}g}" if abs(x) >= 1e-3 and abs(x) < 1e4 else f"{x:.{digits - 1}e}"


def pct(x):
    return f"{100 * x:.2f}%"


def md_table(header, rows):
    def cell(c):
        return str(c).replace("|", "\\|")     # |x| inside a markdown table cell
    out = ["| " + " | ".join(cell(c) for c in header) + " |",
           "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


COLORS = {"petronetto2010": "tab:red", "default": "tab:blue"}


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_histograms(hist_runs, path):
    """Fig. 10-11: top row both configurations on one scale (log counts),
    bottom row each configuration on its own range."""
    plt = _pyplot()
    arrays = hist_runs["arrays"]
    panels = (("curl_d", "curl d / mean |curl v|  (Fig. 10 left)"),
              ("div_r", "div r / mean |div v|  (Fig. 10 right)"),
              ("h_mag", f"|h|, exact |h0| = {H_MAGNITUDE}  (Fig. 11)"))

    def values(a, key):
        if key == "h_mag":
            return a[key]
        return a[key] / a["curl_scale" if key == "curl_d" else "div_scale"]

    fig, axes = plt.subplots(1 + len(arrays), 3, figsize=(15, 3.4 * (1 + len(arrays))),
                             squeeze=False)
    for col, (key, title) in enumerate(panels):
        allv = np.concatenate([values(a, key) for a in arrays.values()])
        lo, hi = np.quantile(allv, [0.001, 0.999])
        if key != "h_mag":
            lo, hi = -max(abs(lo), abs(hi)), max(abs(lo), abs(hi))
        ax = axes[0][col]
        for m, a in arrays.items():
            ax.hist(values(a, key), bins=np.linspace(lo, hi, 101), histtype="step", lw=1.4,
                    color=COLORS[m], label=LABEL[m])
        ax.set_yscale("log")
        ax.set_title(title + ", both", fontsize=9)
        for row, (m, a) in enumerate(arrays.items(), start=1):
            ax2 = axes[row][col]
            x = values(a, key)
            lo2, hi2 = np.quantile(x, [0.002, 0.998])
            if key != "h_mag":
                lo2, hi2 = -max(abs(lo2), abs(hi2)), max(abs(lo2), abs(hi2))
            ax2.hist(x, bins=np.linspace(lo2, hi2, 81), color=COLORS[m], alpha=0.8)
            ax2.set_title(f"{LABEL[m]}: {title.split('  ')[0]}", fontsize=9)
        for a_ in [axes[r][col] for r in range(1 + len(arrays))]:
            a_.axvline(H_MAGNITUDE if key == "h_mag" else 0.0, color="k", ls="--", lw=0.8)
            a_.set_ylabel("particles")
        axes[0][col].legend(fontsize=8)
    n = next(iter(hist_runs["rows"].values()))["n"]
    fig.suptitle(f"SPH-HH differential properties, field trig_h0.1, {n} blue-noise points "
                 f"(dashed: the exact value)", fontsize=11)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=100)
    plt.close(fig)


def _size_ticks(ax, sizes):
    from matplotlib.ticker import FixedLocator, NullLocator
    sizes = sorted(set(int(n) for n in sizes))
    ax.xaxis.set_major_locator(FixedLocator(sizes))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xticklabels([f"{n / 1000:.1f}k" for n in sizes])


def plot_convergence(conv, orders, path):
    plt = _pyplot()
    fields_ = list(conv)
    fig, axes = plt.subplots(1, len(fields_), figsize=(6.2 * len(fields_), 4.6), squeeze=False)
    styles = {"err_d": ("o", "-", "d"), "err_r": ("s", "--", "r"), "err_h": ("^", ":", "h")}
    for ax, fname in zip(axes[0], fields_):
        for m in CONFIGS:
            rows = [r for r in conv[fname] if r["method"] == m]
            n = [r["n"] for r in rows]
            for key, (mk, ls, lab) in styles.items():
                p = orders[(fname, m, key)]
                ax.loglog(n, [r[key] for r in rows], marker=mk, ls=ls, color=COLORS[m],
                          label=f"{LABEL[m]} {lab} (p={p:.2f})")
        ax.axhline(TARGET_MEAN_ERROR, color="gray", lw=0.8, ls="-.")
        _size_ticks(ax, [r["n"] for r in conv[fname]])
        ax.set_xlabel("particles N")
        ax.set_ylabel("mean error / mean |v0|")
        ax.set_title(f"field {fname}: err ~ spacing^p (dash-dot: 1% target)", fontsize=10)
        ax.legend(fontsize=7, ncol=2)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)


def plot_critical_points(cps, n, conv_rows, path):
    """Left: offset of each found centre from the true one, in particle spacings
    (circle: one spacing).  Right: the largest offset against N."""
    plt = _pyplot()
    markers = {"source": "o", "sink": "s", "cw_vortex": "v", "ccw_vortex": "^"}
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 5))
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(np.cos(t), np.sin(t), color="gray", lw=0.8)
    lim = 1.2
    for m, rows in cps.items():
        for r in rows:
            if r.get("spurious") or r["found_x"] == "" or r["true_x"] == "":
                continue
            spacing = math.hypot(r["found_x"] - r["true_x"], r["found_y"] - r["true_y"]) / \
                max(r["dist_spacings"], 1e-300)
            dx = (r["found_x"] - r["true_x"]) / spacing if r["dist_spacings"] else 0.0
            dy = (r["found_y"] - r["true_y"]) / spacing if r["dist_spacings"] else 0.0
            lim = max(lim, 1.1 * abs(dx), 1.1 * abs(dy))
            ax.plot(dx, dy, markers[r["kind"]], color=COLORS[m], mfc="none", ms=8)
        n_sp = sum(r.get("spurious", 0) for r in rows)
        ax.plot([], [], "o", color=COLORS[m], label=f"{LABEL[m]} ({n_sp} spurious)")
    for kind, mk in markers.items():
        ax.plot([], [], mk, color="k", mfc="none", label=kind)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.axhline(0, color="gray", lw=0.5)
    ax.axvline(0, color="gray", lw=0.5)
    ax.set_xlabel("found - true, x (spacings)")
    ax.set_ylabel("found - true, y (spacings)")
    ax.set_title(f"critical points, gaussian field, N={n} (circle: one spacing)", fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    for m in CONFIGS:
        rows = [r for r in conv_rows if r["method"] == m and r.get("cp_max_dist_spacings") != ""]
        ax2.loglog([r["n"] for r in rows], [r["cp_max_dist_spacings"] for r in rows], "o-",
                   color=COLORS[m], label=LABEL[m])
    ax2.axhline(1.0, color="gray", lw=0.8, ls="-.")
    _size_ticks(ax2, [r["n"] for r in conv_rows])
    ax2.set_xlabel("particles N")
    ax2.set_ylabel("largest distance to the true centre (spacings)")
    ax2.set_title("largest critical-point offset against N (dash-dot: one spacing)",
                  fontsize=10)
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend()
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------

def source_version():
    """The checkout's commit (with '+changes' when the library files differ from it)."""
    import subprocess
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO_ROOT, text=True,
                             capture_output=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "taichi_hh"],
                               cwd=REPO_ROOT, text=True, capture_output=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (rev + ("+changes" if dirty else "")) if rev else "unknown"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("--quick", action="store_true",
                    help="small run: sizes 1600,3300, table at 3300, histograms at 2000")
    ap.add_argument("--out", default=str(REPO_ROOT / "outputs" / "benchmarks"),
                    help="output directory (default: %(default)s)")
    ap.add_argument("--sizes", default=None,
                    help="comma-separated particle counts of the convergence sweep "
                         f"(default {','.join(map(str, DEFAULT_SIZES))})")
    ap.add_argument("--table-n", type=int, default=None,
                    help=f"points of the Fig. 12 error table (default {TABLE_N})")
    ap.add_argument("--hist-n", type=int, default=None,
                    help=f"points of the Fig. 10-11 histograms (default {HIST_N})")
    ap.add_argument("--tol", type=float, default=1e-8,
                    help="solver tolerance of the default configuration (default %(default)g, "
                         "the library default)")
    ap.add_argument("--fallback-tols", default="1e-7,1e-6",
                    help="looser tolerances tried in turn when a default-configuration solve "
                         "fails with SolverError (default %(default)s; '' for none)")
    ap.add_argument("--paper-tol", type=float, default=None,
                    help="override the paper configuration's tolerance (published: 1e-6)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the blue-noise samples")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    args = ap.parse_args(argv)
    args.fallback_tols = parse_list(args.fallback_tols)
    if args.sizes:
        sizes = parse_list(args.sizes, int)
    else:
        sizes = list(QUICK_SIZES if args.quick else DEFAULT_SIZES)
    table_n = args.table_n or (QUICK_TABLE_N if args.quick else TABLE_N)
    hist_n = args.hist_n or (QUICK_HIST_N if args.quick else HIST_N)
    if min(sizes + [table_n, hist_n]) < 100 or not (args.tol > 0):
        ap.error("sizes must be >= 100 and tol > 0")

    t_start = time.perf_counter()
    import taichi_hh as thh
    from taichi_hh.validation import fields
    thh.init(arch="cpu", precision="f64", threads=args.threads,
             offline_cache_dir=os.environ.get("TAICHI_HH_CACHE",
                                              str(REPO_ROOT / ".taichi_cache")))

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    runner = Runner(args, log)
    study = Study(thh, fields, runner, args, log)
    FG, FT, FH = fields.get("gaussian"), fields.get("trig"), constant_harmonic_field(fields)

    log(f"(a, b, d) constant-harmonic field {FH.name}, N~{hist_n}")
    hist = study.run(FH, hist_n, keep_arrays=True)
    log(f"(c, d, f) gaussian field, N~{table_n}")
    table = study.run(FG, table_n, critical=True)
    log("(e) convergence")
    conv = {"gaussian": [], "trig": []}
    for n in sizes:
        for F in (FG, FT):
            out = study.run(F, n, critical=F is FG)
            conv[F.name] += [out["rows"][m] for m in CONFIGS]
    run_seconds = time.perf_counter() - t_start

    orders = {}
    for fname, rows in conv.items():
        for m in CONFIGS:
            sel = [r for r in rows if r["method"] == m]
            for key in ("err_d", "err_r", "err_h"):
                orders[(fname, m, key)] = loglog_slope([r["spacing"] for r in sel],
                                                    [r[key] for r in sel])

    # ---- tables ---------------------------------------------------------------------
    sections = []     # (title, header, rows) printed and written as markdown

    tr = table["rows"]
    n_tab = tr["default"]["n"]
    hdr = ["measure", "paper (published)", "paper config (ours)", "default", "exact d0, r0"]
    rows = []
    f12p, f12d, f12x = table["fig12"]["petronetto2010"], table["fig12"]["default"], \
        table["fig12_exact"]
    for meas, stat, pub_key in (
            ("|d-d0|/|v0|", "mean", None), ("|r-r0|/|v0|", "mean", None),
            ("|h-h0|/|v0|", "mean", "|h|/|v0|"),
            ("|d-d0|/|v0|", "median", None), ("|r-r0|/|v0|", "median", None),
            ("|d-d0|/|v0|", "max", None), ("|r-r0|/|v0|", "max", None),
            ("|h-h0|/|v0|", "max", "|h|/|v0|"),
            ("|d-d0|", "mean", None), ("|r-r0|", "mean", None), ("|h-h0|", "mean", "|h|"),
            ("|curl d|", "mean", None), ("|div r|", "mean", None),
            ("curl d (signed)", "mean", None), ("div r (signed)", "mean", None),
            ("curl d (signed)", "median", None), ("div r (signed)", "median", None),
            ("|cos(r,d)|", "mean", None), ("|v0|", "mean", None)):
        i = ("max", "mean", "var", "median").index(stat)
        pub_key = pub_key or meas
        if pub_key == "|h|/|v0|":      # the paper's field has no harmonic part: |h| is its error
            pub = tuple(x / PAPER_FIG12["|v0|"][1] for x in PAPER_FIG12["|h|"])
        else:
            pub = PAPER_FIG12.get(pub_key)
        label = f"{stat} {meas}" + (f" (paper: {pub_key}, h0 = 0)" if pub_key != meas else "")
        rows.append([label, g(pub[i]) if pub else "", g(f12p[meas][stat]), g(f12d[meas][stat]),
                     g(f12x[meas][stat]) if meas in f12x else ""])
    rows.append(["Eq. 16 sum V <d,r>", g(PAPER_EQ16), g(tr["petronetto2010"]["eq16"]),
                 g(tr["default"]["eq16"]), g(tr["default"]["eq16_exact"])])
    rows.append(["Eq. 16 normalised <d,r>/(|d||r|)", "",
                 g(tr["petronetto2010"]["eq16_normalized"]),
                 g(tr["default"]["eq16_normalized"]), g(tr["default"]["eq16_exact_normalized"])])
    rows.append(["iterations phi / psi", "",
                 f"{tr['petronetto2010']['iterations_phi']} / "
                 f"{tr['petronetto2010']['iterations_psi']}",
                 f"{tr['default']['iterations_phi']} / {tr['default']['iterations_psi']}", ""])
    rows.append(["solver tol / preconditioner", "1e-06 / Jacobi",
                 f"{tr['petronetto2010']['tol']:g} / {tr['petronetto2010']['preconditioner']}",
                 f"{tr['default']['tol']:g} / {tr['default']['preconditioner']}", ""])
    rows.append(["seconds (decompose)", "", f"{tr['petronetto2010']['seconds']:.2f}",
                 f"{tr['default']['seconds']:.2f}", ""])
    sections.append((f"(c) Fig. 12 error table: gaussian field, {n_tab} blue-noise points "
                     f"(paper: 13287 points, its own analytic field; h0 = constant "
                     f"(0.05, 0.02) here, none in the paper, so its |h| row compares "
                     f"with our |h-h0|; 'exact' = the analytic d0, r0 through the same "
                     f"measures: |curl d0| and |div r0| with the default operator; the paper's "
                     f"signed curl d / div r rows are printed there as div d / curl r)", hdr, rows))

    hr = hist["rows"]
    n_hist = hr["default"]["n"]
    rows = []
    for m in CONFIGS:
        a, r = hist["arrays"][m], hr[m]
        rows.append([LABEL[m], g(r["curl_d_rel"]), g(r["curl_d0_rel"]),
                     g(float(np.median(np.abs(a["curl_d"]))) / a["curl_scale"]),
                     g(r["div_r_rel"]), g(r["div_r0_rel"]),
                     g(float(np.median(np.abs(a["div_r"]))) / a["div_scale"])])
    sections.append((f"(a) Fig. 10: curl d and div r (should vanish), field {FH.name}, "
                     f"{n_hist} points; each configuration's own divergence operator; "
                     f"relative to mean |curl v| and mean |div v|; 'floor' = the same "
                     f"operator on the exact d0, r0",
                     ["config", "mean |curl d|", "floor", "median |curl d|",
                      "mean |div r|", "floor", "median |div r|"], rows))

    rows = []
    for m in CONFIGS:
        hm = hist["arrays"][m]["h_mag"]
        rows.append([LABEL[m], g(float(hm.mean()), 4), g(float(hm.std())),
                     g(float(np.quantile(hm, 0.05)), 4), g(float(np.quantile(hm, 0.95)), 4),
                     pct(float((np.abs(hm - H_MAGNITUDE) <= 0.01 * H_MAGNITUDE).mean())),
                     pct(hr[m]["err_h"])])
    sections.append((f"(b) Fig. 11: |h| on the constant-harmonic field (|h0| = {H_MAGNITUDE}), "
                     f"{n_hist} points",
                     ["config", "mean |h|", "std", "5%", "95%", "within 1% of 0.1",
                      "mean |h-h0| / mean |v0|"], rows))

    rows = []
    for label, res_rows in ((f"{FH.name} N={n_hist}", hr), (f"gaussian N={n_tab}", tr)):
        rows.append([label, g(res_rows["petronetto2010"]["eq16_normalized"]),
                     g(res_rows["default"]["eq16_normalized"]),
                     g(res_rows["default"]["eq16_exact_normalized"]),
                     g(res_rows["petronetto2010"]["eq16"]), g(res_rows["default"]["eq16"])])
    sections.append(("(d) Eq. 16 L2 orthogonality <d, r> / (|d| |r|) (V_j = m_j / rho_j); "
                     "exact = the analytic d0, r0 with the same quadrature; raw = sum V <d, r> "
                     "(paper: 2.13e-6 on its Fig. 12 field)",
                     ["field", "paper config", "default", "exact", "raw paper config",
                      "raw default"], rows))

    rows = []
    for fname, rr in conv.items():
        for n in sizes:
            sel = {r["method"]: r for r in rr if abs(r["n"] - n) <= 0.05 * n}
            if len(sel) < 2:
                continue
            p, d = sel["petronetto2010"], sel["default"]
            rows.append([fname, str(d["n"]), pct(p["err_d"]), pct(p["err_r"]), pct(p["err_h"]),
                         pct(d["err_d"]), pct(d["err_r"]), pct(d["err_h"]),
                         f"{p['seconds']:.1f} / {d['seconds']:.1f}"])
        rows.append([fname, "order p",
                     *[f"{orders[(fname, m, k)]:.2f}" for m in CONFIGS
                       for k in ("err_d", "err_r", "err_h")], ""])
    sections.append(("(e) mean error / mean |v0| against particle count; order p of "
                     "err ~ spacing^p (least squares over all sizes; p = 2 means 4x smaller "
                     "per halved spacing)",
                     ["field", "N", "paper d", "paper r", "paper h", "default d", "default r",
                      "default h", "seconds paper / default"], rows))

    rows = []
    for m in CONFIGS:
        for c in table["cps"].get(m, []):
            rows.append([LABEL[m], c["kind"],
                         "" if c["true_x"] == "" else f"({c['true_x']:.3f}, {c['true_y']:.3f})",
                         "" if c["found_x"] == "" else f"({c['found_x']:.4f}, {c['found_y']:.4f})",
                         "" if c["dist_spacings"] == "" else f"{c['dist_spacings']:.2f}",
                         "spurious" if c.get("spurious") else ("yes" if c["matched"] else "NO")])
    sections.append((f"(f) critical points, gaussian field, {n_tab} points (spacing "
                     f"{tr['default']['spacing']:.4f}): nearest found point of the same kind",
                     ["config", "kind", "true", "found", "distance / spacing",
                      "within one spacing"], rows))
    rows = []
    for n in sizes:
        sel = {r["method"]: r for r in conv["gaussian"] if abs(r["n"] - n) <= 0.05 * n}
        if len(sel) < 2:
            continue
        rows.append([str(sel["default"]["n"])] + [
            f"{sel[m]['cp_matched']}/{sel[m]['cp_true']}, {sel[m]['cp_spurious']} spurious, "
            f"max {g(sel[m]['cp_max_dist_spacings'])} sp." for m in CONFIGS])
    sections.append(("(f) critical points against particle count (matched / true, spurious, "
                     "largest distance in spacings)", ["N", "paper config", "default"], rows))

    d13 = tr["default"]
    checks = [
        (f"default mean error of d <= 1% at N={n_tab}", d13["err_d"] <= TARGET_MEAN_ERROR,
         pct(d13["err_d"])),
        (f"default mean error of r <= 1% at N={n_tab}", d13["err_r"] <= TARGET_MEAN_ERROR,
         pct(d13["err_r"])),
        (f"default harmonic part recovered to 1% at N={n_tab}",
         d13["err_h"] <= TARGET_MEAN_ERROR, pct(d13["err_h"])),
        ("default errors fall under refinement (every order p > 0.5)",
         all(orders[(f, "default", k)] > 0.5 for f in conv for k in ("err_d", "err_r", "err_h")),
         ", ".join(f"{f} {k[-1]} {orders[(f, 'default', k)]:.2f}" for f in conv
                   for k in ("err_d", "err_r", "err_h"))),
        (f"default critical points within one spacing, none spurious (N={n_tab})",
         d13.get("cp_matched") == d13.get("cp_true") and d13.get("cp_spurious") == 0,
         f"{d13.get('cp_matched')}/{d13.get('cp_true')} matched, {d13.get('cp_spurious')} "
         f"spurious, max {g(d13.get('cp_max_dist_spacings'))} spacings"),
        ("default beats the paper configuration (d, r, h at every size)",
         all(r_d[k] < r_p[k] for f in conv for r_p, r_d in zip(conv[f][0::2], conv[f][1::2])
             for k in ("err_d", "err_r", "err_h")),
         "largest default/paper error ratio " + g(max(
             r_d[k] / r_p[k] for f in conv for r_p, r_d in zip(conv[f][0::2], conv[f][1::2])
             for k in ("err_d", "err_r", "err_h")))),
    ]
    target_note = ("" if table_n >= 10000 else
                   f"(the targets are stated for ~13k points; this run's table used N={n_tab})")

    # ---- print --------------------------------------------------------------------
    cmd = " ".join(["python benchmarks/petronetto_analysis.py"]
                   + list(sys.argv[1:] if argv is None else argv))
    for title, header, rows in sections:
        print(f"\n{title}\n")
        print(format_table(header, rows))
    print("\nissue 4 targets\n")
    print(format_table(["target", "met", "measured"],
                       [[t, "yes" if ok else "NO", m] for t, ok, m in checks], align="lll"))
    if target_note:
        print(target_note)
    notes = list(runner.notes)
    print(f"\nsolver: default tol {args.tol:g}" + (", fallbacks " + ", ".join(
        f"{t:g}" for t in args.fallback_tols) if args.fallback_tols else "") +
        "; paper configuration as published (Jacobi BiCGSTAB, 1e-6) unless noted")
    for nt in notes or ["no workaround was needed: every solve succeeded as configured"]:
        print("note: " + nt)
    print(f"\nrun time {run_seconds:.0f} s")

    # ---- files --------------------------------------------------------------------
    out = Path(args.out)
    all_rows = []
    seen = set()
    for key, res in study.cache.items():
        if key in seen:
            continue
        seen.add(key)
        all_rows += [res["rows"][m] for m in CONFIGS]
    write_csv_atomic(out / "petronetto_runs.csv", all_rows, RUN_FIELDS)

    fig12_rows = []
    for m in CONFIGS:
        for meas, st in table["fig12"][m].items():
            pub = PAPER_FIG12.get(meas)
            fig12_rows.append(dict(method=m, n=n_tab, measure=meas, **st,
                                   paper_max=pub[0] if pub else "",
                                   paper_mean=pub[1] if pub else "",
                                   paper_var=pub[2] if pub else "",
                                   paper_median=pub[3] if pub else ""))
    write_csv_atomic(out / "petronetto_fig12.csv", fig12_rows,
                     ["method", "n", "measure", "max", "mean", "var", "median", "paper_max",
                      "paper_mean", "paper_var", "paper_median"])

    prop_rows = []
    for m in CONFIGS:
        a, r = hist["arrays"][m], hr[m]
        for q, vals, scale in (("curl_d", a["curl_d"], a["curl_scale"]),
                               ("div_r", a["div_r"], a["div_scale"]),
                               ("curl_d0", a["curl_d0"], a["curl_scale"]),
                               ("div_r0", a["div_r0"], a["div_scale"]),
                               ("h_mag", a["h_mag"], 1.0)):
            s = summary_stats(np.abs(vals))
            prop_rows.append(dict(field=FH.name, n=r["n"], method=m, quantity=q, scale=scale,
                                  **{k: v for k, v in s.items()},
                                  p05=float(np.quantile(vals, 0.05)),
                                  p95=float(np.quantile(vals, 0.95))))
        for label, rr in ((FH.name, hr), ("gaussian", tr)):
            prop_rows.append(dict(field=label, n=rr[m]["n"], method=m, quantity="eq16_normalized",
                                  mean=rr[m]["eq16_normalized"]))
            prop_rows.append(dict(field=label, n=rr[m]["n"], method=m, quantity="eq16",
                                  mean=rr[m]["eq16"]))
    write_csv_atomic(out / "petronetto_properties.csv", prop_rows,
                     ["field", "n", "method", "quantity", "scale", "max", "mean", "var", "median",
                      "p05", "p95"])

    conv_rows = [dict(field=f, method=m, measure=k, order=orders[(f, m, k)],
                      sizes=" ".join(str(r["n"]) for r in conv[f] if r["method"] == m))
                 for f in conv for m in CONFIGS for k in ("err_d", "err_r", "err_h")]
    write_csv_atomic(out / "petronetto_convergence.csv", conv_rows,
                     ["field", "method", "measure", "order", "sizes"])

    cp_rows = [dict(method=m, n=n_tab, **c) for m in CONFIGS for c in table["cps"].get(m, [])]
    write_csv_atomic(out / "petronetto_critical_points.csv", cp_rows,
                     ["method", "n", "kind", "true_x", "true_y", "found_x", "found_y",
                      "dist_spacings", "matched", "spurious"])

    plot_histograms(hist, out / "petronetto_histograms.png")
    plot_convergence(conv, orders, out / "petronetto_convergence.png")
    plot_critical_points(table["cps"], n_tab, conv["gaussian"],
                         out / "petronetto_critical_points.png")

    md = [f"# Petronetto et al. 2010 analyses, redone\n",
          f"Made by `{cmd.strip()}` on {time.strftime('%Y-%m-%d')} in {run_seconds:.0f} s "
          f"(library at {source_version()}; 2-core CPU, f64). 'paper' = `method=\"petronetto2010\"`, 'default' = "
          f"`method=\"default\"`, both on the same blue-noise points (seed {args.seed} "
          f"unless noted). Errors are mean |x - x0| over mean |v0|.\n",
          f"Solver: default configuration at tol {args.tol:g}"
          + (f" (falling back to {', '.join(f'{t:g}' for t in args.fallback_tols)} on a "
             f"SolverError)" if args.fallback_tols else "")
          + "; paper configuration as published (Jacobi BiCGSTAB to 1e-6) unless a note "
            "below says otherwise.\n"]
    for title, header, rows in sections:
        md += [f"## {title}\n", md_table(header, rows), ""]
    md += ["Reading the tables: the paper's own field differs from ours (theirs is not given "
           "in closed form), so only the order of its numbers compares.  Pointwise "
           "|cos(r, d)| is no property of the decomposition (the exact d0, r0 give 0.75 on "
           "the gaussian field, where both are small far from the bumps); Eq. 16's integral "
           "is.  The exact integral is 0 for both fields: the 'exact' values are the "
           "quadrature floor of the particle volumes.", ""]
    md += ["## issue 4 targets\n",
           md_table(["target", "met", "measured"], [[t, "yes" if ok else "**no**", m]
                                                    for t, ok, m in checks]), ""]
    if target_note:
        md += [target_note, ""]
    md += ["## notes\n"] + [f"- {nt}" for nt in (notes or ["every solve succeeded as "
                                                           "configured (no workaround used)"])]
    md += ["", "Figures: `petronetto_histograms.png` (a, b), `petronetto_convergence.png` (e), "
               "`petronetto_critical_points.png` (f).", ""]
    text = "\n".join(md).encode()
    write_bytes_atomic(out / "petronetto_summary.md", text)
    print(f"\nwrote petronetto_*.csv, *.png and petronetto_summary.md to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
