"""Build the API reference from the docstrings with pdoc: ``python docs/build_api.py [-o DIR]``.

Writes HTML for ``taichi_hh`` and each of its subpackages (default ``docs/api/``,
not committed; open ``index.html``).  Needs pdoc (``pip install -e ".[test]"``
installs it).  Why a script rather than ``pdoc taichi_hh``: the package's
``__all__`` names only its API, so pdoc would not descend into the
subpackages, and ``decompose``, ``project``, ``PointSet`` and the result
classes load on first use (they import Taichi), which pdoc does not trigger.
"""
import argparse
import pathlib
import re
import sys

SUBPACKAGES = ["sph", "geometry", "linalg", "hhd", "flow", "validation", "app"]
MODULES = ["taichi_hh"] + [f"taichi_hh.{name}" for name in SUBPACKAGES]


def _sphinx_tilde(rst):
    """Wrap pdoc's reST conversion: Sphinx's ``:class:`~a.b.C``` (shown as ``C``)
    becomes ``:class:`a.b.C```, which pdoc shows and links; without this the
    tilde is printed."""
    def convert(contents, *args, **kwargs):
        return rst(re.sub(r"(:[a-z]+:`)~", r"\1", contents), *args, **kwargs)
    return convert


def build(output_directory):
    """Write the HTML reference of :data:`MODULES` into ``output_directory``."""
    import pdoc
    import pdoc.docstrings
    import pdoc.render

    if hasattr(pdoc.docstrings, "rst"):
        pdoc.docstrings.rst = _sphinx_tilde(pdoc.docstrings.rst)

    import taichi_hh
    for name in taichi_hh.__all__:
        getattr(taichi_hh, name)  # load the lazy names, so pdoc finds them in the module
    pdoc.render.configure(docformat="restructuredtext", math=False, search=True,
                          footer_text=f"taichi-hh {taichi_hh.__version__}")
    pdoc.pdoc(*MODULES, output_directory=pathlib.Path(output_directory))


def main(argv=None):
    root = pathlib.Path(__file__).resolve().parent.parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default=str(root / "docs" / "api"),
                        help="output directory (default: docs/api in the checkout)")
    args = parser.parse_args(argv)
    try:
        import pdoc  # noqa: F401
    except ImportError:
        sys.exit("build_api: pdoc is not installed (pip install -e \".[test]\" or pip install pdoc)")
    build(args.output)
    print(f"API reference written to {args.output}/index.html")


if __name__ == "__main__":
    main()
