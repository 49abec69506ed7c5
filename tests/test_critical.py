"""Critical points with significance (issue 17): none on fields without any
(harmonic, constant, rigid rotation under Neumann), also with 1% noise; the
known ones found, with strengths to rank them."""
import warnings

import numpy as np
import pytest

import taichi_hh as thh
from taichi_hh.errors import AccuracyWarning
from taichi_hh.geometry.box import Box
from taichi_hh.hhd.critical import CriticalPoint
from taichi_hh.validation import fields

UNIT = Box((0.0, 0.0), (1.0, 1.0))


def _noisy(v, level, seed):
    rng = np.random.default_rng(seed)
    return v + level * np.linalg.norm(v, axis=1).mean() * rng.standard_normal(v.shape)


def _decompose(pts, v, domain, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)    # the rotation under Neumann
        return thh.decompose(pts, v, domain, **kw)


@pytest.fixture(scope="module")
def unit_points():
    return UNIT.sample_interior(3300, kind="poisson", seed=3)


FEATURELESS = {
    "harmonic": lambda p: np.c_[p[:, 0], -p[:, 1]] + [0.3, 0.1],
    "constant": lambda p: np.tile([0.3, -0.2], (len(p), 1)),
    "rotation": lambda p: np.c_[0.5 - p[:, 1], p[:, 0] - 0.5],
}


@pytest.mark.parametrize("noise", [0.0, 0.01])
@pytest.mark.parametrize("name", list(FEATURELESS))
def test_no_critical_points_where_there_are_none(unit_points, name, noise):
    """Before: 12 on the clean harmonic field, 14-38 on the noisy rotation (the
    zeros of components that are noise).  The rotation under the default
    (Neumann) condition is all h: psi carries nothing, so no vortex."""
    v = FEATURELESS[name](unit_points)
    if noise:
        v = _noisy(v, noise, seed=7)
    res = _decompose(unit_points, v, UNIT)
    assert res.critical_points() == []


@pytest.mark.parametrize("condition", ["normal-parallel", "natural"])
def test_rotation_has_its_centre_as_only_vortex_when_r_carries_it(unit_points, condition):
    """Under normal-parallel and natural r is the rotation: its centre is a
    counter-clockwise vortex, and the potential's extrema at the boundary
    (psi = 0 there, or the corners of the natural psi) are no critical points:
    r does not vanish there, or its curl has the other sign."""
    v = FEATURELESS["rotation"](unit_points)
    for noise in (0.0, 0.01):
        res = _decompose(unit_points, _noisy(v, noise, 8) if noise else v, UNIT,
                         boundary_condition=condition)
        found = res.critical_points()
        assert len(found) == 1 and found[0].kind == "ccw_vortex", found
        assert np.hypot(found[0].x - 0.5, found[0].y - 0.5) < 0.5 * res.stats["spacing"]


@pytest.mark.parametrize("noise", [0.0, 0.01])
@pytest.mark.parametrize("name", ["gaussian", "hole"])
def test_known_points_found_within_half_a_spacing(name, noise):
    """Measured within 0.15 spacings at 3.3k points, strengths 0.82-0.88, with
    and without 1% noise."""
    F = fields.get(name)
    pts = F.sample(3300, "poisson", seed=3)
    v = F.evaluate(pts).v
    res = _decompose(pts, _noisy(v, noise, 9) if noise else v, F.domain)
    found = res.critical_points()
    assert len(found) == len(F.critical_points), found
    for x, y, kind in F.critical_points:
        match = [c for c in found if c.kind == kind]
        assert len(match) == 1, (kind, found)
        assert np.hypot(match[0].x - x, match[0].y - y) < 0.5 * res.stats["spacing"]
    strengths = [c.strength for c in found]
    assert strengths == sorted(strengths, reverse=True) and min(strengths) > 0.5


def test_critical_point_unpacks_as_before():
    c = CriticalPoint(0.1, 0.2, "source", 0.7)
    x, y, kind = c
    assert (x, y, kind) == (0.1, 0.2, "source") and c.strength == 0.7
    assert c == (0.1, 0.2, "source") and "strength=0.7" in repr(c)


def test_threshold_ranks_by_strength():
    """Two vortices of different strength: the weaker one goes when the
    threshold passes its strength."""
    pts = UNIT.sample_interior(3300, kind="poisson", seed=4)
    strong = fields.Bump((0.3, 0.5), 0.02, 0.07)
    weak = fields.Bump((0.7, 0.5), 0.006, 0.07)
    grad = strong(pts)[1] + weak(pts)[1]
    v = np.c_[grad[:, 1], -grad[:, 0]]                   # r = J grad psi
    res = _decompose(pts, v, UNIT)
    found = res.critical_points()
    assert [c.kind for c in found] == ["ccw_vortex", "ccw_vortex"], found
    assert found[0].x < 0.5 < found[1].x and 0.2 < found[1].strength < 0.4
    assert len(res.critical_points(threshold=found[1].strength * 1.1)) == 1
