"""write_take / write_blendshape_basis: content round trip, UsdValidation, extents, UsdSkel synthesis."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pxr")

from wface.io import usd  # noqa: E402
from wface.testing.synthetic_face import synthetic_face, synthetic_take  # noqa: E402

_F32 = 2e-7  # float32 storage of ~0.1 m coordinates: relative round-off 6e-8, a few ulps


@pytest.fixture(scope="module")
def face():
    return synthetic_face(nx=6, ny=6, nz=1)


@pytest.fixture(scope="module")
def take(face):
    return synthetic_take(face, n_frames=8, fps=30.0)


def _write(tmp_path, face, take, suffix=".usdc", **over):
    kw = dict(
        model=face,
        node_positions_m=take["node_positions_m"],
        fps=take["fps"],
        captured_markers_m=take["captured_markers_m"],
        simulated_markers_m=take["simulated_markers_m"],
        cranium_affines=take["cranium_affines"],
        jaw_affines=take["jaw_affines"],
        activations=take["activations"],
        basis=take["basis"],
        basis_weights=take["basis_weights"],
    )
    kw.update(over)
    return usd.write_take(tmp_path / f"take{suffix}", **kw)


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_take_passes_usd_validation_and_extents(tmp_path, face, take, suffix):
    path = _write(tmp_path, face, take, suffix)
    assert usd.validate_stage(path) == []
    assert usd.check_extents(path) == []
    usd.assert_stage_valid(path)
    head = path.read_bytes()[:8]
    assert head.startswith(b"#usda") == (suffix == ".usda")


def test_take_content(tmp_path, face, take):
    from pxr import Usd, UsdGeom

    path = _write(tmp_path, face, take, metadata={"solver": "test", "frames_note": 8})
    stage = Usd.Stage.Open(str(path))
    F = take["node_positions_m"].shape[0]
    assert stage.GetTimeCodesPerSecond() == 30.0 and stage.GetEndTimeCode() == F - 1
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert stage.GetRootLayer().customLayerData["wface"]["solver"] == "test"

    # Skin: compact vertices; nodeId maps back; topology equals the model's triangles.
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin"))
    node_id = np.asarray(UsdGeom.PrimvarsAPI(skin).GetPrimvar("wface:nodeId").Get())
    np.testing.assert_array_equal(node_id, np.unique(face.skin_triangles))
    tri = node_id[np.asarray(skin.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)]
    np.testing.assert_array_equal(tri, face.skin_triangles)
    for f in (0, F // 2, F - 1):
        np.testing.assert_allclose(
            np.asarray(skin.GetPointsAttr().Get(f)), take["node_positions_m"][f, node_id], atol=_F32
        )
    act_pv = UsdGeom.PrimvarsAPI(skin).GetPrimvar("wface:activation")
    assert act_pv.GetInterpolation() == "vertex" and len(act_pv.Get(0)) == node_id.size
    assert len(skin.GetDisplayColorPrimvar().GetAttr().GetTimeSamples()) == F

    # Markers: one named locator each (translate op per frame, hidden while missing), coloured balls.
    cap = stage.GetPrimAtPath("/Face/Markers/Captured")
    sim = stage.GetPrimAtPath("/Face/Markers/Simulated")
    m0 = face.marker_names[0]
    ball = UsdGeom.Sphere(stage.GetPrimAtPath(f"/Face/Markers/Captured/{m0}/{m0}"))
    assert tuple(ball.GetDisplayColorPrimvar().Get()[0]) == pytest.approx((0.9, 0.05, 0.05))
    ball = UsdGeom.Sphere(stage.GetPrimAtPath(f"/Face/Markers/Simulated/{m0}_tracked/{m0}_tracked"))
    assert tuple(ball.GetDisplayColorPrimvar().Get()[0]) == pytest.approx((0.05, 0.8, 0.1))
    capm = take["captured_markers_m"]
    hidden = 0
    for k, name in enumerate(face.marker_names):
        loc = stage.GetPrimAtPath(f"/Face/Markers/Captured/{name}")
        assert loc.GetAttribute("wface:markerName").Get() == name
        for f in range(F):
            vis = UsdGeom.Imageable(loc).ComputeVisibility(Usd.TimeCode(f))
            if np.all(np.isfinite(capm[f, k])):
                assert vis == UsdGeom.Tokens.inherited
                m = np.asarray(UsdGeom.Xformable(loc).GetLocalTransformation(Usd.TimeCode(f)))
                np.testing.assert_allclose(m[3, :3], capm[f, k], atol=1e-12)
            else:
                assert vis == UsdGeom.Tokens.invisible
                m = np.asarray(UsdGeom.Xformable(loc).GetLocalTransformation(Usd.TimeCode(f)))
                np.testing.assert_array_equal(m[:3, :3], 0.0)  # scaled away for DCCs that ignore visibility
                hidden += 1
    assert hidden > 0  # the take has missing markers, so the test saw the hidden branch
    assert list(sim.GetAttribute("wface:markerNames").Get()) == face.marker_names
    assert list(cap.GetAttribute("wface:markerNames").Get()) == face.marker_names

    # Bones: the jaw Xform sits under the cranium's (its affines are relative, as wface.controls);
    # the composed world transform of each bone moves its attached nodes where the take has them.
    cache = UsdGeom.XformCache()
    x = take["node_positions_m"]
    for bone, mesh_path in (("cranium", "/Face/Bones/Cranium/skull"), ("jaw", "/Face/Bones/Cranium/Jaw/mandible")):
        prim = stage.GetPrimAtPath(mesh_path)
        assert prim, mesh_path
        nodes = face.nodes_of_bone(bone)
        for f in (0, F // 2, F - 1):
            cache.SetTime(Usd.TimeCode(f))
            m = np.asarray(cache.GetLocalToWorldTransform(prim))
            np.testing.assert_allclose(face.rest_positions_m[nodes] @ m[:3, :3] + m[3, :3], x[f, nodes], atol=1e-12)

    # Muscles: one time-sampled float per muscle, plus the array.
    prim = stage.GetPrimAtPath("/Face/Muscles")
    assert list(prim.GetAttribute("wface:muscleNames").Get()) == face.muscle_names
    for m, name in enumerate(face.muscle_names):
        attr = prim.GetAttribute(f"wface:activation:{name}")
        assert attr.GetTimeSamples() == [float(f) for f in range(F)]
        got = [attr.Get(f) for f in range(F)]
        np.testing.assert_allclose(got, take["activations"][:, m], atol=1e-7)
    np.testing.assert_allclose(
        np.asarray(prim.GetAttribute("wface:activations").Get(3)), take["activations"][3], atol=1e-7
    )


def test_activation_heat_map_follows_activation(tmp_path, face, take):
    from pxr import Usd, UsdGeom

    act = np.zeros((2, face.n_muscles))
    act[1, 0] = 1.0  # only the first muscle, fully on, in frame 1
    x = np.repeat(face.rest_positions_m[None], 2, axis=0)
    path = usd.write_take(tmp_path / "heat.usda", model=face, node_positions_m=x, fps=24, activations=act)
    stage = Usd.Stage.Open(str(path))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Face/Skin")).GetPrimvar("wface:activation")
    a0, a1 = np.asarray(pv.Get(0)), np.asarray(pv.Get(1))
    assert np.all(a0 == 0.0) and a1.max() > 0.9 and a1.min() < 0.01  # far from the muscle: ~0
    assert usd.validate_stage(path) == [] and usd.check_extents(path) == []


@pytest.mark.parametrize("frame", [0, 3, 5])
def test_blendshape_query_reproduces_basis_synthesis(tmp_path, face, take, frame):
    path = _write(tmp_path, face, take, ".usda")
    got = usd.blendshape_points(path, "/Face/Basis/Mesh", frame)
    skin = np.unique(face.skin_triangles)
    want = take["basis"].synthesize(take["basis_weights"][frame])[skin]  # E0 + sum_i x_i e_i
    np.testing.assert_allclose(got, want, atol=_F32)
    if frame:
        assert np.abs(want - take["basis"].neutral_m[skin]).max() > 1e-4  # the weights really move it


def test_standalone_basis_blender_structure(tmp_path, face, take):
    from pxr import Usd, UsdSkel

    skin = np.unique(face.skin_triangles)
    remap = np.full(face.n_nodes, -1)
    remap[skin] = np.arange(skin.size)
    basis = take["basis"].restricted(skin)
    path = usd.write_blendshape_basis(
        tmp_path / "basis.usda",
        basis=basis,
        face_vertex_counts=None,
        face_vertex_indices=remap[face.skin_triangles],
        weights=take["basis_weights"],
        fps=30,
    )
    usd.assert_stage_valid(path)
    stage = Usd.Stage.Open(str(path))
    root = stage.GetDefaultPrim()
    assert root.IsA(UsdSkel.Root)
    mesh = stage.GetPrimAtPath("/Face/Mesh")
    binding = UsdSkel.BindingAPI(mesh)
    assert mesh.HasAPI(UsdSkel.BindingAPI)
    shapes = list(binding.GetBlendShapesAttr().Get())
    targets = binding.GetBlendShapeTargetsRel().GetTargets()
    assert len(shapes) == len(targets) == basis.n_shapes
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath(binding.GetSkeletonRel().GetTargets()[0]))
    anim_path = UsdSkel.BindingAPI(skel.GetPrim()).GetAnimationSourceRel().GetTargets()[0]
    anim = UsdSkel.Animation(stage.GetPrimAtPath(anim_path))
    assert list(anim.GetBlendShapesAttr().Get()) == shapes
    assert len(anim.GetBlendShapeWeightsAttr().GetTimeSamples()) == len(take["basis_weights"])
    for f in (2, 5):
        np.testing.assert_allclose(
            usd.blendshape_points(path, "/Face/Mesh", f), basis.synthesize(take["basis_weights"][f]), atol=_F32
        )


def test_take_minimal_inputs(tmp_path, face, take):
    path = usd.write_take(tmp_path / "min.usda", model=face, node_positions_m=take["node_positions_m"][:1], fps=60)
    usd.assert_stage_valid(path)


@pytest.mark.parametrize(
    "over, match",
    [
        (dict(node_positions_m=np.zeros((3, 5, 3))), "node_positions_m must have shape"),
        (dict(activations=np.zeros((8, 99))), "activations must have shape"),
        (dict(activations=np.zeros((7, 3))), "activations must have shape"),
        (dict(jaw_affines=np.zeros((8, 4, 4))), "jaw_affines must have shape"),
        (dict(simulated_markers_m=np.full((8, 16, 3), np.nan)), "simulated_markers_m contains NaN"),
        (dict(basis_weights=None), "basis given without basis_weights"),
        (dict(basis_weights=np.zeros((8, 2))), "basis_weights must have shape"),
        (dict(fps=0.0), "fps must be a positive"),
        (dict(captured_markers_m=np.zeros((8, 5, 3))), "differ in count"),
    ],
)
def test_take_errors_name_the_problem(tmp_path, face, take, over, match):
    with pytest.raises(usd.UsdWriteError, match=match):
        _write(tmp_path, face, take, **over)


def test_node_positions_nan_is_refused(tmp_path, face, take):
    x = take["node_positions_m"].copy()
    x[2, 5, 1] = np.nan
    with pytest.raises(usd.UsdWriteError, match="node_positions_m contains NaN.*index \\(2, 5, 1\\)"):
        _write(tmp_path, face, take, node_positions_m=x)


# ---------------------------------------------------------------- the checks themselves can fail
def test_check_extents_catches_a_stale_extent(tmp_path):
    from pxr import Usd, UsdGeom

    path = usd.write_mesh_animation(
        tmp_path / "m.usda",
        points_m=np.random.default_rng(1).random((3, 6, 3)),
        face_vertex_counts=None,
        face_vertex_indices=[[0, 1, 2], [3, 4, 5]],
    )
    stage = Usd.Stage.Open(str(path))
    UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Mesh")).GetExtentAttr().Set([(0, 0, 0), (0.1, 0.1, 0.1)], 1.0)
    problems = usd.check_extents(stage)
    assert len(problems) == 1 and "/Face/Mesh at time 1" in problems[0]
    with pytest.raises(usd.UsdValidationFailed, match="outside the extent"):
        usd.assert_stage_valid(stage)


def test_usd_validators_run_and_report(tmp_path):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(tmp_path / "bad.usda"))  # no metersPerUnit / upAxis / defaultPrim
    mesh = UsdGeom.Mesh.Define(stage, "/M")
    mesh.GetPrim().CreateRelationship("skel:skeleton").SetTargets(["/Skel"])  # skel property without the API
    problems = usd.validate_stage(stage)
    text = "\n".join(problems)
    assert "StageMetadataChecker" in text
    assert "SkelBindingApiAppliedValidator" in text


def test_z_up_rotates_the_root(tmp_path, face, take):
    from pxr import Usd, UsdGeom

    x = take["node_positions_m"][:2]
    path = usd.write_take(tmp_path / "z.usda", model=face, node_positions_m=x, fps=24, up_axis="Z")
    usd.assert_stage_valid(path)
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    skin = stage.GetPrimAtPath("/Face/Skin")
    m = np.asarray(UsdGeom.Xformable(skin).ComputeLocalToWorldTransform(Usd.TimeCode(1)))
    local = np.asarray(UsdGeom.Mesh(skin).GetPointsAttr().Get(1), dtype=np.float64)
    world = local @ m[:3, :3] + m[3, :3]
    want = np.stack([local[:, 0], -local[:, 2], local[:, 1]], axis=1)  # +y up -> +z up, front +z -> -y
    np.testing.assert_allclose(world, want, atol=1e-12)


def test_check_extents_catches_a_small_extents_hint(tmp_path, face, take):
    from pxr import Usd, UsdGeom, Vt

    path = _write(tmp_path, face, take, ".usda")
    stage = Usd.Stage.Open(str(path))
    basis = UsdGeom.ModelAPI(stage.GetPrimAtPath("/Face/Basis"))
    neutral = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Basis/Mesh")).GetPointsAttr().Get())
    box = np.stack([neutral.min(0), neutral.max(0)]).astype(np.float32)
    basis.SetExtentsHint(Vt.Vec3fArray.FromNumpy(box))  # the neutral only: too small for the animation
    problems = usd.check_extents(stage)
    assert problems and all("extentsHint" in p for p in problems)


def test_without_vertex_colors_the_skin_colour_is_constant(tmp_path, face, take):
    from pxr import Usd, UsdGeom

    path = _write(tmp_path, face, take, ".usda", vertex_colors=False)
    stage = Usd.Stage.Open(str(path))
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin"))
    assert skin.GetDisplayColorPrimvar().GetInterpolation() == "constant"
    assert skin.GetDisplayColorPrimvar().GetAttr().GetTimeSamples() == []
    assert len(UsdGeom.PrimvarsAPI(skin).GetPrimvar("wface:activation").GetAttr().GetTimeSamples()) == 8


def test_muscle_names_become_unique_identifiers(tmp_path, face, take):
    from dataclasses import replace

    from pxr import Usd

    odd = replace(face, muscle_names=["levator-sup (L)", "levator_sup__L_", "3rd muscle"])
    path = usd.write_take(
        tmp_path / "odd.usda",
        model=odd,
        node_positions_m=take["node_positions_m"],
        fps=30,
        activations=take["activations"],
    )
    usd.assert_stage_valid(path)
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/Face/Muscles")
    attrs = sorted(a.GetName() for a in prim.GetAttributes() if a.GetName().startswith("wface:activation:"))
    assert attrs == [
        "wface:activation:_3rd_muscle",
        "wface:activation:levator_sup__L_",
        "wface:activation:levator_sup__L__1",
    ]
    assert list(prim.GetAttribute("wface:muscleNames").Get()) == odd.muscle_names


def test_basis_objects_with_their_own_topology(tmp_path, face, take):
    """Duck typing: e.g. wface.basis.ActuationBasis (neutral_m, shapes_m, names, face_counts, face_indices)."""
    from types import SimpleNamespace

    skin = np.unique(face.skin_triangles)
    remap = np.full(face.n_nodes, -1)
    remap[skin] = np.arange(skin.size)
    b = take["basis"].restricted(skin)
    other = SimpleNamespace(
        neutral_m=b.neutral_m,
        shapes_m=b.deltas_m,
        names=b.names,
        face_counts=np.full(len(face.skin_triangles), 3),
        face_indices=remap[face.skin_triangles].ravel(),
    )
    path = usd.write_blendshape_basis(tmp_path / "b.usdc", basis=other, weights=take["basis_weights"], fps=30)
    usd.assert_stage_valid(path)
    np.testing.assert_allclose(
        usd.blendshape_points(path, "/Face/Mesh", 3), b.synthesize(take["basis_weights"][3]), atol=_F32
    )
    with pytest.raises(usd.UsdWriteError, match="needs neutral_m"):
        usd.write_blendshape_basis(
            tmp_path / "c.usdc",
            basis=SimpleNamespace(names=[]),
            face_vertex_counts=None,
            face_vertex_indices=[[0, 1, 2]],
        )


def test_wface_basis_actuation_basis_is_written_as_blend_shapes(tmp_path, face, take):
    core = pytest.importorskip("wface.basis.core")
    skin = np.unique(face.skin_triangles)
    remap = np.full(face.n_nodes, -1)
    remap[skin] = np.arange(skin.size)
    b = take["basis"].restricted(skin)
    ab = core.ActuationBasis(
        b.neutral_m, b.deltas_m, b.names, np.full(len(face.skin_triangles), 3), remap[face.skin_triangles].ravel()
    )
    path = usd.write_blendshape_basis(tmp_path / "ab.usda", basis=ab, weights=take["basis_weights"], fps=30)
    usd.assert_stage_valid(path)
    w = take["basis_weights"][4]
    np.testing.assert_allclose(
        usd.blendshape_points(path, "/Face/Mesh", 4), ab.neutral_m + np.tensordot(w, ab.shapes_m, 1), atol=_F32
    )


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_read_take_round_trip(tmp_path, face, take, suffix):
    path = _write(tmp_path, face, take, suffix)
    got = usd.read_take(path)
    F = take["node_positions_m"].shape[0]
    assert got["fps"] == take["fps"] and got["n_frames"] == F
    ids = got["skin_node_ids"]
    np.testing.assert_array_equal(ids[got["skin_triangles"]], face.skin_triangles)
    np.testing.assert_allclose(got["skin_points_m"], take["node_positions_m"][:, ids], atol=_F32)
    np.testing.assert_allclose(got["activations"], take["activations"], atol=1e-7)
    assert got["muscle_names"] == face.muscle_names and got["marker_names"] == face.marker_names
    cap = take["captured_markers_m"]
    np.testing.assert_array_equal(np.isnan(got["captured_markers_m"]), np.isnan(cap))
    np.testing.assert_allclose(got["captured_markers_m"], cap, atol=_F32)
    np.testing.assert_allclose(got["simulated_markers_m"], take["simulated_markers_m"], atol=_F32)
    np.testing.assert_allclose(got["cranium_affines"], take["cranium_affines"], atol=1e-12)
    np.testing.assert_allclose(got["jaw_affines"], take["jaw_affines"], atol=1e-12)
    np.testing.assert_allclose(got["basis_weights"], take["basis_weights"], atol=1e-7)
    assert got["basis_names"] == take["basis"].names
    assert got["vertex_activation"].shape == (F, ids.size)
    assert got["jaw_frame"] == "cranium"


def test_jaw_in_world_frame_is_a_sibling(tmp_path, face, take):
    from pxr import Usd, UsdGeom

    c, j = take["cranium_affines"], take["jaw_affines"]
    world = np.concatenate([c[:, :, :3] @ j[:, :, :3], (c[:, :, :3] @ j[:, :, 3:] + c[:, :, 3:])], axis=2)
    path = _write(tmp_path, face, take, ".usda", jaw_affines=world, jaw_frame="world")
    usd.assert_stage_valid(path)
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/Face/Bones/Jaw/mandible")
    assert prim and not stage.GetPrimAtPath("/Face/Bones/Cranium/Jaw")
    nodes = face.nodes_of_bone("jaw")
    m = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(4)))
    np.testing.assert_allclose(
        face.rest_positions_m[nodes] @ m[:3, :3] + m[3, :3], take["node_positions_m"][4, nodes], atol=1e-12
    )
    got = usd.read_take(path)
    assert got["jaw_frame"] == "world"
    np.testing.assert_allclose(got["jaw_affines"], world, atol=1e-12)
    with pytest.raises(usd.UsdWriteError, match="jaw_frame"):
        _write(tmp_path, face, take, ".usda", jaw_frame="skull")


def test_the_colours_reach_a_renderer_through_a_material(tmp_path, face, take):
    """The skin's heat map and the bones' white are read by a bound preview material (a DCC renderer
    ignores a bare displayColor: Blender rendered the skin grey); the material reads each prim's own
    displayColor (Blender: an Attribute node into Base Color)."""
    from pxr import Usd, UsdShade

    path = _write(tmp_path, face, take, ".usda")
    stage = Usd.Stage.Open(str(path))
    skin = stage.GetPrimAtPath("/Face/Skin")
    material, _ = UsdShade.MaterialBindingAPI(skin).ComputeBoundMaterial()
    assert material and material.GetPath() == "/Face/Looks/DisplayColor"
    surface = material.ComputeSurfaceSource()[0]
    source = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    reader = UsdShade.Shader(source.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3"
    assert reader.GetInput("varname").Get() == "displayColor"
    bones = [p for p in Usd.PrimRange(stage.GetPrimAtPath("/Face/Bones")) if p.GetTypeName() == "Mesh"]
    assert bones and all(UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()[0] for p in bones)
    assert usd.validate_stage(path) == []
