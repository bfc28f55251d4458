"""The take's UsdSkel rig: USD's own skinning equals ``rig_points``, and the rig reproduces the FEM face
where it is exact by construction (one muscle at full activation, the jaw at its largest opening)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pxr")

from wface.controls import IDENTITY_BONES, bone_affines, jaw_from_intuitive, jaw_limits  # noqa: E402
from wface.faces.builtin import build_face  # noqa: E402
from wface.io.usd import blendshape_points, rig_points  # noqa: E402
from wface.takes import Take, simulate_poses, write_take_usd  # noqa: E402
from wface.takes.shapes import JAW_SHAPE, shape_weights, skin_rig  # noqa: E402

_F32_M = 2e-7  # float32 storage of ~0.1 m coordinates, a few ulps
_SOLVE_M = 1e-8  # the quasistatic solves converge to a relative residual of 1e-6: ~1e-8 m on this face


@pytest.fixture(scope="module")
def face():
    return build_face(1500)


@pytest.fixture(scope="module")
def rig(face):
    return skin_rig(face)


def _take(face, activations, jaw_deg, head_deg):
    bones = np.tile(IDENTITY_BONES, (len(jaw_deg), 1))
    for i, (j, h) in enumerate(zip(jaw_deg, head_deg, strict=True)):
        bones[i, 12:] = jaw_from_intuitive(face.jaw_joint, opening_deg=j)
        c, s = np.cos(np.deg2rad(h)), np.sin(np.deg2rad(h))
        bones[i, :9] = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).ravel()
        bones[i, 9:12] = [0.002 * i, 0.0, 0.001]
    names = list(face.muscle_names)
    frames = np.arange(5, 5 + len(bones))
    return Take(activations=activations, fps=30.0, bones=bones, muscle_names=names, frames=frames, joint=face.jaw_joint)


def test_usd_skinning_equals_rig_points(tmp_path, face, rig):
    from pxr import Usd, UsdSkel

    a = np.zeros((3, face.n_muscles))
    a[:, face.muscle_index("zygomaticus_major_l")] = [0.0, 0.5, 1.0]
    a[:, face.muscle_index("orbicularis_oris_lower")] = [0.2, 0.0, 0.7]
    take = _take(face, a, [0.0, 6.0, 12.0], [0.0, 4.0, -3.0])
    x = simulate_poses(face, take).x_m
    path = write_take_usd(tmp_path / "t.usda", face, x, take=take, rig="all")
    stage = Usd.Stage.Open(str(path))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Face/Rig")), Usd.PrimDefaultPredicate)
    mesh = stage.GetPrimAtPath("/Face/Rig/SkinRig")
    skel_query = cache.GetSkelQuery(UsdSkel.BindingAPI(mesh).GetInheritedSkeleton())
    skinning = cache.GetSkinningQuery(mesh)
    theta_max = rig.info["jaw_open_full_deg"]
    for i, t in enumerate(take.frames):
        code = Usd.TimeCode(float(t))
        from pxr import Vt

        pts = Vt.Vec3fArray.FromNumpy(blendshape_points(stage, str(mesh.GetPath()), float(t)).astype(np.float32))
        assert skinning.ComputeSkinnedPoints(skel_query.ComputeSkinningTransforms(code), pts, code)
        C, J = bone_affines(take.bones[i])
        w = np.concatenate([shape_weights(face, a[i : i + 1])[1][0], [[0.0, 6.0, 12.0][i] / theta_max]])[None]
        np.testing.assert_allclose(np.asarray(pts), rig_points(rig, w, C[None], J[None])[0], atol=5 * _F32_M)


def test_the_joints_sit_at_the_skull_and_the_hinge(tmp_path, face):
    """A DCC draws and turns the jaw bone at the condyles' midpoint (the joints were all bound at the
    origin, a jaw turned by hand pivoted 18 mm off its hinge), and the skinned skin is unchanged."""
    from pxr import Usd, UsdSkel

    from wface.io.usd.take import joint_pivots

    a = np.zeros((2, face.n_muscles))
    take = _take(face, a, [0.0, 10.0], [0.0, 5.0])
    x = simulate_poses(face, take).x_m
    stage = Usd.Stage.Open(str(write_take_usd(tmp_path / "t.usda", face, x, take=take, rig="all")))
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/Face/Rig/Skel"))
    pivots = joint_pivots(face)
    bind = [np.array(m.ExtractTranslation()) for m in skel.GetBindTransformsAttr().Get()]
    np.testing.assert_allclose(bind, pivots, atol=1e-9)
    np.testing.assert_allclose(pivots[1], face.jaw_joint.midpoint_m)
    query = UsdSkel.Cache().GetSkelQuery(skel)
    hinge_now = [np.array(m.ExtractTranslation()) for m in query.ComputeJointSkelTransforms(Usd.TimeCode(6.0))][1]
    C, J = bone_affines(take.bones[1])
    expected = C[:, :3] @ (J[:, :3] @ pivots[1] + J[:, 3]) + C[:, 3]  # the hinge carried by the bones
    np.testing.assert_allclose(hinge_now, expected, atol=1e-6)  # the rig takes the nearest rotation


def test_rig_is_exact_where_it_is_built_to_be(face, rig):
    skin = np.unique(face.skin_triangles)
    theta_max = jaw_limits(face.jaw_joint)["opening_deg"][1]
    m = face.muscle_index("zygomaticus_major_l")
    a = np.zeros((2, face.n_muscles))
    a[0, m] = 1.0
    take = _take(face, a, [0.0, theta_max], [0.0, 0.0])
    x = simulate_poses(face, take).y_m[:, skin]  # cranium frame: the take's small head translation left out
    eye = np.tile(np.hstack([np.eye(3), np.zeros((3, 1))]), (2, 1, 1))
    J = np.stack([bone_affines(b)[1] for b in take.bones])
    w = np.zeros((2, rig.deltas_m.shape[0]))
    w[0, m] = 1.0
    w[1, rig.names.index(JAW_SHAPE)] = 1.0
    got = rig_points(rig, w, eye, J)
    np.testing.assert_allclose(got[0], x[0], atol=_SOLVE_M)  # a muscle's own shape at weight 1
    np.testing.assert_allclose(got[1], x[1], atol=_SOLVE_M)  # the jaw corrective at theta_max


def test_jaw_weights_follow_the_bones(face, rig):
    skin = np.unique(face.skin_triangles)
    where = {int(n): k for k, n in enumerate(skin)}
    for bone, expected in (("jaw", 1.0), ("cranium", 0.0)):
        nodes = [where[n] for n in face.nodes_of_bone(bone) if n in where]
        assert nodes, bone
        np.testing.assert_allclose(rig.jaw_weights[nodes], expected, atol=1e-6)
    assert 0.2 < np.median(rig.jaw_weights) < 0.8 or np.ptp(rig.jaw_weights) == pytest.approx(1.0)


def test_a_mesh_carried_by_the_skin_joins_the_rig(tmp_path, face, rig):
    """A render mesh bound to the skin (here: the skin triangles' centroids, barycentric weights 1/3)
    gets the same joints and shape names, and USD skins it as ``rig_points`` of the carried rig."""
    import scipy.sparse as sp
    from pxr import Usd, UsdSkel, Vt

    from wface.io.usd import write_take

    skin = np.unique(face.skin_triangles)
    local = np.searchsorted(skin, face.skin_triangles)  # (t, 3) compact skin ids
    t = len(local)
    W = sp.csr_matrix((np.full(3 * t, 1 / 3), (np.repeat(np.arange(t), 3), local.ravel())), shape=(t, skin.size))
    render = rig.carried(W, W @ rig.rest_m)
    assert render.names == rig.names and render.deltas_m.shape == (len(rig.names), t, 3)
    tri = np.arange(t - t % 3).reshape(-1, 3)  # any topology over the centroids will do
    a = np.zeros((2, face.n_muscles))
    a[1, face.muscle_index("zygomaticus_major_r")] = 0.7
    take = _take(face, a, [0.0, 10.0], [0.0, 5.0])
    C, J = (np.stack(p) for p in zip(*(bone_affines(b) for b in take.bones), strict=True))
    w = np.column_stack([shape_weights(face, a)[1], [0.0, 10.0 / rig.info["jaw_open_full_deg"]]])
    x = np.repeat(face.rest_positions_m[None], 2, axis=0)
    path = write_take(
        tmp_path / "r.usda",
        model=face,
        node_positions_m=x,
        fps=30.0,
        activations=a,
        cranium_affines=C,
        jaw_affines=J,
        rig=rig,
        rig_weights=w,
        rig_meshes={"RenderMesh": (render, np.full(len(tri), 3), tri.ravel())},
    )
    stage = Usd.Stage.Open(str(path))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Face/Rig")), Usd.PrimDefaultPredicate)
    mesh = stage.GetPrimAtPath("/Face/Rig/RenderMesh")
    skel_query = cache.GetSkelQuery(UsdSkel.BindingAPI(mesh).GetInheritedSkeleton())
    expected = rig_points(render, w, C, J)
    for f in range(2):
        pts = Vt.Vec3fArray.FromNumpy(blendshape_points(stage, str(mesh.GetPath()), float(f)).astype(np.float32))
        code = Usd.TimeCode(float(f))
        assert cache.GetSkinningQuery(mesh).ComputeSkinnedPoints(skel_query.ComputeSkinningTransforms(code), pts, code)
        np.testing.assert_allclose(np.asarray(pts), expected[f], atol=5 * _F32_M)
    assert np.abs(expected[1] - expected[0]).max() > 1e-3  # the render mesh moves with the curves and the jaw


def test_the_default_rig_holds_the_shapes_the_take_uses(tmp_path, face):
    from pxr import Usd, UsdSkel

    a = np.zeros((2, face.n_muscles))
    a[1, face.muscle_index("mentalis_l")] = 0.4
    take = _take(face, a, [0.0, 0.0], [0.0, 0.0])  # the jaw stays shut
    x = np.repeat(face.rest_positions_m[None], 2, axis=0)
    stage = Usd.Stage.Open(str(write_take_usd(tmp_path / "a.usda", face, x, take=take)))
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/Face/Rig/Skel/Anim"))
    assert list(anim.GetBlendShapesAttr().Get()) == ["mentalis_l"]  # no jaw_open: the jaw does not move
    assert list(anim.GetBlendShapeWeightsAttr().Get(6.0)) == pytest.approx([0.4])
    still = write_take_usd(tmp_path / "b.usda", face, x, take=_take(face, np.zeros_like(a), [0.0, 0.0], [0.0, 0.0]))
    assert not Usd.Stage.Open(str(still)).GetPrimAtPath("/Face/Rig")  # nothing moves: no rig


def test_a_failed_rig_solve_loses_no_take(tmp_path, face, monkeypatch):
    from pxr import Usd

    import wface.takes.usd as take_usd

    def inverting(*_args, **_kwargs):
        raise RuntimeError("muscle mentalis_l at activation 1.0 inverts 3 tets")

    monkeypatch.setattr(take_usd, "skin_rig", inverting)  # what muscle_shapes raises on an inverting face
    a = np.zeros((2, face.n_muscles))
    a[1, face.muscle_index("mentalis_l")] = 0.4
    x = np.repeat(face.rest_positions_m[None], 2, axis=0)
    with pytest.warns(RuntimeWarning, match="without the UsdSkel rig"):
        path = write_take_usd(tmp_path / "a.usda", face, x, take=_take(face, a, [0.0, 0.0], [0.0, 0.0]))
    stage = Usd.Stage.Open(str(path))
    assert stage.GetPrimAtPath("/Face/Skin") and not stage.GetPrimAtPath("/Face/Rig")  # the exact cache is there
    assert "inverts 3 tets" in stage.GetRootLayer().customLayerData["wface"]["rig_skipped"]


def _render_patch(face, tmp_path):
    """A render mesh over 300 skin triangles, its vertices 1.5 mm in and out of the skin in turn (so
    both kinds of binding are used), written in centimetres in a turned frame with UVs."""
    from wface.faces.render_mesh import bind_render_mesh
    from wface.mesh.surface import vertex_normals

    x = face.rest_positions_m
    tris = face.skin_triangles[:300]
    used, local = np.unique(tris, return_inverse=True)
    n = vertex_normals(x, face.skin_triangles)[used]
    p_m = x[used] + n * np.where(np.arange(len(used)) % 2, 0.0015, -0.0015)[:, None]
    c, s = np.cos(0.3), np.sin(0.3)
    placement = np.eye(4)
    placement[:3, :3] = 0.01 * np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # file cm, turned -> model m
    placement[:3, 3] = [0.01, -0.02, 0.005]
    p_file = (p_m - placement[:3, 3]) @ np.linalg.inv(placement[:3, :3]).T
    lines = [f"v {a:.12g} {b:.12g} {d:.12g}" for a, b, d in p_file]
    lines += [f"vt {u:.4f} {v:.4f}" for u, v in np.random.default_rng(0).random((3 * len(tris), 2))]
    lines += ["usemtl Face"] + [
        "f " + " ".join(f"{v + 1}/{3 * k + j + 1}" for j, v in enumerate(t)) for k, t in enumerate(local.reshape(-1, 3))
    ]
    (tmp_path / "patch.obj").write_text("\n".join(lines) + "\n")
    rm = bind_render_mesh(face, tmp_path / "patch.obj", units="cm", source_to_model=placement)
    assert len(rm.binding.inside) > 50 and len(rm.binding.outside) > 50
    return rm


def test_the_render_mesh_joins_the_rig_in_its_own_units(tmp_path, face, rig):
    """A take written with a rig and a render mesh carries the render mesh in the SkelRoot too: its
    own shapes (its binding on each muscle's whole equilibrium) in the file's centimetres and frame,
    placed by geomBindTransform; UsdSkel skins it as ``rig_points``, exactly like the point cache
    beside it where the rig is exact (a muscle alone at 1, the jaw at its largest opening)."""
    from pxr import Usd, UsdGeom, UsdShade, UsdSkel, Vt

    from wface.io.usd import assert_stage_valid
    from wface.takes.shapes import render_mesh_rig

    rm = _render_patch(face, tmp_path)
    theta_max = rig.info["jaw_open_full_deg"]
    m = face.muscle_index("zygomaticus_major_l")
    a = np.zeros((4, face.n_muscles))
    a[1, m] = 1.0
    a[3, m], a[3, face.muscle_index("orbicularis_oris_lower")] = 0.6, 0.3
    jaw_deg = [0.0, 0.0, theta_max, 9.0]
    bones = np.tile(IDENTITY_BONES, (4, 1))
    for i, j in enumerate(jaw_deg):
        bones[i, 12:] = jaw_from_intuitive(face.jaw_joint, opening_deg=j)
    bones[3, :9] = np.array([[np.cos(0.1), 0, np.sin(0.1)], [0, 1, 0], [-np.sin(0.1), 0, np.cos(0.1)]]).ravel()
    take = Take(activations=a, fps=30.0, bones=bones, muscle_names=list(face.muscle_names), joint=face.jaw_joint)
    x = simulate_poses(face, take).x_m
    path = write_take_usd(tmp_path / "r.usda", face, x, take=take, rig="all", render_mesh=rm)
    assert_stage_valid(path)  # extents, the SkelRoot's extentsHint through the geomBindTransform
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/Face/Rig/RenderMesh")
    assert stage.GetPrimAtPath("/Face/RenderMesh/RenderMeshCache")  # the exact point cache stays beside it
    usd_mesh = UsdGeom.Mesh(prim)
    np.testing.assert_allclose(np.asarray(usd_mesh.GetPointsAttr().Get()), rm.mesh.points, atol=1e-5)  # cm
    assert list(usd_mesh.GetFaceVertexCountsAttr().Get()) == rm.mesh.face_vertex_counts.tolist()
    st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying" and list(st.GetIndices()) == rm.mesh.uv_indices.tolist()
    bind = np.asarray(UsdSkel.BindingAPI(prim).GetGeomBindTransformAttr().Get())
    np.testing.assert_allclose(bind.T, rm.source_to_model, atol=1e-15)
    assert list(UsdSkel.BindingAPI(prim).GetBlendShapesAttr().Get()) == rig.names
    # its material groups, bound to the render mesh layer's own materials (a DCC gives both one look)
    cache_prim = stage.GetPrimAtPath("/Face/RenderMesh/RenderMeshCache")
    for mesh_prim in (prim, cache_prim):
        subsets = UsdShade.MaterialBindingAPI(mesh_prim).GetMaterialBindSubsets()
        assert [list(sub.GetIndicesAttr().Get()) for sub in subsets] == [rm.mesh.face_groups["Face"].tolist()]
        bound = UsdShade.MaterialBindingAPI(subsets[0].GetPrim()).ComputeBoundMaterial()[0]
        assert bound and bound.GetPath() == "/Face/RenderMesh/Materials/Face"

    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Face/Rig")), Usd.PrimDefaultPredicate)
    skel_query = cache.GetSkelQuery(UsdSkel.BindingAPI(prim).GetInheritedSkeleton())
    rm_rig = render_mesh_rig(face, rm)
    C, J = (np.stack(p) for p in zip(*(bone_affines(b) for b in take.bones), strict=True))
    w = np.column_stack([shape_weights(face, a)[1], np.array(jaw_deg) / theta_max])
    expected = rig_points(rm_rig, w, C, J)
    exact = np.stack([rm.model_points(f) for f in x])
    for f in range(4):
        pts = Vt.Vec3fArray.FromNumpy(blendshape_points(stage, str(prim.GetPath()), float(f)).astype(np.float32))
        code = Usd.TimeCode(float(f))
        assert cache.GetSkinningQuery(prim).ComputeSkinnedPoints(skel_query.ComputeSkinningTransforms(code), pts, code)
        np.testing.assert_allclose(np.asarray(pts), expected[f], atol=5 * _F32_M)  # USD's skinning, in metres
    for f in range(3):  # rest, the muscle's own shape, the jaw corrective: exact
        np.testing.assert_allclose(expected[f], exact[f], atol=_SOLVE_M, err_msg=f"frame {f}")
    err_mm = np.linalg.norm(expected[3] - exact[3], axis=1) * 1e3
    assert 0.0 < err_mm.max() < 3.0  # a mix: the rig's linearisation, as on the skin ("Take rig")
    info = stage.GetRootLayer().customLayerData["wface"]
    assert info["render_mesh_rig_max_error_mm"] == pytest.approx(err_mm.max(), rel=1e-6)
    assert np.abs(exact[1] - exact[0]).max() > 1e-3  # the render mesh moves with the muscle


def test_a_shape_that_did_not_converge_is_named(face):
    from wface.physics.simulator import Simulator
    from wface.takes.shapes import muscle_shapes

    class Stopping(Simulator):
        def solve(self, *args, **kwargs):  # two Newton iterations: far from the 1e-6 tolerance
            return super().solve(*args, **{**kwargs, "max_iterations": 2})

    with pytest.warns(UserWarning, match=r"muscle mentalis_l's shape .*not converged"):
        muscle_shapes(face, muscles=["mentalis_l"], simulator=Stopping(face))
