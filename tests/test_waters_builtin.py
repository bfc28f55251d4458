"""Waters muscles on wface's built-in face: layout fitted by its markers, jaw weights from its bones."""

from __future__ import annotations

import numpy as np
import pytest

from wface.faces.builtin import build_face
from wface.facs import EXPRESSIONS
from wface.waters.expressions import expression_pose
from wface.waters.face_model import builtin_face_layout, face_model_rig, harmonic_jaw_weights
from wface.waters.layout import load_layout
from wface.waters.muscles import LinearMuscle


@pytest.fixture(scope="module")
def face():
    return build_face(5000)


@pytest.fixture(scope="module")
def rig(face):
    return face_model_rig(face)


def test_harmonic_jaw_weights_follow_the_bones(face):
    w = harmonic_jaw_weights(face)
    assert np.all((w >= 0) & (w <= 1))
    np.testing.assert_array_equal(w[face.nodes_of_bone("jaw")], 1.0)
    np.testing.assert_array_equal(w[face.nodes_of_bone("cranium")], 0.0)
    chin = face.marker_positions_m[face.marker_names.index("Chin")]
    brow = face.marker_positions_m[face.marker_names.index("Eyebrow_Center")]
    x = face.rest_positions_m
    assert w[np.argmin(np.linalg.norm(x - chin, axis=1))] > 0.9
    assert w[np.argmin(np.linalg.norm(x - brow, axis=1))] < 0.1


def test_layout_fitted_to_the_builtin_face(face, rig):
    lay = rig[0].layout
    assert lay.muscle_names == load_layout("ict").muscle_names
    np.testing.assert_allclose(lay.jaw.pivot_m, face.jaw_joint.midpoint_m)
    skin = rig[1]
    from wface.mesh.closest import SurfaceQuery

    ins = np.stack([m.insertion_m for m in lay.muscles if isinstance(m, LinearMuscle)])
    assert SurfaceQuery(skin.vertices_m, skin.triangles()).closest(ins).distance_m.max() < 1e-9
    # markers carried over: the left mouth corner is on the subject's left (+x)
    assert lay.landmarks_m["Mouth_Lend"][0] > 0


def test_packaged_builtin_layout_matches_a_fresh_fit():
    packaged = load_layout("builtin")
    fresh = builtin_face_layout()
    hint = "stale wface/data/waters_builtin.json: regenerate with save_layout(builtin_face_layout(), path)"
    for a, b in zip(packaged.muscles, fresh.muscles, strict=True):
        ref = a.bone_m if isinstance(a, LinearMuscle) else a.centre_m
        new = b.bone_m if isinstance(b, LinearMuscle) else b.centre_m
        np.testing.assert_allclose(ref, new, atol=1e-6, err_msg=f"{a.name}: {hint}")


@pytest.mark.parametrize("name", list(EXPRESSIONS))
def test_every_preset_deforms_the_builtin_skin(rig, face, name):
    r, skin, nodes = rig
    pose = expression_pose(name, muscle_names=r.muscle_names)
    x = r.deform(pose.contractions, jaw_opening_deg=pose.jaw_opening_deg)
    assert np.all(np.isfinite(x))
    d = np.linalg.norm(x - skin.vertices_m, axis=1)
    attached = np.isin(nodes, face.attached_nodes)
    np.testing.assert_array_equal(d[attached & (r.jaw_weights == 0)], 0.0)  # bone-fixed border stays
    assert d.max() < 0.05
    assert (d.max() == 0.0) == (name == "neutral")


def test_builtin_rig_uses_the_harmonic_jaw_weights(face, rig):
    r, _, nodes = rig
    np.testing.assert_array_equal(r.jaw_weights, harmonic_jaw_weights(face)[nodes])


def test_an_action_unit_on_one_side_sets_that_side_of_the_preset():
    """--au AU12R=0 on the happy preset used to leave the right smile on (contributions combine by max)."""
    one_sided = expression_pose("happy", extra_action_units={"AU12R": 0.0}).contractions
    assert one_sided["zygomaticus_major_l"] == 1.0 and one_sided["zygomaticus_major_r"] == 0.0
    half = expression_pose("happy", extra_action_units={"AU12": 0.5}).contractions
    assert half["zygomaticus_major_l"] == half["zygomaticus_major_r"] == 0.5  # the AU set, both sides
    back = expression_pose("happy", extra_action_units={"AU12R": 0.0, "AU12": 1.0}).contractions
    assert back["zygomaticus_major_r"] == 1.0


def test_the_builtin_skin_carries_the_takes_texture_coordinates(face, tmp_path):
    """`wface waters --mesh builtin` wrote a mesh without UVs where the same skin in a take's USD has
    them: one projection for both (wface.mesh.uv.skin_uv), written as primvars:st."""
    from pxr import Usd, UsdGeom

    from wface.io.usd import write_surface_mesh
    from wface.mesh.uv import skin_uv
    from wface.waters.face_model import skin_surface

    mesh, nodes = skin_surface(face)
    local = np.searchsorted(nodes, face.skin_triangles)
    np.testing.assert_allclose(mesh.uv, skin_uv(face.rest_positions_m[nodes], local))
    stage = Usd.Stage.Open(str(write_surface_mesh(tmp_path / "s.usda", mesh)))
    mesh_prim = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    st = UsdGeom.PrimvarsAPI(mesh_prim).GetPrimvar("st")
    assert st and len(st.ComputeFlattened()) == 3 * mesh.n_faces  # face-varying, one per corner
