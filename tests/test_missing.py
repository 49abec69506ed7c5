"""Missing data as instruments deliver it: NaN rows (pivpy, xarray), numpy
masks, a ``valid`` array, and invalid vectors written as exact zeros."""
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import AccuracyWarning, InputError
from taichi_hh.validation import fields

TRIG = fields.get("trig")


@pytest.fixture(scope="module")
def field_with_gaps():
    pts = TRIG.sample(1500, "random", seed=7)
    v = TRIG.evaluate(pts).v
    rng = np.random.default_rng(3)
    gone = np.zeros(len(pts), dtype=bool)
    gone[rng.choice(len(pts), 60, replace=False)] = True
    return pts, v, gone


def test_nan_rows_are_left_out_and_nan_in_the_result(field_with_gaps):
    pts, v, gone = field_with_gaps
    holed = v.copy()
    holed[gone, 0] = np.nan                   # one NaN component makes the row missing
    res = thh.decompose(pts, holed, (0, 0, 1, 1))
    alone = thh.decompose(pts[~gone], v[~gone], (0, 0, 1, 1))
    assert res.stats["n_invalid"] == gone.sum()
    assert res.valid.tolist() == (~gone).tolist()
    for got, want in ((res.curl_free, alone.curl_free), (res.div_free, alone.div_free),
                      (res.harmonic, alone.harmonic)):
        assert got.shape == v.shape
        assert np.isnan(got[gone]).all()
        np.testing.assert_array_equal(got[~gone], want)
    for got, want in ((res.phi, alone.phi), (res.psi, alone.psi),
                      (res.divergence, alone.divergence), (res.curl, alone.curl)):
        assert got.shape == (len(pts),) and np.isnan(got[gone]).all()
        np.testing.assert_array_equal(got[~gone], want)
    np.testing.assert_array_equal(res.points, pts)            # aligned with the input
    assert np.isnan(res.vectors[gone]).all()
    # the critical points are those of the valid rows
    assert [c[:3] for c in res.critical_points()] == [c[:3] for c in alone.critical_points()]


def test_masks_and_valid_are_missing_like_nan(field_with_gaps):
    pts, v, gone = field_with_gaps
    ref = thh.decompose(pts[~gone], v[~gone], (0, 0, 1, 1))
    masked = np.ma.masked_array(v, mask=np.c_[gone, np.zeros_like(gone)])
    by_mask = thh.decompose(pts, masked, (0, 0, 1, 1))
    by_valid = thh.decompose(pts, v, (0, 0, 1, 1), valid=~gone)
    masked_points = np.ma.masked_array(pts, mask=np.c_[gone, gone])
    by_point_mask = thh.decompose(masked_points, v, (0, 0, 1, 1))
    for res in (by_mask, by_valid, by_point_mask):
        assert res.stats["n_invalid"] == gone.sum()
        np.testing.assert_array_equal(res.curl_free[~gone], ref.curl_free)
        assert np.isnan(res.curl_free[gone]).all()


def test_missing_rows_refused_on_request_and_bad_markers(field_with_gaps):
    pts, v, gone = field_with_gaps
    holed = v.copy()
    holed[gone] = np.nan
    first = int(np.flatnonzero(gone)[0])
    with pytest.raises(InputError, match=f"{gone.sum()} of {len(pts)} rows are missing.*"
                                         f"first row {first}"):
        thh.decompose(pts, holed, (0, 0, 1, 1), invalid="error")
    with pytest.raises(InputError, match="invalid must be one of"):
        thh.decompose(pts, v, (0, 0, 1, 1), invalid="drop")
    with pytest.raises(InputError, match="valid must be a boolean array of shape"):
        thh.decompose(pts, v, (0, 0, 1, 1), valid=~gone[:-1])
    with pytest.raises(InputError, match="all 1500 rows are missing"):
        thh.decompose(pts, v * np.nan, (0, 0, 1, 1))
    inf = v.copy()
    inf[5, 1] = -np.inf
    with pytest.raises(InputError, match="infinite values, first in row 5"):
        thh.decompose(pts, inf, (0, 0, 1, 1))
    with pytest.raises(InputError, match="complex"):
        thh.decompose(pts, v + 1j, (0, 0, 1, 1))
    with pytest.raises(InputError, match="complex"):
        thh.decompose(pts.astype(complex), v, (0, 0, 1, 1))


def test_a_block_of_zero_vectors_is_named():
    """DaVis text and Insight .vec files write invalid vectors as zeros: a block
    of them is named (rows, where) with the remedy; a field with a few exact
    zeros is not."""
    pts = TRIG.sample(1500, "random", seed=8)
    v = TRIG.evaluate(pts).v
    block = (np.abs(pts[:, 0] - 0.6) < 0.08) & (np.abs(pts[:, 1] - 0.4) < 0.08)
    zeroed = v.copy()
    zeroed[block] = 0.0
    with pytest.warns(AccuracyWarning, match=rf"{block.sum()} of 1500 vectors are exactly zero"
                                             r".*x 0.5.*mark them missing"):
        res = thh.decompose(pts, zeroed, (0, 0, 1, 1))
    assert any("exactly zero" in f for f in res.stats["flags"])
    few = v.copy()
    few[:2] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)
        thh.decompose(pts, few, (0, 0, 1, 1))
    # marked missing, the block is a gap and the warning goes
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)
        res = thh.decompose(pts, zeroed, (0, 0, 1, 1), valid=~block)
    assert res.stats["n_invalid"] == block.sum()
