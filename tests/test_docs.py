"""Every code snippet in the README and docs/ runs as written.

The snippets of one page run in order in one scratch directory (a guide's
later snippet reads what an earlier one wrote): ``python`` blocks with this
interpreter, ``bash`` blocks with bash, where a line starting with
``taichi-hh`` runs ``python -m taichi_hh`` and one starting with ``python``
this interpreter, the checkout on PYTHONPATH.  An HTML comment on the line
before a block's fence changes that:

* ``<!-- ci:test -->``: not run here; CI runs it (.ci/run);
* ``<!-- doc:not-run: REASON -->``: not run, for the reason given (required);
* ``<!-- doc:slow -->``: run by ``pytest -m slow`` only (the slow test runs
  every runnable block of the page, the default test all but these).
"""
import os
import pathlib
import re
import shlex
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))
FENCE = re.compile(r"(?:^(<!--[^\n]*?-->)[ \t]*\n)?^```(python|bash|sh|console)[ \t]*\n(.*?)^```",
                   flags=re.S | re.M)


def blocks(path):
    """[(language, code, marker)] of the page, in order."""
    return [(lang, code, (marker or "").strip()) for marker, lang, code in
            FENCE.findall(path.read_text())]


def page_id(path):
    return str(path.relative_to(ROOT))


def _bash(code: str) -> str:
    py = shlex.quote(sys.executable)
    lines = []
    for line in code.splitlines():
        stripped = line.lstrip()
        indent = line[:len(line) - len(stripped)]
        if stripped.startswith("taichi-hh "):
            line = f"{indent}{py} -m taichi_hh {stripped[len('taichi-hh '):]}"
        elif stripped.startswith("python "):
            line = f"{indent}{py} {stripped[len('python '):]}"
        lines.append(line)
    return "\n".join(lines) + "\n"


def run_page(path, tmp_path, slow: bool):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    ran = 0
    for k, (lang, code, marker) in enumerate(blocks(path)):
        if marker.startswith("<!-- ci:test") or marker.startswith("<!-- doc:not-run"):
            continue
        if marker.startswith("<!-- doc:slow") and not slow:
            continue
        if lang == "python":
            script = tmp_path / f"snippet_{k}.py"
            script.write_text(code)
            cmd = [sys.executable, str(script)]
        else:
            script = tmp_path / f"snippet_{k}.sh"
            script.write_text(_bash(code))
            cmd = ["bash", "-euo", "pipefail", str(script)]
        proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=900)
        first = code.strip().splitlines()[0] if code.strip() else ""
        assert proc.returncode == 0, (f"{page_id(path)} block {k} ({lang}: {first!r}) failed:\n"
                                      + proc.stderr[-2000:])
        ran += 1
    return ran


PAGES = [p for p in DOCS if blocks(p)]


@pytest.mark.parametrize("path", PAGES, ids=page_id)
def test_page_snippets_run(path, tmp_path):
    run_page(path, tmp_path, slow=False)


SLOW_PAGES = [p for p in PAGES if any(m.startswith("<!-- doc:slow") for _, _, m in blocks(p))]


@pytest.mark.slow
@pytest.mark.parametrize("path", SLOW_PAGES, ids=page_id)
def test_page_snippets_run_with_the_slow_ones(path, tmp_path):
    run_page(path, tmp_path, slow=True)


def test_every_code_block_is_runnable_or_says_why_not():
    """No code block escapes the tests silently: each is python or bash, and
    one that is not run names its reason."""
    for path in DOCS:
        text = path.read_text()
        fences = re.findall(r"^```(\S*)[ \t]*\n", text, flags=re.M)
        # fences alternate open, close; the opening ones carry the language
        for lang in fences[0::2]:
            assert lang in ("python", "bash", "sh", "console", "text", "toml", "json"), \
                f"{page_id(path)}: a ```{lang or '(no language)'} block; runnable blocks are " \
                "python or bash, listings text/toml/json"
        runnable = [lang for lang in fences[0::2] if lang in ("python", "bash", "sh", "console")]
        assert len(blocks(path)) == len(runnable), f"{page_id(path)}: a block the tests do not see"
        for _, _, marker in blocks(path):
            if marker.startswith("<!-- doc:not-run"):
                assert re.match(r"<!-- doc:not-run: \S", marker), \
                    f"{page_id(path)}: {marker} gives no reason"
    readme = blocks(ROOT / "README.md")
    assert [m for _, _, m in readme].count("<!-- ci:test -->") == 1


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
    # the public entry points carry their docstrings into the page, Sphinx
    # roles rendered (no ":class:" or "~module.Name" left in the text)
    assert "Helmholtz-Hodge" in top
    prose = re.sub(r'<div class="pdoc-code codehilite">.*?</div>', "", top, flags=re.S)
    assert ":class:`" not in prose and ">~taichi_hh." not in prose


def _anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def test_links_and_figures_resolve():
    """Every relative link and image of README and docs/ points at a file of the
    checkout (and an anchor at a heading of that page)."""
    for path in DOCS:
        text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue                       # http(s), mailto
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            assert dest.exists(), f"{page_id(path)}: link to missing {target}"
            if anchor and dest.suffix == ".md":
                headings = re.findall(r"^#+ (.*)$", dest.read_text(), flags=re.M)
                assert anchor in {_anchor(h) for h in headings}, \
                    f"{page_id(path)}: no heading for #{anchor} in {file or page_id(path)}"
