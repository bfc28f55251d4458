"""Bad input through the Python API is refused by name, before it becomes a wrong number.

Each case was reproduced by a user of the API: a NaN bone target solved to "converged" with NaN
nodes, a typo in ``TrackOptions.prior`` ran without priors, marker data in millimetres tracked to
nonsense, a (3, n) vector gave K v 126 % off, a model with a NaN node saved and then could not be
loaded, a Waters rig on a mesh in millimetres moved nothing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from wface.controls import jaw_from_intuitive
from wface.faces import build_face
from wface.model import ModelError, save_model
from wface.physics import Simulator
from wface.tracking.estimator import TrackOptions
from wface.tracking.rig import FaceRig
from wface.tracking.sequence import embed_model_markers, track_sequence
from wface.warp_runtime import resolve_device


@pytest.fixture(scope="module")
def face():
    return build_face(1000)


@pytest.fixture(scope="module")
def sim(face):
    return Simulator(face)


def test_solve_refuses_nan_targets_and_warm_starts(face, sim):
    target = face.rest_positions_m[face.attached_nodes].copy()
    target[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"attached_positions has NaN or inf in 1 row\(s\), first \[3\]"):
        sim.solve(None, target)
    x0 = face.rest_positions_m.copy()
    x0[7] = np.inf
    with pytest.raises(ValueError, match=r"x0 has NaN or inf .* first \[7\]"):
        sim.solve(None, None, x0)
    with pytest.raises(ValueError, match="tol must be a positive number"):
        sim.solve(None, tol=-1.0)


def test_a_simulator_refuses_a_model_with_nan_nodes(face):
    bad = dataclasses.replace(face, rest_positions_m=face.rest_positions_m.copy())
    bad.rest_positions_m[5] = np.nan
    with pytest.raises(ValueError, match=r"rest_positions_m has NaN or inf .* first \[5\]"):
        Simulator(bad)
    with pytest.raises(ModelError, match="NaN"):
        save_model(bad, "never_written.npz")


def test_stiffness_matvec_and_muscle_forces_check_their_arrays(face, sim):
    v = np.ones((face.n_nodes, 3))
    with pytest.raises(ValueError, match=r"v has shape \(3, \d+\), expected"):
        sim.stiffness_matvec(None, None, v.T)
    with pytest.raises(ValueError, match="v has shape"):
        sim.stiffness_matvec(None, None, v[:-1])
    np.testing.assert_allclose(sim.stiffness_matvec(None, None, v.ravel()), sim.stiffness_matvec(None, None, v))
    with pytest.raises(ValueError, match="positions has NaN"):
        sim.muscle_forces(np.full_like(face.rest_positions_m, np.nan))


def test_float32_solves_converge_at_their_own_default_tolerance(face):
    a = {"zygomaticus_major_l": 0.8}
    eq64 = Simulator(face).solve(a)
    eq32 = Simulator(face, precision="float32").solve(a)
    assert eq64.converged and eq32.converged and eq32.residual_rel <= 1e-3
    assert np.abs(eq32.x - eq64.x).max() < 1e-6  # m


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("prior", "Auto", r"prior must be one of \('auto', 'temporal', 'off'\), got 'Auto'"),
        ("factor_at", "bogus", "factor_at must be one of"),
        ("gn_steps", -1, "gn_steps must be an integer >= 1"),
        ("prior_passes", 1.5, "prior_passes must be an integer"),
        ("robust_mm", -1.0, "robust_mm must be a positive number or None"),
        ("noise_mm", float("nan"), "noise_mm must be a positive number or None"),
        ("temporal_weight", -0.1, "temporal_weight must be a number >= 0"),
    ],
)
def test_track_options_refuse_what_the_tracker_would_misread(field, value, message):
    with pytest.raises(ValueError, match=message):
        TrackOptions(**{field: value})


def test_track_options_keep_their_legal_values():
    TrackOptions(prior="off", robust_mm=None, prior_passes=0, temporal_weight=0.0, factor_at="prediction")


def test_track_sequence_refuses_millimetres_and_a_wrong_name_count(face):
    markers = embed_model_markers(face)
    rest = markers.positions(face.rest_positions_m)[None]
    with pytest.raises(ValueError, match=r"\d+ marker_names for \d+ markers"):
        track_sequence(face, rest, marker_names=face.marker_names[:-1], markers=markers)
    with pytest.raises(ValueError, match="must be in metres"):
        track_sequence(face, rest * 1000.0, marker_names=face.marker_names, markers=markers)


def test_markers_are_embedded_and_read_with_checked_shapes(face):
    with pytest.raises(ValueError, match=r"markers_rest_m has shape \(5, 2\)"):
        embed_model_markers(face, np.zeros((5, 2)))
    pts = face.marker_positions_m.copy()
    pts[2] = np.nan
    with pytest.raises(ValueError, match=r"NaN or inf at 1 marker\(s\), first \[2\]"):
        embed_model_markers(face, pts)
    with pytest.raises(ValueError, match="positions have shape"):
        embed_model_markers(face).positions(face.rest_positions_m[:-1])


def test_rig_equilibrium_refuses_infinite_controls(face):
    rig = FaceRig(face)
    c = rig.rest_controls()
    c[0] = np.inf
    with pytest.raises(ValueError, match=r"controls have NaN or inf at \[0\]"):
        rig.equilibrium(c)


def test_small_inputs_are_named(face):
    with pytest.raises(ValueError, match="activation vector must be"):
        face.activation_vector(np.zeros((2, face.n_muscles // 2)))
    with pytest.raises(ValueError, match="activation vector must be"):
        face.activation_vector(np.array(["0.5"] * face.n_muscles))
    with pytest.raises(ValueError, match="opening_deg must be a finite number"):
        jaw_from_intuitive(face.jaw_joint, opening_deg=float("nan"))
    with pytest.raises(ValueError, match="device must be 'cpu', 'cuda'"):
        resolve_device("gpu")


def test_waters_rig_on_a_mesh_in_the_wrong_units_is_refused():
    from wface.testing.synthetic_head import synthetic_head
    from wface.waters import WatersRig, load_layout

    head = synthetic_head()
    layout = load_layout("builtin")
    with pytest.raises(ValueError, match="no muscle of layout .* reaches a vertex"):
        WatersRig(layout, head.vertices_m * 1000.0)
    with pytest.raises(FileNotFoundError, match="packaged layouts: builtin, ict"):
        load_layout("ictt")


def test_a_take_prints_as_one_line():
    from wface.takes.take import Take

    take = Take(activations=np.zeros((500, 36)), fps=60.0, bones=np.zeros((500, 24)), source="tracked")
    text = repr(take)
    assert text == "Take(500 frames at 60 fps, 36 muscles, frames 0..499, with bones, source='tracked')"
