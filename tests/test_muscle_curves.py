"""Each muscle's own fibre curves (``Material.muscle_curves``; docs/design.md, "Muscle fibres"): ArtiSynth's
lip-opening demo gives OOP BlemkerMuscle's curves and every other muscle GenericMuscle's. Forces and exact
tangent of a model mixing curves against central differences (float64), the projected tangent's definiteness,
a muscle's own curves against the law's, GenericMuscle's stress in closed form, the activation columns, and
the file format."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from tests.test_fibre_deviatoric import _fd_forces, _fd_stiffness
from wface.model import FIBRE_CURVES, FORMAT_VERSION, Material, ModelError, load_model, model_sha256, save_model
from wface.physics import Simulator
from wface.testing.models import box_model, single_tet_model

_FD_REL = 2e-6  # central differences with h = 1e-6 edge (as tests/test_fibre_deviatoric.py)
_SIGMA = 1.0e5  # the Badin demo's sigma_max (Pa)
_BADIN = replace(Material.artisynth(), sigma_max_pa=_SIGMA, fibre_stress="deviatoric")
_MIXED = {"muscle_0": "blemker", "muscle_1": "generic"}


def _box(material: Material):
    return box_model((2, 2, 1), muscles=2, fibre_direction=(0.8, 0.0, 0.6), material=material)


def _state(X: np.ndarray, seed: int) -> np.ndarray:
    """Fibres stretched to 1.15 along x, J ~ 0.88, a little noise."""
    return X @ np.diag([1.15, 0.9, 0.85]).T + 0.001 * np.random.default_rng(seed).normal(size=X.shape)


@pytest.mark.parametrize("law", ["deviatoric", "uniaxial"])
def test_mixed_curves_forces_and_exact_tangent_match_central_differences(law):
    model = _box(replace(_BADIN, fibre_stress=law, muscle_curves=_MIXED))
    sim = Simulator(model, precision="float64")
    for seed, a in ((30, np.array([0.8, 0.3])), (31, np.array([0.0, 1.0])), (32, np.array([0.5, 0.0]))):
        x = _state(model.rest_positions_m, seed)
        f = sim.forces(x, a)
        g, Kfd = _fd_forces(sim, x, a, 1e-8), _fd_stiffness(sim, x, a, 1e-8)
        assert np.abs(g - f).max() < _FD_REL * np.abs(f).max()
        K = sim.assemble_stiffness(x, a, project=False).toarray()
        assert np.abs(K - Kfd).max() < _FD_REL * np.abs(K).max()
        ev = np.linalg.eigvalsh(sim.assemble_stiffness(x, a).toarray())
        assert ev[0] > -1e-9 * ev[-1]


def test_every_muscles_own_curves_are_the_laws_bit_for_bit():
    """Blemker's curves named for every muscle are ``fibre_stress = "blemker"``, wface's named for every muscle
    are "deviatoric": forces, energy, tangent and activation columns the same bits."""
    every = {"muscle_0": "blemker", "muscle_1": "blemker"}
    pairs = [
        (replace(_BADIN, fibre_stress="blemker"), replace(_BADIN, muscle_curves=every)),
        (_BADIN, replace(_BADIN, muscle_curves={"muscle_0": "wface", "muscle_1": "wface"})),
    ]
    for law, named in pairs:
        s0, s1 = Simulator(_box(law)), Simulator(_box(named))
        x, a = _state(s0.model.rest_positions_m, 33), np.array([0.6, 0.2])
        e0, f0 = s0.energy_and_forces(x, a)
        e1, f1 = s1.energy_and_forces(x, a)
        assert e0 == e1 and np.array_equal(f0, f1)
        for project in (True, False):
            k0 = s0.assemble_stiffness(x, a, project=project).toarray()
            assert np.array_equal(k0, s1.assemble_stiffness(x, a, project=project).toarray())
        assert np.array_equal(s0.muscle_forces(x), s1.muscle_forces(x))
    # and one muscle's own curves change that muscle alone
    s0, s1 = Simulator(_box(_BADIN)), Simulator(_box(replace(_BADIN, muscle_curves={"muscle_1": "generic"})))
    x = _state(s0.model.rest_positions_m, 34)
    c0, c1 = s0.muscle_forces(x), s1.muscle_forces(x)
    assert np.array_equal(c0[0], c1[0]) and np.abs(c0[1] - c1[1]).max() > 1e-3 * np.abs(c0[1]).max()


def test_an_idle_generic_muscle_is_a_muscle_without_fibres():
    """GenericMuscle has no passive stress: a generic muscle at activation 0 exerts nothing, so forces and
    tangents equal those of the model whose muscle has strength 0 (``without_idle_fibres``), where wface's
    passive curve, stretched, does not."""
    generic = _box(replace(_BADIN, muscle_curves={"muscle_1": "generic"}))
    strength0 = replace(_box(_BADIN), muscle_strength=np.array([1.0, 0.0]))
    x, a = _state(generic.rest_positions_m, 35), np.array([0.7, 0.0])
    sg, s0, sw = Simulator(generic), Simulator(strength0), Simulator(_box(_BADIN))
    np.testing.assert_allclose(sg.forces(x, a), s0.forces(x, a), rtol=0, atol=1e-12 * np.abs(s0.forces(x, a)).max())
    kg = sg.assemble_stiffness(x, a, project=False).toarray()
    np.testing.assert_allclose(kg, s0.assemble_stiffness(x, a, project=False).toarray(), atol=1e-12 * np.abs(kg).max())
    assert np.abs(sw.forces(x, a) - s0.forces(x, a)).max() > 1e-4 * np.abs(s0.forces(x, a)).max()


@pytest.mark.parametrize("a", [0.3, 1.0])
def test_generic_muscle_stress_is_artisynths_closed_form(a):
    """GenericMuscle.computeStressAndTangent with no passive stress: J sigma = e sigma_max lam~ (n n^T - I/3),
    lam~ = J^-1/3 |F d|, n = F d / |F d|, at any stretch (no force-length curve); here times the tet's
    volume fraction, the fibres alone (no flesh)."""
    bare = Material(mu10_pa=0.0, mu01_pa=0.0, kappa_pa=0.0, sigma_max_pa=_SIGMA, fibre_stress="deviatoric")
    model = single_tet_model(material=replace(bare, muscle_curves={"muscle_0": "generic"}))
    sim = Simulator(model, precision="float64")
    X = model.rest_positions_m
    rng = np.random.default_rng(36)
    for F in [np.diag([2.0, 0.7, 0.7]), np.diag([0.4, 1.3, 1.2]), np.eye(3) + 0.3 * rng.normal(size=(3, 3))]:
        if np.linalg.det(F) < 0.3:
            continue
        x = X @ F.T
        tau = -(sim.forces(x, np.array([a])).T @ x) / model.rest_volume_m3[0]  # sum_a f_a x_a^T = -V0 P F^T
        q = F @ model.fibre_direction[0]
        lt, n = np.linalg.det(F) ** (-1 / 3) * np.linalg.norm(q), q / np.linalg.norm(q)
        ref = model.fibre_fraction[0] * a * _SIGMA * lt * (np.outer(n, n) - np.eye(3) / 3)
        np.testing.assert_allclose(tau, ref, atol=1e-10 * np.abs(ref).max())


def test_activation_columns_of_mixed_curves_are_the_force_derivative():
    model = _box(replace(_BADIN, muscle_curves=_MIXED))
    sim = Simulator(model, precision="float64")
    x = _state(model.rest_positions_m, 37)
    fi = sim.muscle_forces(x)
    a = np.array([0.4, 0.7])
    for i in range(2):
        e = np.eye(2)[i] * 0.1
        fd = (sim.forces(x, a + e) - sim.forces(x, a - e)) / 0.2  # affine in a: exact to round-off
        np.testing.assert_allclose(fi[i], fd, atol=1e-9 * np.abs(fd).max())


def test_muscle_curves_save_load_and_are_checked(tmp_path):
    model = _box(_BADIN)
    mixed = model.with_material(replace(_BADIN, muscle_curves=_MIXED))
    assert mixed.material.muscle_curves == (("muscle_0", "blemker"), ("muscle_1", "generic"))
    assert FIBRE_CURVES == ("wface", "blemker", "generic")
    assert mixed.material.curves_of(["muscle_1", "other"]).tolist() == [2, 0]  # a muscle not named: the law's
    path = save_model(mixed, tmp_path / "mixed.npz")
    back = load_model(path)
    assert back.material == mixed.material and model_sha256(back) == model_sha256(mixed)
    assert json.loads(bytes(np.load(path)["header_json"]).decode())["format_version"] == 5 <= FORMAT_VERSION
    plain = save_model(model, tmp_path / "plain.npz")  # without them the file is the format it was
    assert json.loads(bytes(np.load(plain)["header_json"]).decode())["format_version"] == 2
    assert "muscle_curves" not in json.loads(bytes(np.load(plain)["header_json"]).decode())["material"]
    with pytest.raises(ModelError, match="curves must be one of"):
        Material(muscle_curves={"OOP": "hill"})
    with pytest.raises(ModelError, match="named twice"):
        Material(muscle_curves=(("OOP", "generic"), ("OOP", "blemker")))
    with pytest.raises(ModelError, match=r"names \['OOP'\], which are not muscles of this model"):
        model.with_material(replace(_BADIN, muscle_curves={"OOP": "blemker"})).validate()
