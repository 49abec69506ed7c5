"""Hostile input through the scenes (issue 15), a few hundred particles and
short end times.  Each case: one line naming the problem and status 2, or a
run that does what the documentation says.

Cases tested elsewhere: options that cannot run, refused at parse time
(tests/test_scenes.py::test_scene_options_that_cannot_run_stop_at_parse_time:
negative viscosity, density ratio 0/inf, zero or negative box, output interval
0, radius 0 or too large, too few particles, amplitude, wavelength); --config
errors (test_config_file_round_trip_and_errors); Ctrl-C, a second Ctrl-C, a
blow-up and resuming bit-identically (tests/test_runloop.py); a resumed scene
following the uninterrupted one (test_droplet_resume_continues_the_run).
"""
import csv
import io
import os
import subprocess
import sys
import warnings

import imageio.v3 as iio
import numpy as np
import pytest

from taichi_hh.app import runloop
from taichi_hh.app.scene import run_scene
from taichi_hh.app.scenes import get
from taichi_hh.errors import AccuracyWarning
from taichi_hh.flow import twophase

DROPLET = get("rising-droplet")
FAST = ["--particles", "300", "--output-interval", "0.1", "--quiet", "--frame-width", "60",
        "--no-vtk"]


def scene(argv, capsys=None, scene_def=DROPLET):
    """(exit status, stderr, SceneRun or None) of a scene run in-process."""
    try:
        result, code = run_scene(scene_def, [str(a) for a in argv]), 0
    except SystemExit as exc:
        result, code = None, exc.code
    err = capsys.readouterr().err if capsys else ""
    return code, err, result


def error_line(err):
    lines = [ln for ln in err.strip().splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_fresh_run_clears_an_earlier_longer_run(tmp_path, capsys):
    """The old frames used to survive and mix into --movie (41 frames)."""
    out = tmp_path / "run"
    assert scene(FAST + ["--end-time", "0.2", "--out", out])[0] == 0
    (out / "notes.txt").write_text("not ours")
    code, err, _ = scene(FAST + ["--end-time", "0.1", "--out", out, "--movie", "gif"], capsys)
    assert code == 0
    assert sorted(p.name for p in out.glob("frame_*.png")) == ["frame_00000.png",
                                                                "frame_00001.png"]
    assert iio.imread(out / "rising_droplet.gif", index=None).shape[0] == 2
    assert (out / "notes.txt").read_text() == "not ours"
    with open(out / "diagnostics.csv") as fh:
        assert [float(r["time"]) for r in csv.DictReader(fh)] == pytest.approx([0.0, 0.1])


def test_fresh_run_says_what_it_removed(tmp_path, capsys):
    out = tmp_path / "run"
    scene(FAST + ["--end-time", "0.1", "--out", out])
    _, err, _ = scene([a for a in FAST if a != "--quiet"] + ["--end-time", "0.1", "--out", out],
                      capsys)
    # config.toml, diagnostics.csv, checkpoint.npz, 2 frames, 2 particle files
    assert f"fresh run: removed 7 files of an earlier run in {out}" in err


def test_resume_keeps_the_checkpoint_options_and_refuses_others(tmp_path, capsys):
    """A different --particles used to be ignored silently."""
    out = tmp_path / "run"
    assert scene(FAST + ["--end-time", "0.1", "--out", out, "--viscosity", "0.004"])[0] == 0
    code, err, _ = scene(FAST[2:] + ["--particles", "500", "--end-time", "0.2", "--out", out,
                                     "--resume"], capsys)
    assert code == 2
    assert "--particles 500 differs from its 300 (drop the option" in error_line(err)
    # options not given come from the checkpoint (not the defaults: 10500 particles)
    code, _, res = scene(["--quiet", "--no-vtk", "--frame-width", "60", "--end-time", "0.2",
                          "--out", out, "--resume", "--dt-max", "0.01"])
    assert code == 0 and res.args.particles == 300 and res.args.viscosity == 0.004
    assert res.flow.params.dt_max == 0.01 and max(res.dts) <= 0.01 + 1e-15
    assert res.flow.n_fluid == 288


@pytest.mark.parametrize("setup, message", [
    ("none", "--resume: no checkpoint in {out}: nothing to resume (run without --resume)"),
    ("corrupt", "is not a readable checkpoint (a truncated or damaged zip archive"),
    ("garbage", "is not a readable checkpoint (it is not a zip archive"),
    ("other_scene", "--resume: {out} holds a rayleigh_taylor run, not rising_droplet"),
])
def test_resume_from_nothing_or_a_wrong_checkpoint_exits_2(tmp_path, capsys, setup, message):
    out = tmp_path / "run"
    out.mkdir()
    if setup == "corrupt":
        good = tmp_path / "good"
        scene(FAST + ["--end-time", "0.1", "--out", good])
        data = (good / "checkpoint.npz").read_bytes()
        (out / "checkpoint.npz").write_bytes(data[: len(data) // 2])
    elif setup == "garbage":
        (out / "checkpoint.npz").write_bytes(b"\x00" * 100)
    elif setup == "other_scene":
        scene(FAST + ["--end-time", "0.1", "--out", out], scene_def=get("rayleigh-taylor"))
    capsys.readouterr()
    code, err, _ = scene(FAST + ["--end-time", "0.2", "--out", out, "--resume"], capsys)
    assert code == 2 and message.format(out=out) in error_line(err)


def test_out_that_is_a_file_exits_2(tmp_path, capsys):
    target = tmp_path / "a_file"
    target.write_text("keep")
    for out, message in ((target, "is a file, not a directory"),
                         (target / "sub", "cannot create the directory")):
        code, err, _ = scene(FAST + ["--end-time", "0.1", "--out", out], capsys)
        assert code == 2 and f"--out {out}: {message}" in error_line(err)
    assert target.read_text() == "keep"


@pytest.mark.parametrize("cause, advice", [
    ("left-box", "'--resume --dt-max "),
    ("solver", "'--resume --solver-tol 1e-03' continues from it with a looser"),
])
def test_blow_up_advice_names_options_the_scenes_have(tmp_path, capsys, monkeypatch, cause,
                                                      advice):
    real = twophase.TwoPhaseFlow.step

    def step(self, dt):
        if self.step_count >= 2:
            raise twophase.BlowUpError("made up for the test", cause=cause)
        return real(self, dt)

    monkeypatch.setattr(twophase.TwoPhaseFlow, "step", step)
    code, err, _ = scene(FAST + ["--end-time", "0.3", "--out", tmp_path / "run"], capsys)
    assert code == 2 and f"[{cause}]" in err and advice in err
    if cause == "left-box":             # the advice is an option the scene takes
        dt = float(err.split("--dt-max ")[1].split("'")[0])
        monkeypatch.setattr(twophase.TwoPhaseFlow, "step", real)
        code, _, res = scene(FAST + ["--end-time", "0.2", "--out", tmp_path / "run",
                                     "--resume", "--dt-max", str(dt)])
        assert code == 0 and max(res.dts) <= dt + 1e-15


def test_time_step_options_beyond_the_measured_range_warn(tmp_path):
    with pytest.warns(AccuracyWarning, match=r"cfl = 2 \(measured up to 0.5\)"):
        code, _, _ = scene(FAST + ["--end-time", "0.1", "--out", tmp_path / "run",
                                   "--cfl", "2"])
    assert code == 0


def test_piped_progress_prints_a_line_during_a_slow_stretch(monkeypatch):
    """--viscosity 10 ran 40k tiny steps with no line for 40 s when piped."""
    clock = [0.0]
    monkeypatch.setattr(runloop.time, "monotonic", lambda: clock[0])
    out = io.StringIO()
    bar = runloop.ProgressBar(1.0, out, log_interval=30.0)
    for k in range(1, 101):                  # 1e-4 of the run per step, 1 s each
        clock[0] += 1.0
        bar.update(1e-4 * k, k)
    lines = out.getvalue().splitlines()
    assert len(lines) == 3 and lines[0].startswith("t = 0.003 / 1") and "step 30" in lines[0]


@pytest.mark.slow
def test_f32_run_gets_past_t_0(tmp_path):
    """--precision f32 used to stop at t = 0: the pressure solve stagnates near
    2e-4 against f64's 1e-6 tolerance.  A subprocess: f32 needs its own runtime."""
    import taichi_hh
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [os.path.dirname(os.path.dirname(os.path.abspath(taichi_hh.__file__)))]
        + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    proc = subprocess.run([sys.executable, "-m", "taichi_hh", "scene", "rising-droplet",
                           *FAST, "--end-time", "0.2", "--precision", "f32", "--out",
                           str(tmp_path / "f32")], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    with open(tmp_path / "f32" / "diagnostics.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["time"]) for r in rows] == pytest.approx([0.0, 0.1, 0.2], abs=1e-6)
    assert all(np.isfinite(float(r["kinetic_energy"])) for r in rows)


def test_scene_script_internal_error_is_one_line_with_a_report(tmp_path, capsys, monkeypatch):
    import dataclasses
    import tempfile
    from taichi_hh.app.scene import main

    def bug(flow):
        raise ZeroDivisionError("a bug in a measure")

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    code = main(dataclasses.replace(DROPLET, measures=bug),
                FAST + ["--end-time", "0.1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert code == 1 and len(lines) == 1 and "Traceback" not in err
    assert lines[0].startswith("rising_droplet.py: internal error: ZeroDivisionError: a bug in "
                               f"a measure (full report in {tmp_path}")
    assert any(p.name.startswith("taichi-hh-error-") for p in tmp_path.iterdir())
