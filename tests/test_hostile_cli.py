"""Hostile input through the command line (issue 15): bad input ends in one
line ``taichi-hh CMD: error: ...`` and status 2, a bug in one line naming a
report file and status 1; no traceback, no result file of a failed command.

Runs ``cli.main`` in-process (see tests/test_cli.py, whose
test_bad_input_exits_2_with_one_line covers missing files, malformed CSV and
npz, NaN values, missing arrays, wrong shapes, points outside --domain, bad
--domain strings and failed solves; test_bad_option_values_are_usage_errors
bad option values; test_python_dash_m_reports_errors the same through
``python -m``).
"""
import os

import numpy as np
import pytest

from taichi_hh.app import io as thio
from taichi_hh.validation import fields
from test_cli import RUNTIME, run


@pytest.fixture(scope="module")
def field_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile_cli")
    f = fields.get("trig")
    files = {}
    for name, n in (("good", 300), ("few", 30), ("five", 5)):
        pts = f.sample(n, kind="poisson", seed=1)
        np.savez(d / f"{name}.npz", points=pts, vectors=f.evaluate(pts).v)
        files[name] = d / f"{name}.npz"
    good = (d / "good.npz").read_bytes()
    (d / "garbage.npz").write_bytes(bytes(range(256)) * 8)
    (d / "empty.npz").write_bytes(b"")
    (d / "truncated.npz").write_bytes(good[: len(good) // 2])
    files.update({k: d / f"{k}.npz" for k in ("garbage", "empty", "truncated")})
    files["dir"] = d
    return files


def one_error_line(stderr, command="decompose"):
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"taichi-hh {command}: error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


@pytest.mark.parametrize("case, message", [
    ("garbage", "not a zip archive: it starts with bytes 00 01 02 03"),
    ("empty", "the file is empty"),
    ("truncated", "a truncated or damaged zip archive"),
])
def test_unreadable_npz_is_named_not_called_pickled(field_files, tmp_path, case, message):
    """Garbage bytes used to be reported as 'pickled data'."""
    rc, _, err = run(["decompose", field_files[case], "-o", tmp_path, "-q", *RUNTIME])
    line = one_error_line(err)
    assert rc == 2 and message in line and "pickle" not in line


def test_out_that_is_a_file_is_refused_before_any_work(field_files, tmp_path):
    target = tmp_path / "a_file"
    target.write_text("keep me")
    for out, message in ((target, "is a file, not a directory"),
                         (target / "sub", "cannot create the directory (Not a directory)")):
        rc, stdout, err = run(["decompose", field_files["good"], "-o", out, *RUNTIME])
        line = one_error_line(err)            # no progress line either: refused first
        assert rc == 2 and f"--out {out}: {message}" in line and stdout == ""
    assert target.read_text() == "keep me"


def test_failed_figure_leaves_no_result_files(field_files, tmp_path, monkeypatch):
    """components.npz used to stay behind while the command exited 2."""
    from taichi_hh.app import figures

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(figures, "decomposition_figures", broken)
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    rc, _, err = run(["decompose", field_files["good"], "-o", out, "-q", *RUNTIME])
    assert rc == 2 and "No space left on device" in one_error_line(err)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_internal_error_is_one_line_naming_the_report(field_files, tmp_path, monkeypatch):
    import taichi_hh.hhd.decompose as dec

    def bug(*args, **kwargs):
        raise RuntimeError("an internal bug")

    monkeypatch.setattr(dec, "decompose", bug)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)
    rc, _, err = run(["decompose", field_files["good"], "-o", tmp_path / "o", "-q", *RUNTIME])
    lines = err.strip().splitlines()
    assert rc == 1 and len(lines) == 1 and "Traceback" not in err
    assert lines[0].startswith("taichi-hh decompose: internal error: RuntimeError: an "
                               "internal bug (full report in ")
    report = lines[0].split("full report in ")[1].split(";")[0]
    assert os.path.dirname(report) == str(tmp_path)
    text = open(report).read()
    assert "Traceback" in text and "an internal bug" in text


def test_few_points_warn_in_one_line_and_too_few_are_refused(field_files, tmp_path):
    rc, _, err = run(["decompose", field_files["few"], "-o", tmp_path / "few", "-q",
                      "--no-figures", *RUNTIME])
    # every warning one line (30 points also leave h visibly not harmonic,
    # which is flagged in a line of its own), the number of points in one
    lines = err.strip().splitlines()
    assert rc == 0 and all(ln.startswith("taichi-hh decompose: warning: ") for ln in lines)
    assert sum(ln.startswith("taichi-hh decompose: warning: only ") for ln in lines) == 1
    rc, _, err = run(["decompose", field_files["five"], "-o", tmp_path / "five", "-q",
                      *RUNTIME])
    assert rc == 2 and "too few to decompose" in one_error_line(err)
    assert not (tmp_path / "five" / "components.npz").exists()


def test_stale_temp_files_of_a_killed_run_are_removed(field_files, tmp_path):
    """A SIGKILL during a write leaves .tmp-<pid>-*.npz: the next run removes it
    (its process is gone) and keeps a live process's temp file."""
    out = tmp_path / "out"
    out.mkdir()
    dead = out / ".tmp-999999999-abc.npz"          # no such process id
    dead.write_bytes(b"PK\x03\x04 half an archive")
    live = out / f".tmp-{os.getpid()}-xyz.npz"
    live.write_bytes(b"being written")
    rc, _, _ = run(["decompose", field_files["good"], "-o", out, "-q", "--no-figures",
                    "--no-vtk", *RUNTIME])
    assert rc == 0 and not dead.exists() and live.exists()
    assert sorted(p.name for p in out.iterdir()) == sorted([live.name, "components.npz"])


def test_atomic_write_names_its_temp_file_by_process(tmp_path):
    seen = []
    with thio.atomic_path(str(tmp_path / "x.npz")) as tmp:
        seen.append(os.path.basename(tmp))
        open(tmp, "w").write("data")
    assert seen[0].startswith(f".tmp-{os.getpid()}-") and seen[0].endswith(".npz")
    assert os.listdir(tmp_path) == ["x.npz"]
    with pytest.raises(RuntimeError):
        with thio.atomic_path(str(tmp_path / "y.npz")) as tmp:
            open(tmp, "w").write("half")
            raise RuntimeError("interrupted")
    assert os.listdir(tmp_path) == ["x.npz"]         # the temp file went on the way out
