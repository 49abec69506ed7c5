"""Sweeps of the decomposition, the projection and the Rayleigh-Taylor flow,
one configuration ("task") at a time, each timed and scored against an exact
answer, in a pool of worker processes.

A task is a dict: ``task`` (``hhd`` | ``project`` | ``rt``), the analytic field
(:mod:`~taichi_hh.validation.fields`) and sampling
(:func:`~taichi_hh.validation.layouts.sample`), ``method`` and option
``overrides`` (or FlowParams ``params``), ``n``, ``seed``, ``repeats``,
``precision``; its result is one CSV row (:data:`CSV_FIELDS`).  A task that
raises is a row with ``status=error`` and the exception (``error``: class,
``reason``: SolverError.reason or BlowUp.cause, ``message``), never a lost row:
the speed-accuracy sweep and the stability map chart failures beside
successes.  Times come from the library's own clocks: ``res.stats["seconds"]``
of :func:`~taichi_hh.decompose` and :attr:`TwoPhaseFlow.timings`.
"""
from __future__ import annotations

import math
import multiprocessing as mp
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from ..errors import AccuracyWarning
from ..hhd.decompose import METHODS, decompose
from ..hhd.project import project
from . import fields
from .layouts import sample
from .measures import as_float, median, relative_errors
from .rt import SingleMode

CSV_FIELDS = ["group", "label", "task", "field", "sampling", "method", "overrides", "precision",
              "n_points", "repeats", "status", "error", "reason", "message",
              "setup_s", "solve_s", "components_s", "total_s", "wall_s",
              "iterations_phi", "iterations_psi", "residual_phi", "residual_psi",
              "mean_neighbours", "err", "err_d", "err_r", "err_h", "err_d_max", "err_r_max",
              "err_h_max", "finite", "max_abs_ratio", "flags",
              "s_theory", "s_measured", "relative_error", "steps", "t_end", "max_speed",
              "flow_solve_s", "flow_neighbours_s", "flow_operators_s", "flow_iterations"]

#: Petronetto et al. 2010, Table 9: (N, kappa) -> (seconds of the whole
#: decomposition, iterations curl-free, iterations div-free); REFERENCE.md.
PETRONETTO_TABLE9 = {
    (1640, 1e-8): (4.31, 1234, 629), (1640, 1e-2): (2.23, 476, 477),
    (5000, 1e-8): (37.78, 2609, 636), (5000, 1e-2): (9.53, 407, 411),
    (18221, 1e-8): (130.39, 683, 582), (18221, 1e-2): (78.95, 393, 391),
}

GRADIENTS = ("basic", "difference", "colin_difference", "symmetric", "corrected")
LAPLACIANS = ("basic", "colin_difference", "brookshaw")


def variant(name: str) -> tuple[str, dict]:
    """(method bundle, option overrides) of a variant label."""
    if name in ("default", "petronetto2010", "colin2006"):
        return name, {}
    kind, _, val = name.partition(":")
    if kind == "grad":
        return "default", {"divergence": val, "gradient": val, "neumann_gradient": val}
    if kind == "lap":
        return "default", {"laplacian": val}
    raise ValueError(f"unknown variant {name!r}")


#: Configurations this worker process has compiled (the first run of a new one
#: is an untimed warm-up).
_SEEN: set = set()


def _worker_init(precision: str, threads: int) -> None:
    from .. import runtime
    runtime.init(arch="cpu", precision=precision, threads=threads, verbose=False)


def _error_fields(exc: BaseException) -> dict:
    return {"status": "error", "error": type(exc).__name__,
            "reason": getattr(exc, "reason", "") or getattr(exc, "cause", "") or "",
            "message": " ".join(str(exc).split())[:300]}


def _corrupt(task: dict, v: np.ndarray) -> np.ndarray:
    """``task["corrupt"] == "nan"``: one NaN in the input vectors (to provoke an
    InputError); ``"duplicate"`` (handled by the callers): a repeated point."""
    if task.get("corrupt") == "nan":
        v = v.copy()
        v[len(v) // 2, 0] = np.nan
    return v


def run_hhd(task: dict) -> dict:
    """One decomposition configuration: warm-up when new to this worker, then
    ``repeats`` timed runs.  Never raises: an exception becomes the row's status."""
    F = fields.get(task["field"])
    pts = sample(F.domain, task["n"], task.get("sampling", "poisson"), task.get("seed", 1))
    ex = F.evaluate(pts)
    vecs = _corrupt(task, ex.v)
    if task.get("corrupt") == "duplicate":
        pts = np.vstack([pts, pts[:1]])
        vecs = np.vstack([vecs, vecs[:1]])
    vmean = float(np.linalg.norm(ex.v, axis=1).mean())
    opts = dict(task.get("overrides", {}))
    if "boundary_condition" not in opts and METHODS[task["method"]].boundary_condition == "auto":
        # the field's parts are exact under its own condition (the sweep measures
        # errors against them), not under whatever the default would choose
        opts["boundary_condition"] = F.conditions[0]
    row = {"n_points": len(pts)}
    sig = (task["method"], tuple(sorted((k, v) for k, v in opts.items()
                                        if k not in ("tol", "kappa", "max_iterations"))))
    times = {"setup": [], "solve": [], "components": [], "total": [], "wall": []}
    res = None
    import warnings
    try:
        # an AccuracyWarning is recorded from stats["flags"], not printed
        warnings.simplefilter("ignore", AccuracyWarning)
        if sig not in _SEEN:          # compile; a failure here is the row's answer
            _SEEN.add(sig)
            decompose(pts, vecs, F.domain, method=task["method"], **opts)
        for _ in range(task.get("repeats", 1)):
            t0 = time.perf_counter()
            res = decompose(pts, vecs, F.domain, method=task["method"], **opts)
            wall = time.perf_counter() - t0
            s = res.stats["seconds"]
            times["setup"].append(s["setup"] + s["divergence"] + s.get("assemble", 0.0))
            times["solve"].append(s.get("preconditioner", 0.0) + s.get("solve", 0.0)
                                  + s.get("natural", 0.0))
            times["components"].append(s.get("components", 0.0))
            times["total"].append(s["total"])
            times["wall"].append(wall)
    except Exception as exc:          # noqa: BLE001 - recorded, not hidden
        row.update(_error_fields(exc))
        return row
    st = res.stats
    comps = (res.curl_free, res.div_free, res.harmonic, res.phi, res.psi)
    finite = all(np.isfinite(a).all() for a in comps)
    vmax = float(np.abs(ex.v).max())
    big = max(float(np.nanmax(np.abs(a))) if np.isfinite(a).any() else math.inf
              for a in comps[:3])
    row.update({"status": "ok", "finite": finite, "max_abs_ratio": big / vmax,
                "iterations_phi": st.get("iterations_phi"),
                "iterations_psi": st.get("iterations_psi"),
                "residual_phi": st.get("residual_phi"), "residual_psi": st.get("residual_psi"),
                "mean_neighbours": st.get("mean_neighbours"),
                "flags": "; ".join(st.get("flags", [])),
                "repeats": len(times["total"])})
    for k, v in times.items():
        row[f"{k}_s"] = median(v)
    errs = {}
    for name, got, exact in (("d", res.curl_free, ex.d), ("r", res.div_free, ex.r),
                             ("h", res.harmonic, ex.h)):
        errs[name], row[f"err_{name}_max"] = relative_errors(got, exact, vmean)
        row[f"err_{name}"] = errs[name]
    row["err"] = max(errs.values())
    return row


def run_project(task: dict) -> dict:
    """One null-divergence projection: error of the result against the exact
    divergence-free part r + h (relative to mean |v|) and the divergence left."""
    F = fields.get(task["field"])
    pts = sample(F.domain, task["n"], task.get("sampling", "poisson"), task.get("seed", 1))
    ex = F.evaluate(pts)
    vmean = float(np.linalg.norm(ex.v, axis=1).mean())
    row = {"n_points": len(pts)}
    opts = dict(task.get("overrides", {}))
    vecs = _corrupt(task, ex.v)
    try:
        t0 = time.perf_counter()
        out = project(pts, vecs, F.domain, iterations=task.get("iterations", 1),
                      method=task["method"], **opts)
        row["total_s"] = row["wall_s"] = time.perf_counter() - t0
    except Exception as exc:          # noqa: BLE001
        row.update(_error_fields(exc))
        return row
    w = np.asarray(out.vectors, dtype=np.float64)
    row["finite"] = bool(np.isfinite(w).all() and np.isfinite(out.max_divergence).all())
    row["max_abs_ratio"] = float(np.nanmax(np.abs(w)) / np.abs(ex.v).max()) if row["finite"] \
        else math.inf
    row["err"], row["err_r_max"] = relative_errors(w, ex.r + ex.h, vmean)
    row["err_r"] = row["err"]
    row["status"] = "ok"
    row["message"] = (f"max|div| {out.max_divergence[0]:.3g} -> {out.max_divergence[-1]:.3g}")
    its = out.stats.get("iterations")
    row["iterations_phi"] = int(np.sum(its)) if its is not None else ""
    return row


def run_rt(task: dict) -> dict:
    """Rayleigh-Taylor growth of one mode (:class:`~taichi_hh.validation.rt.SingleMode`)
    with extra FlowParams (``task["params"]``, e.g. solver_tol, cfl), recording
    every step's max speed and solver iterations."""
    record = {"max_speed": 0.0, "iterations": 0}

    def on_step(info):
        ms = info.get("max_speed", 0.0)
        record["max_speed"] = ms if not np.isfinite(ms) else max(record["max_speed"], ms)
        record["iterations"] += info.get("iterations", 0)

    row = {}
    case = None
    try:
        case = SingleMode(task.get("ratio", 2.0), task["n"],
                          viscosity=task.get("viscosity", 2e-3),
                          shifting=task.get("shifting", 2.0), params=task.get("params", {}))
        out, (ts, amps) = case.run(task.get("max_time", 6.0), on_step)
    except Exception as exc:          # noqa: BLE001
        row.update(_error_fields(exc))
        if case is not None:
            flow = case.flow
            row.update({"n_points": flow.n_fluid, "steps": flow.step_count, "t_end": flow.time})
        return row
    tm = case.flow.timings
    finite = bool(np.isfinite(amps).all() and np.isfinite(out["s_measured"])
                  and np.isfinite(record["max_speed"]))
    row.update({"status": "ok", "n_points": out["particles"], "s_theory": out["s_theory"],
                "s_measured": out["s_measured"], "relative_error": out["relative_error"],
                "err": abs(out["relative_error"]), "steps": out["steps"], "t_end": out["t_end"],
                "wall_s": out["wall_seconds"], "total_s": out["wall_seconds"],
                "max_speed": record["max_speed"], "finite": finite,
                "max_abs_ratio": float(np.nanmax(np.abs(amps)) / abs(amps[0])),
                "flow_solve_s": tm["solve"], "flow_neighbours_s": tm["neighbours"],
                "flow_operators_s": tm["operators"], "flow_iterations": record["iterations"]})
    return row


def run_task(task: dict) -> dict:
    """Dispatch one task (``task["task"]`` in hhd | project | rt) and return its
    CSV row (the task's descriptive fields plus the measurements)."""
    base = {"group": task.get("group", ""), "label": task.get("label", ""),
            "task": task["task"], "field": task.get("field", ""),
            "sampling": task.get("sampling", ""), "method": task.get("method", ""),
            "overrides": ";".join(f"{k}={v}" for k, v in
                                  {**task.get("overrides", {}), **task.get("params", {})}.items()),
            "precision": task.get("precision", "f64"), "repeats": task.get("repeats", 1)}
    try:
        fn = {"hhd": run_hhd, "project": run_project, "rt": run_rt}[task["task"]]
        row = fn(task)
    except Exception as exc:          # a bug in the sweep, not in a method
        row = _error_fields(exc)
        row["message"] = "benchmark script: " + traceback.format_exc(limit=3)[-300:]
    for k in ("status", "error", "reason", "message"):
        row.setdefault(k, "")
    return {**base, **row, **{k: v for k, v in task.get("extra", {}).items()}}


def run_pool(tasks: list[dict], workers: int = 2, threads: int = 1,
             on_done=None) -> list[dict]:
    """Run tasks in process pools (spawn), one pool per precision (Taichi's
    precision is process-wide), each worker with ``threads`` Taichi CPU
    threads; ``on_done(count)`` after each finished task.  Rows in task order;
    a worker that died gives a row with ``status=crash``."""
    rows: list = [None] * len(tasks)
    done = 0
    ctx = mp.get_context("spawn")
    for precision in sorted({t.get("precision", "f64") for t in tasks}, reverse=True):
        idx = [i for i, t in enumerate(tasks) if t.get("precision", "f64") == precision]
        # longest first keeps both workers busy to the end
        idx.sort(key=lambda i: -tasks[i].get("cost", 1.0))
        with ProcessPoolExecutor(max_workers=max(1, min(workers, len(idx))), mp_context=ctx,
                                 initializer=_worker_init,
                                 initargs=(precision, threads)) as pool:
            futures = {pool.submit(run_task, tasks[i]): i for i in idx}
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    rows[i] = fut.result()
                except Exception as exc:     # the worker died (a crash in Taichi)
                    rows[i] = {**{k: tasks[i].get(k, "") for k in ("group", "label", "task")},
                               **_error_fields(exc), "status": "crash"}
                done += 1
                if on_done is not None:
                    on_done(done)
    return rows


def read_rows(path) -> list[dict]:
    """Rows of a CSV of :data:`CSV_FIELDS` (and extra columns), numbers
    converted back."""
    import csv
    rows = []
    with open(path) as fh:
        for r in csv.DictReader(fh):
            for k, v in r.items():
                if k in ("n_points", "iterations_phi", "iterations_psi", "repeats", "steps",
                         "flow_iterations") and v not in ("", None):
                    r[k] = int(float(v))
                elif k == "finite":
                    r[k] = v == "True"
                elif k.endswith("_s") or (k.startswith("err") and k != "error") or k in (
                        "residual_phi", "residual_psi", "mean_neighbours", "max_abs_ratio",
                        "s_theory", "s_measured", "relative_error", "t_end", "max_speed"):
                    r[k] = as_float(v)
            rows.append(r)
    return rows


