"""taichi_hh.arrays: the column-by-column reductions equal numpy's axis
reductions (bit for bit where the order of the sum is not involved)."""
import numpy as np
import pytest

from taichi_hh import arrays


@pytest.mark.parametrize("k", [1, 2, 3])
def test_column_reductions_are_numpys(k):
    rng = np.random.default_rng(k)
    a = rng.standard_normal((1001, k)) * 10.0 ** rng.integers(-3, 4, size=k)
    lo, hi = arrays.bounds(a)
    assert np.array_equal(lo, a.min(axis=0)) and np.array_equal(hi, a.max(axis=0))
    # a mean's sum runs in another order: equal to its rounding
    assert np.allclose(arrays.column_mean(a), a.mean(axis=0), rtol=1e-14, atol=0)
    flags = a > 0.5
    assert np.array_equal(arrays.rows_any(flags), flags.any(axis=1))


def test_rows_all_finite_names_the_bad_rows_only_when_there_are_some():
    a = np.random.default_rng(0).random((50, 2))
    assert arrays.rows_all_finite(a) is None
    a[[3, 7, 7, 40], [1, 0, 1, 0]] = [np.nan, np.inf, -np.inf, np.nan]
    ok = arrays.rows_all_finite(a)
    assert np.array_equal(ok, np.isfinite(a).all(axis=1))
    assert np.flatnonzero(~ok).tolist() == [3, 7, 40]
