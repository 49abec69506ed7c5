"""The scene loop: outputs at the right times, Ctrl-C and blow-up stops, resuming
to the same diagnostics, checkpoints, the diagnostics CSV, progress, options.

A toy "scene" (Euler steps of y' = -y) stands in for the physics."""
import argparse
import io
import math
import os
import signal

import numpy as np
import pytest

from taichi_hh import runtime
from taichi_hh.errors import SolverError
from taichi_hh.errors import BlowUp
from taichi_hh.app.runloop import (Checkpoint, DiagnosticsWriter, ProgressBar,
                               add_common_arguments, check_finite, check_inside, run)

COLUMNS = ["time", "step", "dt", "y", "error"]


def scene(out, *, t_end=1.0, dt=0.01, interval=0.1, resume=False, fail_at=None,
          clip=False, stream=None):
    """A scene script in miniature.  fail_at: (step, action) with action one of
    "raise-ki" (KeyboardInterrupt inside a step), "sigint" (a real SIGINT during
    a step), "blowup", "solver"."""
    ckpt = os.path.join(out, "checkpoint.npz")
    if resume:
        st = Checkpoint.load(ckpt)
    else:
        st = {"t": 0.0, "step": 0, "y": np.array([1.0, 2.0])}
    state = {"t": st["t"], "step": st["step"], "y": np.array(st["y"])}
    diag = DiagnosticsWriter(os.path.join(out, "diagnostics.csv"), COLUMNS,
                             resume_time=state["t"] if resume else None)
    outputs = []

    def step_fn(t_stop=None):
        h = dt if t_stop is None else min(dt, t_stop - state["t"])
        if fail_at and state["step"] + 1 == fail_at[0]:
            action = fail_at[1]
            if action == "raise-ki":
                raise KeyboardInterrupt
            if action == "sigint":
                signal.raise_signal(signal.SIGINT)   # handled when the step is done
            if action == "blowup":
                raise BlowUp("non-finite values in velocity: 3 entries", cause="non-finite")
            if action == "solver":
                raise SolverError("BiCGSTAB broke down", reason="breakdown", iteration=3,
                                  residual=1.0)
        state["y"] = state["y"] * (1.0 - h)
        state["t"] += h
        state["step"] += 1
        return state["t"], h, {"dt": h}

    def on_output(t, step, info):
        outputs.append(t)
        diag.write(info, time=t, step=step, y=state["y"][0],
                   error=state["y"][0] - math.exp(-t))

    def checkpoint_fn():
        return Checkpoint.save(ckpt, state)

    step_fn_used = step_fn if clip else (lambda: step_fn())
    try:
        result = run(step_fn_used, t0=state["t"], t_end=t_end, output_interval=interval,
                     on_output=on_output, checkpoint_fn=checkpoint_fn, step0=state["step"],
                     output_at_start=not resume, stream=stream or io.StringIO())
    finally:
        diag.close()
    return result, outputs, state


def read(path):
    with open(path) as fh:
        return fh.read()


def test_runs_to_the_end_with_outputs_at_the_output_times(tmp_path):
    (t, step), outputs, state = scene(str(tmp_path))
    assert step == 100 and t == pytest.approx(1.0)
    assert np.allclose(outputs, np.arange(11) * 0.1)
    rows = read(tmp_path / "diagnostics.csv").splitlines()
    assert rows[0] == ",".join(COLUMNS) and len(rows) == 12
    assert rows[1].startswith("0.0,0,,1.0,")           # t0: no step info yet
    last = rows[-1].split(",")
    assert int(last[1]) == 100 and float(last[2]) == 0.01
    assert float(last[3]) == pytest.approx(0.99 ** 100)
    assert Checkpoint.load(str(tmp_path / "checkpoint.npz"))["step"] == 100


def test_step_fn_with_a_stop_time_lands_on_output_times(tmp_path):
    (t, step), outputs, _ = scene(str(tmp_path), dt=0.03, interval=0.1, t_end=0.45, clip=True)
    assert outputs == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4, 0.45], abs=1e-12)
    assert t == pytest.approx(0.45, abs=1e-12)


def test_large_steps_skip_output_times_without_repeating(tmp_path):
    _, outputs, _ = scene(str(tmp_path), dt=0.25, interval=0.1, t_end=1.0)
    assert outputs == pytest.approx([0.0, 0.25, 0.5, 0.75, 1.0])


@pytest.mark.parametrize("action,at", [("raise-ki", 37), ("sigint", 37), ("sigint", 40)])
def test_interrupt_then_resume_gives_the_uninterrupted_diagnostics(tmp_path, action, at):
    ref, run1 = tmp_path / "ref", tmp_path / "run"
    ref.mkdir(), run1.mkdir()
    scene(str(ref))
    msg = io.StringIO()
    with pytest.raises(SystemExit) as exc:
        scene(str(run1), fail_at=(at, action), stream=msg)
    assert exc.value.code == 130
    text = msg.getvalue()
    assert "interrupted at t=" in text and "--resume" in text
    saved = Checkpoint.load(str(run1 / "checkpoint.npz"))
    if action == "sigint":         # the step finished, then its state was saved
        assert saved["step"] == at and "state saved to" in text
    else:                          # stopped mid-step: the last output's checkpoint stays
        assert saved["step"] == 30 and "middle of a step" in text
    (t, step), outputs, _ = scene(str(run1), resume=True)
    assert step == 100 and outputs[0] == pytest.approx(0.5 if at == 40 else 0.4)
    assert read(run1 / "diagnostics.csv") == read(ref / "diagnostics.csv")
    assert not [f for f in os.listdir(run1) if f.startswith(".tmp")]


def test_sigint_handler_is_restored(tmp_path):
    before = signal.getsignal(signal.SIGINT)
    scene(str(tmp_path), t_end=0.05)
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.parametrize("action,words", [("blowup", ["non-finite", "velocity"]),
                                          ("solver", ["solver", "broke down"])])
def test_blow_up_stops_with_status_2_and_keeps_the_last_checkpoint(tmp_path, action, words):
    msg = io.StringIO()
    with pytest.raises(SystemExit) as exc:
        scene(str(tmp_path), fail_at=(25, action), stream=msg)
    assert exc.value.code == 2
    text = msg.getvalue()
    assert "blew up" in text and "t=0.24" in text and "checkpoint.npz" in text
    for w in words:
        assert w in text
    assert Checkpoint.load(str(tmp_path / "checkpoint.npz"))["step"] == 20
    rows = read(tmp_path / "diagnostics.csv").splitlines()
    assert len(rows) == 1 + 3                         # outputs at 0, 0.1, 0.2


def test_custom_blowup_types_and_time_not_advancing():
    class FlowBlowUp(RuntimeError):
        pass

    def boom():
        raise FlowBlowUp("12 particles left the box")

    kw = dict(t0=0.0, t_end=1.0, output_interval=0.1, on_output=lambda *a: None,
              checkpoint_fn=lambda: "ck.npz", progress=False)
    msg = io.StringIO()
    with pytest.raises(SystemExit) as exc:
        run(boom, blowup_types=(FlowBlowUp,), stream=msg, **kw)
    assert exc.value.code == 2 and "left the box" in msg.getvalue()
    with pytest.raises(FlowBlowUp):                  # not declared: an ordinary error
        run(boom, stream=io.StringIO(), **kw)
    msg = io.StringIO()
    with pytest.raises(SystemExit) as exc:
        run(lambda: (float("nan"), float("nan"), {}), stream=msg, **kw)
    assert exc.value.code == 2 and "time did not advance" in msg.getvalue()


def test_check_helpers():
    check_finite(x=np.zeros((3, 2)))
    with pytest.raises(BlowUp, match="non-finite values in velocity") as exc:
        check_finite(position=np.zeros((3, 2)), velocity=np.array([[0, 1], [np.nan, 0]]))
    assert exc.value.cause == "non-finite"
    check_inside(np.array([[0.5, 0.5]]), (0, 0), (1, 1))
    with pytest.raises(BlowUp, match="1 particles left the box") as exc:
        check_inside(np.array([[0.5, 0.5], [1.2, 0.5]]), (0, 0), (1, 1), margin=0.1)
    assert exc.value.cause == "left-box"
    with pytest.raises(ValueError):
        BlowUp("x", cause="bad")


def test_diagnostics_writer_drops_partial_and_later_rows_on_resume(tmp_path):
    path = str(tmp_path / "d.csv")
    with DiagnosticsWriter(path, ["time", "a", "label"]) as d:
        for k in range(5):
            d.write({"time": 0.1 * k, "a": k}, label="x,y" if k == 1 else None)
    with open(path, "a") as fh:
        fh.write("0.5,5,")                            # a crash mid-line
    lines = read(path).splitlines()
    assert lines[2] == '0.1,1,"x,y"' and lines[-1] == "0.5,5,"
    with DiagnosticsWriter(path, ["time", "a", "label"], resume_time=0.2) as d:
        assert d.rows_kept == 3
        d.write(time=0.3, a=33)
    assert read(path).splitlines() == ["time,a,label", "0.0,0,", '0.1,1,"x,y"',
                                       "0.2,2,", "0.3,33,"]
    # a partial line is also dropped when nothing is truncated
    with open(path, "a") as fh:
        fh.write("0.4,4")
    DiagnosticsWriter(path, ["time", "a", "label"], resume_time=10.0).close()
    assert read(path).endswith("0.3,33,\n")
    with pytest.raises(ValueError, match="columns"):
        DiagnosticsWriter(path, ["time", "b"], resume_time=0.0)
    with DiagnosticsWriter(path, ["time", "a"]) as d:   # fresh: starts over
        with pytest.raises(ValueError, match="unknown diagnostics columns"):
            d.write(time=0.0, b=1)
    assert read(path) == "time,a\n"
    assert sorted(os.listdir(tmp_path)) == ["d.csv"]


def test_resume_without_a_csv_starts_one(tmp_path):
    path = str(tmp_path / "d.csv")
    DiagnosticsWriter(path, ["time"], resume_time=1.0).close()
    assert read(path) == "time\n"


def test_checkpoint_round_trip_and_errors(tmp_path):
    path = str(tmp_path / "state.ckpt")               # any name: no .npz appended
    state = {"positions": np.random.default_rng(0).random((5, 2)), "phases": np.arange(5),
             "time": 0.25, "step": 7, "name": "droplet", "done": False}
    assert Checkpoint.save(path, state) == path
    assert os.listdir(tmp_path) == ["state.ckpt"]
    back = Checkpoint.load(path)
    assert set(back) == set(state)
    assert np.array_equal(back["positions"], state["positions"])
    assert back["time"] == 0.25 and isinstance(back["time"], float)
    assert back["step"] == 7 and isinstance(back["step"], int)
    assert back["name"] == "droplet" and back["done"] is False
    with pytest.raises(ValueError, match="not a numeric"):
        Checkpoint.save(path, {"bad": {"a": 1}})
    with pytest.raises(FileNotFoundError, match="--resume"):
        Checkpoint.load(str(tmp_path / "missing.npz"))
    np.savez(str(tmp_path / "other.npz"), x=np.zeros(2))
    with pytest.raises(ValueError, match="not a taichi_hh checkpoint"):
        Checkpoint.load(str(tmp_path / "other.npz"))
    np.savez(str(tmp_path / "future.npz"), x=np.zeros(2),
             **{Checkpoint.VERSION_KEY: np.asarray(99)})
    with pytest.raises(ValueError, match="format 99"):
        Checkpoint.load(str(tmp_path / "future.npz"))


class FakeTTY(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_without_a_tty_prints_a_line_per_tenth():
    out = io.StringIO()
    bar = ProgressBar(2.0, out)
    for k in range(1, 201):
        bar.update(0.01 * k, k)
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 10 and "\r" not in out.getvalue()
    assert lines[-1].startswith("t = 2 / 2") and "100%" in lines[-1] and "step 200" in lines[-1]
    assert "steps/s" in lines[0] and "ETA" in lines[0]


def test_eta_follows_the_recent_step_rate_when_the_time_step_shrinks(monkeypatch):
    """One wall second per step throughout; the time step halves after t = 1.
    Left: 0.7 / 0.01 = 70 steps, 70 s.  The run's average wall time per
    simulated time would promise 80 / 1.3 * 0.7 = 43 s."""
    from taichi_hh.app import runloop
    clock = [0.0]
    monkeypatch.setattr(runloop.time, "monotonic", lambda: clock[0])
    bar = ProgressBar(2.0, io.StringIO())
    t = 0.0
    for k in range(1, 81):
        clock[0] = float(k)
        t += 0.02 if k <= 50 else 0.01
        bar.update(t, k)
    assert bar.line().endswith("ETA 1:10")


def test_progress_bar_on_a_tty_redraws_in_place_at_most_5_times_a_second():
    out = FakeTTY()
    bar = ProgressBar(1.0, out)
    for k in range(1, 1001):
        bar.update(0.001 * k, k)                      # far faster than 5 per second
    bar.close()
    text = out.getvalue()
    assert 2 <= text.count("\r") <= 5 and text.endswith("\n") and text.count("\n") == 1
    assert "100%" in text.split("\r")[-1]


def test_common_arguments():
    ap = add_common_arguments(argparse.ArgumentParser(), {"particles": 5000, "out": "outputs/x"})
    args = ap.parse_args([])
    # the arch's default: $TAICHI_HH_ARCH where set (vulkan in CI's Vulkan run), else cpu
    assert (args.particles, args.out, args.arch, args.movie, args.color, args.precision) == \
        (5000, "outputs/x", runtime.default_arch(), "none", "phase", "f64")
    assert args.resume is False and args.quiet is False
    args = ap.parse_args("--particles 100 --end-time 0.5 --resume --movie gif --fps 12 "
                         "--frame-width 640 --color speed --precision f32 --quiet --arch gpu".split())
    assert (args.particles, args.end_time, args.resume, args.movie, args.fps, args.frame_width,
            args.color, args.precision, args.quiet, args.arch) == \
        (100, 0.5, True, "gif", 12.0, 640, "speed", "f32", True, "gpu")
    help_text = ap.format_help()
    for action in ap._actions:
        if action.dest != "help":
            assert action.help and "default" in action.help, action.dest
    assert "(default: 5000)" in help_text
    for bad in (["--particles", "0"], ["--end-time", "-1"], ["--movie", "avi"], ["--fps", "nan"]):
        with pytest.raises(SystemExit):
            ap.parse_args(bad)
    with pytest.raises(ValueError, match="unknown default"):
        add_common_arguments(argparse.ArgumentParser(), {"particle": 1})


@pytest.mark.parametrize("action", [None, "sigint", "raise-ki", "blowup"])
def test_flush_comes_before_every_stop_message_and_at_the_end(action):
    """With a writer beside the loop (``flush_fn``), whatever was handed over is
    written before the loop says which checkpoint it kept, and before it returns."""
    events, state = [], {"t": 0.0}

    def step_fn():
        if action and round(state["t"] / 0.01) + 1 == 15:
            if action == "sigint":
                signal.raise_signal(signal.SIGINT)
            elif action == "raise-ki":
                raise KeyboardInterrupt
            else:
                raise BlowUp("non-finite values in velocity", cause="non-finite")
        state["t"] += 0.01
        return state["t"], 0.01, {}

    class Stream(io.StringIO):
        def write(self, text):
            if text.strip():
                events.append("message")
            return super().write(text)

    def checkpoint_fn():
        events.append("checkpoint")
        return "ck.npz"

    kw = dict(t0=0.0, t_end=0.3, output_interval=0.1, on_output=lambda *a: events.append("output"),
              checkpoint_fn=checkpoint_fn, flush_fn=lambda: events.append("flush"),
              progress=False, stream=Stream())
    if action is None:
        run(step_fn, **kw)
        assert events[-1] == "flush" and events.count("output") == 4
        return
    with pytest.raises(SystemExit):
        run(step_fn, **kw)
    assert events[-2:] == ["flush", "message"]
    if action == "sigint":                            # the checkpoint of the stop, then the flush
        assert events[-3] == "checkpoint"
