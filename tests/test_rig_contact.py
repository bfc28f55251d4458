"""Jacobians of equilibria with contact (wface.tracking.rig with ``contact=``) against central differences."""

from __future__ import annotations

import numpy as np
import pytest

from wface.faces.builtin import build_face
from wface.physics.contact import Contact
from wface.physics.penalty import TRACKING_SMOOTHING_M
from wface.tracking.rig import FaceRig

# Equilibria solved to a relative residual of 1e-11, central differences h = 1e-4 (activations) /
# 1e-5 (jaw): truncation ~1e-8 relative; the exact pair Hessian uses second differences with
# 1e-5 m steps (~1e-7 relative). Measured agreement: 2e-7.
_REL_TOL = 2e-5
_PRESS = ("orbicularis_oris_upper", "orbicularis_oris_lower", "mentalis_l", "mentalis_r")
# C2 penalty: no pair switches at exactly zero force between c - h and c + h. With the C1 penalty the
# jaw translation columns differ by 1 % (measured), a pair crossing g = 0. Two ramps: 0.05 mm, and the
# one the tracking commands use (0.5 mm).


@pytest.fixture(scope="module", params=[5e-5, TRACKING_SMOOTHING_M], ids=["ramp-0.05mm", "tracking-ramp"])
def pressed(request):
    face = build_face(2000)
    contact = Contact(face, regions="lips,teeth", smoothing_m=request.param)
    rig = FaceRig(face, tol=1e-11, contact=contact, max_iterations=100)
    c = rig.rest_controls()
    for m in _PRESS:
        c[face.muscle_index(m)] = 0.8
    c[face.muscle_index("zygomaticus_major_l")] = 0.3
    state = rig.equilibrium(c)
    return face, rig, c, state, rig.jacobian(state)


def test_lips_are_pressed(pressed):
    face, rig, c, state, _ = pressed
    assert state.converged and state.stats["contact_force_n"] > 1.0  # measured 57 N (0.05 mm ramp), 56 N (0.5 mm)
    # Without contact the same pose overlaps the lips by millimetres.
    free = FaceRig(face, tol=1e-8).equilibrium(c)
    assert rig.contact.penetration(free.y_m)["max_penetration_m"] > 1e-3


@pytest.mark.parametrize("which", ["orbicularis_oris_lower", "zygomaticus_major_l", 0, 9, 11])
def test_jacobian_with_contact_matches_central_differences(pressed, which):
    face, rig, c, state, J = pressed
    M = face.n_muscles
    col = face.muscle_index(which) if isinstance(which, str) else M + 12 + which
    h = 1e-4 if isinstance(which, str) else 1e-5
    cp, cm = c.copy(), c.copy()
    cp[col] += h
    cm[col] -= h
    sp, sm = rig.equilibrium(cp, state.y_m), rig.equilibrium(cm, state.y_m)
    assert sp.converged and sm.converged
    fd = (sp.x_m - sm.x_m) / (2 * h)
    assert np.abs(fd - J[:, :, col]).max() <= _REL_TOL * np.abs(fd).max()


def test_contact_changes_the_jacobian_and_none_changes_nothing(pressed):
    face, rig, c, state, J = pressed
    plain = FaceRig(face, tol=1e-11)
    none = FaceRig(face, tol=1e-11, contact=None)
    s0, s1 = plain.equilibrium(c), none.equilibrium(c)
    assert np.array_equal(s0.x_m, s1.x_m) and s1.stats == {}
    J0, J1 = plain.jacobian(s0), none.jacobian(s1)
    assert np.array_equal(J0, J1)
    col = face.muscle_index("orbicularis_oris_lower")
    assert np.abs(J0[:, :, col] - J[:, :, col]).max() > 0.1 * np.abs(J[:, :, col]).max()  # measured 27 %


def test_the_contact_jacobian_keeps_its_factor_for_chord_steps(pressed):
    """With contact, ``linearize`` keeps the factor of K_UU plus the contact Hessian (the Jacobian the
    same as without keeping it) and a nearby solve takes chord steps with it, no new factorisation, to
    the equilibrium a fresh Newton solve finds; a RowsLinearization predicts with it too."""
    face, rig, c, state, _ = pressed
    lin = rig.linearize(state)
    plain = rig.linearize(state, keep_factor=False)
    assert lin.chord is not None and plain.chord is None
    np.testing.assert_array_equal(lin.jy, plain.jy)
    c2 = c.copy()
    c2[face.muscle_index("orbicularis_oris_lower")] += 0.02
    dc_y = np.concatenate([c2[: face.n_muscles] - c[: face.n_muscles], np.zeros(12)])
    guess = state.y_m + lin.predict(dc_y)
    before = dict(rig.counters)
    chorded = rig.equilibrium(c2, guess, chord=lin.chord, tol=1e-8)
    assert chorded.converged and rig.counters["chord_steps"] > before["chord_steps"]
    assert rig.counters["factorizations"] == before["factorizations"]
    fresh = FaceRig(face, tol=1e-8, contact=rig.contact, max_iterations=100).equilibrium(c2, guess)
    assert np.abs(chorded.y_m - fresh.y_m).max() < 1e-6
    rows = rig.linearize_rows(state, np.arange(5), lin.jy.reshape(-1, 3, lin.jy.shape[1])[:5])
    assert rows is not None
    np.testing.assert_allclose(rows.predict(dc_y), lin.predict(dc_y), atol=1e-9)
    jaw = np.zeros_like(dc_y)
    jaw[face.n_muscles + 10] = 1e-4  # the jaw's vertical translation: the lower teeth push the lip
    np.testing.assert_allclose(rows.predict(jaw), lin.predict(jaw), atol=1e-9 + 1e-6 * np.abs(lin.predict(jaw)).max())
    rows.free()
    lin.free()
