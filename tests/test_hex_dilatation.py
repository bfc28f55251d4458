"""One volume ratio per hex (wface.physics.hex_dilatation): derivatives against finite differences,
the per-point term on affine fields, Jensen's inequality off them, the projected Hessian, a patch
test through ``HexBody`` and the checks that keep the bulk term from counting twice."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tests.test_hexes import SIZE_M, _distorted_box
from wface.physics import Simulator
from wface.physics.hex_dilatation import MeanDilatation
from wface.physics.hex_solve import HexBody
from wface.physics.hexes import hex_quadrature, quadrature_model

KAPPA_PA = 2.5e4


def _quad(seed=0):
    model, hexes = _distorted_box(seed=seed)
    return model, hex_quadrature(model.rest_positions_m, hexes)


@pytest.mark.parametrize("potential", ["quadratic", "log"])
def test_forces_and_hessian_match_finite_differences(potential):
    """f = -dE/dx and H = d2E/dx2 (exact, unprojected), float64 central differences, a non-affine state;
    a wedge (collapsed hex, repeated nodes) included."""
    model, quad = _quad(seed=2)
    x_rest = model.rest_positions_m
    wedge = np.array([[0, 1, 2, 3, 4, 5, 5, 4]])
    xw = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1]], dtype=float) * 0.01
    rng = np.random.default_rng(7)
    for q, X in ((quad, x_rest), (hex_quadrature(xw, wedge), xw)):
        md = MeanDilatation(q, KAPPA_PA, potential)
        x = X + rng.normal(0.0, 0.08 * np.ptp(X), X.shape) * 0.05
        _, f = md.energy_and_forces(x)
        H = md.hessian(x, project=False).toarray()
        h = 1e-7
        for dof in rng.choice(x.size, min(10, x.size), replace=False):
            dx = np.zeros(x.size)
            dx[dof] = h
            dx = dx.reshape(x.shape)
            (ep, fp), (em, fm) = md.energy_and_forces(x + dx), md.energy_and_forces(x - dx)
            assert -(ep - em) / (2 * h) == pytest.approx(f.reshape(-1)[dof], rel=1e-6, abs=1e-12)
            np.testing.assert_allclose(
                -(fp - fm).reshape(-1) / (2 * h), H[:, dof], rtol=1e-5, atol=1e-6 * np.abs(H).max()
            )
        np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())


def test_affine_fields_give_the_per_point_bulk_energy():
    """Under an affine map every Gauss point has J = det A, so one ratio per hex is the per-point term:
    the log potential equals the flesh kernels' kappa/2 (ln J)^2 (bulk alone: mu = 0), and a
    volume-preserving map costs nothing and pushes nowhere."""
    model, quad = _quad()
    A = np.array([[1.1, 0.05, -0.02], [0.03, 0.93, 0.04], [-0.01, 0.02, 1.02]])
    x = model.rest_positions_m @ A.T
    md = MeanDilatation(quad, KAPPA_PA, "log")
    np.testing.assert_allclose(md.volume_ratios(x), np.linalg.det(A), rtol=1e-12)
    bulk_only = replace(
        model, material=replace(model.material, mu10_pa=0.0, mu01_pa=0.0, kappa_pa=KAPPA_PA, sigma_max_pa=0.0)
    )
    e_point = Simulator(quadrature_model(bulk_only, quad)).energy(quad.virtual_positions(x), np.array([0.0]))
    assert md.energy_and_forces(x)[0] == pytest.approx(e_point, rel=1e-10)
    iso = A / np.cbrt(np.linalg.det(A))
    e, f = md.energy_and_forces(model.rest_positions_m @ iso.T)
    assert e == pytest.approx(0.0, abs=1e-20) and np.abs(f).max() < 1e-12


def test_one_ratio_per_hex_is_below_the_per_point_term_off_affine_fields():
    """Jensen: the hex's ratio is the volume-weighted mean of its points' det F, and the quadratic U is
    convex, so V0 U(mean J) <= sum_g w_g U(J_g), strictly when the points' J differ."""
    model, quad = _quad(seed=4)
    md = MeanDilatation(quad, KAPPA_PA, "quadratic")
    rng = np.random.default_rng(9)
    x = model.rest_positions_m + rng.normal(0.0, 6e-4, model.rest_positions_m.shape)
    y = quad.virtual_positions(x)
    t = quad.virtual_tets
    Ds = np.stack([y[t[:, k]] - y[t[:, 0]] for k in (1, 2, 3)], axis=2)
    Dm = np.stack([quad.virtual_rest_m[t[:, k]] - quad.virtual_rest_m[t[:, 0]] for k in (1, 2, 3)], axis=2)
    J = np.linalg.det(Ds @ np.linalg.inv(Dm))
    per_point = float(np.sum(quad.gauss_volume_m3 * 0.5 * KAPPA_PA * (J - 1.0) ** 2))
    mean_J = np.bincount(quad.hex_of_point, weights=quad.gauss_volume_m3 * J) / md.rest_volume_m3
    np.testing.assert_allclose(md.volume_ratios(x), mean_J, rtol=1e-12)
    e = md.energy_and_forces(x)[0]
    assert e < per_point
    assert e == pytest.approx(float(np.sum(md.rest_volume_m3 * 0.5 * KAPPA_PA * (mean_J - 1.0) ** 2)), rel=1e-12)


def test_projected_hessian_is_psd_and_equals_the_exact_one_where_that_is():
    model, quad = _quad(seed=6)
    md = MeanDilatation(quad, KAPPA_PA)
    x = model.rest_positions_m * np.array([1.2, 1.0, 1.0])  # stretched: p > 0, the exact Hessian indefinite
    exact, proj = md.hessian(x, project=False).toarray(), md.hessian(x).toarray()
    assert np.linalg.eigvalsh(exact).min() < -1e-6 * np.abs(exact).max()
    assert np.linalg.eigvalsh(proj).min() > -1e-9 * np.abs(proj).max()
    at_rest = md.hessian(model.rest_positions_m)  # p = 0: the rank-one term alone, already PSD
    np.testing.assert_allclose(
        at_rest.toarray(), md.hessian(model.rest_positions_m, project=False).toarray(), atol=1e-9
    )


def test_patch_equilibrium_with_one_ratio_per_hex_is_affine():
    """The flesh kernels' deviatoric part plus the element bulk term, boundary on an affine map that
    changes the volume: the free interior node's equilibrium is the affine position."""
    model, hexes = _distorted_box(seed=5)
    quad = hex_quadrature(model.rest_positions_m, hexes)
    deviatoric = replace(model, material=replace(model.material, kappa_pa=0.0))
    body = HexBody(
        Simulator(quadrature_model(deviatoric, quad)), quad, _free(model), dilatation=MeanDilatation(quad, 1e5)
    )
    X = model.rest_positions_m
    A = np.array([[1.05, 0.02, 0.0], [0.0, 0.97, 0.03], [0.01, 0.0, 1.04]])
    target = X @ A.T
    free = _free(model)
    x0 = target.copy()
    x0[free] += 1e-3
    # 1e-11: the potential's rounding alone once stopped the line search below 1e-7, 5e-14 m off; the
    # slopes at both ends of the step now read the decrease there
    r = body.solve(np.array([0.5]), x0, tol=1e-11)
    assert r.converged and r.iterations <= 10
    np.testing.assert_allclose(r.x_m[free], target[free], atol=1e-12)


def _free(model):
    X = model.rest_positions_m
    return np.flatnonzero(np.all((X > 1e-9) & (X < np.array(SIZE_M) - 1e-9), axis=1))


def test_bad_arguments_are_named():
    model, quad = _quad()
    with pytest.raises(ValueError, match="potential"):
        MeanDilatation(quad, KAPPA_PA, "cubic")
    with pytest.raises(ValueError, match="bulk_modulus_pa"):
        MeanDilatation(quad, -1.0)
    md = MeanDilatation(quad, KAPPA_PA)
    with pytest.raises(ValueError, match="count twice"):  # the kernels' kappa still on
        HexBody(Simulator(quadrature_model(model, quad)), quad, _free(model), dilatation=md)
    other = hex_quadrature(model.rest_positions_m, quad.hexes)
    deviatoric = replace(model, material=replace(model.material, kappa_pa=0.0))
    with pytest.raises(ValueError, match="same HexQuadrature"):
        HexBody(Simulator(quadrature_model(deviatoric, other)), other, _free(model), dilatation=md)
