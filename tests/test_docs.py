"""Every Python snippet in the README and docs/ runs as written."""
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))


def snippets():
    for path in DOCS:
        text = path.read_text()
        for k, block in enumerate(re.findall(r"```python\n(.*?)```", text, flags=re.S)):
            yield pytest.param(block, id=f"{path.relative_to(ROOT)}#{k}")


@pytest.mark.parametrize("code", list(snippets()))
def test_snippet_runs(code, tmp_path):
    script = tmp_path / "snippet.py"
    script.write_text(code)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]


# The public names the API reference must document (taichi_hh.html), and one
# page per subpackage.
API_NAMES = ["decompose", "project", "Box", "Polygon", "PointSet", "init", "HHDResult",
             "ProjectionResult", "InputError", "NeighbourError", "SolverError",
             "TaichiHHError", "AccuracyWarning"]
API_PAGES = ["taichi_hh.html"] + [f"taichi_hh/{name}.html" for name in
                                  ("sph", "geometry", "linalg", "hhd", "flow", "validation", "app")]


def test_api_reference_builds(tmp_path):
    # CI installs the test extra, which has pdoc; only a bare environment skips.
    pytest.importorskip("pdoc")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, str(ROOT / "docs" / "build_api.py"), "-o", str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    for page in API_PAGES:
        assert (tmp_path / page).is_file(), page
    top = (tmp_path / "taichi_hh.html").read_text()
    missing = [name for name in API_NAMES if f'id="{name}"' not in top]
    assert not missing, f"not documented in taichi_hh.html: {missing}"
    # pdoc warns (and drops the name) when a public name does not resolve
    assert "does not resolve" not in proc.stderr, proc.stderr[-2000:]
    # the public entry points carry their docstrings into the page
    assert "Helmholtz-Hodge" in top
