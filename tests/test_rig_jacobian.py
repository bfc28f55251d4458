"""Jacobians of the equilibrium (Sifakis et al. 2005, eqs. 5-6) against central differences of re-solved equilibria."""

from __future__ import annotations

import numpy as np
import pytest

from wface.controls import attached_positions, jaw_from_intuitive, params_from_affine
from wface.faces.builtin import build_face
from wface.tracking.rig import FaceRig

# Central differences with h = 1e-4 (activations) / 1e-5 (jaw parameters) of equilibria solved to
# a relative residual of 1e-11: truncation O(h^2) ~ 1e-8 relative, solver error ~ 1e-9.
_REL_TOL = 1e-5


@pytest.fixture(scope="module")
def setup():
    model = build_face(2000)
    rig = FaceRig(model, tol=1e-11)
    c = rig.rest_controls()
    M = model.n_muscles
    rng = np.random.default_rng(0)
    c[:M] = rng.uniform(0.1, 0.4, size=M)  # interior activations: no bound kinks
    # The cranium check below rotates the world-frame solve, which needs a rotation-invariant energy:
    # the intra-oral pressure's dead load is fixed in the cranium frame, so it is off here (its
    # column is still checked: it does not depend on its own value).
    c[model.muscle_index("intraoral_pressure")] = 0.0
    c[M + 12 :] = jaw_from_intuitive(model.jaw_joint, 8.0, 0.003, 1.0)
    rot = np.linalg.qr(np.eye(3) + 0.05 * rng.normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    c[M : M + 12] = params_from_affine(rot, [0.01, -0.005, 0.002])
    state = rig.equilibrium(c)
    return model, rig, c, state, rig.jacobian(state)


@pytest.mark.parametrize(
    "which", ["zygomaticus_major_l", "orbicularis_oris_lower", "mentalis_r", "intraoral_pressure", 0, 4, 8, 9, 11]
)
def test_columns_match_central_differences(setup, which):
    model, rig, c, state, J = setup
    M = model.n_muscles
    col = model.muscle_index(which) if isinstance(which, str) else M + 12 + which
    h = 1e-4 if isinstance(which, str) else 1e-5
    cp, cm = c.copy(), c.copy()
    cp[col] += h
    cm[col] -= h
    fd = (rig.equilibrium(cp, state.y_m).x_m - rig.equilibrium(cm, state.y_m).x_m) / (2 * h)
    assert np.abs(fd - J[:, :, col]).max() <= _REL_TOL * np.abs(fd).max()


def test_analytic_cranium_columns_equal_solve_based(setup):
    """Rigid generators of the cranium: the analytic columns equal eq. 6 solved with every
    attached node (cranium and jaw) moved by dMc X + dtc (the flesh energy is rotation invariant)."""
    model, rig, c, state, J = setup
    M = model.n_muscles
    Mc = c[M : M + 9].reshape(3, 3)
    K = rig.sim.assemble_stiffness(state.y_m, np.clip(c[:M], 0, 1), project=False).tocsr()
    U, C = rig._free_dofs, rig._fixed_dofs
    from wface.solvers.linear import DirectFactor

    Xw = state.x_m
    XC = Xw[model.attached_nodes]
    for k in range(3):  # infinitesimal rotations about the world axes, at the current pose
        W = np.zeros((3, 3))
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        W[i, j], W[j, i] = -1.0, 1.0
        dMc = W @ Mc
        dtc = W @ c[M + 9 : M + 12]  # rotating the world also turns the cranium translation
        analytic = (
            np.einsum("nrab,ab->nr", J[:, :, M : M + 9].reshape(-1, 3, 3, 3), dMc) + J[:, :, M + 9 : M + 12] @ dtc
        )
        # Solve-based in the world frame: K is rotated, so use the world-frame tangent at X.
        Kw = rig.sim.assemble_stiffness(Xw, np.clip(c[:M], 0, 1), project=False).tocsr()
        dXC = (XC @ W.T).ravel()
        dXU = DirectFactor(Kw[U][:, U]).solve(-(Kw[U][:, C] @ dXC))
        solved = np.zeros(3 * model.n_nodes)
        solved[U], solved[C] = dXU, dXC
        assert np.abs(solved.reshape(-1, 3) - analytic).max() <= 1e-6 * np.abs(analytic).max()
    del K


def test_rigid_cranium_motion_moves_every_node_rigidly(setup):
    model, rig, c, state, _ = setup
    M = model.n_muscles
    c2 = c.copy()
    theta = 0.3
    R = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    Mc = c[M : M + 9].reshape(3, 3)
    c2[M : M + 12] = params_from_affine(R @ Mc, R @ c[M + 9 : M + 12] + [0.02, 0.0, -0.01])
    s2 = rig.equilibrium(c2, state.y_m)
    expected = state.x_m @ R.T + [0.02, 0.0, -0.01]
    assert np.abs(s2.x_m - expected).max() < 1e-9


def test_attached_positions_follow_bones(setup):
    model, rig, c, state, _ = setup
    M = model.n_muscles
    world = attached_positions(model, c[M:], frame="world")
    assert np.abs(state.x_m[model.attached_nodes] - world).max() < 1e-12


def test_held_muscles_columns_are_zero_and_the_others_unchanged(setup):
    """``FaceRig.linearize(held=)`` solves only the columns of the muscles not held (the jaw's always):
    those equal the full Jacobian's, the held ones are zero, and the solves counted are the columns solved."""
    model, rig, c, state, _ = setup
    M = model.n_muscles
    held = np.zeros(M, dtype=bool)
    held[[0, 3, model.muscle_index("mentalis_r")]] = True
    full = rig.linearize(state, keep_factor=False)
    before = rig.counters["linear_solves"]
    part = rig.linearize(state, keep_factor=False, held=held)
    assert rig.counters["linear_solves"] - before == M + 12 - held.sum()
    assert np.array_equal(part.held, held)
    assert not np.any(part.jy[:, np.flatnonzero(held)])
    keep = np.concatenate([~held, np.ones(12, dtype=bool)])
    np.testing.assert_allclose(part.jy[:, keep], full.jy[:, keep], rtol=0, atol=1e-10 * np.abs(full.jy).max())
    assert rig.linearize(state, keep_factor=False, held=np.zeros(M, dtype=bool)).held is None
    nodes = np.array([3, 17, 40])  # older rows stand in for the held columns at their nodes only
    older = np.random.default_rng(1).normal(size=(3, 3, M + 12))
    part.fill = (nodes, older)
    rows = part.node_rows(nodes)
    assert np.array_equal(rows[:, :, np.flatnonzero(held)], older[:, :, np.flatnonzero(held)])
    assert np.array_equal(rows[:, :, keep], part.jy.reshape(-1, 3, M + 12)[nodes][:, :, keep])
    assert not np.any(part.node_rows(nodes + 1)[:, :, np.flatnonzero(held)])
