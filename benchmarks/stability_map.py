"""Stability map: where each method breaks down or loses accuracy, every cell a
real run, and whether the failure is reported.

    python benchmarks/stability_map.py [--quick] [--out DIR] [--workers 2]

Families (rows x columns; every cell one run in a worker process):

``disorder``  decomposition variants (the bundles ``default``,
              ``petronetto2010``, ``colin2006``; ``grad:X`` = divergence,
              gradient and Neumann-row gradient variant X; ``lap:X`` = Laplacian
              variant X) and the null-divergence projection (``project:default``,
              ``project:colin2006`` with Colin's 5 passes) on the ``trig``
              field, the points pushed from a lattice through jittered lattices
              (jitter 0.3, 0.6, 1.0 spacings) and blue noise to uniform random
              points and clusters (half the points in four Gaussian clusters of
              width 0.05, local density up to ~20x the mean).
``support``   the same rows on blue noise, support / mean spacing from 3 down
              to 0.8 (too few neighbours).
``kappa``     Petronetto's ridge term from 0 upward, with and without the
              bordered compatibility unknown, for ``petronetto2010`` (published:
              kappa 1e-3, unbordered) and the default (kappa 0, bordered), on the
              ``gaussian`` field (their Table 9 field); cells show iterations.
``flow``      the Rayleigh-Taylor growth of one mode (benchmarks/rt_growth.py,
              density ratio 2, viscosity 2e-3, shifting 2 unless the row
              changes it, free-slip walls): time step past the stable limit
              (all of FlowParams ``cfl``, ``viscous_cfl``, ``force_cfl`` and
              ``dt_max`` multiplied by the factor, from their defaults), density ratio 1.2 ... 1000, viscosity down to 0,
              particle shifting off / on.
``input``     bad input: a NaN vector, a duplicated point.

Status of a cell (thresholds stated here and in the chart):

``ok``            finished, error within the thresholds below;
``inaccurate``    finished without an error but err > 0.25 (decomposition: the
                  worst of mean |d - d_exact|, |r - r_exact|, |h - h_exact| over
                  mean |v|; projection: mean |w - (r + h)_exact| / mean |v|;
                  flow: |s_SPH / s_theory - 1|), or err > 4 x the same row's
                  reference cell (blue noise, the bundle's own support and kappa,
                  flow at its defaults): it lost accuracy as it was pushed;
``flagged``       returned, but flagged by the library's own consistency
                  check (``AccuracyWarning``, ``stats["flags"]``: components
                  carrying more than 4x the field's energy): reported;
``error``         raised an exception of this package naming the cause
                  (InputError, NeighbourError, SolverError with its ``reason``,
                  BlowUpError with its ``cause``): reported;
``garbage``       returned without an error but with NaN/inf or absurd values
                  (a component larger than 100 x max |v|; a flow speed above
                  10, five times the free-fall speed over the box height):
                  must never happen;
``crash``         the worker process died, or an exception that is not one of
                  the package's own (a bug either way).

Writes ``stability_map.csv`` and ``stability_map.png`` to ``--out`` (default
outputs/charts; quick: ``stability_map_quick.*``) and prints, per family, the
table and the edge of each row (the first column that is not ok).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from _common import REPO_ROOT, add_repo_to_path, format_table, run_tasks, write_csv_atomic

add_repo_to_path()
from taichi_hh.validation.stability import (ERR_ABS, ERR_REL, as_float,  # noqa: E402
                                            classify)
from taichi_hh.validation.sweep import CSV_FIELDS, read_rows, variant  # noqa: E402
from taichi_hh.hhd.options import METHODS  # noqa: E402


MAP_FIELDS = ["family", "row", "column", "status", "note", "ref_err"] + CSV_FIELDS
COLORS = {"ok": "#7fc97f", "inaccurate": "#fdc086", "error": "#80b1d3", "flagged": "#beaed4",
          "garbage": "#e41a1c", "crash": "#444444"}

HHD_ROWS = ["default", "petronetto2010", "colin2006", "grad:basic", "grad:difference",
            "grad:symmetric", "grad:corrected", "lap:basic", "lap:brookshaw",
            "project:default", "project:colin2006"]
QUICK_ROWS = ["default", "petronetto2010", "colin2006", "grad:basic", "grad:corrected",
              "project:default"]
BUNDLE_SUPPORT = {name: opts.support_ratio for name, opts in METHODS.items()}


def _row_task(row: str, n: int, **kw) -> dict:
    if row.startswith("project:"):
        m = row.split(":", 1)[1]
        t = {"task": "project", "method": m, "overrides": {},
             "iterations": 5 if m == "colin2006" else 1}
    else:
        m, o = variant(row)
        t = {"task": "hhd", "method": m, "overrides": dict(o)}
    t.update({"n": n, "field": "trig", "sampling": "poisson", "seed": 3, "repeats": 1,
              "precision": "f64", "cost": n})
    over = kw.pop("overrides", {})
    t["overrides"].update(over)
    t.update(kw)
    return t


def _bundle(row: str) -> str:
    m = row.split(":", 1)[1] if row.startswith("project:") else variant(row)[0]
    return m


def build_tasks(quick: bool) -> list[dict]:
    tasks = []

    def add(family, row, column, task, reference=False):
        task["extra"] = {"family": family, "row": row, "column": column,
                         "reference": reference}
        task["group"], task["label"] = family, f"{row} @ {column}"
        tasks.append(task)

    n = 900 if quick else 1600
    rows = QUICK_ROWS if quick else HHD_ROWS
    samplings = ["lattice", "jitter0.6", "poisson", "random", "clustered", "clusters",
                 "gradient"] if quick else \
        ["lattice", "jitter0.3", "jitter0.6", "jitter1.0", "poisson", "random", "clustered",
         "clusters", "gradient"]
    for r in rows:
        for s in samplings:
            add("disorder", r, s, _row_task(r, n, sampling=s), reference=(s == "poisson"))
    ratios = [3.5, 2.5, 2.0, 1.5, 1.0] if quick else [4.0, 3.5, 3.0, 2.5, 2.0, 1.75, 1.5, 1.25,
                                                       1.0, 0.8]
    for r in rows:
        own = BUNDLE_SUPPORT.get(_bundle(r), 2.5)
        for s in ratios:
            add("support", r, f"{s:g}", _row_task(r, n, overrides={"support_ratio": s}),
                reference=(s == own))
    kap_rows = {"petronetto2010": ("petronetto2010", {}),
                "petronetto2010 bordered": ("petronetto2010", {"bordered": True}),
                "default unbordered": ("default", {"bordered": False}),
                "default": ("default", {})}
    kappas = [0.0, 1e-8, 1e-3, 1e-1] if quick else [0.0, 1e-10, 1e-8, 1e-6, 1e-4, 1e-3, 1e-2,
                                                     1e-1, 1.0]
    if quick:
        kap_rows = {k: kap_rows[k] for k in ("petronetto2010", "default unbordered")}
    nk = 1640
    for r, (m, o) in kap_rows.items():
        own = 1e-3 if m == "petronetto2010" else 0.0
        for k in kappas:
            t = {"task": "hhd", "method": m, "overrides": {**o, "kappa": k}, "n": nk,
                 "field": "gaussian", "sampling": "poisson", "seed": 3, "repeats": 1,
                 "precision": "f64", "cost": nk * 3}
            add("kappa", r, f"{k:g}", t, reference=(k == own))
    # flow: Rayleigh-Taylor
    nf = 800 if quick else 1800
    tmax = 0.6 if quick else 2.0

    def rt(params=None, **kw):
        # free-slip walls: the linear theory's setting (benchmarks/rt_growth.py)
        base = {"task": "rt", "n": nf, "ratio": 2.0, "max_time": tmax,
                "params": {"walls": "free-slip", **(params or {})},
                "precision": "f64", "cost": 60 * nf}
        base.update(kw)
        return base

    from taichi_hh.flow.twophase import FlowParams
    d = FlowParams()
    factors = [1, 16, 64] if quick else [1, 2, 4, 8, 16, 32, 64]
    for f in factors:
        p = {"cfl": d.cfl * f, "viscous_cfl": d.viscous_cfl * f, "force_cfl": d.force_cfl * f,
             "dt_max": d.dt_max * f}
        add("flow", "time step x", f"x{f}", rt(params=p), reference=(f == 1))
    for ratio in ([2.0, 100.0] if quick else [1.2, 2.0, 10.0, 100.0, 1000.0]):
        add("flow", "density ratio", f"{ratio:g}", rt(ratio=ratio), reference=(ratio == 2.0))
    for nu in ([2e-3, 0.0] if quick else [2e-3, 5e-4, 1e-4, 0.0]):
        add("flow", "viscosity", f"{nu:g}", rt(viscosity=nu), reference=(nu == 2e-3))
    for sh in [2.0, 0.0]:
        add("flow", "shifting", "on (2)" if sh else "off", rt(shifting=sh),
            reference=(sh == 2.0))
    # bad input
    add("input", "decompose", "NaN vector", _row_task("default", 400, corrupt="nan"))
    add("input", "decompose", "duplicate point", _row_task("default", 400, corrupt="duplicate"))
    add("input", "project", "NaN vector", _row_task("project:default", 400, corrupt="nan"))
    return tasks


def make_chart(cells: list[dict], path: Path, quick: bool) -> None:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch, Rectangle
    from taichi_hh.app.io import atomic_savefig
    families = list(dict.fromkeys(c["family"] for c in cells))
    layout = {}
    for fam in families:
        fc = [c for c in cells if c["family"] == fam]
        rows = list(dict.fromkeys(c["row"] for c in fc))
        width = max(sum(1 for c in fc if c["row"] == r) for r in rows)
        layout[fam] = (fc, rows, width)
    heights = [len(layout[f][1]) + 1.2 for f in families]
    width = max(w for _, _, w in layout.values())
    fig = Figure(figsize=(2.0 + 1.35 * width, 0.42 * sum(heights) + 1.2))
    gs = fig.add_gridspec(len(families), 1, height_ratios=heights, hspace=0.55,
                          left=0.14, right=0.99, top=0.93, bottom=0.06)
    for k, fam in enumerate(families):
        fc, rows, _ = layout[fam]
        ax = fig.add_subplot(gs[k])
        same_cols = len({tuple(c["column"] for c in fc if c["row"] == r) for r in rows}) == 1
        for i, r in enumerate(rows):
            rc = [c for c in fc if c["row"] == r]
            for j, c in enumerate(rc):
                y = len(rows) - 1 - i
                ax.add_patch(Rectangle((j, y), 1, 1, facecolor=COLORS[c["status"]],
                                       edgecolor="white", lw=1.5))
                text = c["note"].replace("SolverError", "Solver").replace(
                    "NeighbourError", "Neighbour").replace("InputError", "Input").replace(
                    "BlowUpError", "BlowUp")
                if not same_cols:
                    text = f"{c['column']}\n{text}"
                ax.text(j + 0.5, y + 0.5, text, ha="center", va="center", fontsize=5.2,
                        wrap=True)
        ax.set_xlim(0, width)
        ax.set_ylim(0, len(rows))
        ax.set_yticks(np.arange(len(rows)) + 0.5)
        ax.set_yticklabels(rows[::-1], fontsize=7)
        if same_cols:
            cols = [c["column"] for c in fc if c["row"] == rows[0]]
            ax.set_xticks(np.arange(len(cols)) + 0.5)
            ax.set_xticklabels(cols, fontsize=7)
            ax.xaxis.tick_top()
        else:
            ax.set_xticks([])
        ax.set_title(fam, fontsize=9, loc="left")
        for s in ax.spines.values():
            s.set_visible(False)
    handles = [Patch(color=v, label=k) for k, v in COLORS.items()]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, frameon=False)
    fig.suptitle(f"Stability map{' (quick)' if quick else ''}: inaccurate = err > {ERR_ABS:g} "
                 f"or > {ERR_REL:g}x the row's reference; garbage = NaN/absurd without an error",
                 fontsize=9)
    atomic_savefig(fig, str(path), dpi=130)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small map, under two minutes")
    ap.add_argument("--out", default=str(REPO_ROOT / "outputs" / "charts"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--replot", metavar="CSV", help="reclassify and redraw from this CSV")
    ap.add_argument("--docs", action="store_true",
                    help="also copy the map's chart to docs/figures/ (the README's)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    refs = {}
    if args.replot:
        rows = read_rows(args.replot)
        for r in rows:
            r["status"] = r.pop("run_status")
            refs[(r["family"], r["row"])] = as_float(r.get("ref_err"))
    else:
        tasks = build_tasks(args.quick)
        print(f"{len(tasks)} cells, {args.workers} workers", flush=True)
        rows = run_tasks(tasks, args.workers, args.threads, progress=not args.no_progress)
        for r in rows:
            if r.get("reference") and r.get("status") == "ok":
                refs[(r["family"], r["row"])] = as_float(r.get("err"))
    cells = []
    for r in rows:
        ref = refs.get((r["family"], r["row"]), math.nan)
        status, note = classify(r, ref)
        cells.append({**r, "status": status, "note": note, "ref_err": ref,
                      "run_status": r.get("status")})
    out = Path(args.out)
    name = "stability_map_quick" if args.quick else "stability_map"
    write_csv_atomic(out / f"{name}.csv", cells, MAP_FIELDS + ["run_status", "message"])
    make_chart(cells, out / f"{name}.png", args.quick)
    if args.docs:
        make_chart(cells, REPO_ROOT / "docs" / "figures" / "stability_map.png", args.quick)
    for fam in dict.fromkeys(c["family"] for c in cells):
        fc = [c for c in cells if c["family"] == fam]
        print(f"\n== {fam}")
        print(format_table(["row", "column", "N", "status", "note"],
                           [[c["row"], c["column"], c.get("n_points", ""), c["status"],
                             c["note"].replace("\n", "; ")] for c in fc], "llrll"))
    print("\nEdges (first column, in the order run, that is not ok):")
    for fam in dict.fromkeys(c["family"] for c in cells):
        for row in dict.fromkeys(c["row"] for c in cells if c["family"] == fam):
            rc = [c for c in cells if c["family"] == fam and c["row"] == row]
            bad = [c for c in rc if c["status"] != "ok"]
            print(f"  {fam:9s} {row:24s} " + (f"{bad[0]['column']}: {bad[0]['status']}"
                                              if bad else "all ok"))
    garbage = [c for c in cells if c["status"] in ("garbage", "crash")]
    print(f"\n{len(garbage)} garbage/crash cell(s)")
    for c in garbage:
        print(f"  {c['family']} {c['row']} @ {c['column']}: {c['note'].replace(chr(10), ' ')} "
              f"[{c.get('message', '')[:200]}]")
    print(f"wrote {out / (name + '.csv')} and {out / (name + '.png')}; "
          f"{time.perf_counter() - t0:.0f} s")
    return cells


if __name__ == "__main__":
    main()
