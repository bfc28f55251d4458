"""Waters (1987) muscle formulas at known points (docs/design.md, "Waters muscles")."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wface.waters.muscles import (
    LinearMuscle,
    SphincterMuscle,
    linear_muscle_displacement,
    linear_muscle_factors,
    sphincter_muscle_displacement,
)

_TOL = 1e-12  # float64 round-off on O(1e-2) lengths


def _muscle(**kw) -> LinearMuscle:
    # The slide's parameters in centimetres -> metres: zone 35 deg, fall-start 7, fall-finish 14, K 0.75.
    base = dict(
        name="zygomaticus_major_l",
        bone_m=[0.0, 0.0, 0.0],
        insertion_m=[0.07, 0.0, 0.0],
        zone_deg=35.0,
        fall_start_m=0.07,
        fall_finish_m=0.14,
        spring_constant_m=0.0075,
    )
    base.update(kw)
    return LinearMuscle(**base)


def _at(dist: float, angle_deg: float = 0.0) -> np.ndarray:
    a = np.radians(angle_deg)
    return np.array([[dist * np.cos(a), dist * np.sin(a), 0.0]])


def test_bony_attachment_does_not_move():
    m = _muscle(bone_m=[0.01, -0.02, 0.03], insertion_m=[0.08, -0.02, 0.03])
    d = linear_muscle_displacement(m.bone_m[None], m, 1.0)
    assert np.all(d == 0.0)
    # and the pull vanishes continuously toward V1 (R = cos((1 - D/Rs) pi/2) -> 0)
    near = linear_muscle_displacement(m.bone_m[None] + [1e-6, 0, 0], m, 1.0)
    assert np.linalg.norm(near) < 1e-6 * np.pi / 2 / m.fall_start_m * m.spring_constant_m * 1.01


def test_full_pull_at_fall_start_on_axis():
    m = _muscle()
    d = linear_muscle_displacement(_at(0.07), m, 1.0)[0]
    # A = R = 1: displacement K toward V1.
    np.testing.assert_allclose(d, [-0.0075, 0.0, 0.0], atol=_TOL)


@pytest.mark.parametrize("dist", [0.01, 0.035, 0.05, 0.07])
def test_radial_rising_cosine_inside_fall_start(dist):
    a, r, _ = linear_muscle_factors(_at(dist), _muscle())
    assert a[0] == pytest.approx(1.0, abs=_TOL)
    assert r[0] == pytest.approx(np.cos((1 - dist / 0.07) * np.pi / 2), abs=_TOL)


@pytest.mark.parametrize("dist", [0.07, 0.09, 0.105, 0.13, 0.14])
def test_radial_falling_cosine_between_fall_start_and_finish(dist):
    _, r, _ = linear_muscle_factors(_at(dist), _muscle())
    assert r[0] == pytest.approx(np.cos((dist - 0.07) / (0.14 - 0.07) * np.pi / 2), abs=_TOL)


def test_zero_at_and_beyond_fall_finish():
    m = _muscle()
    d = linear_muscle_displacement(np.vstack([_at(0.14), _at(0.15), _at(0.3, 10.0)]), m, 1.0)
    assert np.all(np.abs(d) < _TOL)


@pytest.mark.parametrize("angle", [0.0, 10.0, 17.5, 30.0, 34.9])
def test_angular_cosine_inside_zone(angle):
    a, _, _ = linear_muscle_factors(_at(0.07, angle), _muscle())
    assert a[0] == pytest.approx(np.cos(angle / 35.0 * np.pi / 2), abs=1e-9)


@pytest.mark.parametrize("angle", [35.5, 60.0, 90.0, 180.0])
def test_no_effect_outside_zone_of_influence(angle):
    d = linear_muscle_displacement(_at(0.07, angle), _muscle(), 1.0)
    assert np.all(d == 0.0)


def test_elasticity_is_exponent_on_falloff_and_pull_is_linear_in_contraction():
    p = _at(0.09, 12.0)
    a, r, _ = linear_muscle_factors(p, _muscle())
    d10 = linear_muscle_displacement(p, _muscle(elasticity=10.0), 0.4)
    assert np.linalg.norm(d10) == pytest.approx(0.4 * 0.0075 * (a[0] * r[0]) ** 10, rel=1e-12)
    d1 = linear_muscle_displacement(p, _muscle(), 1.0)
    np.testing.assert_allclose(linear_muscle_displacement(p, _muscle(), 0.25), 0.25 * d1, atol=_TOL)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-0.2, 0.2), min_size=3, max_size=3),
    st.floats(0.0, 1.0),
)
def test_pull_points_at_bone_and_never_exceeds_k(xyz, c):
    m = _muscle(bone_m=[0.01, 0.02, -0.01], insertion_m=[0.06, 0.05, 0.0])
    p = np.array([xyz])
    d = linear_muscle_displacement(p, m, c)[0]
    assert np.linalg.norm(d) <= c * m.spring_constant_m + _TOL
    to_bone = m.bone_m - p[0]
    if np.linalg.norm(d) > 0:
        assert np.linalg.norm(np.cross(d, to_bone)) <= 1e-9 * np.linalg.norm(to_bone) * np.linalg.norm(d)
        assert d @ to_bone > 0


# ------------------------------------------------------------------------------------- sphincter
def _sphincter(**kw) -> SphincterMuscle:
    base = dict(
        name="orbicularis_oris_upper",
        centre_m=[0.0, -0.03, 0.1],
        horizontal=[1, 0, 0],
        vertical=[0, 1, 0],
        semi_axes_m=[0.03, 0.02, 0.02],
        tension=0.3,
    )
    base.update(kw)
    return SphincterMuscle(**base)


def test_sphincter_centre_and_outside_do_not_move():
    s = _sphincter()
    pts = np.array([s.centre_m, s.centre_m + [0.031, 0, 0], s.centre_m + [0, 0.021, 0], s.centre_m + [0, 0, 0.03]])
    assert np.all(np.abs(sphincter_muscle_displacement(pts, s, 1.0)) < _TOL)


def test_sphincter_formula_on_axis_and_in_plane():
    s = _sphincter()
    p = s.centre_m + np.array([[0.015, 0.0, 0.005]])  # rho = sqrt(0.25 + 0.0625)
    rho = np.hypot(0.5, 0.25)
    d = sphincter_muscle_displacement(p, s, 0.8)[0]
    np.testing.assert_allclose(d, [-0.8 * 0.3 * np.cos(rho * np.pi / 2) * 0.015, 0.0, 0.0], atol=_TOL)


def test_sphincter_is_mirror_symmetric_about_both_axes():
    rng = np.random.default_rng(4)
    s = _sphincter(horizontal=[1, 0.2, 0], vertical=[-0.2, 1, 0.1])  # a tilted ring
    frame = np.stack([s.horizontal, s.vertical, s.normal])
    local = rng.uniform(-1, 1, (500, 3)) * s.semi_axes_m
    for axis in (0, 1):
        flip = np.ones(3)
        flip[axis] = -1
        p = s.centre_m + local @ frame
        q = s.centre_m + (local * flip) @ frame
        dp = sphincter_muscle_displacement(p, s, 1.0) @ frame.T
        dq = sphincter_muscle_displacement(q, s, 1.0) @ frame.T
        np.testing.assert_allclose(dq, dp * flip, atol=1e-15)
    # no pull along the ring's normal
    d = sphincter_muscle_displacement(s.centre_m + local @ frame, s, 1.0)
    np.testing.assert_allclose(d @ s.normal, 0.0, atol=1e-15)


# ------------------------------------------------------------------------------------- bad input
def test_bad_inputs_name_the_problem():
    with pytest.raises(ValueError, match="fall_finish_m"):
        _muscle(fall_start_m=0.05, fall_finish_m=0.04)
    with pytest.raises(ValueError, match="coincide"):
        _muscle(insertion_m=[0, 0, 0])
    with pytest.raises(ValueError, match="NaN"):
        _muscle(bone_m=[np.nan, 0, 0])
    with pytest.raises(ValueError, match="zone_deg"):
        _muscle(zone_deg=0)
    with pytest.raises(ValueError, match="region"):
        _muscle(region="middle")
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        linear_muscle_displacement(np.zeros((4, 2)), _muscle())
    with pytest.raises(ValueError, match="NaN"):
        linear_muscle_displacement(np.full((1, 3), np.nan), _muscle())
    with pytest.raises(ValueError, match="contraction"):
        linear_muscle_displacement(np.zeros((1, 3)), _muscle(), 1.5)
    with pytest.raises(ValueError, match="parallel"):
        _sphincter(vertical=[2, 0, 0])
    with pytest.raises(ValueError, match="tension"):
        _sphincter(tension=1.5)


def test_sphincter_protrusion_pushes_along_the_normal_with_the_same_falloff():
    s = _sphincter(protrusion_m=0.006)
    p = s.centre_m + np.array([[0.015, 0.0, 0.005], [0.0, 0.0, 0.0]])
    rho = np.hypot(0.5, 0.25)
    d = sphincter_muscle_displacement(p, s, 0.5)
    r = np.cos(rho * np.pi / 2)
    np.testing.assert_allclose(d[0], [-0.5 * 0.3 * r * 0.015, 0.0, 0.5 * 0.006 * r], atol=_TOL)
    np.testing.assert_allclose(d[1], [0.0, 0.0, 0.5 * 0.006], atol=_TOL)  # the centre comes forward by c K_n
    flat = sphincter_muscle_displacement(p, _sphincter(), 0.5)
    np.testing.assert_allclose(d[:, :2], flat[:, :2], atol=_TOL)  # the in-plane part is unchanged


def test_sphincter_lower_semi_axis_stretches_the_ring_below_the_centre_only():
    s = _sphincter(lower_semi_axis_m=0.05)
    assert s.reach_m == 0.05 and s.below_m == 0.05 and _sphincter().below_m == 0.02
    above = s.centre_m + np.array([[0.0, 0.015, 0.0]])
    below = s.centre_m + np.array([[0.0, -0.04, 0.0]])  # outside the symmetric ring, inside the egg
    symmetric = sphincter_muscle_displacement(above, _sphincter())
    np.testing.assert_allclose(sphincter_muscle_displacement(above, s), symmetric, atol=_TOL)
    assert np.all(sphincter_muscle_displacement(below, _sphincter()) == 0.0)
    d = sphincter_muscle_displacement(below, s, 1.0)[0]
    np.testing.assert_allclose(d, [0.0, 0.3 * np.cos(0.8 * np.pi / 2) * 0.04, 0.0], atol=_TOL)  # up, toward the centre
    with pytest.raises(ValueError, match="lower_semi_axis_m"):
        _sphincter(lower_semi_axis_m=-0.01)
    with pytest.raises(ValueError, match="protrusion_m"):
        _sphincter(protrusion_m=float("nan"))
