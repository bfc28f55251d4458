"""Each command's USD inside a real DCC: Blender (the PyPI ``bpy`` module) imports it headless.

Optional group: it runs when a Python with ``bpy`` is found (``$WFACE_BLENDER_PYTHON``, else
``.venv-blender/bin/python`` in the repository, else this interpreter if it imports ``bpy``) and
skips with the reason otherwise. ``bpy`` pins its own numpy (1.26 for bpy 5.0), so it lives in a
virtual environment of its own::

    python3 -m venv .venv-blender && .venv-blender/bin/pip install bpy   # ~370 MB download, 1 GB installed

What Blender must show (issue 16): every Mesh prim that moves in the stage deforms or moves between
the first and the last frame (the exact point cache, the UsdSkel rig, bones, a render mesh when a
stage has one), the rig's shape-key values follow the activation curves, bones and teeth face
outward (positive signed volume with Blender's normals), the scene's frame range is the capture's
frame numbers, and markers are named objects, scaled to 0 while missing.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT

pytest.importorskip("pxr")

from wface.cli import main  # noqa: E402
from wface.io.mocap import MocapTake, write_mocap  # noqa: E402
from wface.takes.usd import ACTIVE_WEIGHT  # noqa: E402

_PROBE = Path(__file__).with_name("blender_probe.py")
_KEY_TOL = 1e-5  # shape-key values: float32 keyframes of weights in [0, 1]
_MOVED_M = 1e-6  # "moves": more than a micrometre between the first and the last frame


def _blender_python() -> str | None:
    candidates = [os.environ.get("WFACE_BLENDER_PYTHON"), str(REPO_ROOT / ".venv-blender" / "bin" / "python")]
    if importlib.util.find_spec("bpy") is not None:
        candidates.append(sys.executable)
    for c in candidates:
        if c and Path(c).exists():
            ok = subprocess.run([c, "-c", "import bpy"], capture_output=True, timeout=120).returncode == 0
            if ok:
                return c
    return None


@pytest.fixture(scope="module")
def blender():
    py = _blender_python()
    if py is None:
        pytest.skip(
            "no Python with bpy (Blender as a module): python3 -m venv .venv-blender && "
            ".venv-blender/bin/pip install bpy, or set WFACE_BLENDER_PYTHON"
        )
    return py


@pytest.fixture(scope="module")
def stages(tmp_path_factory, blender):
    """animation.usdc of demo (with a render mesh: a patch of the skin in centimetres), track
    (--frames 2:4), edit, resim and waters, on a 1,500-tet face."""
    from wface.faces.builtin import build_face

    root = tmp_path_factory.mktemp("dcc")
    small = ["--tets", "1500"]
    face = build_face(1500)
    tris = face.skin_triangles[:200]
    used, local = np.unique(tris, return_inverse=True)
    lines = [f"v {a:.9f} {b:.9f} {c:.9f}" for a, b, c in face.rest_positions_m[used] * 100.0]
    faces = [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in local.reshape(-1, 3)]
    lines += ["usemtl Lip", *faces[:100], "usemtl Cheek", *faces[100:]]  # two material groups
    (root / "patch.obj").write_text("\n".join(lines) + "\n")
    render = ["--render-mesh", str(root / "patch.obj"), "--render-mesh-units", "cm"]
    assert main(["demo", "--out", str(root / "demo"), *small, "--frames", "4", "--no-pictures", *render]) == 0
    truth = np.load(root / "demo" / "truth.npz")
    names = face.marker_names
    captured = truth["markers_m"].copy()
    captured[0] = truth["clean_markers_m"][0]  # a complete neutral frame: `track` fails on a gap there (pre-existing)
    write_mocap(MocapTake(captured, list(names), 30.0), root / "take.trc")
    track = ["track", "--mocap", str(root / "take.trc"), "--out", str(root / "track"), "--frames", "2:4"]
    track += ["--neutral-frame", "0"]  # the take starts neutral; frame 2 does not
    assert main([*track, *small, "--no-pictures"]) == 0
    edit = ["edit", "exaggerate", "--take", str(root / "track"), "--factor", "1.5", "--out", str(root / "edit")]
    assert main([*edit, *small, "--no-pictures"]) == 0
    # the cheeks sucked in (AU35: the intra-oral pressure at -0.8, a signed channel): the rig's suction shape
    suck = ["edit", "layer", "--take", str(root / "track"), "--add", "AU35=1", "--weight", "0.8"]
    assert main([*suck, "--out", str(root / "suck"), *small, "--no-pictures"]) == 0
    assert main(["resim", "--take", str(root / "track"), "--out", str(root / "resim"), *small, "--substeps", "2"]) == 0
    waters = ["waters", "--mesh", "builtin", "--expression", "happy", "--blend-to", "surprise", "--frames", "3"]
    assert main([*waters, *small, "--no-render", "--out", str(root / "waters")]) == 0
    paths = {k: root / k / "animation.usdc" for k in ("demo", "track", "edit", "resim", "suck")}
    paths["waters"] = root / "waters" / "happy_to_surprise.usda"  # text, as the pose's own (--usdc: binary)
    run = subprocess.run([blender, str(_PROBE), *map(str, paths.values())], capture_output=True, text=True, timeout=600)
    probes = [json.loads(ln[6:]) for ln in run.stdout.splitlines() if ln.startswith("PROBE ")]
    assert len(probes) == len(paths), run.stdout[-2000:] + run.stderr[-2000:]
    return {k: (p, probe) for (k, p), probe in zip(paths.items(), probes, strict=True)}


def _usd_facts(path: Path) -> dict:
    """What the stage itself says: time codes, rig weights per time code, which Mesh prims move, NaN markers."""
    from pxr import Usd, UsdGeom, UsdSkel

    from wface.io.usd import read_take

    stage = Usd.Stage.Open(str(path))
    t0, t1 = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    xf0, xf1 = UsdGeom.XformCache(t0), UsdGeom.XformCache(t1)
    moving = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        if prim.HasAPI(UsdSkel.BindingAPI):
            moving[prim.GetName()] = True
            continue
        pts = UsdGeom.Mesh(prim).GetPointsAttr()
        p0 = np.asarray(pts.Get(t0)) @ np.asarray(xf0.GetLocalToWorldTransform(prim))[:3, :3]
        p1 = np.asarray(pts.Get(t1)) @ np.asarray(xf1.GetLocalToWorldTransform(prim))[:3, :3]
        p0 = p0 + np.asarray(xf0.GetLocalToWorldTransform(prim))[3, :3]
        p1 = p1 + np.asarray(xf1.GetLocalToWorldTransform(prim))[3, :3]
        moving[prim.GetName()] = bool(np.abs(p1 - p0).max() > _MOVED_M)
    facts = {"t0": t0, "t1": t1, "fps": stage.GetTimeCodesPerSecond(), "moving": moving}
    anim = stage.GetPrimAtPath("/Face/Rig/Skel/Anim")
    if anim:
        a = UsdSkel.Animation(anim)
        names = list(a.GetBlendShapesAttr().Get())
        w = a.GetBlendShapeWeightsAttr()
        facts["weights"] = {t: dict(zip(names, w.Get(t), strict=True)) for t in w.GetTimeSamples()}
        take = read_take(path)
        facts["activations"], facts["muscles"] = take["activations"], take["muscle_names"]
        facts["captured"] = take.get("captured_markers_m")
        facts["marker_names"] = take.get("marker_names")
    return facts


@pytest.mark.parametrize("command", ["demo", "track", "edit", "resim", "waters", "suck"])
def test_every_mesh_deforms_and_the_scene_range_is_the_capture(stages, command):
    path, probe = stages[command]
    facts = _usd_facts(path)
    assert (probe["frame_start"], probe["frame_end"]) == (facts["t0"], facts["t1"])
    objects = probe["objects"]
    for name, moves in facts["moving"].items():
        assert name in objects, f"{command}: Mesh prim {name} missing in Blender ({sorted(objects)})"
        if moves:
            assert objects[name]["moved_m"] > _MOVED_M, f"{command}: {name} does not move in Blender"
    assert any(facts["moving"].values())


def test_track_keeps_the_capture_frame_numbers(stages):
    path, probe = stages["track"]
    assert (probe["frame_start"], probe["frame_end"]) == (2, 3)  # --frames 2:4
    csv_frames = np.loadtxt(path.parent / "controls.csv", delimiter=",", skiprows=1, usecols=0)
    np.testing.assert_array_equal(csv_frames, [2, 3])
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    assert stage.GetRootLayer().customLayerData["wface"]["first_frame"] == 2
    assert stage.GetTimeCodesPerSecond() == 30.0


def _shape_curves(muscles: list[str], activations: np.ndarray) -> tuple[list[str], np.ndarray]:
    """(shape names, (T, B) weights) the rig drives: a muscle's activation; a signed actuator's
    positive part and its suction part (``wface.takes.shapes.shape_weights``), each with its own key."""
    from wface.facs import ACTUATORS
    from wface.takes.shapes import SUCTION_SUFFIX

    names, cols = [], []
    for m, name in enumerate(muscles):
        names.append(name)
        cols.append(np.maximum(activations[:, m], 0.0))
        if name in ACTUATORS:
            names.append(name + SUCTION_SUFFIX)
            cols.append(np.maximum(-activations[:, m], 0.0))
    return names, np.stack(cols, axis=1)


@pytest.mark.parametrize("command", ["demo", "track", "edit", "resim", "suck"])
def test_shape_keys_follow_the_activation_curves(stages, command):
    path, probe = stages[command]
    facts = _usd_facts(path)
    rig = probe["objects"]["SkinRig"]
    assert rig["shape_keys"], f"{command}: no shape keys on the rig"
    frames = range(probe["frame_start"], probe["frame_end"] + 1)
    shapes, curves = _shape_curves(facts["muscles"], np.minimum(facts["activations"], 1.0))
    used = [n for b, n in enumerate(shapes) if curves[:, b].max() > ACTIVE_WEIGHT]
    assert set(rig["shape_keys"][0]) == {*used, "jaw_open"}  # a key per muscle the take uses, plus the jaw
    for i, (f, keys) in enumerate(zip(frames, rig["shape_keys"], strict=True)):
        for name in used:
            assert keys[name] == pytest.approx(curves[i, shapes.index(name)], abs=_KEY_TOL), (command, f, name)
        assert keys["jaw_open"] == pytest.approx(facts["weights"][float(f)]["jaw_open"], abs=_KEY_TOL)
    if command == "suck":
        assert "intraoral_pressure_suction" in used  # the suction shape, driven by -a >= 0
    values = np.array([[k[n] for n in used] for k in rig["shape_keys"]])
    assert np.ptp(values, axis=0).max() > 1e-3, f"{command}: the curves do not vary, so the test shows nothing"
    if command == "track":  # the tracked curves themselves
        act = np.load(path.parent / "controls.npz")["activations"]
        tracked_shapes, tracked = _shape_curves(facts["muscles"], np.minimum(act, 1.0))
        cols = [tracked_shapes.index(n) for n in used]
        np.testing.assert_allclose(values, tracked[:, cols], atol=_KEY_TOL)


def test_the_render_mesh_in_the_rig_animates_in_blender(stages):
    """The render mesh joins the rig (``/Face/Rig/RenderMesh``, centimetres placed by its
    geomBindTransform): in Blender its shape keys are the skin rig's, driven by the same curves, and
    its vertices are where UsdSkel's own skinning puts them (Blender turns Y-up into Z-up)."""
    from pxr import Usd, UsdSkel, Vt

    from wface.io.usd import blendshape_points

    path, probe = stages["demo"]
    rig, mesh = probe["objects"]["SkinRig"], probe["objects"]["RenderMesh"]
    assert mesh["parent"] == "Rig" and mesh["moved_m"] > _MOVED_M
    cached = probe["objects"]["RenderMeshCache"]  # the point cache beside it, under a name a TD can read
    assert cached["parent"] == "Face" and cached["vertices"] == mesh["vertices"] and cached["moved_m"] > _MOVED_M
    assert sorted(mesh["materials"]) == sorted(cached["materials"]) == ["Cheek", "Lip"]  # one look on both
    assert mesh["shape_keys"] and len(mesh["shape_keys"]) == len(rig["shape_keys"])
    for keys, skin_keys in zip(mesh["shape_keys"], rig["shape_keys"], strict=True):
        assert keys == pytest.approx(skin_keys, abs=_KEY_TOL)
    assert np.ptp([list(k.values()) for k in mesh["shape_keys"]], axis=0).max() > 1e-3  # the keys animate
    stage = Usd.Stage.Open(str(path))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Face/Rig")), Usd.PrimDefaultPredicate)
    prim = stage.GetPrimAtPath("/Face/Rig/RenderMesh")
    skel_query = cache.GetSkelQuery(UsdSkel.BindingAPI(prim).GetInheritedSkeleton())
    for f, got in ((probe["frame_start"], mesh["first_vertices"]), (probe["frame_end"], mesh["last_vertices"])):
        pts = Vt.Vec3fArray.FromNumpy(blendshape_points(stage, str(prim.GetPath()), float(f)).astype(np.float32))
        code = Usd.TimeCode(float(f))
        assert cache.GetSkinningQuery(prim).ComputeSkinnedPoints(skel_query.ComputeSkinningTransforms(code), pts, code)
        q = np.asarray(pts, dtype=np.float64)
        np.testing.assert_allclose(np.asarray(got), np.stack([q[:, 0], -q[:, 2], q[:, 1]], axis=1), atol=1e-6)


def test_bones_face_outward(stages):
    _, probe = stages["demo"]
    bones = {n: o for n, o in probe["objects"].items() if o["type"] == "MESH" and o["parent"] in ("Cranium", "Jaw")}
    assert {"cranium", "jaw", "upper_teeth", "lower_teeth"} <= set(bones)
    for name, o in bones.items():
        assert o["signed_volume_m3"] > 0, f"{name} is wound inward"


def test_markers_are_named_locators_hidden_while_missing(stages):
    path, probe = stages["demo"]
    facts = _usd_facts(path)
    cap = facts["captured"]
    hidden = 0
    for k, name in enumerate(facts["marker_names"]):
        o = probe["objects"][name]
        assert o["parent"] == "Captured" and probe["objects"][f"{name}_tracked"]["parent"] == "Simulated"
        # a mesh ball with the display-colour material: Blender drops a Sphere prim's binding (grey markers)
        assert o["materials"] == probe["objects"][f"{name}_tracked"]["materials"] == ["DisplayColor"]
        missing = ~np.all(np.isfinite(cap[:, k]), axis=1)
        np.testing.assert_array_equal(np.array(o["scale"]) == 0.0, missing)
        hidden += int(missing.sum())
    assert hidden > 0  # the demo drops samples, so the hidden branch was seen


def test_waters_on_the_ict_head_keeps_uvs_and_materials_in_blender(blender, tmp_path):
    from conftest import data_path

    obj = data_path("ict-facekit", "generic_neutral_mesh.obj")
    args = ["waters", "--mesh", str(obj), "--expression", "happy", "--blend-to", "surprise", "--frames", "2"]
    assert main([*args, "--no-render", "--out", str(tmp_path)]) == 0
    paths = [tmp_path / "happy.usda", tmp_path / "happy_to_surprise.usda"]
    run = subprocess.run([blender, str(_PROBE), *map(str, paths)], capture_output=True, text=True, timeout=600)
    probes = [json.loads(ln[6:]) for ln in run.stdout.splitlines() if ln.startswith("PROBE ")]
    assert len(probes) == 2, run.stderr[-2000:]
    for probe in probes:
        mesh = probe["objects"]["Mesh"]
        assert (mesh["vertices"], mesh["uv_layers"], len(mesh["materials"])) == (26719, 1, 12)
        assert "M_Face" in mesh["materials"]
    assert probes[1]["objects"]["Mesh"]["moved_m"] > 1e-3  # happy -> surprise moves the mouth by millimetres


def test_speech_on_the_badin_face_plays_in_blender(blender, badin_model_path, tmp_path):
    """`wface speech`'s stage (two frames of the closure gesture on the 45,496-tet Badin face, with its
    rig: one solve per muscle the gesture drives) imports into Blender: the skin's point cache and
    the rig deform, the shape keys follow the excitation curves, the range is the stage's."""
    out = tmp_path / "speech"
    args = ["speech", "--model", str(badin_model_path), "--gesture", "closure", "--max-frames", "2"]
    assert main([*args, "--out", str(out)]) == 0
    path = out / "animation.usdc"
    run = subprocess.run([blender, str(_PROBE), str(path)], capture_output=True, text=True, timeout=600)
    probes = [json.loads(ln[6:]) for ln in run.stdout.splitlines() if ln.startswith("PROBE ")]
    assert len(probes) == 1, run.stdout[-2000:] + run.stderr[-2000:]
    probe, facts = probes[0], _usd_facts(path)
    assert (probe["frame_start"], probe["frame_end"]) == (facts["t0"], facts["t1"])
    for name, moves in facts["moving"].items():
        assert name in probe["objects"], f"speech: Mesh prim {name} missing in Blender"
        if moves:
            assert probe["objects"][name]["moved_m"] > _MOVED_M, f"speech: {name} does not move in Blender"
    assert facts["moving"].get("Skin") and "weights" in facts
    rig = probe["objects"]["SkinRig"]
    used = [n for m, n in enumerate(facts["muscles"]) if facts["activations"][:, m].max() > ACTIVE_WEIGHT]
    assert used and set(used) <= set(rig["shape_keys"][0])
    for i, keys in enumerate(rig["shape_keys"]):
        for name in used:
            m = facts["muscles"].index(name)
            assert keys[name] == pytest.approx(min(facts["activations"][i, m], 1.0), abs=_KEY_TOL), (i, name)
