"""Cheaper Python-to-IR transforms of Taichi kernels (paid in every process).

Taichi 1.7's offline cache keeps a kernel's compiled code, not the transform
of its Python source into Taichi's IR: every process walks every kernel's
syntax tree again, function calls inlined and ``ti.static`` loops unrolled
(one node visited many times), before the cache is even looked up.  Two
helpers of that walk cost more than the walk itself and return the same
answer for the same input every time:

* ``ASTTransformerContext.get_pos_info(node)``, the "File ..., line ..."
  text with a caret line under the node, built with ``textwrap`` for every
  node visited (for error messages and the IR's debug information): 59k
  calls for 5.8k distinct texts in a 4k-point natural decomposition and its
  critical points;
* ``getsourcefile`` and ``getsourcelines`` of the function (a scan of
  ``sys.modules`` and a tokenisation of its file) at each call of a
  ``ti.func`` being inlined.

:func:`install` memoises both; the texts are computed by Taichi's own code on
the first request, so errors and the IR (and with it the offline cache's
keys) are unchanged.  The kernels' transforms took 58% less time (a CLI
decomposition of 4000 points: ``benchmarks/cli_startup.py``).  Where
Taichi's layout differs (another version), nothing is changed.
"""
from __future__ import annotations

_installed = False
#: Taichi's own helpers, by name, once :func:`install` replaced them
originals: dict = {}
#: memoised texts kept at most (a process compiling many kernels clears the
#: table past it rather than growing without end)
MAX_TEXTS = 200_000


def install() -> bool:
    """Memoise the two helpers (once per process); True where Taichi's layout
    is the one expected."""
    global _installed
    if _installed:
        return True
    try:
        from taichi.lang import kernel_impl
        from taichi.lang.ast import ast_transformer_utils
        context = ast_transformer_utils.ASTTransformerContext
        pos_info = context.get_pos_info
        source_file = kernel_impl.getsourcefile
        source_lines = kernel_impl.getsourcelines
    except (ImportError, AttributeError):
        return False
    texts = {}

    def get_pos_info(self, node):
        try:
            end = node.end_lineno
            body = getattr(node, "body", None)
            # everything Taichi's text reads: the file, function and offsets,
            # the node's place and kind, its body's first line, its source lines
            key = (self.file, self.func.func.__name__, self.lineno_offset, self.indent,
                   node.lineno, end, node.col_offset, node.end_col_offset,
                   type(node).__name__,
                   body[0].lineno if isinstance(body, list) and body else None,
                   tuple(self.src[node.lineno - 1:end]))
        except (AttributeError, TypeError, IndexError):
            return pos_info(self, node)
        text = texts.get(key)
        if text is None:
            if len(texts) >= MAX_TEXTS:
                texts.clear()
            text = texts[key] = pos_info(self, node)
        return text

    files, lines = {}, {}

    def getsourcefile(obj):
        try:
            return files[obj]
        except KeyError:
            got = files[obj] = source_file(obj)
            return got
        except TypeError:                     # not hashable
            return source_file(obj)

    def getsourcelines(obj):
        try:
            src, start = lines[obj]
        except KeyError:
            src, start = lines[obj] = source_lines(obj)
        except TypeError:
            return source_lines(obj)
        return list(src), start

    originals.update(get_pos_info=pos_info, getsourcefile=source_file,
                     getsourcelines=source_lines)
    context.get_pos_info = get_pos_info
    kernel_impl.getsourcefile = getsourcefile
    kernel_impl.getsourcelines = getsourcelines
    _installed = True
    return True
