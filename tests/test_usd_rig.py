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
from wface.takes.shapes import JAW_SHAPE, skin_rig  # noqa: E402

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
        w = np.concatenate([a[i], [[0.0, 6.0, 12.0][i] / theta_max]])[None]
        np.testing.assert_allclose(np.asarray(pts), rig_points(rig, w, C[None], J[None])[0], atol=5 * _F32_M)


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
    w = np.column_stack([a, [0.0, 10.0 / rig.info["jaw_open_full_deg"]]])
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
