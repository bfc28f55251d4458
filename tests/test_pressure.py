"""Pressure actuators (wface.physics.pressure): a dead pressure load as a signed activation channel.

Physics checked as physics: the force is minus the gradient of the energy (central differences,
float64), the nodal loads add up to the pressure's resultant, a pressurised bar shortens by p L / E,
the attached nodes carry the whole load at equilibrium, and a known suction is recovered from
synthetic markers by the tracker.
"""

from __future__ import annotations

import numpy as np
import pytest

from wface.controls import activation_penalty
from wface.faces.builtin import build_face
from wface.model import FaceModel, ModelError, load_model, save_model
from wface.physics.pressure import pressure_loads
from wface.physics.simulator import Simulator
from wface.takes.edits import exaggerate
from wface.takes.pose import Pose, split_drives
from wface.takes.shapes import SUCTION_SUFFIX, shape_channel, shape_weights
from wface.testing.models import box_model

_P_PA = 2.0e3  # small against the flesh's shear modulus 160 kPa: the bar test stays linear (strain ~0.4 %)


def _pressurised_bar(length_m=0.10, side_m=0.01, cells=(20, 2, 2)) -> FaceModel:
    """A slender bar clamped at x = 0 with a pressure actuator on its free end face (x = L)."""
    bar = box_model(cells, (length_m, side_m, side_m), muscles=1, fibre_fraction=1e-6)
    from wface.mesh.surface import boundary_faces

    faces = boundary_faces(bar.tets)
    end = faces[np.all(np.abs(bar.rest_positions_m[faces, 0] - length_m) < 1e-9, axis=1)]
    bar.muscle_names.append("end_pressure")
    bar.muscle_strength = np.r_[bar.muscle_strength, 1.0]
    bar.surface_groups["end_pressure"] = end
    bar.pressure_actuators["end_pressure"] = _P_PA
    return bar.validate()


@pytest.fixture(scope="module")
def bar():
    return _pressurised_bar()


def test_loads_sum_to_the_pressure_resultant(bar):
    (load,) = pressure_loads(bar)
    # p on the end face (area 1 cm^2, outward normal +x) pushes the flesh along -x
    assert load.force_n.sum(axis=0) == pytest.approx([-_P_PA * 1e-4, 0.0, 0.0], abs=1e-12)
    assert load.channel == bar.muscle_index("end_pressure")


def test_force_is_minus_the_energy_gradient(bar):
    sim = Simulator(bar)
    rng = np.random.default_rng(1)
    x = bar.rest_positions_m + 1e-4 * rng.normal(size=bar.rest_positions_m.shape)
    a = np.array([0.3, -0.7])
    _, f = sim.energy_and_forces(x, a)
    h = 1e-7
    for node in np.unique(bar.surface_groups["end_pressure"])[:4]:
        for d in range(3):
            xp, xm = x.copy(), x.copy()
            xp[node, d] += h
            xm[node, d] -= h
            fd = -(sim.energy(xp, a) - sim.energy(xm, a)) / (2 * h)
            assert fd == pytest.approx(f[node, d], rel=1e-6, abs=1e-9)  # central differences, float64


def test_force_is_linear_in_the_control_with_muscle_forces_as_its_column(bar):
    sim = Simulator(bar)
    x = bar.rest_positions_m * 1.001
    f_plus = sim.forces(x, [0.0, 0.5])
    f_minus = sim.forces(x, [0.0, -0.5])
    column = sim.muscle_forces(x)[1]
    np.testing.assert_allclose(f_plus - f_minus, column, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sim.muscle_force_sum(np.array([0.0, 0.7]), x), 0.7 * column, rtol=0, atol=1e-12)


def test_a_pressurised_bar_shortens_by_p_l_over_e(bar):
    """Uniaxial stress -p along a bar clamped at one end: u(L) = -p L / E with Young's modulus
    E = 9 K G / (3 K + G), G = 2 (mu10 + mu01), K = kappa. The clamped end keeps the cross-section
    from contracting, stiffening the bar over about one width: 5 % is that end effect."""
    m = bar.material
    G, K = 2 * (m.mu10_pa + m.mu01_pa), m.kappa_pa
    E = 9 * K * G / (3 * K + G)
    eq = Simulator(bar).solve([0.0, 1.0], tol=1e-10)
    end = np.unique(bar.surface_groups["end_pressure"])
    u = (eq.x - bar.rest_positions_m)[end, 0].mean()
    assert eq.converged and eq.inverted_elements == 0
    # Newton's full steps all the way down (quadratic convergence), also where the step's energy
    # decrease (~1e-18 J) is below the energy sum's round-off and is read from the forces instead
    assert eq.iterations <= 5 and all(t == 1.0 for t in eq.step_lengths), (eq.history, eq.step_lengths)
    assert u == pytest.approx(-_P_PA * 0.10 / E, rel=0.05)


def test_the_clamp_carries_the_whole_load(bar):
    """Global equilibrium: the internal forces sum to zero, so what the flesh passes to the clamp
    (the elastic forces on the attached nodes) is the whole pressure resultant."""
    sim = Simulator(bar)
    eq = sim.solve([0.0, -1.0], tol=1e-10)
    f = sim.forces(eq.x, [0.0, 0.0])  # elastic forces alone
    on_clamp = f[bar.attached_nodes].sum(axis=0)
    np.testing.assert_allclose(on_clamp, [_P_PA * 1e-4, 0.0, 0.0], atol=1e-9)  # suction pulls the end +x


def test_signed_range_and_validation(bar):
    assert bar.activation_lower_bounds.tolist() == [0.0, -1.0]
    bar.activation_vector([0.0, -1.0])
    with pytest.raises(ValueError, match="muscle_0"):
        bar.activation_vector([-0.1, 0.0])
    with pytest.raises(ValueError, match="end_pressure"):
        bar.activation_vector([0.0, -1.5])
    np.testing.assert_array_equal(bar.clip_activations(np.array([-2.0, -2.0])), [0.0, -1.0])
    pen = activation_penalty(np.array([-0.5, -0.5]), bar.activation_lower_bounds)
    assert pen.value == pytest.approx(0.25) and pen.gradient.tolist() == [-1.0, 0.0]
    broken = _pressurised_bar(cells=(4, 1, 1))
    broken.pressure_actuators["end_pressure"] = -5.0
    with pytest.raises(ModelError, match="maximum pressure"):
        broken.validate()
    broken.pressure_actuators = {"nope": 1.0}
    with pytest.raises(ModelError, match="not an activation channel"):
        broken.validate()


def test_save_load_round_trip_and_format(bar, tmp_path):
    path = save_model(bar, tmp_path / "bar.npz")
    back = load_model(path)
    assert back.pressure_actuators == {"end_pressure": _P_PA}
    np.testing.assert_array_equal(back.surface_groups["end_pressure"], bar.surface_groups["end_pressure"])
    import json

    header = json.loads(bytes(np.load(path)["header_json"]).decode())
    assert header["format_version"] == 3  # refused by a wface that would drop the actuator
    plain = save_model(box_model((2, 1, 1)), tmp_path / "plain.npz")
    assert json.loads(bytes(np.load(plain)["header_json"]).decode())["format_version"] == 1


def test_builtin_face_puffs_and_sucks_the_cheeks():
    face = build_face(1000)
    i = face.muscle_index("intraoral_pressure")
    assert face.activation_lower_bounds[i] == -1.0 and face.facs["AU35"]["intraoral_pressure"] == -1.0
    sim = Simulator(face)
    cheek = face.marker_names.index("Lcheek_Down")
    from scipy.spatial import cKDTree

    node = cKDTree(face.rest_positions_m).query(face.marker_positions_m[cheek])[1]
    forward = []
    for a in (0.5, -0.5):
        eq = sim.solve({"intraoral_pressure": a})
        assert eq.converged and eq.inverted_elements == 0
        forward.append((eq.x - face.rest_positions_m)[node])
    # out of the face (+z forward, +x the subject's left) under pressure, in under suction
    assert forward[0][0] > 1e-3 and forward[1][0] < -1e-3


def test_rig_shapes_split_a_signed_channel():
    face = build_face(1000)
    a = np.zeros((3, face.n_muscles))
    i = face.muscle_index("intraoral_pressure")
    a[:, i] = [0.5, -0.25, 0.0]
    a[0, 0] = 0.2
    names, W = shape_weights(face, a, active=1e-6)
    assert names == [face.muscle_names[0], "intraoral_pressure", "intraoral_pressure" + SUCTION_SUFFIX]
    np.testing.assert_array_equal(W, [[0.2, 0.5, 0.0], [0.0, 0.0, 0.25], [0.0, 0.0, 0.0]])
    assert shape_channel(face, "intraoral_pressure" + SUCTION_SUFFIX) == (i, -1.0)
    with pytest.raises(KeyError):
        shape_channel(face, "zygomaticus_major_l" + SUCTION_SUFFIX)


def test_edits_keep_the_sign_of_suction():
    a = np.array([0.4, -0.6])
    assert split_drives(np.array([0.5, -1.5]))[0].tolist() == [0.5, -1.0]
    big = exaggerate(Pose(a), 2.0)
    np.testing.assert_allclose(big.drive, [0.8, -1.2])  # drives: -1.2 is a = -1 at scale 1.2
    assert big.activations[1] == -1.0
    gone = exaggerate(Pose(np.array([0.4, 0.0])), 0.0)
    assert gone.drive.tolist() == [0.0, 0.0]
