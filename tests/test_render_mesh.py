"""Render meshes (read by wface.mesh.meshfile: tests/test_surface_mesh.py): binding them to the tet mesh
(wface.mesh.embed, wface.faces.render_mesh) and writing them to USD (wface.io.usd.render_mesh)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tests.conftest import data_path
from wface.faces import build_face
from wface.faces.render_mesh import bind_render_mesh
from wface.mesh.embed import bind_points
from wface.mesh.meshfile import SurfaceMesh, read_surface_mesh
from wface.takes.take import Take
from wface.takes.usd import write_take_usd

_EXACT_M = 1e-12  # float64 round-off on positions of ~0.1 m
_USD_M = 2e-7  # float32 points in USD, centimetres: ~1e-6 cm relative


@pytest.fixture(scope="module")
def face():
    return build_face(2000)


def _points_around(face, rng) -> np.ndarray:
    """Points inside the flesh (tet centroids), on the skin, and 1-80 mm outside it."""
    x, skin = face.rest_positions_m, face.skin_triangles
    inside = x[face.tets[rng.choice(face.n_tets, 50, replace=False)]].mean(axis=1)
    t = rng.choice(len(skin), 50, replace=False)
    p = x[skin[t]].mean(axis=1)
    n = np.cross(x[skin[t, 1]] - x[skin[t, 0]], x[skin[t, 2]] - x[skin[t, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    outside = p + n * rng.uniform(0.001, 0.08, (50, 1)) + rng.normal(0, 0.01, (50, 3))
    return np.vstack([inside, p, outside])


def test_a_bound_mesh_reproduces_the_rest_mesh_exactly(face):
    pts = _points_around(face, np.random.default_rng(0))
    b = bind_points(pts, face.rest_positions_m, face.tets, face.skin_triangles)
    assert len(b.inside) >= 50 and len(b.outside) >= 40  # both kinds are exercised
    np.testing.assert_allclose(b.positions(face.rest_positions_m), pts, atol=_EXACT_M, rtol=0)


def test_a_bound_mesh_follows_an_affine_deformation_exactly(face):
    pts = _points_around(face, np.random.default_rng(1))
    b = bind_points(pts, face.rest_positions_m, face.tets, face.skin_triangles)
    c, s = np.cos(0.4), np.sin(0.4)
    A = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[1.3, 0.2, 0.0], [0.0, 0.8, 0.1], [0.05, 0.0, 1.1]]
    )
    t = np.array([0.01, -0.02, 0.03])
    moved = b.positions(face.rest_positions_m @ A.T + t)
    np.testing.assert_allclose(moved, pts @ A.T + t, atol=_EXACT_M, rtol=0)


def test_outside_points_turn_with_a_local_bend(face):
    """A bend of the flesh turns the offsets of the outside points within 2 cm of the skin (a render
    mesh's skin detail): they land far closer to where the bend itself takes them than the closest
    skin point plus its unturned rest offset does (farther out, the bend's curvature over the
    offset, which no local gradient carries, takes over)."""
    pts = _points_around(face, np.random.default_rng(2))[100:]
    b = bind_points(pts, face.rest_positions_m, face.tets, face.skin_triangles)
    bend = lambda p: p + np.array([0, 0, 1.0]) * 2.0 * p[:, :1] ** 2  # noqa: E731 - about the vertical axis
    x = bend(face.rest_positions_m)
    c = np.einsum("kj,kjd->kd", b.tri_weights, x[b.tri_nodes])
    shifted = c + b.offset_m  # the offset carried without turning
    near = np.linalg.norm(b.offset_m, axis=1) < 0.02
    assert near.sum() >= 10
    err = np.linalg.norm(b.positions(x)[b.outside] - bend(pts)[b.outside], axis=1)[near]
    err_shift = np.linalg.norm(shifted - bend(pts)[b.outside], axis=1)[near]
    assert np.median(err) < 0.5 * np.median(err_shift)


def test_far_points_move_continuously_across_skin_triangles():
    """A dense row of points 31-38 mm off the skin of a 5K-tet face (median skin edge 14 mm), sweeping
    across skin triangles, stays a smooth row under a bend of the flesh: no step between neighbours
    grows more than 3 times its rest length (1.1 now). With one deformation gradient per closest
    triangle each triangle boundary crossed was a jump of (F_t - F_t') o, 13 times the rest step here
    (a fold in a render mesh behind the ear). Steps where the closest skin point itself jumps (the
    row crossing the skin's medial axis) are not this test's."""
    face = build_face(5000)
    x, skin = face.rest_positions_m, face.skin_triangles
    front = skin[np.argmax(x[skin].mean(axis=1)[:, 2])]  # the most forward triangle: the nose
    c0 = x[front].mean(axis=0) + np.array([0.03, -0.02, 0.0])  # over the cheek
    n = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    row = c0 + 0.025 * n + np.linspace(-0.015, 0.015, 601)[:, None] * np.array([0.0, 1.0, 0.0])
    b = bind_points(row, x, face.tets, skin)
    assert len(b.outside) == len(row) and len(np.unique(b.tri_nodes, axis=0)) >= 3  # crosses triangles
    bend = lambda p: p + np.array([0, 0, 1.0]) * 4.0 * (p[:, :1] ** 2 + p[:, 1:2] ** 2)  # noqa: E731
    moved = b.positions(bend(x))
    c = np.einsum("kj,kjd->kd", b.tri_weights, x[b.tri_nodes])
    step0 = np.linalg.norm(np.diff(row, axis=0), axis=1)
    step = np.linalg.norm(np.diff(moved, axis=0), axis=1)
    smooth = np.linalg.norm(np.diff(c, axis=0), axis=1) < 2.0 * step0  # the closest point moves with the row
    assert smooth.sum() >= 500
    assert (step[smooth] / step0[smooth]).max() < 3.0


def test_the_render_mesh_goes_to_usd_in_its_own_units(face, tmp_path):
    from pxr import Usd, UsdGeom

    x, skin = face.rest_positions_m, face.skin_triangles
    obj = tmp_path / "patch.obj"
    used = np.unique(skin[:200])
    local = {v: i for i, v in enumerate(used)}
    lines = [f"v {a * 100:.9f} {b * 100:.9f} {c * 100:.9f}" for a, b, c in x[used]]  # centimetres
    lines += [f"vt {u:.3f} {v:.3f}" for u, v in np.random.default_rng(0).random((len(used), 2))]
    lines += ["usemtl Face"] + [
        f"f {local[i] + 1}/{local[i] + 1} {local[j] + 1}/{local[j] + 1} {local[k] + 1}/{local[k] + 1}"
        for i, j, k in skin[:200]
    ]
    obj.write_text("\n".join(lines) + "\n")
    rm = bind_render_mesh(face, obj, units="cm", source_to_model=np.diag([0.01, 0.01, 0.01, 1.0]))
    frames = np.stack([x, x + np.array([0.0, 0.01, 0.0])])  # rest, then 1 cm up
    take = Take(
        activations=np.zeros((2, face.n_muscles)), fps=24.0, muscle_names=face.muscle_names, joint=face.jaw_joint
    )
    path = write_take_usd(tmp_path / "animation.usdc", face, frames, take=take, render_mesh=rm)
    layer = Usd.Stage.Open(str(tmp_path / "animation_render_mesh.usdc"))
    assert UsdGeom.GetStageMetersPerUnit(layer) == 0.01 and layer.GetTimeCodesPerSecond() == 24.0
    mesh = UsdGeom.Mesh(layer.GetPrimAtPath("/RenderMesh/RenderMeshCache"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == rm.mesh.face_vertex_counts.tolist()
    assert list(mesh.GetFaceVertexIndicesAttr().Get()) == rm.mesh.face_vertex_indices.tolist()
    st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying" and list(st.GetIndices()) == rm.mesh.uv_indices.tolist()
    subsets = UsdGeom.Subset.GetGeomSubsets(mesh, "face", "materialBind")
    assert [s.GetPrim().GetName() for s in subsets] == ["Face"] and len(subsets[0].GetIndicesAttr().Get()) == 200
    p1 = np.array(mesh.GetPointsAttr().Get(1.0))
    np.testing.assert_allclose(p1, rm.mesh.points + [0.0, 1.0, 0.0], atol=_USD_M * 100)  # moved 1 cm, in cm
    assert mesh.GetNormalsAttr().GetTimeSamples() == [0.0, 1.0]
    stage = Usd.Stage.Open(str(path))  # the take's stage (metres) references the layer with its placement
    prim = stage.GetPrimAtPath("/Face/RenderMesh/RenderMeshCache")
    world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(0.0))
    pts = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(0.0))
    np.testing.assert_allclose(np.c_[pts, np.ones(len(pts))] @ world, np.c_[x[used], np.ones(len(used))], atol=1e-8)


def test_the_ict_head_binds_to_the_built_in_face(face):
    head = read_surface_mesh(data_path("ict-facekit", "generic_neutral_mesh.obj"))
    assert (head.n_points, head.n_faces, int((head.face_vertex_counts == 3).sum())) == (26719, 26384, 548)
    assert head.meters_per_unit == 0.01 and len(head.uv) == 28911 and len(head.face_groups) == 12
    with pytest.warns(UserWarning, match="Fit the face to it first"):
        rm = bind_render_mesh(face, head)  # not the face's shape: a warning, still bound
    np.testing.assert_allclose(rm.source_points(face.rest_positions_m), head.points, atol=1e-9)  # cm
    up = rm.source_to_model[:3, :3] @ np.array([0.0, 1.0, 0.0]) / 0.01
    assert up[1] > 0.98  # upright: the file's +y stays the face's up (it was turned upside down before)
    assert rm.placement == "aligned"


def _tetrahedron(centre, size):
    v = np.asarray(centre) + size * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    return v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _head_like(face):
    """The face's skin (the mesh's largest part), a small "tooth" on the lower teeth and a part 60 mm
    behind the face (a back of the head), in metres."""
    x, skin = face.rest_positions_m, face.skin_triangles
    used = np.unique(skin)
    local = np.full(face.n_nodes, -1)
    local[used] = np.arange(len(used))
    verts, tris = [x[used]], [local[skin]]
    tooth, tt = _tetrahedron(face.bone_meshes["lower_teeth"].vertices_m.mean(axis=0), 0.002)
    back, bt = _tetrahedron(x[used].mean(axis=0) - [0, 0, 0.06 + np.ptp(x[used][:, 2])], 0.01)
    n0 = len(used)
    verts += [tooth, back]
    tris += [tt + n0, bt + n0 + 4]
    return SurfaceMesh.from_triangles(np.vstack(verts), np.vstack(tris)), n0


def _jaw_turn(face, deg):
    """Rest positions with the jaw's attached nodes turned about the joint's hinge axis; the rotation."""
    from wface.model import BONES

    a = np.radians(deg)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    mid = np.asarray(face.jaw_joint.midpoint_m)
    x = face.rest_positions_m.copy()
    jaw = face.attached_nodes[face.attached_bone == BONES.index("jaw")]
    x[jaw] = (x[jaw] - mid) @ R.T + mid
    return x, lambda p: (p - mid) @ R.T + mid


def test_far_parts_follow_the_cranium_and_a_tooth_its_jaw(face):
    """A jaw that opens carries a separate part near the lower teeth rigidly with it, leaves a part far
    behind the face where the cranium holds it (the local skin would swing it by its lever arm), and the
    binding stays exact at rest and under an affine motion."""
    mesh, n0 = _head_like(face)
    rm = bind_render_mesh(face, mesh, source_to_model=np.eye(4))
    a = rm.binding.anchors
    assert a is not None and set(a.point) >= set(range(n0, n0 + 8))
    x, turn = _jaw_turn(face, 12.0)
    p = rm.model_points(x)
    np.testing.assert_allclose(p[n0 : n0 + 4], turn(mesh.points[n0 : n0 + 4]), atol=_EXACT_M, rtol=0)
    np.testing.assert_allclose(p[n0 + 4 :], mesh.points[n0 + 4 :], atol=_EXACT_M, rtol=0)
    np.testing.assert_allclose(rm.model_points(face.rest_positions_m), mesh.points, atol=_EXACT_M, rtol=0)
    A = np.array([[1.1, 0.05, 0.0], [0.02, 0.95, 0.1], [0.0, -0.03, 1.05]])
    t = np.array([0.01, -0.02, 0.03])
    moved = rm.model_points(face.rest_positions_m @ A.T + t)
    np.testing.assert_allclose(moved, mesh.points @ A.T + t, atol=_EXACT_M, rtol=0)
    # without the anchors the far part swings with the local skin
    bare = bind_points(mesh.points, face.rest_positions_m, face.tets, face.skin_triangles)
    assert np.abs(bare.positions(x)[n0 + 4 :] - mesh.points[n0 + 4 :]).max() > 1e-3


def test_a_file_named_as_the_fit_target_but_shaped_otherwise_is_aligned(face, tmp_path):
    """The fit's placement is used only when the face's skin lies on the mesh so placed."""
    mesh, _ = _head_like(face)
    model = replace(
        face,
        metadata={
            **face.metadata,
            "fit": {
                "surface": "head.obj",
                "surface_vertices": mesh.n_points,
                "surface_meters_per_unit": 1.0,
                "target_to_model": np.eye(4).tolist(),
            },
        },
    )
    same = SurfaceMesh.from_triangles(mesh.points, mesh.triangles())
    same.source = str(tmp_path / "head.obj")
    assert bind_render_mesh(model, same).placement == "fit"
    moved = SurfaceMesh.from_triangles(mesh.points + [0.0, 0.0, 0.02], mesh.triangles())
    moved.source = str(tmp_path / "head.obj")
    with pytest.warns(UserWarning, match="fitted to a mesh of this name"):
        rm = bind_render_mesh(model, moved)
    assert rm.placement == "aligned"
    np.testing.assert_allclose(rm.source_to_model[:3, 3], [0.0, 0.0, -0.02], atol=5e-4)


def _write_skin_patch(face, path, n_triangles: int) -> np.ndarray:
    """An OBJ (metres) of the face's first ``n_triangles`` skin triangles at rest; returns its nodes."""
    x, skin = face.rest_positions_m, face.skin_triangles
    used = np.unique(skin[:n_triangles])
    local = {v: i for i, v in enumerate(used)}
    lines = [f"v {a:.9f} {b:.9f} {c:.9f}" for a, b, c in x[used]]
    lines += [f"f {local[i] + 1} {local[j] + 1} {local[k] + 1}" for i, j, k in skin[:n_triangles]]
    path.write_text("\n".join(lines) + "\n")
    return used


def test_resim_writes_the_render_mesh_too(tmp_path, capsys):
    import json

    from pxr import Usd, UsdGeom

    from wface.cli import main

    used = _write_skin_patch(build_face(2000), tmp_path / "patch.obj", 60)
    out = tmp_path / "smile"
    args = ["resim", "--out", str(out), "--tets", "2000", "--frames", "3", "--substeps", "2", "--json"]
    assert main([*args, "--render-mesh", str(tmp_path / "patch.obj"), "--render-mesh-units", "m"]) == 0
    json.loads(capsys.readouterr().out)  # --json: stdout still holds the summary alone
    stage = Usd.Stage.Open(str(out / "animation.usdc"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/RenderMesh/RenderMeshCache"))
    assert mesh.GetPointsAttr().GetTimeSamples() == [0.0, 1.0, 2.0]
    assert len(mesh.GetPointsAttr().Get(2.0)) == len(used)


def test_edit_puts_the_render_mesh_in_its_rig_too(tmp_path, capsys):
    """README: the render mesh joins the rig (Rig/RenderMesh); wface edit used to add the point cache alone."""
    from pxr import Usd

    from wface.cli import main

    _write_skin_patch(build_face(2000), tmp_path / "patch.obj", 60)
    out = tmp_path / "blend"
    args = ["edit", "blend", "--from", "smile", "--to", "surprise", "--frames", "2", "--tets", "2000", "--usda"]
    assert main([*args, "--no-pictures", "--render-mesh", str(tmp_path / "patch.obj"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "import the animation stage" in text and "import animation.usdc" not in text  # it wrote animation.usda
    stage = Usd.Stage.Open(str(out / "animation.usda"))
    assert stage.GetPrimAtPath("/Face/Rig/RenderMesh") and stage.GetPrimAtPath("/Face/RenderMesh/RenderMeshCache")
    assert stage.GetRootLayer().customLayerData["wface"]["render_mesh_rig_rms_error_mm"] < 1.0


def test_demo_lists_the_render_mesh_layer_it_writes(tmp_path, capsys):
    """The closing lines name every file written, the render mesh's own layer included."""
    from wface.cli import main

    _write_skin_patch(build_face(1000), tmp_path / "patch.obj", 40)
    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--tets", "1000", "--frames", "2", "--no-pictures", "--prior", "temporal"]
    assert main([*args, "--render-mesh", str(tmp_path / "patch.obj"), "--render-mesh-units", "m"]) == 0
    printed = capsys.readouterr().out
    assert (out / "animation_render_mesh.usdc").is_file() and "animation_render_mesh.usdc" in printed


def test_a_take_carries_its_render_mesh_into_resim(tmp_path, capsys):
    """``wface resim --take`` writes the take's render mesh without being told (a user's production mesh
    was silently dropped), ``--render-mesh none`` leaves it out, and a mesh file since moved is said."""
    from wface.cli import main

    _write_skin_patch(build_face(1000), tmp_path / "patch.obj", 40)
    take = tmp_path / "demo"
    args = ["demo", "--out", str(take), "--tets", "1000", "--frames", "2", "--no-pictures", "--prior", "temporal"]
    assert main([*args, "--render-mesh", str(tmp_path / "patch.obj"), "--render-mesh-units", "m"]) == 0
    resim = ["resim", "--take", str(take), "--tets", "1000", "--substeps", "1"]
    capsys.readouterr()
    assert main([*resim, "--out", str(tmp_path / "carried")]) == 0
    assert "render mesh from the take" in capsys.readouterr().err
    assert (tmp_path / "carried" / "animation_render_mesh.usdc").is_file()
    assert main([*resim, "--render-mesh", "none", "--out", str(tmp_path / "without")]) == 0
    assert not (tmp_path / "without" / "animation_render_mesh.usdc").exists()
    (tmp_path / "patch.obj").rename(tmp_path / "moved.obj")
    capsys.readouterr()
    assert main([*resim, "--out", str(tmp_path / "gone")]) == 0
    said = capsys.readouterr().err
    assert "the take's render mesh" in said and "patch.obj is not found" in said
    assert not (tmp_path / "gone" / "animation_render_mesh.usdc").exists()


def test_containing_tets_finds_a_large_tet_among_small_ones():
    """The tet holding a point is found however far its centroid is: a point in a large tet, crowded by 400 small
    tets whose centroids are all nearer to it (a search of the nearest centroids alone, as this used to be, gives -1
    there), and random points on a jittered box mesh agree with testing every tet."""
    from wface.mesh.embed import containing_tets
    from wface.testing.box import box_tet_mesh

    big = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]])
    rng = np.random.default_rng(3)
    base = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]])
    small = [base + np.array([-0.03 - 0.02 * rng.random(), 0.1 * rng.random(), 0.1 * rng.random()]) for _ in range(400)]
    x = np.concatenate([big, *small])
    tets = np.arange(len(x)).reshape(-1, 4)
    p = np.array([[0.05, 0.05, 0.05]])
    tet, w = containing_tets(p, x, tets)
    assert tet[0] == 0
    np.testing.assert_allclose(w[0] @ x[tets[0]], p[0], atol=1e-14)
    assert np.all(w[0] >= 0)

    x, tets = box_tet_mesh((4, 3, 3), (1.0, 0.8, 0.7))
    x = x + 0.03 * rng.standard_normal(x.shape)
    q = rng.uniform(-0.05, 1.05, size=(500, 3)) * [1.0, 0.8, 0.7]
    tet, w = containing_tets(q, x, tets)
    for i, t in enumerate(tet):  # brute force: the point's weights in every tet
        D = np.stack([x[tets[:, j]] - x[tets[:, 0]] for j in (1, 2, 3)], axis=2)
        w123 = np.linalg.solve(D, (q[i] - x[tets[:, 0]])[:, :, None])[:, :, 0]
        holds = np.column_stack([1.0 - w123.sum(axis=1), w123]).min(axis=1) >= -1e-9
        if t < 0:
            assert not holds.any()
        else:
            assert holds[t]
            np.testing.assert_allclose(w[i] @ x[tets[t]], q[i], atol=1e-12)
    assert (tet >= 0).sum() > 300 and (tet < 0).sum() > 20


def test_containing_tets_nearest_for_points_just_outside():
    """A point just outside the mesh is in no tet (-1); with nearest=True it takes the tet it is least
    outside of, one whose face it lies beyond."""
    from wface.mesh.embed import containing_tets
    from wface.testing.box import box_tet_mesh

    x, tets = box_tet_mesh((2, 2, 2), (1.0, 1.0, 1.0))
    p = np.array([[0.5, 0.5, 0.5], [0.3, 0.7, -1e-4]])
    found, _ = containing_tets(p, x, tets)
    assert found[0] >= 0 and found[1] == -1
    near, _ = containing_tets(p, x, tets, nearest=True)
    assert near[0] == found[0]
    corners = x[tets[near[1]]]
    assert np.isclose(corners[:, 2], 0.0).sum() == 3  # a tet with a face on the box's z = 0 side
    assert corners[:, 0].min() <= 0.3 <= corners[:, 0].max() and corners[:, 1].min() <= 0.7 <= corners[:, 1].max()
