"""The memoised helpers of Taichi's kernel transform (taichi_hh.kernel_transform)
return what Taichi's own return, and compile errors still name the place."""
import numpy as np
import pytest
import taichi as ti

from taichi_hh import kernel_transform


@ti.func
def _scaled(x, k: ti.template()):
    out = x
    for _ in ti.static(range(k)):      # unrolled: the same nodes visited k times
        out = out * 2.0 + 1.0
    return out


@ti.kernel
def _twice(a: ti.types.ndarray(), b: ti.types.ndarray()):
    for i in range(a.shape[0]):
        b[i] = _scaled(a[i], 3) + _scaled(a[i] - 1.0, 2)


@ti.kernel
def _broken(a: ti.types.ndarray()):
    for i in range(a.shape[0]):
        a[i] = a[i] + no_such_name   # noqa: F821  (the error under test)


def test_installed_with_taichi_1_7():
    assert kernel_transform.install()
    assert set(kernel_transform.originals) == {"get_pos_info", "getsourcefile", "getsourcelines"}


def test_texts_equal_taichis_own():
    """Every position text the transform asked for while compiling a kernel
    (with an inlined function and an unrolled loop) is Taichi's own text for
    that node."""
    from taichi.lang.ast import ast_transformer_utils
    context = ast_transformer_utils.ASTTransformerContext
    memoised = context.get_pos_info
    asked = []

    def recording(self, node):
        text = memoised(self, node)
        asked.append((self, node, text))
        return text

    context.get_pos_info = recording
    try:
        a = np.arange(5, dtype=np.float64)
        b = np.zeros(5)
        _twice(a, b)
    finally:
        context.get_pos_info = memoised
    x = a
    for _ in range(3):
        x = x * 2 + 1
    y = a - 1
    for _ in range(2):
        y = y * 2 + 1
    np.testing.assert_allclose(b, x + y)
    assert len(asked) > 50
    assert len({t for _, _, t in asked}) < len(asked)          # some texts asked again
    original = kernel_transform.originals["get_pos_info"]
    for ctx, node, text in asked:
        assert text == original(ctx, node)


def test_compile_error_names_the_place():
    with pytest.raises(Exception) as info:
        _broken(np.zeros(3))
    message = str(info.value)
    assert "test_kernel_transform.py" in message
    assert "no_such_name" in message
    line = next(i for i, ln in enumerate(open(__file__).read().splitlines(), 1)
                if "a[i] + no_such_name" in ln)
    assert f"line {line}" in message
    assert "^" in message
