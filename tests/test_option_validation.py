"""Every option of decompose() and project() checked by one validator
(:data:`taichi_hh.hhd.options.OPTION_SPECS` through
:func:`taichi_hh.checks.check_option`), raising InputError with the option's
name and the problem; unknown names refused with the close spellings; complex,
object and string arrays refused; the iteration cap reported with the count it
stopped at (issue 29: nothing silently wrong)."""
from __future__ import annotations

import dataclasses
import inspect
import re

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh import checks
from taichi_hh.errors import InputError
from taichi_hh.hhd.options import (METHODS, MULTILEVEL_OPTION_SPECS, OPTION_SPECS,
                                   PROJECT_OVERRIDES, HHDOptions, options_for)

UNIT = (0.0, 0.0, 1.0, 1.0)


@pytest.fixture(scope="module")
def small():
    """200 uniformly random points in the unit square and a smooth field."""
    pts = np.random.default_rng(7).random((200, 2))
    v = np.c_[np.sin(3 * pts[:, 1]), np.cos(2 * pts[:, 0])]
    return pts, v


# ---- the table -------------------------------------------------------------------------

def test_one_spec_per_field_and_the_bundles_pass_it():
    assert [f.name for f in dataclasses.fields(HHDOptions)] == list(OPTION_SPECS)
    for method, opts in METHODS.items():
        assert options_for(method) == opts
        options_for(method, **PROJECT_OVERRIDES.get(method, {}))


def test_multilevel_specs_name_the_preconditioner_keywords():
    from taichi_hh.poisson.multilevel import MultilevelPreconditioner
    params = inspect.signature(MultilevelPreconditioner.__init__).parameters
    assert set(MULTILEVEL_OPTION_SPECS) == set(params) - {"self", "A", "reuse"}


def test_errors_are_value_errors():
    assert issubclass(InputError, ValueError)


# ---- the problems of the issue ---------------------------------------------------------

@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1e-3])
def test_kappa_nan_inf_negative_refused(small, value):
    pts, v = small
    with pytest.raises(InputError, match=r"kappa must be a finite real number >= 0"):
        thh.decompose(pts, v, UNIT, kappa=value)
    with pytest.raises(InputError, match="kappa"):
        thh.project(pts, v, UNIT, kappa=value)


@pytest.mark.parametrize("value", ["1e-6", b"1e-6", 1e-6 + 0j, True, None, [1e-6]])
def test_tol_not_a_real_number_refused(small, value):
    pts, v = small
    with pytest.raises(InputError, match=r"tol must be a finite real number > 0, got "):
        thh.decompose(pts, v, UNIT, tol=value)


def test_tol_string_names_its_type():
    with pytest.raises(InputError, match=r"tol must be .*got '1e-6' \(a str\)"):
        options_for(tol="1e-6")


@pytest.mark.parametrize("name", ["max_iterations", "support_neighbours", "seed"])
@pytest.mark.parametrize("value", [True, np.bool_(False)])
def test_bool_where_an_integer_is_meant_refused(name, value):
    with pytest.raises(InputError, match=rf"{name} must be an integer.*\(a bool\)"):
        options_for(**{name: value})


@pytest.mark.parametrize("name, value", [("max_iterations", 10.5), ("max_iterations", "100"),
                                         ("max_iterations", 0), ("support_neighbours", 25),
                                         ("seed", -1), ("seed", float("nan"))])
def test_bad_integers_refused(name, value):
    with pytest.raises(InputError, match=rf"{name} must be an integer"):
        options_for(**{name: value})


@pytest.mark.parametrize("name, value", [("bordered", 1), ("remove_mean", "no"),
                                         ("adaptive_support", None)])
def test_bool_options_take_booleans_only(name, value):
    with pytest.raises(InputError, match=rf"{name} must be True or False"):
        options_for(**{name: value})


def test_unknown_option_refused_with_close_names_and_the_list(small):
    pts, v = small
    with pytest.raises(InputError) as info:
        thh.decompose(pts, v, UNIT, tolerance=1e-6)
    msg = str(info.value)
    assert "unknown option 'tolerance'" in msg and "did you mean 'tol'" in msg
    assert "valid names:" in msg and "max_iterations" in msg and "kappa" in msg
    with pytest.raises(InputError, match=r"unknown option 'max_iteration' \(did you mean "
                                         r"'max_iterations'"):
        thh.project(pts, v, UNIT, max_iteration=10)
    with pytest.raises(InputError, match=r"unknown options 'foo', 'bar'"):
        options_for(foo=1, bar=2)


def test_unknown_method_and_choice_suggest_close_names():
    with pytest.raises(InputError, match=r"unknown method 'petronetto'.*did you mean "
                                         r"'petronetto2010'"):
        options_for("petronetto")
    with pytest.raises(InputError, match="unknown method"):
        options_for(["default"])                  # unhashable: no TypeError
    with pytest.raises(InputError, match=r"kernel must be one of \(.*'wendland'.*\), got "
                                         r"'wendlnd' \(did you mean 'wendland'\?\)"):
        options_for(kernel="wendlnd")
    with pytest.raises(InputError, match=r"laplacian must be one of .*got 3$"):
        options_for(laplacian=3)


def test_max_iterations_one_reports_a_consistent_count_and_cap(small):
    pts, v = small
    with pytest.raises(thh.SolverError) as info:
        thh.decompose(pts, v, UNIT, max_iterations=1, boundary_condition="neumann")
    msg = str(info.value)
    assert info.value.reason == "max_iterations"
    count = int(re.search(r"at iteration (\d+)", msg).group(1))
    cap = int(re.search(r"iteration cap (\d+) reached", msg).group(1))
    assert count == cap == info.value.iteration == 1, msg


# ---- HHDOptions itself, canonical values -----------------------------------------------

def test_direct_construction_is_validated_and_canonical():
    with pytest.raises(InputError, match="kappa must be a finite real number"):
        HHDOptions(kappa=float("nan"))
    with pytest.raises(InputError, match="positive_rows must be a finite real number >= 1 "
                                         "or None"):
        HHDOptions(positive_rows=0.5)
    opts = HHDOptions(kappa=np.float32(0.5), tol=np.float64(1e-6), max_iterations=np.int64(50),
                      support_neighbours=1e1, bordered=np.bool_(False), seed=None)
    assert type(opts.kappa) is float and opts.kappa == 0.5
    assert type(opts.tol) is float
    assert type(opts.max_iterations) is int and opts.max_iterations == 50
    assert type(opts.support_neighbours) is int and opts.support_neighbours == 10
    assert opts.bordered is False and opts.seed is None
    assert options_for(tol=1).tol == 1.0                     # ints are reals
    assert HHDOptions(positive_rows=None).positive_rows is None
    with pytest.raises(InputError, match="multilevel preconditioner works with "
                                         "solver='bicgstab'"):
        HHDOptions(preconditioner="multilevel", solver="cgnr")


def test_multilevel_options_names_and_values_checked():
    with pytest.raises(InputError, match=r"unknown multilevel_options entry 'omgea' \(did you "
                                         r"mean 'omega'\?\)"):
        options_for(multilevel_options={"omgea": 0.8})
    with pytest.raises(InputError, match=r"multilevel_options\['omega'\] must be a finite real "
                                         r"number in \(0, 2\)"):
        options_for(multilevel_options={"omega": 2.5})
    with pytest.raises(InputError, match=r"multilevel_options\['post'\] must be an integer"):
        options_for(multilevel_options=(("post", True),))
    with pytest.raises(InputError, match="more than once"):
        options_for(multilevel_options=(("post", 1), ("post", 2)))
    with pytest.raises(InputError, match="multilevel_options must be a dict or"):
        options_for(multilevel_options="V")
    a = options_for(multilevel_options={"weak": 0, "cycle": "V"}).multilevel_options
    b = options_for(multilevel_options=[("cycle", "V"), ("weak", 0.0)]).multilevel_options
    assert a == b == (("cycle", "V"), ("weak", 0.0))


# ---- arrays: complex, object and string data -------------------------------------------

def test_complex_points_and_vectors_refused(small):
    """Refused, not cast (numpy drops the imaginary part with a mere warning);
    the public calls may word it before check_points/check_values do."""
    pts, v = small
    with pytest.raises(InputError, match=r"vectors\b.*\bcomplex"):
        thh.decompose(pts, v + 0j, UNIT)
    with pytest.raises(InputError, match=r"points\b.*\bcomplex"):
        thh.decompose(pts + 1e-3j, v, UNIT)
    with pytest.raises(InputError, match=r"vectors\b.*\bcomplex"):
        thh.project(pts, v.astype(np.complex64), UNIT)
    with pytest.raises(InputError, match=r"pts must be real, got a complex array"):
        checks.check_points(pts + 0j, "pts")
    with pytest.raises(InputError, match=r"v must be real, got a complex array"):
        checks.check_values(v + 0j, len(v), 2, "v")


@pytest.mark.parametrize("bad, kind", [
    (np.array([[0.1, 0.2], [0.3, 0.4]], dtype=object), "object"),
    (np.array([["0.1", "0.2"], ["0.3", "0.4"]]), "string"),
    (np.array([[b"0.1", b"0.2"], [b"0.3", b"0.4"]]), "bytes"),
])
def test_object_and_string_arrays_refused(bad, kind):
    with pytest.raises(InputError, match=rf"pts must be a numeric \(N, 2\) array, got an "
                                         rf"array of {kind} entries"):
        checks.check_points(bad, "pts")
    with pytest.raises(InputError, match=rf"v must be numeric, got an array of {kind} entries"):
        checks.check_values(bad, 2, 2, "v")


def test_real_arrays_still_accepted():
    assert checks.check_points(np.array([[1, 2], [3, 4]], dtype=np.int32)).dtype == np.float64
    assert checks.check_values(np.ones(3, dtype=np.float32), 3, 1).dtype == np.float64
    masked = np.ma.masked_array([[0.0, 1.0], [2.0, 3.0]], mask=False)
    assert checks.check_points(masked).shape == (2, 2)
