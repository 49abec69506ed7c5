"""The counting sort by cell shared by the binned searches: stable, as numpy's."""
import numpy as np
import pytest

from taichi_hh.sph.cell_sort import counting_sort


@pytest.mark.parametrize("n, ncells", [(0, 5), (1, 1), (1000, 7), (5000, 4096)])
def test_counting_sort_is_numpys_stable_argsort(n, ncells):
    cell = np.random.default_rng(n).integers(0, ncells, n).astype(np.int32)
    order, start = counting_sort(cell, ncells)
    assert np.array_equal(order, np.argsort(cell, kind="stable"))
    assert np.array_equal(start, np.r_[0, np.cumsum(np.bincount(cell, minlength=ncells))])
    for c in range(min(ncells, 50)):
        assert np.all(cell[order[start[c]:start[c + 1]]] == c)
