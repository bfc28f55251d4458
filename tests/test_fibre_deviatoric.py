"""The deviatoric muscle fibre stress (``Material.fibre_stress = "deviatoric"``; docs/design.md,
"Muscle fibres"): the fibre curves of lam~ = J^-1/3 |F d|, as ArtiSynth's BlemkerMuscle and
GenericMuscle. Energy against the closed form, forces and tangent against central differences
(float64), the stress's zero trace and its indifference to a pure volume change, the projected
tangent's definiteness, the activation Jacobian columns, float32, the file format, and the
uniaxial default."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from wface.model import FORMAT_VERSION, Material, ModelError, load_model, model_sha256, save_model
from wface.physics import Simulator
from wface.testing.models import box_model, single_tet_model

_FD_REL = 2e-6  # central differences with h = 1e-6 edge: O(h^2) truncation + O(eps/h) round-off
_ROUNDOFF = 1e-12  # float64 round-off relative to the element's stress scale
_SIGMA = 1.0e5  # the Badin demo's sigma_max (Pa): fibre stresses of the Badin flesh's order

# fibres alone (no flesh: every flesh modulus 0), and with ArtiSynth's Badin flesh (C10, C20, kappa 25 kPa)
_BARE = Material(mu10_pa=0.0, mu01_pa=0.0, kappa_pa=0.0, sigma_max_pa=_SIGMA, fibre_stress="deviatoric")
_BADIN = replace(Material.artisynth(), sigma_max_pa=_SIGMA, fibre_stress="deviatoric")
_BLEMKER = replace(_BADIN, fibre_stress="blemker")  # the same with BlemkerMuscle's curves


def _tet(material: Material) -> Simulator:
    return Simulator(single_tet_model(material=material), precision="float64")


def _tet_configurations(X: np.ndarray) -> dict[str, np.ndarray]:
    """Single-tet states (edge 1 cm; fibre (0.6, 0.8, 0)): J from below the clamp's J_c to 1.6."""
    rng = np.random.default_rng(18)
    h = 0.01
    along = np.eye(3) + 0.35 * np.outer([0.6, 0.8, 0.0], [0.6, 0.8, 0.0])  # fibre stretched ~1.35, J = 1.35
    shortened = np.diag([0.8, 0.75, 1.1])  # fibre shortened ~0.77, J = 0.66
    inverted = X.copy()
    inverted[3] = [0.2 * h, 0.2 * h, -0.3 * h]  # det F < 0: phi on its tangent line below J_c
    return {
        "random": X + 0.3 * h * rng.normal(size=X.shape),
        "stretched": X @ along.T,
        "shortened": X @ shortened.T + 0.05 * h * rng.normal(size=X.shape),
        "dilated": X * 1.17 + 0.05 * h * rng.normal(size=X.shape),
        "inverted": inverted,
    }


def _fd_forces(sim: Simulator, x: np.ndarray, a: np.ndarray, h: float) -> np.ndarray:
    g = np.zeros_like(x)
    for i in range(len(x)):
        for d in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, d] += h
            xm[i, d] -= h
            g[i, d] = -(sim.energy(xp, a) - sim.energy(xm, a)) / (2 * h)
    return g


def _fd_stiffness(sim: Simulator, x: np.ndarray, a: np.ndarray, h: float) -> np.ndarray:
    n = x.size
    K = np.zeros((n, n))
    for i in range(len(x)):
        for d in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, d] += h
            xm[i, d] -= h
            K[:, 3 * i + d] = -(sim.forces(xp, a) - sim.forces(xm, a)).ravel() / (2 * h)
    return K


def _kirchhoff(sim: Simulator, x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """tau = P F^T of a single tet from its nodal forces: sum_a f_a x_a^T = -V0 P F^T."""
    f = sim.forces(x, a)
    return -(f.T @ x) / sim.model.rest_volume_m3[0]


def _closed_form_energy(x: np.ndarray, X: np.ndarray, model, a: float) -> float:
    """V0 k (a G_L(lam~) + G_P(lam~)) with lam~ = det(F)^-1/3 |F d| from numpy and the fibre
    integrals G from the ``fibre_curves`` kernel (those are tested in test_fem_kernels.py)."""
    import warp as wp

    from wface.kernels.fem import fem_kernels

    F = (x[1:] - x[0]).T @ np.linalg.inv((X[1:] - X[0]).T)
    lt = np.linalg.det(F) ** (-1 / 3) * np.linalg.norm(F @ model.fibre_direction[0])
    out = wp.zeros((1, 6), dtype=wp.float64)
    curves = int(model.material.fibre_stress == "blemker")
    wp.launch(fem_kernels(wp.float64).fibre_curves, 1, inputs=[wp.array([lt], dtype=wp.float64), curves, out])
    gl, gp = out.numpy()[0, [2, 5]]
    k = model.fibre_fraction[0] * model.material.sigma_max_pa
    return model.rest_volume_m3[0] * k * (a * gl + gp)


@pytest.mark.parametrize("law", ["deviatoric", "blemker"])
def test_energy_is_the_fibre_curves_of_the_deviatoric_stretch(law):
    sim, uni = _tet(replace(_BARE, fibre_stress=law)), _tet(replace(_BARE, fibre_stress="uniaxial"))
    X = sim.model.rest_positions_m
    for name, x in _tet_configurations(X).items():
        if name == "inverted":
            continue  # below J_c lam~ follows phi's tangent line, not J^-1/3
        for a in (0.0, 0.6, 1.0):
            ref = _closed_form_energy(x, X, sim.model, a)
            assert sim.energy(x, np.array([a])) == pytest.approx(ref, rel=1e-12, abs=1e-20), f"{name}, a = {a}"
            if a > 0:  # (passive-only fibres shorter than rest carry nothing in either law)
                assert abs(uni.energy(x, np.array([a])) - ref) > 1e-6 * abs(ref), "the laws should differ at J != 1"


@pytest.mark.parametrize(
    "material",
    [_BARE, _BADIN, replace(_BARE, fibre_stress="blemker"), _BLEMKER],
    ids=["fibres", "badin", "blemker-fibres", "blemker-badin"],
)
def test_forces_and_exact_tangent_match_central_differences_on_one_tet(material):
    sim = _tet(material)
    X = sim.model.rest_positions_m
    h = 1e-6 * 0.01
    for name, x in _tet_configurations(X).items():
        for a in (0.0, 0.5, 1.0):
            act = np.array([a])
            f = sim.forces(x, act)
            if not np.abs(f).any():  # bare, slack and passive (shortened, a = 0): nothing to differentiate
                assert not np.abs(_fd_forces(sim, x, act, h)).any() and not sim.energy(x, act)
                continue
            err = np.abs(_fd_forces(sim, x, act, h) - f).max() / np.abs(f).max()
            assert err < _FD_REL, f"{name}, a = {a}: |dE/dx + f| / |f| = {err:.2e}"
            K = sim.assemble_stiffness(x, act, project=False).toarray()
            err = np.abs(K - _fd_stiffness(sim, x, act, h)).max() / np.abs(K).max()
            assert err < _FD_REL, f"{name}, a = {a}: |K + df/dx| / |K| = {err:.2e}"
            np.testing.assert_allclose(K, K.T, atol=1e-9 * np.abs(K).max())


@pytest.mark.parametrize("material", [_BADIN, _BLEMKER], ids=["deviatoric", "blemker"])
def test_forces_and_exact_tangent_match_central_differences_on_a_few_tets(material):
    model = box_model((2, 1, 1), muscles=2, fibre_direction=(0.8, 0.0, 0.6), material=material)
    sim = Simulator(model, precision="float64")
    X = model.rest_positions_m
    rng = np.random.default_rng(19)
    x = X @ np.diag([1.15, 0.9, 0.85]).T + 0.001 * rng.normal(size=X.shape)  # J ~ 0.88, fibres stretched
    a = np.array([0.8, 0.3])
    h = 1e-6 * 0.01
    f = sim.forces(x, a)
    assert np.abs(_fd_forces(sim, x, a, h) - f).max() < _FD_REL * np.abs(f).max()
    K = sim.assemble_stiffness(x, a, project=False).toarray()
    assert np.abs(K - _fd_stiffness(sim, x, a, h)).max() < _FD_REL * np.abs(K).max()


def test_deviatoric_fibre_stress_has_zero_trace():
    """tr(sigma) = tr(tau) / J = 0 at random F, for any activation; the uniaxial stress's trace is T lam."""
    sim, uni = _tet(_BARE), _tet(replace(_BARE, fibre_stress="uniaxial"))
    X = sim.model.rest_positions_m
    rng = np.random.default_rng(20)
    Fs = [F for F in np.eye(3) + 0.3 * rng.normal(size=(12, 3, 3)) if np.linalg.det(F) > 0.3][:6]
    for F in Fs:  # J above J_c, where lam~ = J^-1/3 |F d| exactly
        x = X @ F.T + 0.01
        for a in (0.3, 1.0):
            tau = _kirchhoff(sim, x, np.array([a]))
            assert abs(np.trace(tau)) < _ROUNDOFF * np.abs(tau).max() * 10, f"tr tau = {np.trace(tau):.3g}"
            np.testing.assert_allclose(tau, tau.T, atol=_ROUNDOFF * np.abs(tau).max() * 10)  # objectivity
            tau_u = _kirchhoff(uni, x, np.array([a]))
            assert np.trace(tau_u) > 0.1 * np.abs(tau_u).max()


def test_pure_volume_change_leaves_the_deviatoric_fibre_unchanged():
    """Under x = s X (F = s I): W(s F) = W(F), so the fibre does no work on the volume change
    (sum f . x = 0) and its Kirchhoff stress is that at rest; the uniaxial fibre's grows with s."""
    sim, uni = _tet(_BARE), _tet(replace(_BARE, fibre_stress="uniaxial"))
    X = sim.model.rest_positions_m
    a = np.array([0.7])
    tau_rest = _kirchhoff(sim, X, a)
    assert np.abs(tau_rest).max() > 0.1 * _SIGMA  # active at rest: T (d d^T - I/3)
    for s in (0.7, 0.9, 1.1, 1.3):
        E, f = sim.energy_and_forces(s * X, a)
        assert abs(E) < _ROUNDOFF * _SIGMA * sim.model.rest_volume_m3[0]
        assert abs(np.sum(f * (s * X))) < _ROUNDOFF * np.abs(f).max() * 0.01
        np.testing.assert_allclose(_kirchhoff(sim, s * X, a), tau_rest, atol=_ROUNDOFF * _SIGMA * 10)
        assert abs(np.sum(uni.forces(s * X, a) * (s * X))) > 1e-3 * np.abs(f).max() * 0.01


@pytest.mark.parametrize("material", [_BADIN, _BLEMKER], ids=["deviatoric", "blemker"])
def test_projected_tangent_is_positive_semidefinite(material):
    model = box_model((3, 2, 2), muscles=2, fibre_direction=(0.8, 0.0, 0.6), material=material)
    sim = Simulator(model, precision="float64")
    bare = Simulator(model.with_material(replace(_BARE, fibre_stress=material.fibre_stress)), precision="float64")
    X = model.rest_positions_m
    rng = np.random.default_rng(21)
    squashed = X @ np.diag([0.3, 1.0, 1.0]).T + 0.001 * rng.normal(size=X.shape)
    inverted = X.copy()
    inverted[:, 2] = 0.02 - inverted[:, 2]
    configs = [X + 0.004 * rng.normal(size=X.shape) for _ in range(2)] + [X * 1.3, squashed, inverted]
    saw_indefinite = False
    for x in configs:
        for a in (np.zeros(2), np.array([1.0, 0.5])):
            ev = np.linalg.eigvalsh(sim.assemble_stiffness(x, a).toarray())
            assert ev[0] > -1e-9 * ev[-1], f"projected K has eigenvalue {ev[0]:.3g} (max {ev[-1]:.3g})"
            exact = np.linalg.eigvalsh(sim.assemble_stiffness(x, a, project=False).toarray())
            saw_indefinite |= exact[0] < -1e-6 * exact[-1]
            # the fibres' own 9x9 blocks (no flesh to lean on) are PSD per element
            for C in _unpack(bare.tangent(x, a).element_tangents.numpy()):
                w = np.linalg.eigvalsh(C)
                assert w[0] >= -1e-9 * max(w[-1], 1e-30)
    assert saw_indefinite, "the test should include states where the exact Hessian is indefinite"


def _unpack(packed: np.ndarray) -> np.ndarray:
    """(m, 45) packed upper triangles -> (m, 9, 9) symmetric."""
    iu = np.triu_indices(9)
    C = np.zeros((len(packed), 9, 9))
    C[:, iu[0], iu[1]] = packed
    return C + np.triu(C, 1).transpose(0, 2, 1)


def test_projected_tangent_equals_the_exact_one_where_that_is_psd():
    """Projection only clamps: at rest with no activation the deviatoric fibre is slack (T = 0) and
    the Badin flesh's exact tangent is PSD, so projected == exact."""
    sim = _tet(_BADIN)
    X = sim.model.rest_positions_m
    Kp = sim.assemble_stiffness(X, np.zeros(1)).toarray()
    Ke = sim.assemble_stiffness(X, np.zeros(1), project=False).toarray()
    np.testing.assert_allclose(Kp, Ke, atol=1e-10 * np.abs(Ke).max())


def test_muscle_force_columns_are_the_activation_derivative_of_the_forces():
    model = box_model((2, 2, 1), muscles=2, fibre_direction=(0.6, 0.8, 0.0), material=_BADIN)
    sim = Simulator(model, precision="float64")
    X = model.rest_positions_m
    rng = np.random.default_rng(22)
    for x in (X @ np.diag([1.2, 0.8, 0.9]).T + 0.001 * rng.normal(size=X.shape), X * 0.85):
        fi = sim.muscle_forces(x)
        a = np.array([0.4, 0.7])
        for i in range(2):
            e = np.eye(2)[i] * 0.1
            fd = (sim.forces(x, a + e) - sim.forces(x, a - e)) / 0.2  # forces are affine in a: exact to round-off
            np.testing.assert_allclose(fi[i], fd, atol=1e-9 * np.abs(fd).max())
            assert np.abs(fi[i]).max() > 0
        w = np.array([0.4, -0.7])
        np.testing.assert_allclose(
            sim.muscle_force_sum(w, x), np.einsum("i,inc->nc", w, fi), atol=1e-12 * np.abs(fi).max()
        )


def test_float32_agrees_with_float64():
    model = box_model((3, 2, 2), muscles=2, material=_BADIN)
    s64, s32 = Simulator(model), Simulator(model, precision="float32")
    X = model.rest_positions_m
    x = X @ np.diag([1.1, 0.95, 0.9]).T + 0.002 * np.random.default_rng(23).normal(size=X.shape)
    a = np.array([0.4, 0.8])
    f64 = s64.forces(x, a)
    assert np.abs(s32.forces(x, a) - f64).max() < 1e-4 * np.abs(f64).max()  # float32 round-off x ~100
    v = np.random.default_rng(24).normal(size=X.shape)
    for project in (True, False):
        k64 = s64.stiffness_matvec(x, a, v, project=project)
        assert np.abs(s32.stiffness_matvec(x, a, v, project=project) - k64).max() < 1e-4 * np.abs(k64).max()
    fi64 = s64.muscle_forces(x)
    assert np.abs(s32.muscle_forces(x) - fi64).max() < 1e-4 * np.abs(fi64).max()


def test_uniaxial_is_the_default_and_files_without_the_field_load_as_uniaxial(tmp_path):
    model = box_model((2, 1, 1), muscles=1)
    assert model.material.fibre_stress == "uniaxial"
    explicit = model.with_material(replace(model.material, fibre_stress="uniaxial"))
    assert model_sha256(explicit) == model_sha256(model)  # the default is not written: old files hash the same
    X = model.rest_positions_m
    x = X + 0.002 * np.random.default_rng(25).normal(size=X.shape)
    a = np.array([0.6])
    s0, s1 = Simulator(model), Simulator(explicit)
    assert np.array_equal(s0.forces(x, a), s1.forces(x, a))
    dev = Simulator(model.with_material(replace(model.material, fibre_stress="deviatoric")))
    assert not np.array_equal(s0.forces(x, a), dev.forces(x, a))
    path = save_model(model.with_material(replace(model.material, fibre_stress="deviatoric")), tmp_path / "dev.npz")
    assert load_model(path).material.fibre_stress == "deviatoric"
    blemker = save_model(model.with_material(replace(model.material, fibre_stress="blemker")), tmp_path / "bl.npz")
    assert load_model(blemker).material.fibre_stress == "blemker"
    assert not np.array_equal(dev.forces(x, a), Simulator(load_model(blemker)).forces(x, a))
    assert load_model(save_model(model, tmp_path / "uni.npz")).material.fibre_stress == "uniaxial"
    # format 2 (older wface versions refuse it rather than drop the law); the uniaxial default stays format 1
    version = {
        p.name: json.loads(bytes(np.load(p)["header_json"]).decode())["format_version"]
        for p in (path, tmp_path / "uni.npz")
    }
    assert version == {"dev.npz": 2, "uni.npz": 1} and FORMAT_VERSION >= 2
    assert json.loads(bytes(np.load(blemker)["header_json"]).decode())["format_version"] == 2


def test_unknown_fibre_stress_is_refused_naming_the_field():
    with pytest.raises(ModelError, match="fibre_stress must be one of"):
        Material(fibre_stress="volumetric")


def _free_fibre_equilibrium(sim: Simulator, a: float) -> tuple[float, float]:
    """(lam, mu) of the traction-free homogeneous equilibrium F = diag(lam, mu, mu) of a tet whose fibre
    runs along x: tau_xx = tau_yy = 0 (tau_zz = tau_yy by symmetry), by scipy's root finder."""
    from scipy.optimize import fsolve

    X = sim.model.rest_positions_m

    def residual(v):
        tau = _kirchhoff(sim, X @ np.diag([v[0], v[1], v[1]]), np.array([a]))
        return [tau[0, 0] / _SIGMA, tau[1, 1] / _SIGMA]

    lam, mu = fsolve(residual, [0.9, 1.05], xtol=1e-13)
    assert np.abs(residual([lam, mu])).max() < 1e-11
    return float(lam), float(mu)


@pytest.mark.parametrize("a", [0.1, 0.3])
def test_free_active_fibre_keeps_the_volume_only_when_deviatoric(a):
    """The mechanism (README, "Speech gestures"): at a traction-free equilibrium the trace of tau is
    3 kappa ln J (flesh; its deviatoric terms are traceless) plus the fibre's, T lam uniaxial and 0
    deviatoric, so the uniaxial muscle loses volume, ln J = -T(lam) lam / (3 kappa), and the
    deviatoric one keeps it, J = 1: both exact on the Badin flesh (kappa 25 kPa)."""
    material = replace(_BADIN, fibre_stress="uniaxial")
    single = single_tet_model(fibre_direction=(1.0, 0.0, 0.0))
    lam, mu = _free_fibre_equilibrium(Simulator(single.with_material(material)), a)
    k = single.fibre_fraction[0] * _SIGMA
    T = k * a * (1 - 25 / 6 * (lam - 1) ** 2)  # lam in (0.6, 1): f_L's inner parabola, f_P = 0
    assert 0.6 < lam < 1 and np.log(lam * mu * mu) == pytest.approx(-T * lam / (3 * material.kappa_pa), rel=1e-8)
    assert np.log(lam * mu * mu) < -0.05  # J = 0.947 (a = 0.1), 0.910 (0.3): f_L falls as the fibre shortens
    lam_d, mu_d = _free_fibre_equilibrium(Simulator(single.with_material(_BADIN)), a)
    assert lam_d < 0.95 and abs(np.log(lam_d * mu_d * mu_d)) < 1e-10  # the fibre still shortens
    # Blemker's curves: J = 1 too, and the fibre shortens further (its f_L = 1 - 4 x^2 lies above 1 - 25/6 x^2)
    lam_b, mu_b = _free_fibre_equilibrium(Simulator(single.with_material(_BLEMKER)), a)
    assert abs(np.log(lam_b * mu_b * mu_b)) < 1e-10 and lam_b < lam_d


def test_model_info_prints_the_fibre_stress(tmp_path, capsys):
    from wface.cli import main

    model = box_model((2, 1, 1), muscles=1, material=_BADIN)
    path = save_model(model, tmp_path / "dev.npz")
    assert main(["model", "info", str(path)]) == 0
    assert "deviatoric fibre stress" in capsys.readouterr().out
