"""The scenes' output worker (taichi_hh.app.outputs): the same bytes as writing in
the loop's own process, in order, bounded, no Taichi in the worker, errors and
a killed worker surfacing as one line (never a hang), SIGINT ignored."""
import os
import pathlib
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from taichi_hh.app.outputs import MAX_PENDING, OutputError, Outputs, OutputSpec
from taichi_hh.app.particle_files import read_pvd
from taichi_hh.app.runloop import Checkpoint

REPO = pathlib.Path(__file__).resolve().parent.parent


def _particles(n=300, seed=0):
    rng = np.random.default_rng(seed)
    pos = rng.uniform([0.0, 0.0], [1.0, 2.0], (n, 2))
    data = {"velocity": rng.normal(size=(n, 2)), "phase": (pos[:, 1] > 1.0).astype(np.int32),
            "id": np.arange(n), "pressure": rng.normal(size=n)}
    return pos, data


def _spec(out, **kw):
    return OutputSpec(str(out), 96, (0.0, 0.0), (1.0, 2.0), phase_names=("light", "heavy"),
                      wall_px=2, **kw)


def _hand_over(outputs, out, frames=3):
    for k in range(frames):
        pos, data = _particles(seed=k)
        speed = np.linalg.norm(data["velocity"], axis=1)
        colouring = (speed, 0.0, float(speed.max()), "speed") if k % 2 else None
        outputs.frame(k, 0.1 * k, pos, data, colouring)
        outputs.checkpoint(os.path.join(out, "checkpoint.npz"),
                           {"positions": pos, "time": 0.1 * k, "step": k})
        assert outputs.pending <= MAX_PENDING


def _files(folder):
    folder = pathlib.Path(folder)
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_worker_writes_the_same_bytes_in_order_and_imports_no_taichi(tmp_path):
    written = {}
    for workers in (0, 1):
        out = tmp_path / f"w{workers}"
        outputs = Outputs(_spec(out), workers=workers)
        _hand_over(outputs, str(out), frames=4)
        outputs.close()
        written[workers] = _files(out)
        if workers:
            assert outputs.worker_imported_taichi is False
            assert outputs.worker_seconds > 0 and outputs.worker_cpu > 0
    assert sorted(written[1]) == sorted(written[0])
    assert len([f for f in written[1] if f.startswith("frame_")]) == 4
    assert len([f for f in written[1] if f.endswith(".vtu")]) == 4
    for name, content in written[0].items():
        assert written[1][name] == content, name
    # the series lists the frames in order; the checkpoint is the last one handed over
    assert [t for t, _ in read_pvd(str(tmp_path / "w1" / "particles.pvd"))] == \
        pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert Checkpoint.load(str(tmp_path / "w1" / "checkpoint.npz"))["step"] == 3


def test_a_scene_script_as_main_does_not_bring_taichi_into_the_worker(tmp_path):
    # spawn's child imports the parent's __main__ unless it is kept out; a scene
    # script imports Taichi (here: directly), and the worker must not
    script = tmp_path / "main_with_taichi.py"
    script.write_text(textwrap.dedent(f"""
        import numpy as np
        import taichi
        from taichi_hh.app.outputs import Outputs, OutputSpec
        if __name__ == "__main__":
            out = {str(tmp_path / "run")!r}
            o = Outputs(OutputSpec(out, 40, (0.0, 0.0), (1.0, 1.0)), workers=1)
            o.frame(0, 0.0, np.random.default_rng(0).uniform(size=(50, 2)),
                    {{"phase": np.zeros(50, np.int32)}})
            o.close()
            print("worker imported taichi:", o.worker_imported_taichi)
    """))
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "worker imported taichi: False" in done.stdout
    assert (tmp_path / "run" / "frame_00000.png").exists()


def _outputs_that_fail(tmp_path):
    """A worker whose first particle file cannot be written (``particles`` is a
    file, not a folder), one frame handed over: (out, outputs, pos, data)."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "particles").write_text("a file, not a folder")
    outputs = Outputs(_spec(out), workers=1)
    pos, data = _particles()
    outputs.frame(0, 0.0, pos, data)
    return out, outputs, pos, data


def test_a_failed_write_is_one_error_at_the_next_hand_off_and_nothing_follows(tmp_path):
    out, outputs, pos, data = _outputs_that_fail(tmp_path)
    outputs.checkpoint(str(out / "checkpoint.npz"), {"time": 0.0})
    with pytest.raises(OutputError) as err:
        outputs.drain()
    message = str(err.value)
    assert "\n" not in message and "t=0" in message and "failed" in message
    assert "particles" in message
    outputs.close()                     # raised once: closing says nothing more
    # the checkpoint after the failed frame was not written: it would run ahead of it
    assert not (out / "checkpoint.npz").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".tmp")]


def test_a_killed_worker_is_an_error_not_a_hang(tmp_path):
    outputs = Outputs(_spec(tmp_path), workers=1)
    os.kill(outputs.worker_pid, signal.SIGKILL)
    pos, data = _particles()
    with pytest.raises(OutputError, match="output worker stopped"):
        for k in range(2 * MAX_PENDING + 2):         # the hand-offs find out, or the drain
            outputs.frame(k, 0.1 * k, pos, data)
        outputs.drain()
    outputs.close()


def test_the_worker_ignores_sigint(tmp_path):
    outputs = Outputs(_spec(tmp_path), workers=1)
    os.kill(outputs.worker_pid, signal.SIGINT)       # Ctrl-C is the time loop's to handle
    _hand_over(outputs, str(tmp_path), frames=2)
    outputs.close()
    assert outputs.worker_exitcode == 0
    assert (tmp_path / "frame_00001.png").exists()


def test_output_workers_must_be_0_or_1(tmp_path):
    with pytest.raises(ValueError, match="0 or 1"):
        Outputs(_spec(tmp_path), workers=2)


@pytest.mark.parametrize("stop", ["sigint", "blowup"])
def test_a_scene_stopped_by_ctrl_c_or_a_blow_up_has_every_output_it_handed_over(
        tmp_path, capsys, monkeypatch, stop):
    """Ctrl-C (the step finishes, its checkpoint is saved) or a blow-up while the
    worker writes: every output handed over is on disk before the stop message,
    the checkpoint matches the last frame, no temporary file is left, and
    --resume continues to the end with the PVD series in order."""
    from taichi_hh.app.scene import run_scene
    from taichi_hh.app.scenes import get
    from taichi_hh.flow import twophase
    real = twophase.TwoPhaseFlow.step

    def step(self, dt):
        info = real(self, dt)
        if self.step_count == 5:
            if stop == "sigint":
                signal.raise_signal(signal.SIGINT)     # handled when the step is done
            else:
                raise twophase.BlowUpError("made up for the test", cause="non-finite")
        return info

    monkeypatch.setattr(twophase.TwoPhaseFlow, "step", step)
    out = tmp_path / "run"
    argv = ["--particles", "300", "--output-interval", "0.02", "--quiet", "--frame-width", "60",
            "--out", str(out)]
    with pytest.raises(SystemExit) as exc:
        run_scene(get("rising-droplet"), argv + ["--end-time", "0.3"])
    assert exc.value.code == (130 if stop == "sigint" else 2)
    err = capsys.readouterr().err
    assert "checkpoint.npz" in err
    state = Checkpoint.load(str(out / "checkpoint.npz"))
    frames = sorted(out.glob("frame_*.png"))
    entries = read_pvd(str(out / "particles.pvd"))
    assert len(frames) == len(entries) == len(list((out / "particles").glob("*.npz")))
    assert entries[-1][0] <= state["time"] + 1e-12
    if stop == "sigint":                      # the state after the 5th step, saved at the stop
        assert state["step"] == 5
    assert not [p for p in out.rglob(".tmp*")]
    monkeypatch.setattr(twophase.TwoPhaseFlow, "step", real)
    run_scene(get("rising-droplet"), argv + ["--end-time", "0.1", "--resume"])
    times = [t for t, _ in read_pvd(str(out / "particles.pvd"))]
    assert times == sorted(times) and times[-1] == pytest.approx(0.1)
    assert len(times) == len(sorted(out.glob("frame_*.png"))) == 6


def test_after_a_failure_every_hand_off_and_drain_raises_again_never_hangs(tmp_path):
    out, outputs, pos, data = _outputs_that_fail(tmp_path)
    with pytest.raises(OutputError):
        outputs.drain()
    with pytest.raises(OutputError, match="t=0"):
        outputs.frame(1, 0.1, pos, data)
    with pytest.raises(OutputError, match="t=0"):
        outputs.drain()
    outputs.close()
