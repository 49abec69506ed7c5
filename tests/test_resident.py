"""Work arrays on the device (taichi_hh.runtime.resident, on a GPU by default):
the natural split's kernels chained through Device arrays give the numpy
path's answer bit for bit, on whatever arch the session runs (the CPU here,
lavapipe in .ci/vulkan), and pass the kernels far fewer numpy arrays (each
one copied to a GPU and back at every launch)."""
import collections

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh import runtime
from taichi_hh.hhd import natural
from taichi_hh.validation.windows import window_field

WINDOW = thh.Box((0.0, 0.0), (2.0, 1.0))
ELLIPSE = thh.Polygon(np.c_[1.0 + 0.9 * np.cos(np.linspace(0, 2 * np.pi, 41)[:-1]),
                            0.5 + 0.45 * np.sin(np.linspace(0, 2 * np.pi, 41)[:-1])])


def _field(n: int, domain, seed: int = 3):
    pts = domain.sample_interior(n, kind="random", seed=seed)
    ex = window_field().evaluate(pts)
    return pts, ex.v


def _with(monkeypatch, flag: str, call):
    monkeypatch.setenv(runtime.RESIDENT_VARIABLE, flag)
    try:
        return call()
    finally:
        monkeypatch.delenv(runtime.RESIDENT_VARIABLE)


def test_device_array_views_and_copies():
    a = np.arange(24, dtype=np.float64).reshape(2, 3, 4)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(runtime.RESIDENT_VARIABLE, "1")
        d = runtime.to_device(a)
        assert isinstance(d, runtime.Device) and d.shape == (2, 3, 4) and len(d) == 2
        assert d.size == 24 and d.ndim == 3 and d.nbytes == a.nbytes
        assert np.array_equal(runtime.to_host(d), a)
        v = d.reshape(6, -1)
        assert v.shape == (6, 4) and v.nd is d.nd
        assert np.array_equal(v.to_numpy(), a.reshape(6, 4))
        with pytest.raises(ValueError, match="cannot reshape"):
            d.reshape(5, 5)
        with pytest.raises(TypeError, match="int32"):
            runtime.flat(d, np.int32)
        i = runtime.to_device(np.array([3, 1, 2]), np.int32)
        assert i.dtype == np.int32 and np.array_equal(i.to_numpy(), [3, 1, 2])
        assert runtime.work((0, 2)).to_numpy().shape == (0, 2)
        mp.setenv(runtime.RESIDENT_VARIABLE, "0")
        assert isinstance(runtime.work((2, 2)), np.ndarray)
        assert runtime.to_host(a) is a


@pytest.mark.parametrize("domain", [WINDOW, ELLIPSE], ids=["window", "ellipse"])
def test_decomposition_on_device_arrays_is_the_numpy_one(monkeypatch, domain):
    pts, v = _field(6000, domain)
    split = {flag: _with(monkeypatch, flag, lambda: thh.decompose(pts, v, domain))
             for flag in ("0", "1")}
    a, b = split["0"], split["1"]
    assert a.stats["boundary_condition"] == b.stats["boundary_condition"] == "natural"
    for name in ("curl_free", "div_free", "harmonic", "phi", "psi", "divergence", "curl"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    numbers = {k: x for k, x in a.stats.items() if isinstance(x, float) and k != "seconds"}
    assert numbers and all(b.stats[k] == x for k, x in numbers.items()), numbers


def test_a_batch_split_on_device_arrays_is_the_numpy_one(monkeypatch):
    pts, v = _field(4000, WINDOW)
    fields = [v, np.c_[v[:, 1], -v[:, 0]] + 0.3, v * pts[:, :1]]
    sp = np.sqrt(WINDOW.area / len(pts))

    def run():
        return natural.NaturalSetup(pts, WINDOW, sp).split_many(fields)
    a = _with(monkeypatch, "0", run)
    b = _with(monkeypatch, "1", run)
    for x, y in zip(a, b):
        for name in ("phi", "psi", "d", "div_free", "harmonic", "divergence", "curl"):
            assert np.array_equal(getattr(x, name), getattr(y, name)), name
        assert x.energies == y.energies
        assert x.harmonic_ratios() == y.harmonic_ratios()
        assert x.mean_fit_points == y.mean_fit_points


def test_device_arrays_spare_the_kernels_numpy_arguments(monkeypatch):
    """The spline's filter, differences and gathers take no numpy array (their
    inputs are the previous kernels' outputs, on the device), and the split's
    launches take less than half the numpy bytes: what is left is the data
    going in (the fields, the points' set-up, the FFT's potentials) and the
    results coming back, each once."""
    from taichi.lang import kernel_impl
    pts, v = _field(6000, WINDOW)
    sp = np.sqrt(WINDOW.area / len(pts))
    setup = natural.NaturalSetup(pts, WINDOW, sp)     # the points' set-up, as before
    nbytes = collections.Counter()
    chained = collections.Counter()
    call = kernel_impl.Kernel.__call__

    def counted(self, *args, **kwargs):
        b = sum(a.nbytes for a in args if isinstance(a, np.ndarray) and a.nbytes > 1024)
        nbytes[flag] += b
        if self.func.__name__ in ("_spline_filter", "_values_and_gradients", "_tensor_gather"):
            chained[flag] += b
        return call(self, *args, **kwargs)
    monkeypatch.setattr(kernel_impl.Kernel, "__call__", counted)
    for flag in ("0", "1"):
        setup._rows = None
        setup.binned._kernel_arrays = None
        _with(monkeypatch, flag, lambda: setup.split(v))
    assert chained["0"] > 0 and chained["1"] == 0, chained
    assert nbytes["1"] < nbytes["0"] / 2, nbytes
