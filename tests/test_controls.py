"""Controls: penalty derivatives by central differences, joint limits of the intuitive jaw mapping."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wface.controls import (
    IDENTITY_BONES,
    activation_penalty,
    bone_penalty,
    jaw_from_intuitive,
    jaw_joint_penalty,
    jaw_joint_values,
    jaw_limits,
    jaw_params_unchecked,
    jaw_to_intuitive,
    rigidity_penalty,
)
from wface.faces.builtin.face import JAW_JOINT
from wface.model import ModelError

_FD_TOL = 1e-6  # central differences with h = 1e-6 on quartic/quadratic functions: O(h^2) + round-off


def _fd_grad(f, x, h=1e-6):
    g = np.zeros_like(x)
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        g[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


def _fd_hess(grad, x, h=1e-6):
    H = np.zeros((len(x), len(x)))
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        H[:, i] = (grad(x + e) - grad(x - e)) / (2 * h)
    return H


def test_rigidity_gradient_and_hessian():
    rng = np.random.default_rng(0)
    M = np.eye(3) + 0.2 * rng.normal(size=(3, 3))
    p = rigidity_penalty(M, project=False)
    f = lambda v: rigidity_penalty(v.reshape(3, 3)).value  # noqa: E731
    g = lambda v: rigidity_penalty(v.reshape(3, 3)).gradient  # noqa: E731
    assert np.allclose(p.gradient, _fd_grad(f, M.ravel()), atol=_FD_TOL)
    assert np.allclose(p.hessian, _fd_hess(g, M.ravel()), atol=1e-5)
    proj = rigidity_penalty(M).hessian
    assert np.linalg.eigvalsh(proj).min() >= -1e-12  # projected to PSD
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    assert rigidity_penalty(R).value == pytest.approx(0.0, abs=1e-24)  # zero on rotations


def test_activation_penalty_derivatives():
    a = np.array([-0.2, 0.3, 1.4, 0.999, 0.0])
    p = activation_penalty(a)
    assert p.value == pytest.approx(0.04 + 0.16)
    assert np.allclose(p.gradient, _fd_grad(lambda v: activation_penalty(v).value, a), atol=_FD_TOL)
    assert np.allclose(np.diag(p.hessian), [2, 0, 2, 0, 0])


def test_jaw_joint_penalty_derivatives():
    rng = np.random.default_rng(1)
    p0 = jaw_from_intuitive(JAW_JOINT, 10.0, 0.004, 1.0) + 0.01 * rng.normal(size=12)
    pen = jaw_joint_penalty(JAW_JOINT, p0)
    assert pen.value > 0
    assert np.allclose(pen.gradient, _fd_grad(lambda v: jaw_joint_penalty(JAW_JOINT, v).value, p0), atol=_FD_TOL)
    assert np.allclose(pen.hessian, _fd_hess(lambda v: jaw_joint_penalty(JAW_JOINT, v).gradient, p0), atol=1e-5)
    full = bone_penalty(JAW_JOINT, np.concatenate([IDENTITY_BONES[:12], p0]))
    assert full.value == pytest.approx(pen.value + rigidity_penalty(p0[:9].reshape(3, 3)).value)


@settings(max_examples=60, deadline=None)
@given(st.floats(-20, 60), st.floats(-0.02, 0.03), st.floats(-10, 10))
def test_intuitive_jaw_stays_inside_the_joint(opening, protrusion, lateral):
    p = jaw_from_intuitive(JAW_JOINT, opening, protrusion, lateral)
    psi = jaw_joint_values(JAW_JOINT, p)
    d, s, s_c = JAW_JOINT.track_length_m, JAW_JOINT.max_opening_sine, JAW_JOINT.max_closing_sine
    assert np.allclose(psi[:3], 0.0, atol=1e-12)
    assert -1e-12 <= psi[3] <= d + 1e-12 and -1e-12 <= psi[4] <= d + 1e-12
    assert -s - 1e-12 <= psi[5] <= s_c + 1e-12
    assert jaw_joint_penalty(JAW_JOINT, p).value < 1e-24
    assert rigidity_penalty(p[:9].reshape(3, 3)).value < 1e-24


def test_closing_past_rest_down_to_the_freeway_space():
    # The built-in face's rest is the postural rest: the jaw closes past it by 4 mm at the incisors
    # (100 mm from the hinge axis), 2.29 degrees; a joint without a closing range keeps rest as its limit.
    closing = np.degrees(np.arcsin(JAW_JOINT.max_closing_sine))
    assert closing == pytest.approx(np.degrees(0.004 / 0.100)) and jaw_limits(JAW_JOINT)["opening_deg"][0] == -closing
    pose = jaw_to_intuitive(JAW_JOINT, jaw_from_intuitive(JAW_JOINT, -1.5, 0.002, 1.0))
    assert pose["opening_deg"] == pytest.approx(-1.5) and pose["protrusion_m"] == pytest.approx(0.002)
    p = jaw_from_intuitive(JAW_JOINT, -1.5)
    assert jaw_joint_penalty(JAW_JOINT, p).value < 1e-24  # inside the range: no penalty
    chin = np.array([0.0, -0.10, 0.09])
    assert (p[:9].reshape(3, 3) @ chin + p[9:] - chin)[1] > 0.002  # closing lifts the chin
    assert jaw_to_intuitive(JAW_JOINT, jaw_from_intuitive(JAW_JOINT, -9.0))["opening_deg"] == pytest.approx(-closing)
    with pytest.raises(ValueError, match="allowed \\[-2.3, 35.0\\]"):
        jaw_from_intuitive(JAW_JOINT, -3.0, clamp=False)
    at_limit = jaw_from_intuitive(JAW_JOINT, -closing, clamp=False)
    beyond = jaw_params_unchecked(JAW_JOINT, -np.radians(closing + 1.0), 0.0, 0.0)  # 1 degree further
    assert jaw_joint_penalty(JAW_JOINT, at_limit).value < 1e-24 < jaw_joint_penalty(JAW_JOINT, beyond).value
    closed = replace(JAW_JOINT, max_closing_sine=0.0)  # the default: rest is the closed limit
    assert jaw_limits(closed)["opening_deg"][0] == 0.0
    assert jaw_to_intuitive(closed, jaw_from_intuitive(closed, -1.5))["opening_deg"] == pytest.approx(0.0, abs=1e-9)
    assert jaw_joint_penalty(closed, p).value > 0
    with pytest.raises(ModelError, match="max_closing_sine"):
        replace(JAW_JOINT, max_closing_sine=-0.1).validate()


def test_intuitive_round_trip_and_limits():
    pose = jaw_to_intuitive(JAW_JOINT, jaw_from_intuitive(JAW_JOINT, 20.0, 0.006, 3.0))
    assert pose["opening_deg"] == pytest.approx(20.0) and pose["lateral_deg"] == pytest.approx(3.0)
    assert pose["protrusion_m"] == pytest.approx(0.006)
    with pytest.raises(ValueError, match="joint limits"):
        jaw_from_intuitive(JAW_JOINT, 50.0, clamp=False)
    assert jaw_limits(JAW_JOINT)["opening_deg"][1] == pytest.approx(35.0)
    # Opening moves the chin down and back, lateral yaw moves it toward the subject's left (+x).
    M, t = (
        jaw_from_intuitive(JAW_JOINT, 20.0, 0.0, 2.0)[:9].reshape(3, 3),
        jaw_from_intuitive(JAW_JOINT, 20.0, 0.0, 2.0)[9:],
    )
    chin = np.array([0.0, -0.10, 0.09])
    move = M @ chin + t - chin
    assert move[1] < -0.01 and move[2] < 0 and move[0] > 0
