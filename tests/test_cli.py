"""The command line (taichi-hh decompose / project), its readers, writers and figures.

Runs ``cli.main([...])`` in-process on a small analytic field (~1500 points),
always with the session's arch and ``--precision f64`` so that the session's Taichi runtime
(conftest) is reused rather than re-initialised.
"""
import contextlib
import csv
import dataclasses
import io as _io
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.app import cli
from taichi_hh.validation import fields
from taichi_hh.app import figures
from taichi_hh.app import io as thio
from conftest import ARCH
RUNTIME = ["--arch", ARCH, "--precision", "f64"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run(argv):
    """(exit code, stdout, stderr) of cli.main(argv); SystemExit (argparse) counts."""
    out, err = _io.StringIO(), _io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cli.main([str(a) for a in argv])
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    return rc, out.getvalue(), err.getvalue()


def write_csv(path, points, vectors, header="u,extra,y,v,x"):
    cols = [c.strip().lower() for c in header.split(",")] if header else ["x", "y", "u", "v"]
    with open(path, "w") as fh:
        if header:
            fh.write(header + "\n")
        for p, q in zip(points, vectors):
            val = {"x": p[0], "y": p[1], "u": q[0], "v": q[1], "extra": 1.0}
            fh.write(",".join(repr(float(val[c])) for c in cols) + "\n")


@pytest.fixture(scope="module")
def gaussian_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_fields")
    f = fields.get("gaussian")
    pts = f.sample(1500, seed=0)
    vec = f.evaluate(pts).v
    npz = d / "gauss.npz"
    np.savez(npz, points=pts, vectors=vec)
    csvp = d / "gauss.csv"
    write_csv(csvp, pts, vec)                   # reordered header plus an extra column
    return {"dir": d, "npz": npz, "csv": csvp, "points": pts, "vectors": vec, "field": f}


@pytest.fixture(scope="module")
def decomposed(gaussian_files):
    out = gaussian_files["dir"] / "dec_npz"
    rc, stdout, stderr = run(["decompose", gaussian_files["npz"], "--domain", "0,0,1,1",
                              "-o", out, *RUNTIME])
    return {"rc": rc, "out": out, "stdout": stdout, "stderr": stderr}


# --------------------------------------------------------------------------- decompose
def test_decompose_writes_readable_components(decomposed, gaussian_files):
    assert decomposed["rc"] == 0, decomposed["stderr"]
    with np.load(decomposed["out"] / "components.npz", allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    n = len(gaussian_files["points"])
    for key in ("points", "v", "d", "r", "h"):
        assert data[key].shape == (n, 2), key
    for key in ("phi", "psi", "divergence", "curl"):
        assert data[key].shape == (n,), key
    np.testing.assert_array_equal(data["points"], gaussian_files["points"])
    np.testing.assert_array_equal(data["v"], gaussian_files["vectors"])
    np.testing.assert_allclose(data["d"] + data["r"] + data["h"], data["v"], atol=1e-12)
    assert data["xs"].shape == data["ys"].shape == data["kinds"].shape
    assert sorted(data["kinds"].tolist()) == ["ccw_vortex", "cw_vortex", "sink", "source"]
    exact = {k: (x, y) for x, y, k in gaussian_files["field"].critical_points}
    for x, y, k in zip(data["xs"], data["ys"], data["kinds"]):
        assert np.hypot(x - exact[k][0], y - exact[k][1]) < 0.03, (k, x, y)


def test_decompose_writes_the_components_as_vtu_too(decomposed):
    import meshio
    assert decomposed["rc"] == 0
    mesh = meshio.read(decomposed["out"] / "components.vtu")
    with np.load(decomposed["out"] / "components.npz") as z:
        assert np.array_equal(mesh.points[:, :2], z["points"])
        for key in ("v", "d", "r", "h"):
            assert np.array_equal(mesh.point_data[key][:, :2], z[key]), key
        for key in ("phi", "psi", "divergence", "curl"):
            assert np.array_equal(mesh.point_data[key], z[key]), key


def test_components_match_library(decomposed, gaussian_files):
    assert decomposed["rc"] == 0
    res = thh.decompose(gaussian_files["points"], gaussian_files["vectors"],
                        domain=thh.Box((0, 0), (1, 1)))
    with np.load(decomposed["out"] / "components.npz") as z:
        for key, ref in (("d", res.curl_free), ("r", res.div_free), ("h", res.harmonic),
                         ("phi", res.phi), ("psi", res.psi), ("divergence", res.divergence),
                         ("curl", res.curl)):
            scale = np.abs(ref).max()
            np.testing.assert_allclose(z[key], ref, rtol=0, atol=1e-6 * scale, err_msg=key)
        cps = res.critical_points()
        assert sorted(z["kinds"].tolist()) == sorted(k for _, _, k in cps)


def test_decompose_figures_are_pngs(decomposed):
    import imageio.v3 as iio
    for name in ("arrows.png", "magnitude.png"):
        path = decomposed["out"] / name
        assert path.read_bytes()[:8] == PNG_MAGIC, name
        img = iio.imread(path)
        assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 300
        assert img[..., :3].std() > 10, f"{name} looks blank"
    assert not [p for p in os.listdir(decomposed["out"]) if p.startswith(".tmp-")]


def test_decompose_summary_and_progress(decomposed, gaussian_files):
    err = decomposed["stderr"]
    out = " ".join(decomposed["stdout"].split())            # the summary is wrapped
    n = len(gaussian_files["points"])
    assert f"Decomposed {n} points" in out
    assert "Critical points: 4" in out and "components.npz" in out and "magnitude.png" in out
    assert "Mean |v|" in out and "|h|" in out
    for stage in ("reading", "setup", "natural potentials", "drawing figures"):
        assert stage in err, stage
    # the default chose the natural condition and says why: the field's stream
    # crosses the box's walls
    assert "boundary condition natural (chosen by --boundary-condition auto: the flow " \
        "crosses the boundary, normal flux" in out
    assert "Traceback" not in err


def test_csv_input_gives_the_same_components(decomposed, gaussian_files):
    out = gaussian_files["dir"] / "dec_csv"
    rc, stdout, stderr = run(["decompose", gaussian_files["csv"], "--domain", "0,0,1,1", "-o",
                              out, "--no-figures", "--no-vtk", "-q", *RUNTIME])
    assert rc == 0, stderr
    assert stderr == ""                                   # --quiet
    assert sorted(os.listdir(out)) == ["components.npz"]  # --no-figures --no-vtk
    with np.load(out / "components.npz") as a, \
            np.load(decomposed["out"] / "components.npz") as b:
        np.testing.assert_array_equal(a["points"], b["points"])
        for key in ("d", "r", "h", "phi", "psi"):
            np.testing.assert_allclose(a[key], b[key], rtol=0,
                                       atol=1e-6 * np.abs(b[key]).max(), err_msg=key)


def test_options_only_override_what_is_given():
    from taichi_hh.hhd.decompose import METHODS, options_for
    args = cli.build_parser().parse_args(["decompose", "f.npz", "--method", "petronetto2010",
                                          "--tol", "1e-5", "--no-bordered"])
    over = cli.option_overrides(args)
    assert over == {"tol": 1e-5, "bordered": False}
    opts = options_for(args.method, **over)
    assert opts == dataclasses.replace(METHODS["petronetto2010"], tol=1e-5, bordered=False)
    args = cli.build_parser().parse_args(["decompose", "dir/my.field.csv"])
    assert cli.option_overrides(args) == {}
    assert cli.output_dir(args) == os.path.join("outputs", "my.field_decompose")


def test_positive_rows_takes_a_number_or_off(capsys):
    """--positive-rows: a number >= 1 (the option's float), or off (its None,
    which an option not given cannot say)."""
    from taichi_hh.hhd.decompose import options_for
    parser = cli.build_parser()
    for given, want in (("2", 2.0), ("off", None)):
        args = parser.parse_args(["decompose", "f.npz", "--positive-rows", given])
        over = cli.option_overrides(args)
        assert over == {"positive_rows": want}
        assert options_for("default", **over).positive_rows == want
    with pytest.raises(SystemExit):
        parser.parse_args(["decompose", "f.npz", "--positive-rows", "0.5"])
    assert "must be a number >= 1 or 'off'" in capsys.readouterr().err


# --------------------------------------------------------------------------- project
def test_project(gaussian_files):
    out = gaussian_files["dir"] / "proj"
    rc, stdout, stderr = run(["project", gaussian_files["npz"], "--domain", "0,0,1,1", "-o",
                              out, "--iterations", "2", *RUNTIME])
    assert rc == 0, stderr
    pts, vec = thio.read_field(out / "projected.npz")      # the result is again a field
    np.testing.assert_array_equal(pts, gaussian_files["points"])
    with np.load(out / "projected.npz") as z:
        assert z["max_divergence"].shape == z["sum_sq_divergence"].shape == (3,)
        assert z["max_divergence"][-1] < 0.5 * z["max_divergence"][0]
        np.testing.assert_array_equal(z["initial"], gaussian_files["vectors"])
    with open(out / "measures.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["pass"]) for r in rows] == [0, 1, 2]
    for name in ("projection_arrows.png", "projection_measures.png"):
        data = (out / name).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 5000, name
    assert "Projected 1" in stdout and "2 passes" in stdout and "projection 2/2" in stderr


# --------------------------------------------------------------------------- bad input
def _bad_files(d, pts, vec):
    files = {}
    p = d / "no_v.csv"
    write_csv(p, pts[:50], vec[:50], header="x,y,u")
    files["no_column"] = p
    p = d / "inf.csv"
    write_csv(p, pts[:50], vec[:50], header="x,y,u,v")
    lines = p.read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",inf"           # file line 4
    p.write_text("\n".join(lines) + "\n")
    files["inf_csv"] = p
    p = d / "word.csv"
    write_csv(p, pts[:50], vec[:50], header="")
    lines = p.read_text().splitlines()
    lines[6] = "0.5,0.5,abc,0.1"                              # file line 7
    p.write_text("\n".join(lines) + "\n")
    files["word_csv"] = p
    v = vec.copy()
    v[10, 1] = np.inf
    p = d / "inf.npz"
    np.savez(p, points=pts, vectors=v)
    files["inf_npz"] = p
    p = d / "missing_array.npz"
    np.savez(p, points=pts, velocity=vec)
    files["missing_array"] = p
    p = d / "shape.npz"
    np.savez(p, points=pts, vectors=np.c_[vec, vec[:, :1]])
    files["shape"] = p
    p = d / "notzip.npz"
    p.write_text("hello")
    files["notzip"] = p
    return files


@pytest.fixture(scope="module")
def bad_files(gaussian_files, tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_bad")
    return d, _bad_files(d, gaussian_files["points"], gaussian_files["vectors"])


@pytest.mark.parametrize("case, extra, message", [
    ("missing", [], "no such file"),
    ("no_column", [], "lacks column(s) v"),
    ("inf_csv", [], "line 4: column v is 'inf'"),
    ("word_csv", [], "line 7: column u is not a number"),
    ("inf_npz", [], "with inf, first at index 10"),
    ("missing_array", [], "missing array(s) vectors"),
    ("shape", [], "shape (N, 2)"),
    ("notzip", [], "not a readable .npz"),
    ("good", ["--domain", "0,0,0.5,0.5"], "outside the domain"),
    ("good", ["--domain", "0,0,1"], "four numbers"),
    ("good", ["--domain", "1,0,0,1"], "x0 < x1"),
    ("good", ["--domain", "nowhere.json"], "no such file"),
    ("good", ["--max-iterations", "2", "--boundary-condition", "neumann"], "max_iterations"),
    ("good", ["--support-ratio", "0.8"], "no neighbour within the kernel support"),
])
def test_bad_input_exits_2_with_one_line(case, extra, message, bad_files, gaussian_files):
    d, files = bad_files
    field = d / "missing.npz" if case == "missing" else (
        gaussian_files["npz"] if case == "good" else files[case])
    out = d / f"out_{case}_{len(extra)}_{abs(hash(tuple(extra)))}"
    rc, stdout, stderr = run(["decompose", field, "-o", out, "-q", *extra, *RUNTIME])
    assert rc == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("taichi-hh decompose: error: "), stderr
    assert message in lines[0], lines[0]
    assert "Traceback" not in stderr
    assert not (out / "components.npz").exists()


def test_project_refuses_petronetto_boundary(gaussian_files, tmp_path):
    rc, _, stderr = run(["project", gaussian_files["npz"], "-o", tmp_path / "p", "-q",
                         "--method", "petronetto2010", *RUNTIME])
    assert rc == 2 and stderr.startswith("taichi-hh project: error: ") and "boundary" in stderr


def test_bad_option_values_are_usage_errors(gaussian_files):
    for opt in (["--tol", "-1"], ["--support-ratio", "0"], ["--kernel", "gauss"],
                ["--max-iterations", "1.5"]):
        rc, _, stderr = run(["decompose", gaussian_files["npz"], *opt, *RUNTIME])
        assert rc == 2 and opt[0] in stderr and "Traceback" not in stderr


def test_python_dash_m_reports_errors(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [os.path.dirname(os.path.dirname(os.path.abspath(thh.__file__)))] +
        [p for p in [os.environ.get("PYTHONPATH")] if p]))
    proc = subprocess.run([sys.executable, "-m", "taichi_hh", "decompose",
                           str(tmp_path / "none.csv"), *RUNTIME], capture_output=True,
                          text=True, env=env, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == \
        f"taichi-hh decompose: error: {tmp_path / 'none.csv'}: no such file"
    assert "Traceback" not in proc.stderr
    assert proc.stdout == ""


# --------------------------------------------------------------------------- help
@pytest.mark.parametrize("command", ["decompose", "project"])
def test_help_mentions_every_option(command):
    from taichi_hh.hhd.decompose import HHDOptions
    rc, out, _ = run([command, "--help"])
    assert rc == 0
    flags = ["--" + f.name.replace("_", "-") for f in dataclasses.fields(HHDOptions)
             if f.name not in cli.LIBRARY_ONLY_OPTIONS]
    flags += ["--domain", "--out", "--method", "--arch", "--precision", "--no-figures",
              "--quiet", "FIELD"]
    flags += ["--critical-threshold"] if command == "decompose" else ["--iterations"]
    for flag in flags:
        assert flag in out, flag
    parser = cli.build_parser()
    sub = parser._subparsers._group_actions[0].choices[command]
    for action in sub._actions:
        assert action.help and len(action.help) > 10, action.dest     # every option explained
    assert "default" in out and "petronetto2010" in out and "wendland" in out


def test_top_level_help():
    rc, out, _ = run(["--help"])
    assert rc == 0 and "decompose" in out and "project" in out


# --------------------------------------------------------------------------- readers
def test_read_field_csv_variants(tmp_path):
    pts = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    vec = np.array([[1.0, -1.0], [2.0, -2.0], [3.0, 1e-3]])
    p = tmp_path / "plain.csv"
    p.write_text("# a comment\n\n" + "\n".join(
        f"{a},{b},{c},{d}" for (a, b), (c, d) in zip(pts, vec)) + "\n")
    got = thio.read_field(p)
    np.testing.assert_array_equal(got[0], pts)
    np.testing.assert_array_equal(got[1], vec)
    p = tmp_path / "header.csv"
    write_csv(p, pts, vec, header=" V , X,extra,Y,U")
    got = thio.read_field(p)
    np.testing.assert_array_equal(got[0], pts)
    np.testing.assert_array_equal(got[1], vec)
    p = tmp_path / "five.csv"
    p.write_text("1,2,3,4,5\n")
    with pytest.raises(thh.InputError, match="line 1: without a header .* exactly 4"):
        thio.read_field(p)
    p = tmp_path / "short.csv"
    p.write_text("x,y,u,v\n1,2,3,4\n1,2,3\n")
    with pytest.raises(thh.InputError, match="line 3: expected 4 columns"):
        thio.read_field(p)
    p = tmp_path / "field.txt"                   # text: the PIV readers take it
    p.write_text("1,2,3,4\n")
    assert thio.read_field(p)[0].tolist() == [[1.0, 2.0]]
    p = tmp_path / "field.xyz"
    p.write_text("1,2,3,4\n")
    with pytest.raises(thh.InputError, match="unknown field format"):
        thio.read_field(p)


def test_read_domain(tmp_path):
    box = thio.read_domain("-1, -2, 3, 4")
    assert isinstance(box, thh.Box) and box.lo == (-1.0, -2.0) and box.hi == (3.0, 4.0)
    h = fields.get("hole").domain
    p = tmp_path / "hole.json"
    p.write_text(json.dumps({"outer": h.outer.tolist(), "holes": [r.tolist() for r in h.holes]}))
    poly = thio.read_domain(str(p))
    assert isinstance(poly, thh.Polygon) and len(poly.holes) == 1
    assert poly.area == pytest.approx(h.area)
    p.write_text('{"outer": [[0, 0], [1, 0]]}')
    with pytest.raises(thh.InputError, match="domain file"):
        thio.read_domain(str(p))
    p.write_text('{"outer": [[0, 0], [1, 0], [1, 1]], "hole": []}')
    with pytest.raises(thh.InputError, match="unknown key"):
        thio.read_domain(str(p))
    args = cli.build_parser().parse_args(["decompose", "f.npz", "--domain=-1,-1,1,1"])
    assert thio.read_domain(args.domain) == thh.Box((-1, -1), (1, 1))


# --------------------------------------------------------------------------- figures
def test_even_subsample_and_masked_triangulation():
    f = fields.get("hole")
    pts = f.sample(3000, seed=2)
    idx = figures.even_subsample(pts, f.domain)
    assert 400 <= len(idx) <= 900 and len(np.unique(idx)) == len(idx)
    tri = figures.masked_triangulation(pts, f.domain)
    kept = tri.triangles[~tri.mask]
    centroids = pts[kept].mean(axis=1)
    assert f.domain.contains(centroids).all()
    assert tri.mask.any()                                   # the hole's triangles are gone
    assert len(figures.even_subsample(pts[:100], f.domain)) == 100


def _module_run(*args):
    env = dict(os.environ)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "taichi_hh", *args], capture_output=True,
                          text=True, env=env, timeout=300)


def test_version_and_info_print_only_their_own_lines():
    proc = _module_run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"taichi-hh {thh.__version__}"
    proc = _module_run("info", "--arch", "auto")
    assert proc.returncode == 0 and proc.stderr == ""
    lines = proc.stdout.splitlines()
    assert lines[0].startswith(f"taichi_hh {thh.__version__}: Taichi arch=")
    assert all(not ln.startswith("[") for ln in lines)           # no Taichi log line
    assert len(lines) <= 2


def test_boolean_options_are_flags_not_strings():
    parser = cli.build_parser()
    args = parser.parse_args(["decompose", "f.csv", "--no-remove-mean", "--bordered"])
    assert args.remove_mean is False and args.bordered is True
    assert parser.parse_args(["decompose", "f.csv", "--remove-mean"]).remove_mean is True
    assert parser.parse_args(["decompose", "f.csv"]).remove_mean is None    # the bundle's value
    with pytest.raises(SystemExit):
        with contextlib.redirect_stderr(_io.StringIO()):
            parser.parse_args(["decompose", "f.csv", "--remove-mean", "no"])


def test_help_names_each_default_once(scene_module):
    mod = scene_module("rising_droplet")
    out = _io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        mod.main(mod.SCENE, ["--help"])
    text = " ".join(out.getvalue().split())
    options = text.split(" --")
    assert not [o for o in options if o.count("(default") > 1]
    assert "(default: 10500)" in text                            # a plain default is shown


def test_scene_subcommand_runs_the_installed_scene(tmp_path):
    """``taichi-hh scene NAME`` runs the scene defined in the package (what the
    scripts in scenes/ run), with the scene's own options."""
    rc, _, err = run(["scene", "rayleigh-taylor", "--particles", "800", "--end-time", "0.1",
                      "--out", tmp_path / "rt", "--quiet", "--frame-width", "100", "--no-vtk"])
    assert rc == 0, err
    assert sorted(p.name for p in (tmp_path / "rt").glob("frame_*.png")) == \
        ["frame_00000.png", "frame_00001.png"]
    with open(tmp_path / "rt" / "diagnostics.csv") as fh:
        assert "mode_amplitude" in fh.readline()
    rc, _, err = run(["scene", "no-such-scene"])
    assert rc == 2 and "invalid choice" in err


def test_decompose_leaves_out_missing_rows(gaussian_files, tmp_path):
    """A CSV with NaN vectors, an empty cell and a ``valid`` column: the rows are
    left out and counted in the summary, NaN in components.npz, the figures
    drawn from the valid rows; ``--domain alpha`` is made from the valid points."""
    pts, vec = gaussian_files["points"], gaussian_files["vectors"]
    path = tmp_path / "gaps.csv"
    with open(path, "w") as fh:
        fh.write("x,y,u,v,valid\n")
        for k, (p, q) in enumerate(zip(pts, vec)):
            u = "nan" if k % 50 == 7 else repr(float(q[0]))
            v = "" if k % 50 == 9 else repr(float(q[1]))
            fh.write(f"{float(p[0])!r},{float(p[1])!r},{u},{v},{0 if k % 50 == 11 else 1}\n")
    missing = np.array([k % 50 in (7, 9, 11) for k in range(len(pts))])
    out = tmp_path / "out"
    rc, stdout, err = run(["decompose", path, "-o", out, "--quiet", *RUNTIME])
    assert rc == 0, err
    assert f"Decomposed {len(pts) - missing.sum()} points" in stdout
    assert f"({missing.sum()} rows missing" in stdout
    with np.load(out / "components.npz") as z:
        assert np.isnan(z["d"][missing]).all() and np.isfinite(z["d"][~missing]).all()
    assert (out / "arrows.png").read_bytes()[:8] == PNG_MAGIC
    rc, stdout, err = run(["decompose", path, "-o", tmp_path / "alpha", "--quiet",
                           "--domain", "alpha", "--no-figures", *RUNTIME])
    assert rc == 0, err


def test_a_grid_listed_node_by_node_is_decomposed_as_a_grid(tmp_path):
    """PIV text exports list every node, invalid ones as NaN: the CLI finds the
    grid, cuts the masked block out of the domain and uses the natural
    condition; with --domain it decomposes the points as given."""
    f = fields.get("gaussian")
    x = np.linspace(0.01, 0.99, 40)
    X, Y = np.meshgrid(x, x)
    pts = np.c_[X.ravel(), Y.ravel()]
    vec = f.evaluate(pts).v
    block = (np.abs(pts[:, 0] - 0.5) < 0.1) & (np.abs(pts[:, 1] - 0.5) < 0.1)
    vec[block] = np.nan
    path = tmp_path / "piv.csv"
    write_csv(path, pts, vec, header="x,y,u,v")
    out = tmp_path / "out"
    rc, stdout, err = run(["decompose", path, "-o", out, "--quiet", "--no-figures", *RUNTIME])
    assert rc == 0, err
    stdout = " ".join(stdout.split())                        # the summary is wrapped
    assert "(a 40 x 40 grid: its domain from the valid nodes)" in stdout
    assert f"Decomposed {len(pts) - block.sum()} points" in stdout
    assert "free-space potentials" in stdout                 # the natural condition
    with np.load(out / "components.npz") as z:
        assert np.isnan(z["d"][block]).all() and np.isfinite(z["d"][~block]).all()
        np.testing.assert_array_equal(z["points"], pts)
    rc, stdout, err = run(["decompose", path, "-o", tmp_path / "box", "--quiet", "--no-figures",
                           "--domain", "0,0,1,1", *RUNTIME])
    assert rc == 0, err
    stdout = " ".join(stdout.split())
    assert "x 40 grid" not in stdout and "chosen by --boundary-condition auto" in stdout


def test_figures_scales_are_robust_and_say_so(tmp_path):
    """One spike does not set the arrow or colour scale; axes carry the unit;
    a flagged h is titled so."""
    rng = np.random.default_rng(0)
    values = rng.random(5000)
    spiked = values.copy()
    spiked[7] = 1e6
    assert figures.robust_top(spiked) == pytest.approx(figures.robust_top(values), rel=1e-3)
    assert figures.robust_top([np.nan, np.inf]) == 0.0
    f = fields.get("trig")
    pts = f.sample(600, seed=1)
    v = f.evaluate(pts).v
    res = thh.decompose(pts, v, f.domain)
    res.stats["flags"] = ["h is not harmonic: test"]
    assert "NOT harmonic" in figures.component_titles(res)["h"]
    box = thh.Box((0, 0), (1, 1))
    fig = figures.new_figure(3, 3)
    ax = fig.subplots()
    figures.setup_axes(ax, box, "t", "mm")
    assert ax.get_xlabel() == "x [mm]" and ax.get_ylabel() == "y [mm]"
    paths = figures.decomposition_figures(res, f.domain, tmp_path, units="mm")
    assert all(open(p, "rb").read(8) == PNG_MAGIC for p in paths)


def test_messages_name_the_remedy_in_command_line_syntax(gaussian_files, tmp_path):
    """The library's advice (``invalid='missing'``, ``boundary_condition='natural'``)
    reaches the command line as ``--invalid missing``, ``--boundary-condition
    natural``; names that are no option stay as they are."""
    from taichi_hh.app.errors_report import option_rewriter
    rewrite = option_rewriter(cli.build_parser())
    assert rewrite("use boundary_condition='natural' or tol=1e-6; valid=False rows") == \
        "use --boundary-condition natural or --tol 1e-6; valid=False rows"
    pts, vec = gaussian_files["points"][:300], gaussian_files["vectors"][:300].copy()
    vec[3] = np.nan
    path = tmp_path / "gap.csv"
    write_csv(path, pts, vec, header="x,y,u,v")
    rc, out, err = run(["decompose", path, "-o", tmp_path / "o", "--quiet", "--no-figures",
                        "--invalid", "error", *RUNTIME])
    assert rc == 2 and "--invalid missing (the default)" in err and "invalid='" not in err


def test_alpha_sets_the_radius_of_domain_alpha_and_its_messages_use_the_command_line(tmp_path):
    """--alpha A: the alpha shape's radius with --domain alpha (refused without
    it, on one line).  Data in two pieces at the default radius (a lattice with
    a gap 6 spacings wide) are refused with the radius that joins them as
    --alpha, never with --domain alpha again; with --alpha 5 the gap is filled
    and the field decomposes."""
    import re
    x, y = np.meshgrid(np.arange(20.0), np.arange(10.0))
    pts = np.c_[x.ravel(), y.ravel()]
    pts = pts[(pts[:, 0] <= 7) | (pts[:, 0] >= 13)]
    path = tmp_path / "gap.npz"
    np.savez(path, points=pts, vectors=np.c_[np.sin(pts[:, 1] / 3), np.cos(pts[:, 0] / 4)])
    common = ["--quiet", "--no-figures", "--no-vtk", *RUNTIME]
    assert cli.build_parser().parse_args(["decompose", "f.npz", "--alpha", "5"]).alpha == 5.0
    from taichi_hh.app.errors_report import option_rewriter
    assert option_rewriter(cli.build_parser())("give domain=('alpha', 3.1) or domain='hull'") \
        == "give --domain alpha --alpha 3.1 or --domain hull"
    for command in ("decompose", "project"):
        rc, _, err = run([command, path, "-o", tmp_path / command, "--domain", "alpha", *common])
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert "2 pieces" in err and "give --domain alpha --alpha 3.1 or more, or --domain hull" \
            in err, err
        assert re.search(r"--domain alpha(?! --alpha)", err) is None
        assert "alpha=" not in err and "domain=" not in err and "near (13, " in err
    rc, out, err = run(["decompose", path, "-o", tmp_path / "joined", "--domain", "alpha",
                        "--alpha", "5", *common])
    assert rc == 0, err
    with np.load(tmp_path / "joined" / "components.npz") as z:
        assert np.isfinite(z["h"]).all()
    for extra in ([], ["--domain", "hull"], ["--domain", "0,0,19,9"]):
        rc, _, err = run(["decompose", path, "-o", tmp_path / "refused", "--alpha", "5",
                          *extra, *common])
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert "--alpha 5 (the alpha shape's radius) applies only with --domain alpha" in err
    rc, _, err = run(["decompose", path, "--domain", "alpha", "--alpha", "0", *common])
    assert rc == 2 and "--alpha" in err and "positive" in err
