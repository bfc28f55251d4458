"""Files that are wrong in ways a reader let through (a user's pass over the CLI with bad input):
each is refused now with a message that names the file and the problem."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wface.faces.builtin import build_face
from wface.faces.render_mesh import bind_render_mesh
from wface.files import FileFormatError, read_landmarks
from wface.mesh.meshfile import read_surface_mesh
from wface.model import ModelError, load_model, save_model

_SQUARE = "v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3 4\n"


@pytest.fixture(scope="module")
def face():
    return build_face(1500)


@pytest.mark.parametrize("line", ["v nan 0 0", "v 0 inf 0", "v 0.1 0.1", "v 1 2 x", "v np.float64(0.0) 0 0"])
def test_an_obj_vertex_that_is_not_three_numbers_is_refused(tmp_path, line):
    """tinyobjloader reads such a vertex as 0 0 0: the mesh then had a spike to the origin."""
    path = tmp_path / "bad.obj"
    path.write_text(_SQUARE.replace("v 0.1 0.1 0\n", line + "\n"))
    with pytest.raises(ValueError, match=r"bad.obj:3: a vertex needs 3 finite coordinates"):
        read_surface_mesh(path)
    path.write_text(_SQUARE.replace("v 0.1 0.1 0\n", "v 0.1 0.1 0 1\n"))  # a w coordinate is fine
    assert read_surface_mesh(path).n_points == 4


@pytest.mark.parametrize(("scale", "what"), [(1000.0, "kilometre"), (0.0, "one point")])
def test_a_render_mesh_of_no_head_size_is_refused(face, tmp_path, scale, what):
    """A mesh read 1000 times too large, or all in one point, was bound and written (800 m across)."""
    path = tmp_path / "head.obj"
    skin = face.rest_positions_m[np.unique(face.skin_triangles)]
    pts = skin[:4] * scale if scale else np.repeat(skin[:1], 4, axis=0)
    path.write_text("".join(f"v {a:.9g} {b:.9g} {c:.9g}\n" for a, b, c in pts) + "f 1 2 3\nf 1 3 4\n")
    with pytest.raises(ValueError, match=r"head.obj is .* m across .* where the face's skin is"):
        bind_render_mesh(face, path, units="m")


def test_a_landmark_point_must_be_finite_and_named_once(tmp_path):
    path = tmp_path / "lm.json"
    path.write_text('{"Chin": [NaN, 2, 3], "NoseTop": 4}')  # json reads NaN
    with pytest.raises(FileFormatError, match=r"landmark 'Chin': the point \[nan, 2, 3\] is not 3 finite numbers"):
        read_landmarks(path, points=True)
    path.write_text('{"Chin": 3, "NoseTop": 4, "Chin": 5}')  # json keeps the last without a word
    with pytest.raises(FileFormatError, match=r"lm.json: the key 'Chin' is given twice"):
        read_landmarks(path)
    path.write_text(json.dumps({"Chin": 3, "NoseTop": [0.1, 0.2, 0.3]}))
    assert read_landmarks(path, points=True) == {"Chin": 3, "NoseTop": [0.1, 0.2, 0.3]}


def test_a_model_in_millimetres_is_refused_naming_the_file(face, tmp_path):
    """Nodes 1000 times too far apart (the bones not): simulate ran with every attachment metres off."""
    path = tmp_path / "face.npz"
    save_model(face, path)
    data = dict(np.load(path))
    data["rest_positions_m"] = data["rest_positions_m"] * 1000.0
    np.savez(tmp_path / "mm.npz", **data)
    with pytest.raises(ModelError, match=r"mm.npz: the flesh spans .* m, where a face spans 0.02 to 2 m"):
        load_model(tmp_path / "mm.npz")


def test_a_header_without_muscle_names_is_named(face, tmp_path):
    """A bare KeyError ("error: muscle_names") before."""
    path = tmp_path / "face.npz"
    save_model(face, path)
    data = dict(np.load(path))
    header = json.loads(bytes(data["header_json"]).decode())
    del header["muscle_names"]
    data["header_json"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(tmp_path / "cut.npz", **data)
    with pytest.raises(ModelError, match=r"cut.npz: the face model lacks header muscle_names"):
        load_model(tmp_path / "cut.npz")
