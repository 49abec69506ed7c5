"""Which part of the several-column BiCGSTAB step faults on CUDA (issue 31).

    TAICHI_HH_ARCH=cuda python benchmarks/bicg_columns_probe.py [--arch cuda] [--n 5000]

Taichi 1.7.4's CUDA backend stops BiCGSTAB's second half-step on two
columns (``bicg_full``) with ``CUDA_ERROR_MISALIGNED_ADDRESS``; ``dot2``,
which folds the same 2 x 2 matrix of partials per lane and returns two
vectors, runs (docs/arch.md, "The several-column fault").  Each variant
below is one kernel, run in a process of its own (a fault ends the CUDA
context) with ``CUDA_LAUNCH_BLOCKING=1`` on the arch asked and on the CPU
with the GPU's schedule (``TAICHI_HH_GPU_SCHEDULE=1``: the same lanes), its
results compared:

* ``bicg_step``: the solver's own kernels as its iteration calls them
  (``bicg_full``, then ``bicg_direction``: with the sums in lanes the new
  direction is a kernel of its own);
* ``fused``: the fold and the direction's loop in one kernel, as
  ``bicg_full`` was: on lavapipe it gave p 1e13 off and z = 0 (``wrong``);
* ``return1`` .. ``return4``: the fold of that step's entries alone,
  returning 1 to 4 vectors of the two columns;
* ``ndarray4``: the fold, its four vectors written to an ndarray instead of
  returned;
* ``args7_return4``: ``return4`` with the seven per-column vector arguments
  and the real tolerance that ``bicg_full`` takes before its arrays.

Prints a table (``ok``, ``wrong``: ran with results off the CPU's, ``fault``:
the process failed, its last line shown) and writes
``outputs/benchmarks/bicg_columns_probe.csv``.  On lavapipe every variant
but ``fused`` is ``ok``.  If ``bicg_step`` runs on CUDA, the joint solve
can be tried there with ``TAICHI_HH_JOINT_COLUMNS=1`` (the test suites of
the solvers and of the Neumann split, :func:`taichi_hh.linalg.krylov.
bicgstab_columns`).
"""

import argparse
import os
import subprocess
import sys
import tempfile

import _common

_common.add_repo_to_path()

VARIANTS = ("bicg_step", "fused", "return1", "return2", "return3", "return4", "ndarray4",
            "args7_return4")
COLS = 2


def _data(n: int):
    import numpy as np
    rng = np.random.default_rng(7)
    return {name: rng.standard_normal((n, COLS) if COLS > 1 else n) for name in
            ("x", "r", "r_hat", "p", "v", "t", "z")} | {"dinv": 1.0 + rng.random(n)}


def _vectors(data: dict):
    """The columns as Taichi vector ndarrays (what the solver passes)."""
    import taichi as ti
    out = {}
    for name, a in data.items():
        if a.ndim == 2:
            nd = ti.Vector.ndarray(COLS, ti.f64, len(a))
        else:
            nd = ti.ndarray(ti.f64, len(a))
        nd.from_numpy(a)
        out[name] = nd
    return out


def _fold_kernels():
    """The probe's own kernels: the fold of bicg_full's entries, its results
    returned (1-4), written to an ndarray, or after seven vector arguments."""
    import taichi as ti
    from taichi_hh.linalg import lanes
    scal = ti.types.vector(COLS, ti.f64)
    vec = ti.types.ndarray(dtype=scal, ndim=1)

    @ti.func
    def entry(i, ts, tt, x: ti.template(), r: ti.template(), r_hat: ti.template(),
              t: ti.template(), z: ti.template()):
        omega = ti.select(tt > 0.0, ts / tt, 0.0)
        x[i] += omega * z[i]
        ri = r[i] - omega * t[i]
        r[i] = ri
        return lanes.pack2(COLS, ri * ri, r_hat[i] * ri)

    @ti.func
    def fold(ts, tt, x: ti.template(), r: ti.template(), r_hat: ti.template(),
             t: ti.template(), z: ti.template(), n, part: ti.template()):
        total = lanes.fold_entries(n, entry, (ts, tt, x, r, r_hat, t, z), 2, COLS, lanes.ADD,
                                   True, False, part)
        return lanes.unpack(COLS, total, 0), lanes.unpack(COLS, total, 1)

    @ti.kernel
    def return1(ts: scal, tt: scal, x: vec, r: vec, r_hat: vec, t: vec, z: vec, n: ti.i32,
                part: ti.types.ndarray()) -> scal:
        rr, rho = fold(ts, tt, x, r, r_hat, t, z, n, part)
        return rr + 0.0 * rho

    @ti.kernel
    def return2(ts: scal, tt: scal, x: vec, r: vec, r_hat: vec, t: vec, z: vec, n: ti.i32,
                part: ti.types.ndarray()) -> (scal, scal):
        rr, rho = fold(ts, tt, x, r, r_hat, t, z, n, part)
        return rr, rho

    @ti.kernel
    def return3(ts: scal, tt: scal, x: vec, r: vec, r_hat: vec, t: vec, z: vec, n: ti.i32,
                part: ti.types.ndarray()) -> (scal, scal, scal):
        rr, rho = fold(ts, tt, x, r, r_hat, t, z, n, part)
        return rr, rho, rr - rho

    @ti.kernel
    def return4(ts: scal, tt: scal, x: vec, r: vec, r_hat: vec, t: vec, z: vec, n: ti.i32,
                part: ti.types.ndarray()) -> (scal, scal, scal, scal):
        rr, rho = fold(ts, tt, x, r, r_hat, t, z, n, part)
        return rr, rho, rr - rho, ti.select(rho > 0.0, 1.0, 0.0)

    @ti.kernel
    def ndarray4(ts: scal, tt: scal, x: vec, r: vec, r_hat: vec, t: vec, z: vec, n: ti.i32,
                 part: ti.types.ndarray(), out: vec):
        rr, rho = fold(ts, tt, x, r, r_hat, t, z, n, part)
        out[0] = rr
        out[1] = rho
        out[2] = rr - rho
        out[3] = ti.select(rho > 0.0, 1.0, 0.0)

    @ti.kernel
    def args7_return4(ts: scal, tt: scal, ss: scal, alpha: scal, rho0: scal, rhat2: scal,
                      active: scal, x: vec, r: vec, r_hat: vec, t: vec, z: vec, btol: ti.f64,
                      n: ti.i32, part: ti.types.ndarray()) -> (scal, scal, scal, scal):
        rr, rho = fold(ts, tt, x, r, r_hat, t, z, n, part)
        flag = ti.select(ti.abs(rho) <= btol * ti.sqrt(rhat2) * ti.sqrt(rr), 1.0, 0.0)
        return rr + 0.0 * (ss + alpha + rho0), rho, active * flag, rr - rho

    return dict(return1=return1, return2=return2, return3=return3, return4=return4,
                ndarray4=ndarray4, args7_return4=args7_return4)


def _fused_kernel():
    """bicg_full as it was: the fold, then the new direction's loop reading
    beta from ``beta_slot``, in one kernel."""
    import taichi as ti
    from taichi_hh.linalg import lanes
    from taichi_hh.linalg.krylov_kernels import bicg_flags, bicg_omega
    scal = ti.types.vector(COLS, ti.f64)
    vec = ti.types.ndarray(dtype=scal, ndim=1)

    @ti.func
    def entry(i, ts, tt, active, x: ti.template(), r: ti.template(), r_hat: ti.template(),
              t: ti.template(), z: ti.template()):
        omega = bicg_omega(ts, tt, active)
        x[i] += omega * z[i]
        ri = r[i] - omega * t[i]
        r[i] = ri
        return lanes.pack2(COLS, ri * ri, r_hat[i] * ri)

    @ti.kernel
    def fused(ts: scal, tt: scal, ss: scal, alpha: scal, rho: scal, rhat2: scal,
              active: scal, x: vec, r: vec, r_hat: vec, p: vec, v: vec, t: vec, z: vec,
              dinv: ti.types.ndarray(dtype=ti.f64, ndim=1), btol: ti.f64, n: ti.i32,
              beta_slot: vec, part: ti.types.ndarray()) -> (scal, scal, scal, scal):
        total = lanes.fold_entries(n, entry, (ts, tt, active, x, r, r_hat, t, z), 2, COLS,
                                   lanes.ADD, True, False, part)
        rr = lanes.unpack(COLS, total, 0)
        rho_new = lanes.unpack(COLS, total, 1)
        omega_flag, rho_flag = bicg_flags(ts, tt, ss, rr, rho_new, rhat2, active, btol)
        go = active * (1.0 - omega_flag) * (1.0 - rho_flag)
        beta_slot[0] = ti.select(go > 0.0, (rho_new / rho) * (alpha / bicg_omega(ts, tt, active)),
                                 0.0)
        for i in range(n):
            pi = r[i] + beta_slot[0] * (p[i] - bicg_omega(ts, tt, active) * v[i])
            p[i] = pi
            z[i] = dinv[i] * pi
        omega_end, rho_end = bicg_flags(ts, tt, ss, rr, rho_new, rhat2, active, btol)
        return rr, rho_new, omega_end, rho_end
    return fused


def run_variant(variant: str, arch: str, n: int, out_path: str) -> None:
    """One variant on ``arch``; its results saved to ``out_path`` (.npz)."""
    import numpy as np
    import taichi as ti
    import taichi_hh as thh
    from taichi_hh.linalg import lanes
    from taichi_hh.linalg.krylov_kernels import solver_kernels
    thh.init(arch=arch)
    data = _data(n)
    nd = _vectors(data)
    ts, tt = np.array([0.7, 1.3]), np.array([2.0, 0.9])
    part = lanes.partials(2, COLS)
    scalars = (ts, tt, np.array([3.0, 2.0]), np.array([0.4, 0.6]), np.array([1.5, -0.8]),
               np.array([4.0, 5.0]), np.array([1.0, 1.0]))
    arrays = tuple(nd[k] for k in ("x", "r", "r_hat", "p", "v", "t", "z", "dinv"))
    beta = ti.Vector.ndarray(COLS, ti.f64, 1)
    if variant == "bicg_step":
        k = solver_kernels(n, cols=COLS)
        res = k.bicg_full(*scalars, *arrays, 1e-14, n, beta)
        if k.bicg_direction is not None:
            k.bicg_direction(ts, tt, scalars[-1], nd["r"], nd["p"], nd["v"], nd["z"],
                             nd["dinv"], n, beta)
    elif variant == "fused":
        res = _fused_kernel()(*scalars, *arrays, 1e-14, n, beta, part)
    else:
        kernel = _fold_kernels()[variant]
        args = (nd["x"], nd["r"], nd["r_hat"], nd["t"], nd["z"])
        if variant == "ndarray4":
            out = ti.Vector.ndarray(COLS, ti.f64, 4)
            kernel(ts, tt, *args, n, part, out)
            res = tuple(out.to_numpy())
        elif variant == "args7_return4":
            res = kernel(ts, tt, np.array([3.0, 2.0]), np.array([0.4, 0.6]),
                         np.array([1.5, -0.8]), np.array([4.0, 5.0]), np.array([1.0, 1.0]),
                         *args, 1e-14, n, part)
        else:
            res = kernel(ts, tt, *args, n, part)
    ti.sync()
    res = res if isinstance(res, (tuple, list)) else (res,)
    arrays = {f"result{i}": np.asarray(a, dtype=np.float64) for i, a in enumerate(res)}
    arrays.update({name: nd[name].to_numpy() for name in ("x", "r", "p", "z")})
    np.savez(out_path, **arrays)


def _spawn(variant: str, arch: str, n: int, path: str) -> tuple:
    env = dict(os.environ, CUDA_LAUNCH_BLOCKING="1", TAICHI_HH_GPU_SCHEDULE="1")
    env.pop("TAICHI_HH_ARCH", None)
    proc = subprocess.run([sys.executable, os.path.abspath(__file__), "--run", variant,
                           "--arch", arch, "--n", str(n), "--out", path],
                          env=env, capture_output=True, text=True, timeout=600)
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    return proc.returncode, (lines[-1] if lines else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default=os.environ.get("TAICHI_HH_ARCH", "cuda"))
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out-dir", default=os.path.join("outputs", "benchmarks"))
    ap.add_argument("--run", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.run:
        run_variant(args.run, args.arch, args.n, args.out)
        return 0
    import numpy as np
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for variant in args.variants.split(","):
            paths = {a: os.path.join(tmp, f"{variant}_{a}.npz") for a in ("cpu", args.arch)}
            ref_rc, ref_msg = _spawn(variant, "cpu", args.n, paths["cpu"])
            rc, msg = _spawn(variant, args.arch, args.n, paths[args.arch])
            diff = float("nan")
            if ref_rc != 0:
                status = "reference failed"
                msg = ref_msg
            elif rc != 0:
                status = "fault"
            else:
                a, b = np.load(paths["cpu"]), np.load(paths[args.arch])
                diff = max(float(np.abs(a[k] - b[k]).max() / max(np.abs(a[k]).max(), 1e-300))
                           for k in a.files)
                status = "ok" if diff < 1e-12 else "wrong"
                msg = ""
            rows.append({"variant": variant, "arch": args.arch, "status": status,
                         "max_rel_diff": diff, "message": msg[-160:]})
            print(f"{variant:15s} {status:8s} {diff:.2e} {msg[-160:]}", flush=True)
    print(_common.format_table(["variant", "status", "max rel diff", "last line"],
                               [[r["variant"], r["status"], f"{r['max_rel_diff']:.1e}",
                                 r["message"][-70:]] for r in rows], align="llrl"))
    path = _common.write_rows(args.out_dir, "bicg_columns_probe.csv", rows)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
