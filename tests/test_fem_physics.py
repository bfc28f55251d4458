"""Physics of the quasistatic solver checked against independent answers: uniaxial Mooney-Rivlin
stretch (closed form), small-strain limit against a linear-elastic solve of the same mesh by
scikit-fem, recovery from inverted elements, bone placement, and the anatomy of the built-in face."""

from __future__ import annotations

import numpy as np
import pytest

from wface.controls import attached_positions_from_affines, jaw_opening_affine, rotation_about_axis
from wface.model import Material
from wface.physics import Simulator, count_inverted
from wface.testing.models import box_model

MAT = Material()
# ArtiSynth's Badin flesh law (C10, C20 (I1~ - 3)^2) with the default's kappa / mu ~ 40
C20_MAT = Material(mu10_pa=2500.0, mu01_pa=0.0, mu20_pa=1175.0, kappa_pa=2.0e5)


# ---------------------------------------------------------------------- uniaxial stretch
def _psi_uniaxial(lam, mu, mat=MAT):
    """Closed-form Mooney-Rivlin energy density for F = diag(lam, mu, mu) (complex-step friendly)."""
    J = lam * mu * mu
    I1 = lam**2 + 2 * mu**2
    I2 = 2 * lam**2 * mu**2 + mu**4
    u = J ** (-2 / 3) * I1 - 3
    return (
        mat.mu10_pa * u
        + mat.mu01_pa * (J ** (-4 / 3) * I2 - 3)
        + mat.mu20_pa * u**2
        + 0.5 * mat.kappa_pa * np.log(J) ** 2
    )


def _d(fun, z, h=1e-30):
    return np.imag(fun(z + 1j * h)) / h  # complex step: exact to round-off


def _uniaxial_state(lam, mat=MAT):
    """Lateral stretch mu with P22 = 0 (traction-free sides) and the nominal stress P11, in Pa."""
    from scipy.optimize import brentq

    mu = brentq(lambda m: _d(lambda mm: _psi_uniaxial(lam, mm, mat), m), 0.5, 1.5, xtol=1e-15)
    return mu, _d(lambda ll: _psi_uniaxial(ll, mu, mat), lam)


@pytest.mark.parametrize("mat", [MAT, C20_MAT], ids=["default", "c20"])
@pytest.mark.parametrize("lam", [1.3, 0.8])
def test_uniaxial_stretch_matches_closed_form(lam, mat):
    """Ends clamped to the homogeneous uniaxial state; Newton must find it for the free (interior
    and side) nodes, and the end reaction must equal P11 A0 (linear tets represent it exactly)."""
    size = (0.04, 0.02, 0.02)
    model = box_model((4, 2, 2), size, cranium_faces=("x-", "x+"), muscles=0).with_material(mat)
    mu, P11 = _uniaxial_state(lam, mat)
    X = model.rest_positions_m
    homogeneous = X * np.array([lam, mu, mu])
    sim = Simulator(model)
    eq = sim.solve(None, homogeneous[model.attached_nodes], tol=1e-10)
    assert eq.converged and eq.inverted_elements == 0
    np.testing.assert_allclose(eq.x, homogeneous, atol=1e-9 * size[0])  # float64 Newton to tol 1e-10
    f = sim.forces(eq.x, None)
    end = np.abs(X[:, 0] - size[0]) < 1e-12
    reaction = -f[end].sum(axis=0)
    area = size[1] * size[2]
    assert reaction[0] == pytest.approx(P11 * area, rel=1e-8)
    assert np.abs(reaction[1:]).max() < 1e-8 * abs(P11) * area
    # sanity of the closed form itself: near the incompressible limit 2 (W1 + W2/lam)(lam - lam^-2),
    # W1 = mu10 + 2 mu20 (I1 - 3), W2 = mu01, I1 = lam^2 + 2/lam (C20: +21 % at lam = 1.3, +13 % at 0.8)
    w1 = mat.mu10_pa + 2 * mat.mu20_pa * (lam**2 + 2 / lam - 3)
    incompressible = 2 * (w1 + mat.mu01_pa / lam) * (lam - lam**-2)
    assert P11 == pytest.approx(incompressible, rel=0.05)  # kappa / mu ~ 40: a few percent compressibility


# ---------------------------------------------------------------------- small strain vs scikit-fem
def _linear_elastic_skfem(X, tets, fixed, values, mu, bulk):
    from skfem import Basis, ElementTetP1, ElementVector, MeshTet, asm, condense, solve
    from skfem.models.elasticity import linear_elasticity

    mesh = MeshTet(X.T.copy(), tets.T.copy())
    basis = Basis(mesh, ElementVector(ElementTetP1()))
    K = asm(linear_elasticity(Lambda=bulk - 2.0 * mu / 3.0, Mu=mu), basis)
    u = np.zeros(basis.N)
    dofs = basis.nodal_dofs  # (3, n): dof of component c at node i
    u[dofs[:, fixed]] = values.T
    D = dofs[:, fixed].ravel()
    u = solve(*condense(K, np.zeros(basis.N), x=u, D=D))
    return u[dofs].T


@pytest.mark.parametrize("mat", [MAT, C20_MAT], ids=["default", "c20"])
def test_small_strain_limit_matches_linear_elasticity(mat):
    """Same mesh and Dirichlet data; Lame parameters from the small-strain limit of the material:
    mu = 2 (mu10 + mu01), bulk modulus K = kappa (mu20 (I1~ - 3)^2 is second order in the strain and
    adds nothing). The difference is geometric nonlinearity, O(strain): it must halve when the
    imposed displacement halves."""
    size = (0.04, 0.02, 0.02)
    model = box_model((4, 2, 2), size, cranium_faces=("x-", "x+"), muscles=0).with_material(mat)
    X = model.rest_positions_m
    fixed = model.attached_nodes
    sim = Simulator(model)
    errors = []
    for amplitude in (2e-5, 1e-5):  # metres on a 4 cm bar: strains 5e-4, 2.5e-4
        disp = np.zeros((fixed.size, 3))
        right = X[fixed, 0] > size[0] / 2
        disp[right] = amplitude * np.array([0.5, 1.0, -0.3])
        eq = sim.solve(None, X[fixed] + disp, tol=1e-10)
        assert eq.converged
        u_nl = eq.x - X
        u_lin = _linear_elastic_skfem(X, model.tets, fixed, disp, 2 * (mat.mu10_pa + mat.mu01_pa), mat.kappa_pa)
        errors.append(np.abs(u_nl - u_lin).max() / np.abs(u_lin).max())
    assert errors[0] < 2e-3, errors
    assert 1.6 < errors[0] / errors[1] < 2.4, errors  # first order in the strain


# ---------------------------------------------------------------------- inversion and solvers
def test_inverted_start_recovers():
    model = box_model((3, 2, 2), (0.03, 0.02, 0.02), cranium_faces=("x-",), muscles=1)
    X = model.rest_positions_m
    sim = Simulator(model)
    x0 = X.copy()
    corner = np.flatnonzero(np.all(np.abs(X - [0.03, 0.02, 0.02]) < 1e-12, axis=1))[0]
    x0[corner] += [-0.018, -0.016, -0.015]  # through its neighbours: several tets inverted
    assert count_inverted(model, x0) > 0
    eq = sim.solve(None, x0=x0)
    assert eq.converged and eq.inverted_elements == 0
    np.testing.assert_allclose(eq.x, X, atol=1e-6 * 0.03)
    act = {"muscle_0": 0.7}
    ref = sim.solve(act)
    again = sim.solve(act, x0=x0)
    assert ref.converged and again.converged and again.inverted_elements == 0
    np.testing.assert_allclose(again.x, ref.x, atol=1e-6 * 0.03)


def test_solution_does_not_depend_on_the_linear_solver_or_stiffness_choice():
    model = box_model((4, 2, 2), cranium_faces=("x-",), muscles=2)
    sim = Simulator(model)
    act = {"muscle_0": 0.9, "muscle_1": 0.2}
    direct = sim.solve(act, solver="direct", tol=1e-10)
    cg = sim.solve(act, solver="cg", tol=1e-10)
    projected = sim.solve(act, solver="direct", stiffness="projected", tol=1e-10)
    reused = sim.solve(act, solver="direct", reuse_factor=True, tol=1e-10)
    assert direct.solver == "direct" and cg.solver == "cg" and cg.cg_iterations > 0
    assert reused.factorizations >= 1 and reused.factorizations <= reused.iterations
    for other in (cg, projected, reused):
        assert other.converged
        np.testing.assert_allclose(other.x, direct.x, atol=1e-8 * 0.04)
    # contracting fibres along x shorten the bar
    assert direct.x[:, 0].max() < model.rest_positions_m[:, 0].max() - 1e-4


# ---------------------------------------------------------------------- bones
def test_attached_positions_compose_cranium_and_jaw():
    model = box_model((2, 2, 2), cranium_faces=("x-",), jaw_faces=("x+",), muscles=0)
    X0 = model.rest_positions_m[model.attached_nodes]
    np.testing.assert_array_equal(attached_positions_from_affines(model), X0)
    rng = np.random.default_rng(0)
    Ac, Am = rng.normal(size=(3, 4)), rng.normal(size=(3, 4))
    got = attached_positions_from_affines(model, cranium=Ac, jaw=Am)
    on_jaw = model.attached_bone == 1
    Mc, tc, Mm, tm = Ac[:, :3], Ac[:, 3], Am[:, :3], Am[:, 3]
    np.testing.assert_allclose(got[~on_jaw], X0[~on_jaw] @ Mc.T + tc, atol=1e-14)
    np.testing.assert_allclose(got[on_jaw], (X0[on_jaw] @ Mm.T + tm) @ Mc.T + tc, atol=1e-14)
    with pytest.raises(ValueError):
        attached_positions_from_affines(model, jaw=np.eye(3))


def test_jaw_opening_rotates_about_the_condyle_axis_and_lowers_the_chin():
    model = box_model((2, 2, 2), cranium_faces=("x-",), jaw_faces=("x+",), muscles=0)
    A = jaw_opening_affine(model, 15.0)
    R, t = A[:, :3], A[:, 3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0)
    m = np.asarray(model.jaw_joint.midpoint_m)
    u = np.asarray(model.jaw_joint.u)
    np.testing.assert_allclose(R @ (m + 0.05 * u) + t, m + 0.05 * u, atol=1e-14)  # the axis stays put
    chin = m + np.array([0.0, -0.05, 0.08])  # in front of and below the joint
    moved = R @ chin + t
    assert moved[1] < chin[1] - 0.01  # down by ~ |r| sin 15 deg
    np.testing.assert_allclose(np.linalg.norm(moved - m), np.linalg.norm(chin - m))
    np.testing.assert_allclose(rotation_about_axis(u, np.deg2rad(15.0)), R)
    np.testing.assert_allclose(jaw_opening_affine(model, 0.0), np.hstack([np.eye(3), np.zeros((3, 1))]), atol=1e-15)


# ---------------------------------------------------------------------- anatomy of the built-in face
@pytest.fixture(scope="module")
def face():
    from wface.faces.builtin import build_face

    model = build_face(3000)
    X = model.rest_positions_m
    nearest = {
        n: int(np.argmin(np.linalg.norm(X - p, axis=1)))
        for n, p in zip(model.marker_names, model.marker_positions_m, strict=True)
    }
    return model, Simulator(model), nearest


def _marker_motion_mm(face, activations, jaw_deg=0.0):
    model, sim, nearest = face
    eq = sim.solve(activations, attached_positions_from_affines(model, jaw=jaw_opening_affine(model, jaw_deg)))
    assert eq.converged and eq.inverted_elements == 0, (eq.residual_rel, eq.inverted_elements)
    d = (eq.x - model.rest_positions_m) * 1e3
    return {name: d[i] for name, i in nearest.items()}


def test_zygomaticus_major_pulls_the_mouth_corner_up_back_and_out(face):
    d = _marker_motion_mm(face, {"zygomaticus_major_l": 1.0})
    corner = d["Mouth_Lend"]
    assert corner[1] > 0.3 and corner[2] < -0.3 and corner[0] > 0.3, corner  # up (+y), back (-z), left (+x)
    assert np.linalg.norm(d["Mouth_Rend"]) < 0.5 * np.linalg.norm(corner)  # the other side moves less
    mirrored = _marker_motion_mm(face, {"zygomaticus_major_r": 1.0})["Mouth_Rend"]
    np.testing.assert_allclose(mirrored * [-1, 1, 1], corner, atol=0.1 * np.linalg.norm(corner))


def test_depressor_and_frontalis_move_their_landmarks(face):
    assert _marker_motion_mm(face, {"depressor_anguli_oris_l": 1.0})["Mouth_Lend"][1] < -0.3  # corner down
    assert _marker_motion_mm(face, {"frontalis_medial_l": 1.0})["Leyebrow_Inside"][1] > 0.3  # brow up


def test_jaw_opening_lowers_the_chin(face):
    d = _marker_motion_mm(face, None, jaw_deg=10.0)
    assert d["Chin"][1] < -3.0  # ~ 10 deg about a condyle axis several cm behind the chin
    assert abs(d["ForeHead_M"][1]) < 0.1 * abs(d["Chin"][1])


@pytest.mark.parametrize(
    "muscle, marker, axis, sign",
    [
        ("levator_labii_superioris_l", "Mouth_UpL1", 1, +1),  # raises the upper lip
        ("risorius_l", "Mouth_Lend", 0, +1),  # draws the corner sideways (+x is the subject's left)
        ("corrugator_l", "Leyebrow_Inside", 0, -1),  # pulls the brow towards the midline
        ("orbicularis_oris_lower", "Mouth_Down", 2, -1),  # the sphincter draws the lower lip in
    ],
)
def test_single_muscles_move_their_landmark_the_anatomical_way(face, muscle, marker, axis, sign):
    d = _marker_motion_mm(face, {muscle: 1.0})[marker]
    assert sign * d[axis] > 0.1, (muscle, marker, d)  # at least 0.1 mm along the anatomical direction
