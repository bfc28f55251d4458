"""The small problem of a Gauss-Newton step (``wface.tracking.steps``): the joint's equalities kept, the
activation box kept, and frozen activations left where they are."""

from __future__ import annotations

import numpy as np
import pytest

from wface.controls import _joint_rows
from wface.faces.builtin import build_face
from wface.tracking.steps import bounded_step, step_basis


@pytest.fixture(scope="module")
def problem():
    model = build_face(2000)
    M = model.n_muscles
    T = step_basis(model.jaw_joint, M)
    rng = np.random.default_rng(3)
    R = rng.normal(size=(3 * M, M + 24))
    H = 2.0 * R.T @ R + 1e-3 * np.eye(M + 24)
    g = rng.normal(size=M + 24) * 10.0
    c = np.zeros(M + 24)
    c[:M] = rng.uniform(0.0, 1.0, size=M)
    return model, T, H, g, c


def test_the_step_keeps_the_box_and_the_joint_equalities(problem):
    model, T, H, g, c = problem
    M = model.n_muscles
    lower = model.activation_lower_bounds
    dc, _ = bounded_step(T, H, g, c, lower)
    a = c[:M] + dc[:M]
    assert np.all(a >= lower - 1e-12) and np.all(a <= 1.0 + 1e-12)
    assert np.any(np.isclose(a, 1.0)) or np.any(np.isclose(a, lower))  # this problem meets its bounds
    A, _, lo, hi = _joint_rows(model.jaw_joint)
    assert np.abs(A[lo == hi] @ dc[M + 12 :]).max() < 1e-12


def test_frozen_activations_stay_and_the_rest_solve_the_reduced_problem(problem):
    model, T, H, g, c = problem
    M = model.n_muscles
    lower = model.activation_lower_bounds
    frozen = np.zeros(M, dtype=bool)
    frozen[::3] = True
    dc, _ = bounded_step(T, H, g, c, lower, frozen=frozen)
    assert not np.any(dc[:M][frozen])
    # the same step as the problem with those activations removed from the controls
    keep = np.concatenate([~frozen, np.ones(24, dtype=bool)])
    Tr = step_basis(model.jaw_joint, int((~frozen).sum()))
    dr, _ = bounded_step(Tr, H[np.ix_(keep, keep)], g[keep], c[keep], lower[~frozen])
    np.testing.assert_allclose(dc[keep], dr, atol=1e-9 * np.abs(dr).max())
    full, _ = bounded_step(T, H, g, c, lower)
    assert 0.5 * dc @ H @ dc + g @ dc >= 0.5 * full @ H @ full + g @ full - 1e-9  # frozen costs descent
