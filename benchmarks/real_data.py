"""Real PIV measurements (issue 28, "data as instruments deliver it"): the
sample fields shipped inside the ``pivpy`` package, read with pivpy's readers
and decomposed with :func:`taichi_hh.decompose_grid`.

    python benchmarks/real_data.py [--datasets jet,urban,...] [--conditions natural,neumann]
                                   [--no-extras] [--no-figures] [--repeats N]

Needs ``pip install "pivpy[lvpyio]"`` (the ``bench`` extra); without pivpy it
prints a note and exits 0.

Datasets (pivpy/data/..., the first frame of each set; the rule that marks a
vector invalid):

* ``jet``: a round air jet with an unlit corner (PIVMAT_jet/B00001.VC7,
  DaVis 7); not (MASK and ENABLED).
* ``urban``: a street canyon, the buildings masked (urban_canopy/B00001.vc7,
  DaVis); not (MASK and ENABLED).
* ``wingtip``: a wing-tip vortex, seeding lost in its core (PIV Challenge
  2001 case A, openpiv_txt/.../StrongVortex/A, OpenPIV text x y u v flags
  mask); NaN or flags != 0.
* ``openpiv``: the OpenPIV tutorial pair (openpiv_txt/exp1_001_b.txt, OpenPIV
  text x y u v s2n); NaN.
* ``davis_txt``: a curved stream in a masked band (PIV_Challenge/B00001.txt,
  DaVis 8 text export); u == v == 0.
* ``soapfilm``: a soap film with vortices (Insight/Run000001..., TSI
  Insight .vec); CHC <= 0.
* ``cavity``: a cavity flow (day2/day2a005000..., TSI Insight .vec, pixel
  units); CHC <= 0.

Readers (pivpy 0.4.0) and what they deliver:

* DaVis .vc7: ``pivpy.io.load_vc7`` gives the grid and ``chc`` = MASK and
  ENABLED (invalid nodes set to zero), but its u, v are the raw first-peak
  vectors ``U0``, ``V0`` in the image's row direction: DaVis's final field is
  the *active choice* (another peak, or the smoothed/filled vector) and v
  points along +y only after the y scale's sign is applied.  The rows here
  take the values from ``lvpyio`` (the library pivpy calls), the active
  choice with the axes' signs (``VectorFrame.as_masked_array``), on pivpy's
  grid and validity; the extra rows "pivpy values" decompose pivpy's own
  values (the zero first-peak vectors of enabled nodes counted invalid).
* OpenPIV text: ``pivpy.io.loadpivtxt`` (the PIVMAT-style reader: raw
  columns, NaN kept, the fifth column in ``chc``).  pivpy's OpenPIVReader
  (``load_openpiv_txt``) reads OpenPIV's sixth column (mask: 1 where the
  image was masked) the wrong way round and zeroes every vector of such a
  file; it also turns NaN into 0.
* DaVis 8 text: ``pivpy.io.load_vec`` (Davis8Reader); no flag column, DaVis
  writes disabled and masked vectors as exact zeros.
* TSI Insight .vec: ``pivpy.io.load_vec`` (InsightVECReader), ``chc`` is
  Insight's CHC column: positive for a valid vector (the correlation peak
  chosen), zero or negative for a vector removed by validation (-1) or not
  computed at the frame's edge (-3); pivpy's own plots only drop CHC == 0.

Per dataset and boundary condition (``default``: :func:`decompose_grid`'s
``auto``, the condition it chose in ``condition_used``;
``natural``; ``neumann``): the grid, valid and invalid nodes, the nodes
decomposed; from ``result.stats`` the energy ratio (|d|^2 + |r|^2 +
|h|^2 over |v|^2, 1 for an exact decomposition), h's harmonicity
(``h_divergence``, ``h_curl``) and the flags; the critical points
(``result.critical_points()``, the filters for measured data on: boundary
artefacts, noise and wrong vectors' dipoles left out), their kinds, how many
the unfiltered search finds (``filter=False``), and how many lie outside the
data (not inside ``result.domain``, or farther than one grid spacing from
every node decomposed); the whole call's seconds after a warm-up call, and
the critical points' seconds (medians of ``--repeats`` calls after a warm-up, the
critical points each on a fresh result: kernels compiled; the layouts and
geometries kept from the earlier calls on the grid, as in a run's frames),
and both again on the grid as if seen for the first time (``new_grid_*``:
``forget_layouts()`` before each).  The issue's
targets: energy ratio <= 1.2, no critical point outside the data, and the
critical points found in less time than the decomposition.

Extra rows (``--no-extras`` leaves them out), labelled in ``variant`` and
``condition``: the VC7 fields as pivpy's reader delivers them ("pivpy
values"); the instrument's field with ``normal-parallel``; "despiked": a
vector farther than 3 local spreads from the median of its 3 x 3
neighbourhood (the normalised median test, Westerweel & Scarano 2005) also
counted invalid, to show what the outliers cost; "sparse masked": a valid
node with fewer than 4 valid nodes among its 8 neighbours also counted
invalid (islands and one-node strips in regions the instrument mostly
rejected), a tighter masking rule.  Columns ``e_d``, ``e_r``, ``e_h``,
``e_rh``: |d|^2, |r|^2, |h|^2 and 2 r.h over |v|^2 summed over the nodes
decomposed (unweighted): where an energy ratio away from 1 comes from.

Writes ``outputs/benchmarks/real_data.csv`` and ``docs/figures/real_<name>.png``
(v, d, r, h arrows and the critical points, the default condition).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from dataclasses import dataclass

import _common

_common.add_repo_to_path()

#: energy ratio and critical points: the issue's targets for real data
ENERGY_TARGET = 1.2
CRITICAL_KINDS = ("source", "sink", "cw_vortex", "ccw_vortex")


@dataclass(frozen=True)
class Dataset:
    name: str
    path: str               # under pivpy/data
    fmt: str                # vc7 | openpiv | davis8 | insight
    flow: str
    units: str              # of the coordinates
    invalid_rule: str


DATASETS = (
    Dataset("jet", "PIVMAT_jet/B00001.VC7", "vc7", "round air jet, unlit corner", "mm",
            "not (MASK and ENABLED)"),
    Dataset("urban", "urban_canopy/B00001.vc7", "vc7", "street canyon, masked buildings", "mm",
            "not (MASK and ENABLED)"),
    Dataset("wingtip", "openpiv_txt/Gamma1_Gamma2_tutorial_notebook/StrongVortex/A/"
            "PIVchallengeCaseAvelField.txt", "openpiv",
            "wing-tip vortex, seeding lost in the core", "px", "NaN or flags != 0"),
    Dataset("openpiv", "openpiv_txt/exp1_001_b.txt", "openpiv", "OpenPIV tutorial exp1_001",
            "px", "NaN"),
    Dataset("davis_txt", "PIV_Challenge/B00001.txt", "davis8", "curved stream in a masked band",
            "mm", "u == v == 0"),
    Dataset("soapfilm", "Insight/Run000001.T000.D000.P000.H001.L.vec", "insight",
            "soap film with vortices", "mm", "CHC <= 0"),
    Dataset("cavity", "day2/day2a005000.T000.D000.P003.H001.L.vec", "insight", "cavity flow",
            "px", "CHC <= 0"),
)
BY_NAME = {d.name: d for d in DATASETS}
CONDITIONS = ("default", "natural", "neumann")
#: extra rows: a condition tried on the instrument's field besides CONDITIONS
EXTRA_CONDITIONS = ("normal-parallel",)
FIELDS = ["dataset", "variant", "condition", "condition_used", "format", "grid", "n_valid",
          "n_invalid", "n_used",
          "energy_ratio", "h_divergence", "h_curl", "n_critical", "n_unfiltered", "n_outside",
          "targets", "seconds", "critical_seconds", "new_grid_seconds",
          "new_grid_critical_seconds", "critical_kinds", "e_d", "e_r", "e_h", "e_rh", "flags", "invalid_rule", "units", "flow", "file"]


def data_dir() -> str:
    import pivpy
    return os.path.join(os.path.dirname(pivpy.__file__), "data")


def _frame(ds, name):
    import numpy as np
    a = np.asarray(ds[name].values, dtype=np.float64)
    return a[..., 0] if a.ndim == 3 else a


def read(spec: Dataset, values: str = "instrument"):
    """``(x, y, u, v)``: x (nx,), y (ny,), u, v (ny, nx) with NaN where the
    instrument marks the vector invalid.  ``values="pivpy"``: the VC7 values
    as pivpy's reader delivers them (module doc)."""
    import numpy as np
    from pivpy import io as pio
    path = os.path.join(data_dir(), spec.path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if spec.fmt == "vc7":
            ds = pio.load_vc7(path)
        elif spec.fmt == "openpiv":
            ds = pio.loadpivtxt(path)
        else:
            ds = pio.load_vec(path)
    x = np.asarray(ds["x"].values, dtype=np.float64)
    y = np.asarray(ds["y"].values, dtype=np.float64)
    u, v, chc = _frame(ds, "u"), _frame(ds, "v"), _frame(ds, "chc")
    if spec.fmt == "vc7":
        invalid = chc == 0                            # pivpy: MASK and ENABLED
        if values == "pivpy":
            invalid |= (u == 0) & (v == 0)            # first peaks DaVis zeroed
        else:
            from lvpyio import read_buffer
            arr = read_buffer(path)[0].as_masked_array()   # the active choice, axes' signs
            u = np.asarray(arr["u"].data, dtype=np.float64)
            v = np.asarray(arr["v"].data, dtype=np.float64)
    elif spec.fmt == "openpiv":
        invalid = np.isnan(u) | np.isnan(v)
        with open(path, errors="ignore") as fh:
            header = fh.readline()
        if header.lstrip().startswith("#") and "flags" in header.split():
            invalid |= chc != 0                       # OpenPIV's outlier flags
    elif spec.fmt == "davis8":
        invalid = (u == 0) & (v == 0)                 # DaVis writes invalid vectors as 0 0
    elif spec.fmt == "insight":
        invalid = chc <= 0                            # TSI CHC: positive = valid
    else:
        raise ValueError(spec.fmt)
    u = np.where(invalid, np.nan, u)
    v = np.where(invalid, np.nan, v)
    return x, y, u, v


def despike(u, v, threshold: float = 3.0, floor: float = 0.01):
    """``(u, v)`` with NaN where the normalised median test (Westerweel &
    Scarano 2005) marks a spike: in either component, the distance from the
    median of the valid 3 x 3 neighbours over their median distance from it
    (plus ``floor`` times the field's median speed, the test's epsilon in the
    data's units) above ``threshold``.  Invalid nodes stay invalid."""
    import numpy as np
    ny, nx = u.shape
    bad = np.zeros(u.shape, dtype=bool)
    eps = floor * float(np.nanmedian(np.hypot(u, v)))
    for comp in (u, v):
        pad = np.pad(comp, 1, constant_values=np.nan)
        neigh = np.stack([pad[1 + dj:1 + dj + ny, 1 + di:1 + di + nx]
                          for dj in (-1, 0, 1) for di in (-1, 0, 1) if dj or di])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")          # all-NaN neighbourhoods
            med = np.nanmedian(neigh, axis=0)
            res = np.nanmedian(np.abs(neigh - med), axis=0)
            score = np.abs(comp - med) / (res + eps)
        bad |= np.nan_to_num(score, nan=0.0) > threshold
    return np.where(bad, np.nan, u), np.where(bad, np.nan, v)


def outside(np, res, critical) -> int:
    """Critical points outside the data: not inside the domain, or farther
    than one grid spacing from every node decomposed."""
    if not critical:
        return 0
    X, Y = np.meshgrid(res.x, res.y)
    nodes = np.c_[X[res.used], Y[res.used]]
    h = max(float(np.median(np.abs(np.diff(res.x)))), float(np.median(np.abs(np.diff(res.y)))))
    pts = np.array([[c.x, c.y] for c in critical], dtype=np.float64)
    inside = res.domain.contains(pts)
    near = np.array([np.hypot(*(nodes - p).T).min() <= h * (1 + 1e-9) for p in pts])
    return int((~(inside & near)).sum())


def mask_sparse(u, v, least: int = 4):
    """``(u, v)`` with NaN at the valid nodes that have fewer than ``least``
    valid nodes among their 8 neighbours: islands and one-node-wide strips in
    regions the instrument mostly rejected (a tighter masking rule)."""
    import numpy as np
    invalid = np.isnan(u) | np.isnan(v)
    ny, nx = u.shape
    pad = np.pad(~invalid, 1, constant_values=False)
    count = sum(pad[1 + dj:1 + dj + ny, 1 + di:1 + di + nx].astype(int)
                for dj in (-1, 0, 1) for di in (-1, 0, 1) if dj or di)
    thin = ~invalid & (count < least)
    return np.where(thin, np.nan, u), np.where(thin, np.nan, v)


def run_one(thh, np, spec, variant, condition, x, y, u, v, repeats: int = 3):
    opts = {} if condition == "default" else {"boundary_condition": condition}

    def call():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return thh.decompose_grid(x, y, u, v, **opts)
    row = {"dataset": spec.name, "variant": variant, "condition": condition, "format": spec.fmt,
           "grid": f"{len(y)}x{len(x)}", "invalid_rule": spec.invalid_rule, "units": spec.units,
           "flow": spec.flow, "file": spec.path}
    invalid = np.isnan(u) | np.isnan(v)
    row.update(n_valid=int((~invalid).sum()), n_invalid=int(invalid.sum()))
    try:
        call()                                   # compile and warm up
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            res = call()
            times.append(time.perf_counter() - t)
        seconds = statistics.median(times)
    except thh.TaichiHHError as exc:
        row.update(n_used=0, energy_ratio=float("nan"), h_divergence=float("nan"),
                   h_curl=float("nan"), n_critical=0, n_unfiltered=0, n_outside=0,
                   targets="error", seconds=float("nan"), critical_seconds=float("nan"),
                   new_grid_seconds=float("nan"), new_grid_critical_seconds=float("nan"),
                   critical_kinds="", flags=f"error: {exc}"[:300])
        row.update(e_d=float("nan"), e_r=float("nan"), e_h=float("nan"), e_rh=float("nan"))
        return row, None, None
    s = res.stats
    from taichi_hh.hhd.critical import critical_points
    from taichi_hh.hhd.grid import forget_layouts
    res.critical_points()                        # warm-up
    times, new_times, new_critical = [], [], []
    for _ in range(repeats):                     # each on a fresh result, as users call it
        fresh = call()
        t = time.perf_counter()
        critical = fresh.critical_points()
        times.append(time.perf_counter() - t)
        # the grid seen for the first time: nothing kept from earlier calls
        forget_layouts()
        t = time.perf_counter()
        first = call()
        t1 = time.perf_counter()
        first.critical_points()
        new_times.append(t1 - t)
        new_critical.append(time.perf_counter() - t1)
    critical_seconds = statistics.median(times)
    unfiltered = critical_points(res, filter=False)
    n_out = outside(np, res, critical)
    met = s["energy_ratio"] <= ENERGY_TARGET and n_out == 0 and critical_seconds < seconds
    kinds = [c.kind for c in critical]
    row.update(condition_used=s.get("boundary_condition", ""),
               n_used=int(res.used.sum()), energy_ratio=float(s["energy_ratio"]),
               h_divergence=float(s["h_divergence"]), h_curl=float(s["h_curl"]),
               n_critical=len(critical), n_unfiltered=len(unfiltered), n_outside=n_out,
               targets="met" if met else "MISSED", seconds=seconds,
               critical_seconds=critical_seconds,
               new_grid_seconds=statistics.median(new_times),
               new_grid_critical_seconds=statistics.median(new_critical),
               critical_kinds=" ".join(f"{kinds.count(k)} {k}" for k in CRITICAL_KINDS
                                       if k in kinds),
               flags=" | ".join(list(s.get("flags", []))))
    row.update(energy_shares(np, res.scattered))
    return row, res, critical


def energy_shares(np, scattered) -> dict:
    """|d|^2, |r|^2, |h|^2 and 2 r.h over |v|^2: plain sums over the nodes
    decomposed (a uniform grid: the volume weights of ``energy_ratio`` but near
    the outline); where a ratio above 1 comes from (components that cancel)."""
    ok = np.isfinite(scattered.vectors).all(axis=1)
    v, d, r, h = (a[ok] for a in (scattered.vectors, scattered.curl_free,
                                  scattered.div_free, scattered.harmonic))
    ev = float((v * v).sum()) or 1.0
    return {"e_d": float((d * d).sum()) / ev, "e_r": float((r * r).sum()) / ev,
            "e_h": float((h * h).sum()) / ev, "e_rh": 2.0 * float((r * h).sum()) / ev}


def figure(res, critical, spec, path, colors: int = 256) -> None:
    """The v, d, r, h arrows and the critical points
    (:func:`taichi_hh.app.figures.arrows_figure`), stored as a palette PNG of
    at most ``colors`` colours (octree: the markers' colours kept exactly; a
    quarter of the RGB file's size)."""
    import io
    import tempfile
    from PIL import Image
    from taichi_hh.app.figures import arrows_figure
    scattered = res.scattered
    if hasattr(scattered, "valid_rows"):
        scattered = scattered.valid_rows()
    with tempfile.TemporaryDirectory() as tmp:
        rgb = os.path.join(tmp, "arrows.png")
        arrows_figure(scattered, res.domain, rgb, critical, target=400, units=spec.units)
        with Image.open(rgb) as im:
            buf = io.BytesIO()
            octree = getattr(Image, "Quantize", Image).FASTOCTREE     # Pillow < 9.1: Image.*
            im.convert("RGB").quantize(colors=colors, method=octree).save(
                buf, format="PNG", optimize=True)
    _common.write_bytes_atomic(path, buf.getvalue())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default=",".join(d.name for d in DATASETS),
                    help="comma-separated, of: " + ", ".join(d.name for d in DATASETS))
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--no-extras", action="store_true",
                    help="leave out the extra rows (pivpy's VC7 values, normal-parallel, "
                    "despiked and sparse-masked fields)")
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--repeats", type=int, default=3,
                    help="timed calls of the decomposition and of the critical points (each "
                         "on a fresh result) after a warm-up; their medians (default: 3)")
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    ap.add_argument("--fig-dir", default=os.path.join("docs", "figures"))
    args = ap.parse_args(argv)
    try:
        import pivpy  # noqa: F401
    except ImportError:
        print('real_data: pivpy is not installed (pip install "pivpy[lvpyio]", or the '
              "bench extra): nothing to do")
        return 0
    import numpy as np
    import taichi_hh as thh
    names = _common.parse_list(args.datasets, str)
    unknown = [n for n in names if n not in BY_NAME]
    if unknown:
        ap.error(f"unknown dataset(s) {unknown}; known: {', '.join(BY_NAME)}")
    conditions = _common.parse_list(args.conditions, str)
    rows = []
    for name in names:
        spec = BY_NAME[name]
        if spec.fmt == "vc7":
            try:
                import lvpyio  # noqa: F401
            except ImportError:
                print(f"{name}: lvpyio is not installed (pip install \"pivpy[lvpyio]\"): skipped")
                continue
        x, y, u, v = read(spec)
        variants = [("instrument", u, v, conditions)]
        if not args.no_extras:
            if spec.fmt == "vc7":
                _, _, up, vp = read(spec, values="pivpy")
                variants.append(("pivpy values", up, vp, ("natural",)))
            variants.append(("instrument", u, v, EXTRA_CONDITIONS))
            variants.append(("despiked", *despike(u, v), ("natural",)))
            variants.append(("sparse masked", *mask_sparse(u, v),
                             ("natural",) + EXTRA_CONDITIONS))
        for variant, uu, vv, conds in variants:
            for condition in conds:
                row, res, critical = run_one(thh, np, spec, variant, condition, x, y, uu, vv,
                                            args.repeats)
                rows.append(row)
                print({k: (f"{val:.4g}" if isinstance(val, float) else val)
                       for k, val in row.items()
                       if k not in ("flags", "invalid_rule", "units", "flow", "file",
                                    "critical_kinds")},
                      flush=True)
                if res is not None and variant == "instrument" and condition == "default" \
                        and not args.no_figures:
                    os.makedirs(args.fig_dir, exist_ok=True)
                    figure(res, critical, spec, os.path.join(args.fig_dir, f"real_{name}.png"))
    if not rows:
        print("real_data: no dataset ran")
        return 0
    cols = ["dataset", "variant", "condition", "condition_used", "grid", "n_valid", "n_invalid", "n_used",
            "energy_ratio", "h_divergence", "h_curl", "n_critical", "n_unfiltered", "n_outside",
            "targets", "seconds", "critical_seconds", "new_grid_seconds",
            "new_grid_critical_seconds", "e_d", "e_r", "e_h", "e_rh", "flags"]

    def cell(r, k):
        val = r[k]
        if k == "flags":
            return str(len([f for f in str(val).split(" | ") if f])) if val else "0"
        return f"{val:.3g}" if isinstance(val, float) else str(val)
    print(_common.format_table(cols, [[cell(r, k) for k in cols] for r in rows],
                               "llll" + "r" * 19))
    print(f"targets: energy ratio <= {ENERGY_TARGET:g}, no critical point outside the data, "
          "critical points in less time than the decomposition (both on a grid decomposed "
          "before, as a run's frames are; new_grid_*: the same on a grid seen for the first "
          "time, nothing kept); flags: their count (text in the CSV)")
    for r in rows:
        if r["critical_kinds"]:
            print(f"  {r['dataset']} {r['variant']} {r['condition']}: {r['critical_kinds']}")
    for r in rows:
        if r["flags"]:
            print(f"  {r['dataset']} {r['variant']} {r['condition']}: {r['flags']}")
    _common.write_rows(args.out_dir, "real_data.csv", rows, FIELDS)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
