"""The persistent worker (app/worker.py, app/worker_client.py): calls through it
give the command line's own files, messages and exit statuses; without one the
command runs in its own process."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

CLI = [sys.executable, "-m", "taichi_hh"]


@pytest.fixture
def worker_env(tmp_path):
    env = dict(os.environ)
    env["TAICHI_HH_WORKER_DIR"] = str(tmp_path / "w")
    env.pop("TAICHI_HH_DEBUG", None)
    env.pop("TAICHI_HH_WORKER", None)
    yield env
    subprocess.run(CLI + ["worker", "stop"], env=env, capture_output=True, timeout=60)


def _field(path, n=700, seed=0, shift=0.0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0.0, 1.0, (n, 2))
    x, y = pts[:, 0] - 0.4 - shift, pts[:, 1] - 0.5
    g = np.exp(-(x ** 2 + y ** 2) / 0.02)
    np.savez(path, points=pts, vectors=np.c_[-y * g + 0.3, x * g + 0.1])
    return str(path)


def _run(args, env, cwd, **kw):
    return subprocess.run(CLI + args, env=env, cwd=cwd, capture_output=True, text=True,
                          timeout=600, **kw)


def _calls(env):
    done = _run(["worker", "status"], env, None)
    if done.returncode != 0:
        return None
    return int(done.stdout.split(" calls")[0].rsplit(" ", 1)[1])


def test_calls_through_the_worker_equal_the_command_line_in_its_own_process(tmp_path, worker_env):
    env = worker_env
    field = _field(tmp_path / "f.npz")
    assert _calls(env) is None                            # none running yet
    started = _run(["worker", "start", "--no-warm-up", "--idle-timeout", "300"], env, tmp_path)
    assert started.returncode == 0, started.stderr
    assert "started" in started.stdout and _calls(env) == 0
    common = ["--no-figures", "--no-vtk"]
    own = _run(["decompose", "f.npz", "-o", "own", "--no-worker"], env, tmp_path)
    first = _run(["decompose", "f.npz", "-o", "w1"], env, tmp_path)
    second = _run(["decompose", field, "-o", str(tmp_path / "w2"), *common], env, "/")
    assert own.returncode == first.returncode == second.returncode == 0, first.stderr
    assert _calls(env) == 2                               # both went to the worker
    # every file the same, byte for byte (arrows.png drawn by the worker's figure helper)
    names = sorted(os.listdir(tmp_path / "own"))
    assert names == sorted(os.listdir(tmp_path / "w1"))
    assert {"arrows.png", "magnitude.png", "components.npz", "components.vtu"} <= set(names)
    for name in names:
        assert (tmp_path / "own" / name).read_bytes() == (tmp_path / "w1" / name).read_bytes(), name
    ref = np.load(tmp_path / "own" / "components.npz")
    for out in ("w1", "w2"):
        got = np.load(tmp_path / out / "components.npz")
        assert sorted(got.files) == sorted(ref.files)
        for name in ref.files:
            assert np.array_equal(got[name], ref[name], equal_nan=True) if \
                got[name].dtype.kind == "f" else np.array_equal(got[name], ref[name]), name
    # the same summary, but for the timings and the output directory
    strip = lambda text: " ".join(w for w in text.split() if not w[0].isdigit()
                                  and "own" not in w and "w1" not in w)
    assert strip(first.stdout) == strip(own.stdout)
    # an error: the same line on stderr and the same status, no files
    bad = ["decompose", "missing.npz", "-o", "bad"]
    err_own = _run(bad + ["--no-worker"], env, tmp_path)
    err_worker = _run(bad, env, tmp_path)
    assert err_own.returncode == err_worker.returncode == 2
    assert err_worker.stderr == err_own.stderr and "error:" in err_worker.stderr
    # argparse's own errors and --help come back too
    usage = _run(["decompose", "f.npz", "--tol", "-1"], env, tmp_path)
    assert usage.returncode == 2 and "--tol" in usage.stderr
    assert _calls(env) == 4
    stopped = _run(["worker", "stop"], env, None)
    assert stopped.returncode == 0 and "stopped" in stopped.stdout
    assert _calls(env) is None
    # no worker: the command runs in its own process
    alone = _run(["decompose", "f.npz", "-o", "alone", *common], env, tmp_path)
    assert alone.returncode == 0, alone.stderr
    got = np.load(tmp_path / "alone" / "components.npz")
    assert np.array_equal(got["d"], ref["d"], equal_nan=True)


def test_a_call_through_the_worker_loads_neither_numpy_nor_taichi(tmp_path, worker_env):
    env = worker_env
    _field(tmp_path / "f.npz", n=300)
    assert _run(["worker", "start", "--no-warm-up"], env, tmp_path).returncode == 0
    probe = ("import sys\nfrom taichi_hh.app import cli\n"
             "code = cli.main(['decompose', 'f.npz', '-o', 'o', '-q', '--no-figures'])\n"
             "print('loaded', [m for m in ('numpy', 'taichi', 'matplotlib') if m in sys.modules], code)")
    done = subprocess.run([sys.executable, "-c", probe], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "loaded [] 0" in done.stdout
    assert (tmp_path / "o" / "components.npz").exists() and _calls(env) == 1


@pytest.mark.slow
def test_ctrl_c_stops_the_call_in_the_worker_as_in_its_own_process(tmp_path, worker_env):
    env = worker_env
    # long enough to be interrupted: a warm series takes about 10 ms a file of
    # these (40 of them were done within the half second this waited)
    files = [_field(tmp_path / f"s{t:03d}.npz", n=3000, shift=0.0005 * t) for t in range(400)]
    assert _run(["worker", "start", "--no-warm-up"], env, tmp_path).returncode == 0
    # SIGINT at its default in the child whatever this process inherited (a
    # test run started in the background by a shell ignores it, and so would
    # the child's Python)
    child = subprocess.Popen(CLI + ["decompose", *files, "-o", "series", "--figures", "none"],
                             env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    for line in child.stderr:                              # the series has started
        if "snapshot" in line or "decompos" in line:
            break
    time.sleep(0.1)
    child.send_signal(signal.SIGINT)
    out, err = child.communicate(timeout=600)
    assert child.returncode == 130, err
    assert "interrupted" in out + err
    assert _calls(env) == 1                               # the worker lives on
