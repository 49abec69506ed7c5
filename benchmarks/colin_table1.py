"""Colin, Egli & Lin 2006, Table 1, redone: their five examples projected five
times with their formulation (``method="colin2006"``) and with our default,
side by side with the published numbers.

    python benchmarks/colin_table1.py [--passes 5] [--out-dir outputs/benchmarks]

Setups: :mod:`taichi_hh.validation.colin_examples` (unit square; example 1: 45 x 45
points, support h = 1/9; examples 2-5: 19 x 19 points, h = 1/5).  colin2006
uses the published support (``support_ratio = h sqrt(N)``); the default its own
(Wendland C2, 2.5 spacings).

Measures (max |div| and sum of squared div over the data points, per pass):

``own``         each method's own divergence, the one it projects against:
                Colin's Eq. 33 (DGAF over data and wall particles at rest) for
                colin2006, as in their Table 1; the quadratic (MLS) divergence
                over the data points for the default.
``colin_eq33``  Colin's Eq. 33 applied to both results.  It counts the wall
                particles' zero velocity, so a field that crosses the walls
                (example 5's rotation, exactly divergence-free) has a large
                value under it: unfair to any projection that keeps the normal
                flux, shown for completeness.
``quadratic``   our quadratic divergence over the data points applied to both
                results: exact on linear fields, so 0 on example 5's input.

Reproduction: example 1's initial measures
come out within 4% (5.12 and 1276 against 5.32 and 1250.48).  Examples 2-4
come out within a factor of about 2 and example 5 not at all: the text's setup
gives max |div| 0.45 and sum 7.9 for the rigid rotation where Table 1 has 2.81
and 82.61.  Neither 18 x 18 or 20 x 20 lattices, supports of 1/9 or 1/10, nor
other spacings (tried 1/18 to 1/45) reproduce those numbers, so the published
setup of examples 2-5 differs from the text in some unstated way.

Writes ``colin_table1.csv`` (one row per example, method, measure and value:
init, pass_1 ... pass_k) and ``colin_table1.png`` (max |div| per pass) to
``--out-dir``.
"""
import argparse
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import REPO_ROOT, add_repo_to_path, format_table, save_figure_atomic, \
    write_csv_atomic  # noqa: E402

add_repo_to_path()


def run(passes: int):
    import numpy as np
    import taichi_hh as thh
    from taichi_hh.validation.colin_examples import TABLE1, colin_divergence, example
    from taichi_hh.sph.pointset import PointSet
    from taichi_hh.hhd.project import project

    dom = thh.Box((0.0, 0.0), (1.0, 1.0))
    rows = []
    for k in sorted(TABLE1):
        pts, vec, h = example(k)
        quad = PointSet(pts, support=2.5 / math.sqrt(len(pts)), area=1.0)
        for method, kw in (("published", None),
                           ("colin2006", {"support_ratio": h * math.sqrt(len(pts))}),
                           ("default", {})):
            if kw is None:
                for value in ("max", "sum_sq"):
                    rows.append({"example": k, "method": method, "measure": "own",
                                 "value": value, "values": TABLE1[k][value], "seconds": ""})
                continue
            t = time.perf_counter()
            res = project(pts, vec, dom, iterations=passes, method=method, history=True, **kw)
            seconds = time.perf_counter() - t
            fields = res.history
            own = list(zip(res.max_divergence, res.sum_sq_divergence))
            iters = res.stats["iterations"]
            eq33 = [colin_divergence(pts, f, h) for f in fields]
            qd = [quad.divergence(f, "quadratic") for f in fields]
            for measure, series in (("own", None), ("colin_eq33", eq33), ("quadratic", qd)):
                if series is None:
                    mx = [o[0] for o in own]
                    ss = [o[1] for o in own]
                else:
                    mx = [float(np.abs(d).max()) for d in series]
                    ss = [float((d ** 2).sum()) for d in series]
                for value, vals in (("max", mx), ("sum_sq", ss)):
                    rows.append({"example": k, "method": method, "measure": measure,
                                 "value": value, "values": vals,
                                 "seconds": f"{seconds:.2f}" if measure == "own" else "",
                                 "solver_iterations": " ".join(map(str, iters))})
            change = float(np.abs(fields[1] - vec).max() / np.abs(vec).max())
            for r in rows[-6:]:
                r["max_change_pass1"] = change
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--passes", type=int, default=5)
    ap.add_argument("--out-dir", default=str(REPO_ROOT / "outputs" / "benchmarks"))
    args = ap.parse_args(argv)
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
    import taichi_hh as thh
    thh.init(arch="cpu", precision="f64")
    rows = run(args.passes)
    k = args.passes

    def fmt(x):
        return f"{x:.3g}" if abs(x) >= 1e-3 or x == 0 else f"{x:.1e}"

    header = ["ex", "method", "measure", "value", "init"] + [str(i) for i in range(1, k + 1)]
    table = [[str(r["example"]), r["method"], r["measure"], r["value"]]
             + [fmt(v) for v in r["values"][: k + 1]] for r in rows]
    print("Colin et al. 2006 Table 1: max |div| and sum of squared div, input then after "
          "each projection pass")
    print(format_table(header, table, align="llll" + "r" * (k + 1)))
    for r in rows:
        if r["value"] == "max" and r["measure"] == "own" and r["method"] != "published":
            print(f"example {r['example']} {r['method']}: solver iterations per pass "
                  f"{r['solver_iterations']}, {r['seconds']} s; largest change of the field in "
                  f"pass 1 {r['max_change_pass1']:.3g} of max |v|")

    fieldnames = ["example", "method", "measure", "value", "init"] + \
        [f"pass_{i}" for i in range(1, k + 1)] + ["solver_iterations", "seconds",
                                                  "max_change_pass1"]
    out_rows = []
    for r in rows:
        d = {key: r.get(key, "") for key in ("example", "method", "measure", "value",
                                              "solver_iterations", "seconds",
                                              "max_change_pass1")}
        vals = list(r["values"])
        d["init"] = vals[0]
        for i in range(1, k + 1):
            d[f"pass_{i}"] = vals[i] if i < len(vals) else ""
        out_rows.append(d)
    out = os.path.join(args.out_dir, "colin_table1.csv")
    write_csv_atomic(out, out_rows, fieldnames)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    exs = sorted({r["example"] for r in rows})
    fig, axes = plt.subplots(1, len(exs), figsize=(3.2 * len(exs), 3.4), sharey=True)
    styles = {("published", "own"): ("k", "o-", "Colin (published)"),
              ("colin2006", "own"): ("C0", "s--", "colin2006 (ours), Eq. 33"),
              ("default", "own"): ("C3", "^-", "default, own (quadratic) div"),
              ("default", "colin_eq33"): ("C3", "v:", "default, Colin's Eq. 33")}
    floor = 1e-9
    for ax, ex in zip(axes, exs):
        for r in rows:
            key = (r["method"], r["measure"])
            if r["example"] != ex or r["value"] != "max" or key not in styles:
                continue
            colour, style, label = styles[key]
            vals = [max(v, floor) for v in r["values"][: k + 1]]
            ax.semilogy(range(len(vals)), vals, style, color=colour, label=label, ms=4)
        ax.set_title(f"example {ex}", fontsize=10)
        ax.set_xlabel("pass")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(f"max |div| (clipped at {floor:g})")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("Colin et al. 2006 Table 1: max |div| per projection pass", fontsize=11)
    fig.tight_layout()
    png = os.path.join(args.out_dir, "colin_table1.png")
    save_figure_atomic(fig, png, dpi=110)
    print(f"wrote {out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
