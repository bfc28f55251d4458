"""The flesh stress from the invariants of C (``flesh_invariants``, the force and energy kernels'
path wherever no singular value is near the inversion clamp) against the signed-SVD path it replaces
there: the same energy and first Piola stress, a test that only ever accepts where the SVD path
would not clamp, and the SVD path taken near and past inversion (docs/design.md, "Inversion safety")."""

from __future__ import annotations

import numpy as np
import pytest

from wface.model import Material

_MATERIALS = {
    "builtin": Material(),
    "artisynth": Material.artisynth(),
    "all_terms": Material(mu10_pa=2500.0, mu01_pa=800.0, mu20_pa=1175.0, kappa_pa=25000.0),
    "quadratic_bulk": Material(
        mu10_pa=2500.0, mu01_pa=800.0, mu20_pa=1175.0, kappa_pa=25000.0, bulk_potential="quadratic"
    ),
}


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _paths(F: np.ndarray, mat: Material, dtype: str = "float64"):
    """(ok, psi_inv, P_inv, psi_svd, P_svd) of the kernel at the rows of F (m, 3, 3)."""
    import warp as wp

    from wface.kernels.flesh import flesh_functions
    from wface.warp_runtime import init_warp

    init_warp()
    S, m33 = (wp.float64, wp.mat33d) if dtype == "float64" else (wp.float32, wp.mat33f)
    k = flesh_functions(S)
    n = len(F)
    out = [
        wp.zeros(n, dtype=wp.int32),
        wp.zeros(n, dtype=S),
        wp.zeros(n, dtype=m33),
        wp.zeros(n, dtype=S),
        wp.zeros(n, dtype=m33),
    ]
    args = [mat.mu10_pa, mat.mu01_pa, mat.mu20_pa, *mat.bulk_moduli_pa(), mat.inversion_clamp]
    wp.launch(k.flesh_stress_paths, n, inputs=[wp.array(F.astype(dtype), dtype=m33), *args, *out])
    return [a.numpy().astype(np.float64) if i else a.numpy() for i, a in enumerate(out)]


def _deformations(rng, n: int, lo: float, hi: float) -> np.ndarray:
    """F = R1 diag(s) R2 with singular values uniform in [lo, hi]."""
    return np.array([_rotation(rng) @ np.diag(rng.uniform(lo, hi, 3)) @ _rotation(rng) for _ in range(n)])


@pytest.mark.parametrize("name", list(_MATERIALS))
def test_invariants_give_the_svd_energy_and_stress_away_from_the_clamp(name):
    mat = _MATERIALS[name]
    rng = np.random.default_rng(3)
    F = np.concatenate(
        [
            _deformations(rng, 40, 0.5, 1.8),  # large strains
            _deformations(rng, 20, 0.97, 1.03),  # the small strains of a face
            np.eye(3)[None],
            np.diag([1.2, 1.2, 1.0 / 1.44])[None],  # isochoric, two equal singular values
        ]
    )
    ok, psi_i, P_i, psi_s, P_s = _paths(F, mat)
    assert ok.all()
    scale = max(mat.mu10_pa, mat.mu01_pa, mat.mu20_pa, mat.kappa_pa)
    np.testing.assert_allclose(psi_i, psi_s, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(P_i, P_s, rtol=0, atol=1e-10 * scale)


def test_invariant_stress_is_the_gradient_of_its_energy():
    """Central differences of the invariant energy in F (float64) give its stress."""
    mat = _MATERIALS["all_terms"]
    rng = np.random.default_rng(5)
    F = _deformations(rng, 6, 0.7, 1.4)
    h = 1e-6
    rows = [F]
    for i in range(3):
        for j in range(3):
            E = np.zeros((3, 3))
            E[i, j] = h
            rows += [F + E, F - E]
    ok, psi, P, _, _ = _paths(np.concatenate(rows), mat)
    assert ok.all()
    n = len(F)
    for i in range(3):
        for j in range(3):
            k = 1 + 2 * (3 * i + j)
            fd = (psi[k * n : (k + 1) * n] - psi[(k + 1) * n : (k + 2) * n]) / (2 * h)
            np.testing.assert_allclose(P[:n, i, j], fd, rtol=0, atol=1e-6 * mat.kappa_pa)


def test_the_test_accepts_only_unclamped_deformations_and_falls_back_near_inversion():
    mat = Material()
    c = mat.inversion_clamp
    rng = np.random.default_rng(11)
    F = np.concatenate(
        [
            _deformations(rng, 300, 0.02, 1.5),  # many with a singular value near or below the clamp
            np.diag([1.0, 1.0, -0.5])[None],  # inverted
            np.diag([1.0, 1.0, 0.5 * c])[None],  # below the clamp
            np.zeros((1, 3, 3)),  # collapsed
        ]
    )
    ok, psi_i, P_i, psi_s, P_s = _paths(F, mat)
    s_min = np.linalg.svd(F, compute_uv=False).min(axis=1) * np.sign(np.linalg.det(F))
    assert np.all(s_min[ok == 1] >= c)  # never accepted where the SVD path would clamp
    assert not ok[-3:].any()
    assert 0 < ok.sum() < len(ok)  # both paths exercised
    accepted = ok == 1
    np.testing.assert_allclose(P_i[accepted], P_s[accepted], rtol=0, atol=1e-8 * mat.kappa_pa)


def test_float32_invariants_agree_with_float64():
    mat = _MATERIALS["artisynth"]
    rng = np.random.default_rng(8)
    F = _deformations(rng, 30, 0.8, 1.25)
    ok64, psi64, P64, _, _ = _paths(F, mat)
    ok32, psi32, P32, _, P32_svd = _paths(F, mat, "float32")
    assert ok32.all() and ok64.all()
    scale = np.abs(P64).max()
    assert np.abs(P32 - P64).max() < 2e-5 * scale
    # no worse than the SVD path in single precision
    assert np.abs(P32 - P64).max() <= 4.0 * max(np.abs(P32_svd - P64).max(), 1e-7 * scale)
