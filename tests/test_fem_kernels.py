"""Constitutive model and element kernels: SVD convention, fibre curves, energy / force / stiffness
consistency by central finite differences (float64), definiteness, invariance, the affine split in
the activations, and float32 against float64."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from wface.model import Material
from wface.physics import Simulator
from wface.testing.models import box_model, single_tet_model

_ROUNDOFF = 1e-12  # float64 round-off relative to the force scale of an element
_FD_REL = 2e-6  # central differences with h = 1e-6 edge: O(h^2) truncation + O(eps/h) round-off


# the default flesh, ArtiSynth's Badin flesh (C10 and C20 (I1~ - 3)^2, no C01; docs/design.md, "Flesh"), and
# that with ArtiSynth's quadratic bulk potential kappa/2 (J - 1)^2
_MATERIALS = {
    "default": Material(),
    "c20": Material.artisynth(),
    "quadratic_bulk": replace(Material.artisynth(), bulk_potential="quadratic"),
}


@pytest.fixture(scope="module", params=list(_MATERIALS))
def tet_sim(request):
    return Simulator(single_tet_model().with_material(_MATERIALS[request.param]), precision="float64")


@pytest.fixture(scope="module", params=list(_MATERIALS))
def box_sim(request):
    return Simulator(box_model((3, 2, 2), muscles=2).with_material(_MATERIALS[request.param]), precision="float64")


def _configurations(X: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Random, inverted and near-degenerate configurations of the single tet (edge 1 cm)."""
    h = 0.01
    configs = {}
    for k in range(3):
        configs[f"random{k}"] = X + 0.35 * h * rng.normal(size=X.shape)
    inv = X.copy()
    inv[3, 2] = -0.4 * h  # node 3 pushed through the opposite face: det F < 0
    configs["inverted"] = inv + 0.02 * h * rng.normal(size=X.shape)
    flat = X.copy()
    flat[3] = [0.3 * h, 0.3 * h, 1e-4 * h]  # nearly flat: smallest singular value ~1e-4 (clamped)
    configs["near_degenerate"] = flat
    stretched = X @ np.diag([1.6, 0.8, 0.9])  # fibre stretch past 1.4: linear passive branch
    configs["stretched"] = stretched
    return configs


def _warp_svd(F: np.ndarray):
    import warp as wp

    from wface.kernels.fem import fem_kernels
    from wface.warp_runtime import init_warp

    init_warp()
    k = fem_kernels(wp.float64)
    n = len(F)
    U = wp.zeros(n, dtype=wp.mat33d)
    s = wp.zeros(n, dtype=wp.vec3d)
    V = wp.zeros(n, dtype=wp.mat33d)
    wp.launch(k.singular_values, n, inputs=[wp.array(F, dtype=wp.mat33d), U, s, V])
    return U.numpy(), s.numpy(), V.numpy()


def test_svd3_convention_is_inversion_safe():
    """Warp 1.19 wp.svd3 (float64): F = U diag(s) V^T, det U = det V = +1, s1 >= s2 >= |s3|, and
    only the smallest singular value carries the sign of det F (Irving et al. 2004)."""
    rng = np.random.default_rng(0)
    F = list(rng.normal(size=(40, 3, 3)))
    F += [np.eye(3), np.diag([1.0, 1.0, -1.0]), np.diag([2.0, -1.0, 0.5]), np.diag([1.0, 1.0, 0.0])]
    F += [np.outer(rng.normal(size=3), rng.normal(size=3)) + 1e-9 * rng.normal(size=(3, 3))]  # rank ~1
    F = np.array(F)
    U, s, V = _warp_svd(F)
    np.testing.assert_allclose(np.einsum("tij,tj,tkj->tik", U, s, V), F, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(U), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(V), 1.0, atol=1e-12)
    assert np.all(s[:, 0] >= s[:, 1] - 1e-14) and np.all(s[:, 1] >= np.abs(s[:, 2]) - 1e-14)
    assert np.all(s[:, :2] >= 0)
    det = np.linalg.det(F)
    sure = np.abs(det) > 1e-12
    assert np.all(np.sign(s[sure, 2]) == np.sign(det[sure]))
    np.testing.assert_allclose(np.sort(np.abs(s), axis=1), np.sort(np.linalg.svd(F)[1], axis=1), rtol=0, atol=1e-10)


# ---------------------------------------------------------------------- fibre curves (docs/design.md, "Muscle fibres")
def _fl(lam):
    x = np.abs(lam - 1.0)
    return np.where(x < 0.4, 1 - 25 / 6 * x**2, np.where(x < 0.6, 25 / 3 * (x - 0.6) ** 2, 0.0))


def _fp(lam):
    x = lam - 1.0
    xe = np.clip(x, 0.0, 0.4)
    f = 0.05 * (np.exp(6.6 * xe) - 6.6 * xe - 1)
    slope = 0.05 * 6.6 * (np.exp(6.6 * 0.4) - 1)
    return np.where(x <= 0, 0.0, np.where(x <= 0.4, f, f + slope * (x - 0.4)))


def _warp_curves(lam: np.ndarray, curves: int = 0) -> np.ndarray:
    import warp as wp

    from wface.kernels.fem import fem_kernels
    from wface.warp_runtime import init_warp

    init_warp()
    k = fem_kernels(wp.float64)
    out = wp.zeros((lam.size, 6), dtype=wp.float64)
    wp.launch(k.fibre_curves, lam.size, inputs=[wp.array(lam, dtype=wp.float64), curves, out])
    return out.numpy()


_BREAKS = (0.4, 0.6, 1.0, 1.4, 1.6)  # the curves' pieces meet here


def _check_curves(curves: int, active, passive, passive_atol: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``fibre_curves`` kernel's columns for ``curves`` against numpy's ``active`` and ``passive``, their
    derivatives by central differences away from the breakpoints and their integrals from 1 (the fibre energy
    per unit volume and sigma_max) by quadrature. Returns the stretches and the columns."""
    from scipy.integrate import quad

    lam = np.linspace(0.2, 2.2, 2001)
    c = _warp_curves(lam, curves)
    np.testing.assert_allclose(c[:, 0], active(lam), atol=1e-14)
    np.testing.assert_allclose(c[:, 3], passive(lam), atol=passive_atol)
    h = 1e-6
    away = np.min(np.abs(lam[:, None] - np.array(_BREAKS)[None]), axis=1) > 10 * h
    cp, cm = _warp_curves(lam + h, curves), _warp_curves(lam - h, curves)
    np.testing.assert_allclose(c[away, 1], ((cp[:, 0] - cm[:, 0]) / (2 * h))[away], atol=1e-7)
    np.testing.assert_allclose(c[away, 4], ((cp[:, 3] - cm[:, 3]) / (2 * h))[away], atol=1e-7)
    for lv, row in zip(lam[::50], c[::50], strict=True):
        il = quad(active, 1.0, lv, points=[0.4, 0.6, 1.4, 1.6], limit=200)[0]
        ip = quad(passive, 1.0, lv, points=[1.4], limit=200)[0]
        assert row[2] == pytest.approx(il, abs=1e-10) and row[5] == pytest.approx(ip, abs=1e-10)
    return lam, c


def test_fibre_curves_match_design_formulas_and_are_c1():
    lam, c = _check_curves(0, _fl, _fp, 1e-13)
    # C1 at every breakpoint: values and slopes agree from both sides (to O(h) of the slope change)
    for b in _BREAKS:
        left, right = _warp_curves(np.array([b - 1e-9])), _warp_curves(np.array([b + 1e-9]))
        np.testing.assert_allclose(left, right, atol=1e-7)
    assert _fl(np.array([1.0]))[0] == 1.0 and c[np.argmin(np.abs(lam - 1.0)), 3] == 0.0


def _blemker_active(lam: np.ndarray) -> np.ndarray:
    """ArtiSynth's BlemkerMuscle.computeStressAndTangent ``fact`` (optLambda 1): its pieces and zero band."""
    f = np.where(lam <= 0.6, 9 * (lam - 0.4) ** 2, np.where(lam < 1.4, 1 - 4 * (1 - lam) ** 2, 9 * (lam - 1.6) ** 2))
    return np.where((lam < 0.4) | (lam > 1.6), 0.0, f)


def _blemker_passive(lam: np.ndarray) -> np.ndarray:
    """BlemkerMuscle's ``fpas`` (P1 0.05, P2 6.6, maxLambda 1.4, zero at and below optLambda): P3 lam + P4 above
    1.4, with P3 = P1 P2 exp(P2 (1.4 - 1)) and P4 = P1 (exp(P2 0.4) - 1) - P3 1.4 (``updateDepCoefs``)."""
    p1, p2 = 0.05, 6.6
    p3 = p1 * p2 * np.exp(p2 * 0.4)
    p4 = p1 * (np.exp(p2 * 0.4) - 1) - p3 * 1.4
    f = np.where(lam <= 1.4, p1 * (np.exp(p2 * (lam - 1)) - 1), p3 * lam + p4)
    return np.where(lam <= 1.0, 0.0, f)


def test_blemker_curves_are_artisynths():
    """``curves`` 1 (``Material.fibre_stress = "blemker"``) against BlemkerMuscle's formulas, their
    derivatives by central differences and integrals by quadrature."""
    lam, c = _check_curves(1, _blemker_active, _blemker_passive, 1e-12)
    # where the two laws part: Blemker's active curve lies above wface's (by x^2 / 6 inside |x| < 0.4) and
    # its passive one starts with slope 0.33 at lam = 1 where wface's starts flat
    wf = _warp_curves(lam, 0)
    inner = np.abs(lam - 1) < 0.4
    np.testing.assert_allclose((c - wf)[inner, 0], (lam[inner] - 1) ** 2 / 6, atol=1e-14)
    just_above = _warp_curves(np.array([1.0 + 1e-9]), 1)[0]
    assert just_above[4] == pytest.approx(0.05 * 6.6, rel=1e-6) and _warp_curves(np.array([1.0 + 1e-9]))[0][4] < 1e-6


def test_generic_curves_are_artisynths():
    """``curves`` 2 (``Material.muscle_curves``: ArtiSynth's GenericMuscle): f_L = 1 at every stretch, no
    passive stress (GenericMuscle's, 0.05 Pa (exp(6.6 x) - 1) / lam, is not scaled by maxStress: below 1 Pa up to
    its maxLambda 1.4, where the curves above are scaled by sigma_max = 1e5 Pa)."""
    lam, c = _check_curves(2, np.ones_like, np.zeros_like, 0.0)
    np.testing.assert_allclose(c[:, 2], lam - 1, atol=1e-14)  # integral of f_L from 1
    assert 0.05 * (np.exp(6.6 * 0.4) - 1) / 1.4 < 1.0  # the passive stress left out, Pa


# ---------------------------------------------------------------------- energy, forces, stiffness
def test_rest_state_has_zero_force_and_energy(box_sim):
    X = box_sim.model.rest_positions_m
    E, f = box_sim.energy_and_forces(X, None)
    scale = box_sim.model.material.kappa_pa * 0.01**2  # bulk modulus x element face area, newtons
    assert abs(E) < _ROUNDOFF * scale * 0.01
    assert np.abs(f).max() < _ROUNDOFF * scale
    # the passive fibre is slack at rest too; an active muscle is not
    f_act = box_sim.forces(X, {"muscle_0": 1.0})
    assert np.abs(f_act).max() > 1e-3 * box_sim.model.material.sigma_max_pa * 0.01**2


def test_forces_are_minus_energy_gradient(tet_sim):
    X = tet_sim.model.rest_positions_m
    a = np.array([0.6])
    h = 1e-6 * 0.01
    for name, x in _configurations(X, np.random.default_rng(1)).items():
        E, f = tet_sim.energy_and_forces(x, a)
        g = np.zeros_like(x)
        for i in range(4):
            for d in range(3):
                xp, xm = x.copy(), x.copy()
                xp[i, d] += h
                xm[i, d] -= h
                g[i, d] = (tet_sim.energy(xp, a) - tet_sim.energy(xm, a)) / (2 * h)
        err = np.abs(g + f).max() / np.abs(f).max()
        assert err < _FD_REL, f"{name}: |dE/dx + f| / |f| = {err:.2e}"


def test_exact_tangent_is_minus_force_jacobian(tet_sim):
    X = tet_sim.model.rest_positions_m
    a = np.array([0.6])
    h = 1e-6 * 0.01
    for name, x in _configurations(X, np.random.default_rng(2)).items():
        K = tet_sim.assemble_stiffness(x, a, project=False).toarray()
        Kfd = np.zeros((12, 12))
        for i in range(4):
            for d in range(3):
                xp, xm = x.copy(), x.copy()
                xp[i, d] += h
                xm[i, d] -= h
                Kfd[:, 3 * i + d] = -(tet_sim.forces(xp, a) - tet_sim.forces(xm, a)).ravel() / (2 * h)
        err = np.abs(K - Kfd).max() / np.abs(K).max()
        assert err < _FD_REL, f"{name}: |K + df/dx| / |K| = {err:.2e}"
        np.testing.assert_allclose(K, K.T, atol=1e-9 * np.abs(K).max())


def test_projected_tangent_is_positive_semidefinite(box_sim):
    model = box_sim.model
    X = model.rest_positions_m
    rng = np.random.default_rng(3)
    configs = [X + 0.004 * rng.normal(size=X.shape) for _ in range(3)]
    squashed = X.copy()
    squashed[:, 0] *= 0.3  # strong compression: exact Hessian indefinite
    configs.append(squashed + 0.001 * rng.normal(size=X.shape))
    inverted = X.copy()
    inverted[:, 2] = 0.02 - inverted[:, 2]  # mirrored: every tet inverted
    configs.append(inverted)
    free = model.free_nodes
    saw_indefinite_exact = False
    for x in configs:
        for a in (np.zeros(2), np.array([1.0, 0.5])):
            K = box_sim.assemble_stiffness(x, a).toarray()
            ev = np.linalg.eigvalsh(K)
            assert ev[0] > -1e-9 * ev[-1], f"projected K has eigenvalue {ev[0]:.3g} (max {ev[-1]:.3g})"
            dofs = (3 * free[:, None] + np.arange(3)).ravel()
            assert np.linalg.eigvalsh(K[np.ix_(dofs, dofs)])[0] > 1e-9 * ev[-1]
            exact = np.linalg.eigvalsh(box_sim.assemble_stiffness(x, a, project=False).toarray())
            saw_indefinite_exact |= exact[0] < -1e-6 * exact[-1]
    assert saw_indefinite_exact, "the test should include states where the exact Hessian is indefinite"
    # at rest the exact Hessian is already PSD, so projection leaves it unchanged
    Kp = box_sim.assemble_stiffness(X, None).toarray()
    Ke = box_sim.assemble_stiffness(X, None, project=False).toarray()
    np.testing.assert_allclose(Kp, Ke, atol=1e-10 * np.abs(Ke).max())


def test_rotation_invariance(box_sim):
    from scipy.spatial.transform import Rotation

    X = box_sim.model.rest_positions_m
    rng = np.random.default_rng(4)
    x = X + 0.003 * rng.normal(size=X.shape)
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    xr = x @ R.T + np.array([0.1, -0.2, 0.05])
    a = np.array([0.7, 0.2])
    E, f = box_sim.energy_and_forces(x, a)
    Er, fr = box_sim.energy_and_forces(xr, a)
    assert Er == pytest.approx(E, rel=1e-10)
    np.testing.assert_allclose(fr, f @ R.T, atol=1e-9 * np.abs(f).max())
    # rigid motions of the rest shape produce no force
    assert np.abs(box_sim.forces(X @ R.T + 0.3, None)).max() < 1e-9 * np.abs(f).max()


def test_forces_are_affine_in_activations(box_sim):
    X = box_sim.model.rest_positions_m
    x = X + 0.002 * np.random.default_rng(5).normal(size=X.shape)
    a = np.array([0.3, 0.9])
    f0 = box_sim.forces(x, np.zeros(2))
    fi = box_sim.muscle_forces(x)
    assert fi.shape == (2, box_sim.model.n_nodes, 3)
    np.testing.assert_allclose(box_sim.forces(x, a), f0 + np.einsum("i,inc->nc", a, fi), atol=1e-9 * np.abs(fi).max())
    assert np.abs(fi[0]).max() > 0 and np.abs(fi[1]).max() > 0


def test_muscle_force_sum_is_the_weighted_sum_of_the_muscle_forces(box_sim):
    """``muscle_force_sum(w, x)`` = sum_i w_i f_i(x) in one launch, with a per-muscle force scale, a
    zero weight (skipped entries) and a negative one (a step), to round-off."""
    X = box_sim.model.rest_positions_m
    x = X @ np.diag([1.1, 0.9, 1.0]).T + 0.002 * np.random.default_rng(15).normal(size=X.shape)
    try:
        for scale, w in ((1.0, [0.3, -0.8]), (np.array([0.5, 1.7]), [0.0, 0.6])):
            box_sim.force_length_scale = scale
            ref = np.einsum("i,inc->nc", np.array(w), box_sim.muscle_forces(x))
            got = box_sim.muscle_force_sum(np.array(w), x)
            assert got.shape == (box_sim.model.n_nodes, 3) and np.abs(ref).max() > 0
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
        with pytest.raises(ValueError, match="weights"):
            box_sim.muscle_force_sum(np.ones(3), x)
    finally:
        box_sim.force_length_scale = 1.0


def test_matrix_free_product_and_diagonal_match_assembled_matrix(box_sim):
    model = box_sim.model
    X = model.rest_positions_m
    rng = np.random.default_rng(6)
    x = X + 0.003 * rng.normal(size=X.shape)
    a = np.array([0.5, 1.0])
    for project in (True, False):
        tan = box_sim.tangent(x, a, project=project)
        K = tan.assemble()
        v = rng.normal(size=X.shape)
        np.testing.assert_allclose(tan.matvec(v).ravel(), K @ v.ravel(), atol=1e-10 * np.abs(K).max())
        np.testing.assert_allclose(tan.diagonal().ravel(), K.diagonal(), atol=1e-10 * np.abs(K).max())
        free = model.free_nodes
        dofs = (3 * free[:, None] + np.arange(3)).ravel()
        Kf = tan.assemble(box_sim.pattern("free"))
        np.testing.assert_allclose(Kf.toarray(), K[dofs][:, dofs].toarray(), atol=1e-12 * np.abs(K).max())


def test_float32_kernels_agree_with_float64():
    model = box_model((3, 2, 2), muscles=2)
    s64, s32 = Simulator(model), Simulator(model, precision="float32")
    X = model.rest_positions_m
    x = X + 0.002 * np.random.default_rng(7).normal(size=X.shape)
    a = np.array([0.4, 0.8])
    f64, f32 = s64.forces(x, a), s32.forces(x, a)
    # float32 positions (1e-7 relative) amplified by kappa / mu ~ 40 in the volumetric stress
    assert np.abs(f32 - f64).max() < 1e-3 * np.abs(f64).max()
    v = np.random.default_rng(8).normal(size=X.shape)
    k64, k32 = s64.stiffness_matvec(x, a, v), s32.stiffness_matvec(x, a, v)
    assert np.abs(k32 - k64).max() < 1e-3 * np.abs(k64).max()
    fi64, fi32 = s64.muscle_forces(x), s32.muscle_forces(x)
    assert np.abs(fi32 - fi64).max() < 1e-4 * np.abs(fi64).max()


def test_material_parameters_are_used():
    """Energy is linear in (mu10, mu01, mu20, kappa) for a fixed deformation (no fibres active)."""
    base = box_model((2, 1, 1), muscles=0)
    X = base.rest_positions_m
    x = X + 0.002 * np.random.default_rng(9).normal(size=X.shape)
    names = ("mu10_pa", "mu01_pa", "mu20_pa", "kappa_pa")
    zero = dict.fromkeys(names, 0.0)
    e = [Simulator(base.with_material(Material(**{**zero, n: 1.0}))).energy(x) for n in names]
    mixed = Material(mu10_pa=2500.0, mu01_pa=800.0, mu20_pa=1175.0, kappa_pa=25000.0)
    total = Simulator(base.with_material(mixed)).energy(x)
    assert total == pytest.approx(sum(getattr(mixed, n) * en for n, en in zip(names, e, strict=True)), rel=1e-10)


def test_flesh_energy_density_matches_closed_form_mooney_rivlin():
    """psi(s), its gradient and Hessian in the singular values against the textbook formula
    psi = mu10 (J^-2/3 I1 - 3) + mu01 (J^-4/3 I2 - 3) + kappa/2 ln^2 J, by complex-step
    derivatives (exact to round-off) for the gradient and complex-step over central differences
    (h = 1e-6, truncation ~1e-10 relative) for the Hessian."""
    import warp as wp

    from wface.kernels.fem import fem_kernels
    from wface.warp_runtime import init_warp

    init_warp()
    mat = Material()
    mu10, mu01, kappa = mat.mu10_pa, mat.mu01_pa, mat.kappa_pa

    def psi(s):
        J = s[0] * s[1] * s[2]
        I1 = s[0] ** 2 + s[1] ** 2 + s[2] ** 2
        I2 = (s[0] * s[1]) ** 2 + (s[0] * s[2]) ** 2 + (s[1] * s[2]) ** 2
        return mu10 * (J ** (-2 / 3) * I1 - 3) + mu01 * (J ** (-4 / 3) * I2 - 3) + 0.5 * kappa * np.log(J) ** 2

    rng = np.random.default_rng(11)
    S = np.sort(rng.uniform(0.3, 2.0, size=(8, 3)), axis=1)[:, ::-1].copy()
    S = np.vstack([S, [1.0, 1.0, 1.0], [1.5, 1.5, 0.6]])
    k = fem_kernels(wp.float64)
    n = len(S)
    p, g, H = wp.zeros(n, dtype=wp.float64), wp.zeros(n, dtype=wp.vec3d), wp.zeros(n, dtype=wp.mat33d)
    wp.launch(
        k.flesh_in_singular_values,
        n,
        inputs=[wp.array(S, dtype=wp.vec3d), mu10, mu01, mat.mu20_pa, kappa, 0.0, mat.inversion_clamp, p, g, H],
    )
    e, hc, hd = np.eye(3), 1e-30, 1e-6
    for i, s in enumerate(S):
        grad = np.array([np.imag(psi(s + 1j * hc * e[d])) / hc for d in range(3)])
        hess = np.array(
            [
                [
                    (np.imag(psi(s + 1j * hc * e[d] + hd * e[c])) - np.imag(psi(s + 1j * hc * e[d] - hd * e[c])))
                    / (2 * hc * hd)
                    for c in range(3)
                ]
                for d in range(3)
            ]
        )
        scale = mu10 + mu01 + kappa
        assert p.numpy()[i] == pytest.approx(psi(s), abs=1e-12 * scale)
        np.testing.assert_allclose(g.numpy()[i], grad, rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(H.numpy()[i], hess, rtol=0, atol=1e-8 * np.abs(hess).max())


def test_float32_newton_reaches_the_float64_equilibrium():
    model = box_model((4, 2, 2), cranium_faces=("x-",), muscles=2)
    act = {"muscle_0": 0.8}
    r64 = Simulator(model).solve(act, tol=1e-10)
    r32 = Simulator(model, precision="float32").solve(act, tol=1e-4)  # float32 forces: ~1e-6 relative noise
    assert r32.converged
    u = np.abs(r64.x - model.rest_positions_m).max()
    assert np.abs(r32.x - r64.x).max() < 1e-4 * u


def test_parallel_cpu_launch_over_tet_ranges_matches_serial(box_sim):
    """Kernels split over threads by tet range: per-tet outputs (tangent, energy) are bit-identical;
    scattered outputs (forces, K v, diag K, assembled K) agree to summation-order round-off."""
    X = box_sim.model.rest_positions_m
    rng = np.random.default_rng(10)
    x = X + 0.003 * rng.normal(size=X.shape)
    v = rng.normal(size=X.shape)
    a = np.array([0.5, 1.0])

    def evaluate():
        tan = box_sim.tangent(x, a)
        return (
            tan.element_tangents.numpy(),
            box_sim.element_energies(x, a),
            box_sim.forces(x, a),
            tan.matvec(v),
            tan.diagonal(),
            tan.assemble().toarray(),
        )

    serial = evaluate()
    box_sim.parallel_min_tets = 0
    try:
        parallel = evaluate()
    finally:
        box_sim.parallel_min_tets = 20_000
    np.testing.assert_array_equal(parallel[0], serial[0])
    np.testing.assert_array_equal(parallel[1], serial[1])
    for p, s in zip(parallel[2:], serial[2:], strict=True):
        np.testing.assert_allclose(p, s, rtol=0, atol=1e-13 * np.abs(s).max())


def test_force_length_scale_exaggerates_the_active_curve_only():
    model = box_model((3, 2, 2), muscles=2)
    X = model.rest_positions_m
    x = X + 0.002 * np.random.default_rng(12).normal(size=X.shape)
    plain, doubled = Simulator(model), Simulator(model, force_length_scale=2.0)
    tol = 1e-12 * np.abs(plain.forces(x, [1.0, 1.0])).max()
    np.testing.assert_allclose(doubled.forces(x, [0.5, 0.25]), plain.forces(x, [1.0, 0.5]), rtol=0, atol=tol)
    np.testing.assert_allclose(doubled.forces(x, None), plain.forces(x, None), rtol=0, atol=tol)  # passive as is
    np.testing.assert_allclose(doubled.muscle_forces(x), 2.0 * plain.muscle_forces(x), rtol=0, atol=tol)
    with pytest.raises(ValueError):
        doubled.forces(x, [1.5, 0.0])  # activations themselves stay in [0, 1]
