"""FaceModel validation names the problem; save/load round-trips bit-exactly; newer files are refused."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from wface.faces.builtin import build_face
from wface.model import FORMAT_VERSION, FaceModel, JawJoint, ModelError, load_model, model_sha256, save_model


@pytest.fixture(scope="module")
def face():
    return build_face(3000)


def _copy(model: FaceModel, **changes) -> FaceModel:
    kwargs = {f: getattr(model, f) for f in model.__dataclass_fields__}
    kwargs.update(changes)
    return FaceModel(**kwargs)


def test_builtin_validates(face):
    assert face.validate() is face


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda m: {"tets": m.tets[:, [0, 2, 1, 3]]}, "non-positive volume"),
        (lambda m: {"tets": np.where(m.tets == 5, m.n_nodes + 3, m.tets)}, "outside"),
        (
            lambda m: {"fibre_fraction": np.where(np.arange(len(m.fibre_fraction)) == 4, 1.5, m.fibre_fraction)},
            "fractions outside [0, 1]",
        ),
        (lambda m: {"fibre_direction": m.fibre_direction * 1.1}, "unit vectors"),
        (
            lambda m: {"rest_positions_m": np.where(np.arange(m.n_nodes)[:, None] == 7, np.nan, m.rest_positions_m)},
            "NaN",
        ),
        (lambda m: {"facs": {"AU12": {"zygomaticus_maximus_l": 1.0}}}, "unknown muscle"),
        (lambda m: {"muscle_names": m.muscle_names[:-1] + [m.muscle_names[0]]}, "not unique"),
        (lambda m: {"attached_bone": np.full_like(m.attached_bone, 3)}, "cranium"),
    ],
)
def test_validation_names_the_problem(face, change, message):
    bad = _copy(face, **change(face))
    with pytest.raises(ModelError, match=message.replace("[", r"\[").replace("]", r"\]")):
        bad.validate()


def test_near_zero_volume_is_degenerate(face):
    x = face.rest_positions_m.copy()
    t0 = face.tets[0]
    # Squash tet 0 almost flat by moving its last node onto the plane of the other three (+ a hair).
    a, b, c, d = x[t0]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    x[t0[3]] = d - (np.dot(d - a, n) - 1e-13) * n
    with pytest.raises(ModelError, match="volume"):
        _copy(face, rest_positions_m=x).validate()


def test_unknown_muscle_and_bad_activation_values(face):
    with pytest.raises(KeyError, match="unknown muscle 'zygomaticus'"):
        face.activation_vector({"zygomaticus": 0.5})
    with pytest.raises(ValueError, match="outside|in \\[0, 1\\]"):
        face.activation_vector({"zygomaticus_major_l": 1.5})
    with pytest.raises(ValueError, match="shape"):
        face.activation_vector(np.zeros(3))


def test_save_load_round_trip_is_bit_exact(face, tmp_path):
    path = save_model(face, tmp_path / "face.npz")
    back = load_model(path)
    for name in (
        "rest_positions_m",
        "tets",
        "skin_triangles",
        "fibre_tet",
        "fibre_muscle",
        "fibre_fraction",
        "fibre_direction",
        "attached_nodes",
        "attached_bone",
        "muscle_strength",
        "marker_positions_m",
    ):
        a, b = getattr(face, name), getattr(back, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name
    assert back.muscle_names == face.muscle_names and back.marker_names == face.marker_names
    assert back.jaw_joint == face.jaw_joint and back.material == face.material and back.facs == face.facs
    for name, mesh in face.bone_meshes.items():
        assert back.bone_meshes[name].vertices_m.tobytes() == mesh.vertices_m.tobytes()
        assert back.bone_meshes[name].bone == mesh.bone
    for name, tri in face.surface_groups.items():
        assert back.surface_groups[name].tobytes() == tri.tobytes()


def test_newer_format_is_refused(face, tmp_path):
    path = save_model(face, tmp_path / "face.npz")
    data = dict(np.load(path))
    header = json.loads(bytes(data["header_json"]).decode())
    header["format_version"] = FORMAT_VERSION + 1
    data["header_json"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(tmp_path / "newer.npz", **data)
    with pytest.raises(ModelError, match="newer wface"):
        load_model(tmp_path / "newer.npz")


def test_missing_and_foreign_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_model(tmp_path / "nope.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ModelError, match="not a wface face model"):
        load_model(tmp_path / "other.npz")


def test_jaw_closing_range_round_trip_and_older_files(face, tmp_path):
    # The built-in face closes past rest (format 4); a joint without a closing range is written as
    # before (no key, the older format) and an older file's joint reads as closing 0.
    assert face.jaw_joint.max_closing_sine > 0
    back = load_model(save_model(face, tmp_path / "face.npz"))
    assert back.jaw_joint == face.jaw_joint and model_sha256(back) == model_sha256(face)
    header = json.loads(bytes(np.load(tmp_path / "face.npz")["header_json"]).decode())
    assert header["format_version"] == 4 and "max_closing_sine" in header["jaw_joint"]
    closed = _copy(face, jaw_joint=replace(face.jaw_joint, max_closing_sine=0.0))
    save_model(closed, tmp_path / "closed.npz")
    header = json.loads(bytes(np.load(tmp_path / "closed.npz")["header_json"]).decode())
    assert header["format_version"] < 4 and "max_closing_sine" not in header["jaw_joint"]
    assert load_model(tmp_path / "closed.npz").jaw_joint.max_closing_sine == 0.0


def test_jaw_joint_checks():
    with pytest.raises(ModelError, match="orthogonal"):
        JawJoint((1, 0, 0), (0.6, 0.8, 0), (0, 0, 0), 0.1, 0.01, 0.5).validate()


def test_model_metadata_keeps_no_wall_clock_times():
    """A fit or an import reports its time, but the model it writes must hash the same each run."""
    from wface.files import without_timings

    report = {"seconds": 3.2, "a": {"seconds": 1.0, "b": [{"seconds": 2.0, "c": 1}]}, "d": 4}
    assert without_timings(report) == {"a": {"b": [{"c": 1}]}, "d": 4}
