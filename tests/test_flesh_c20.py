"""The flesh's C20 term mu20 (I1~ - 3)^2 (ArtiSynth's MooneyRivlinMaterial; docs/design.md, "Flesh"), and
its quadratic bulk potential kappa/2 (J - 1)^2 beside the log one (Material.bulk_potential):
the density, its gradient and Hessian in singular values against the closed form (complex step) above
the inversion clamp and against central differences of the kernel's own energy below it (the
third-derivative path); the material's checks and its file round trip, and that a model without the
term is written and hashed as before."""

from __future__ import annotations

import json
from dataclasses import fields, replace

import numpy as np
import pytest

from wface.model import FORMAT_VERSION, Material, ModelError, load_model, model_sha256, save_model
from wface.testing.models import box_model

_MATERIALS = {
    "c20_alone": Material(mu10_pa=0.0, mu01_pa=0.0, mu20_pa=1.0, kappa_pa=0.0),
    "artisynth": Material.artisynth(),
    "all_terms": Material(mu10_pa=2500.0, mu01_pa=800.0, mu20_pa=1175.0, kappa_pa=25000.0),
    # the quadratic bulk potential kappa/2 (J - 1)^2 (ArtiSynth's default), alone and with the rest
    "quadratic_alone": Material(mu10_pa=0.0, mu01_pa=0.0, kappa_pa=1.0, bulk_potential="quadratic"),
    "artisynth_quadratic": replace(Material.artisynth(), bulk_potential="quadratic"),
}
_H_FD = 1e-6  # central-difference step in the singular values (dimensionless)
_FD_TOL = 1e-7  # relative to the largest entry: O(h^2) truncation ~1e-12 + O(eps/h) round-off ~1e-10


def _psi_closed_form(s, mat: Material):
    """psi(s) = mu10 u + mu01 (J^-4/3 I2 - 3) + mu20 u^2 + kappa/2 ln^2 J (or kappa/2 (J - 1)^2),
    u = J^-2/3 I1 - 3 (complex-step friendly)."""
    J = s[0] * s[1] * s[2]
    I1 = s[0] ** 2 + s[1] ** 2 + s[2] ** 2
    I2 = (s[0] * s[1]) ** 2 + (s[0] * s[2]) ** 2 + (s[1] * s[2]) ** 2
    u = J ** (-2 / 3) * I1 - 3
    dev = mat.mu10_pa * u + mat.mu01_pa * (J ** (-4 / 3) * I2 - 3) + mat.mu20_pa * u**2
    if mat.bulk_potential == "quadratic":
        return dev + 0.5 * mat.kappa_pa * (J - 1) ** 2
    return dev + 0.5 * mat.kappa_pa * np.log(J) ** 2


def _density(S: np.ndarray, mat: Material):
    """The kernel's psi_ext, gradient G and Hessian A at the rows of S (float64)."""
    import warp as wp

    from wface.kernels.fem import fem_kernels
    from wface.warp_runtime import init_warp

    init_warp()
    k = fem_kernels(wp.float64)
    n = len(S)
    p, g, H = wp.zeros(n, dtype=wp.float64), wp.zeros(n, dtype=wp.vec3d), wp.zeros(n, dtype=wp.mat33d)
    args = [mat.mu10_pa, mat.mu01_pa, mat.mu20_pa, *mat.bulk_moduli_pa(), mat.inversion_clamp]
    wp.launch(k.flesh_in_singular_values, n, inputs=[wp.array(S, dtype=wp.vec3d), *args, p, g, H])
    return p.numpy(), g.numpy(), H.numpy()


@pytest.mark.parametrize("name", list(_MATERIALS))
def test_density_gradient_and_hessian_match_the_closed_form_above_the_clamp(name):
    mat = _MATERIALS[name]
    rng = np.random.default_rng(20)
    S = np.sort(rng.uniform(0.3, 2.2, size=(8, 3)), axis=1)[:, ::-1].copy()
    S = np.vstack([S, [1.0, 1.0, 1.0], [1.5, 1.5, 0.6], [2.5, 0.7, 0.6]])
    p, g, H = _density(S, mat)
    e, hc = np.eye(3), 1e-30
    for i, s in enumerate(S):
        grad = np.array([np.imag(_psi_closed_form(s + 1j * hc * e[d], mat)) / hc for d in range(3)])

        def cs(d, c, sign, s=s):
            return np.imag(_psi_closed_form(s + 1j * hc * e[d] + sign * _H_FD * e[c], mat))

        hess = np.array([[(cs(d, c, 1) - cs(d, c, -1)) / (2 * hc * _H_FD) for c in range(3)] for d in range(3)])
        scale = max(abs(_psi_closed_form(s, mat)), np.abs(grad).max(), 1.0)
        assert p[i] == pytest.approx(_psi_closed_form(s, mat), abs=1e-12 * scale), f"psi at s = {s}"
        np.testing.assert_allclose(g[i], grad, rtol=0, atol=1e-12 * scale, err_msg=f"gradient at s = {s}")
        np.testing.assert_allclose(H[i], hess, rtol=0, atol=_FD_TOL * max(np.abs(hess).max(), 1.0))


@pytest.mark.parametrize("name", list(_MATERIALS))
def test_gradient_and_hessian_below_the_clamp_are_those_of_the_extended_energy(name):
    """Below the clamp c = 0.1 the energy is psi(s^) + g(s^).(s - s^): its gradient against central
    differences of the kernel's psi_ext, its Hessian (H + the third derivative contracted with the
    clamp offset where both values are above c) against central differences of the gradient."""
    mat = _MATERIALS[name]
    S = np.array([[1.4, 0.9, 0.04], [1.2, 0.05, -0.3], [1.3, 0.8, -0.5], [0.3, 0.06, -0.2], [1.8, 1.1, 0.02]])
    assert np.all(S.min(axis=1) < mat.inversion_clamp - 10 * _H_FD)  # every row uses the clamped path
    p, g, H = _density(S, mat)
    e = np.eye(3)
    for i, s in enumerate(S):
        shifted = np.array([[s + sign * _H_FD * e[c] for c in range(3)] for sign in (1, -1)]).reshape(6, 3)
        ps, gs, _ = _density(shifted, mat)
        g_fd = (ps[:3] - ps[3:]) / (2 * _H_FD)
        H_fd = ((gs[:3] - gs[3:]) / (2 * _H_FD)).T  # column c: dG / ds_c
        np.testing.assert_allclose(g[i], g_fd, rtol=0, atol=_FD_TOL * np.abs(g[i]).max(), err_msg=f"G at {s}")
        np.testing.assert_allclose(H[i], H_fd, rtol=0, atol=_FD_TOL * np.abs(H[i]).max(), err_msg=f"A at {s}")
        np.testing.assert_allclose(H[i], H[i].T, rtol=0, atol=1e-12 * np.abs(H[i]).max())


def test_c20_is_second_order_at_rest_and_stiffens_with_strain():
    """u = I1~ - 3 vanishes with its gradient at s = (1, 1, 1), so mu20 adds nothing to the small-
    strain moduli (shear modulus 2 (mu10 + mu01)); along a volume-preserving stretch it adds the
    closed form 2 mu20 u du/dlam to the deviatoric stress."""
    alone = _MATERIALS["c20_alone"]
    p, g, H = _density(np.array([[1.0, 1.0, 1.0]]), alone)
    assert p[0] == 0.0 and np.abs(g).max() < 1e-15 and np.abs(H).max() < 1e-14  # round-off of J^-2/3 at J = 1
    lam = np.array([1.1, 1.4, 2.0])
    S = np.stack([lam, lam**-0.5, lam**-0.5], axis=1)
    _, g, _ = _density(S, alone)
    # d/dlam of psi(lam, lam^-1/2, lam^-1/2) = g1 - g2 lam^-3/2 (g2 = g3); closed form with u = lam^2 + 2/lam - 3
    u = lam**2 + 2 / lam - 3
    np.testing.assert_allclose(g[:, 0] - g[:, 1] * lam**-1.5, 2 * u * (2 * lam - 2 / lam**2), rtol=1e-12)


def test_material_checks_name_the_field():
    with pytest.raises(ModelError, match="mu20_pa must be >= 0"):
        Material(mu20_pa=-1.0)
    with pytest.raises(ModelError, match="mu20_pa must be finite"):
        Material(mu20_pa=float("nan"))
    with pytest.raises(ModelError, match="kappa_pa must be finite"):
        Material(kappa_pa=float("inf"))


def test_model_file_keeps_c20_and_a_file_without_it_loads_as_zero(tmp_path):
    model = box_model((2, 1, 1), muscles=0)
    path = save_model(model.with_material(Material.artisynth()), tmp_path / "c20.npz")
    assert load_model(path).material == Material.artisynth()
    # format 2 (older wface versions refuse it rather than drop the term); without it, format 1
    assert json.loads(bytes(np.load(path)["header_json"]).decode())["format_version"] == 2 <= FORMAT_VERSION
    # a model without the term: header and fingerprint as before the field existed
    plain = save_model(model, tmp_path / "plain.npz")
    header = json.loads(bytes(np.load(plain)["header_json"]).decode())
    late = ("mu20_pa", "fibre_stress", "muscle_curves", "bulk_potential")  # written only away from their defaults
    old_fields = {f.name: getattr(model.material, f.name) for f in fields(Material) if f.name not in late}
    assert header["material"] == old_fields and header["format_version"] == 1
    assert load_model(plain).material.mu20_pa == 0.0
    assert model_sha256(load_model(plain)) == model_sha256(model)
    assert model_sha256(model.with_material(Material(mu20_pa=1.0))) != model_sha256(model)


def test_model_file_with_a_bad_material_names_the_file(tmp_path):
    path = save_model(box_model((2, 1, 1), muscles=0), tmp_path / "m.npz")
    data = dict(np.load(path))
    header = json.loads(bytes(data["header_json"]).decode())
    header["material"]["mu20_pa"] = -5.0
    data["header_json"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(ModelError, match=r"bad\.npz: material: mu20_pa must be >= 0"):
        load_model(tmp_path / "bad.npz")
