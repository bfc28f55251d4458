"""A whole take of a FaceModel: skin, markers, bones, muscle activations, a muscle rig, an optional basis.

Display colours (``primvars:displayColor``, linear RGB), the same as the pictures of ``wface.viz``
(Sifakis et al. 2005's convention): the skin is skin-coloured with a heat map over the muscles under
it (red tint over an inactive muscle, yellow over a fully active one, ``wface.viz.muscles``); the
captured markers are red, the simulated / tracked markers green; bones and teeth are bone white. A
preview material reading each prim's ``displayColor`` is bound to them (``wface.io.usd.looks``), so a
DCC's renderer shows the colours too, not only its viewport.

Prims under the default prim ``/<name>`` (an Xform) of ``write_take``:

- ``Skin`` (Mesh): the exact point cache. The nodes used by ``model.skin_triangles``,
  renumbered compactly (their model node ids in the primvar ``wface:nodeId``); topology once,
  points, extent and vertex normals per frame, ``primvars:st`` texture coordinates
  (``wface.mesh.uv.skin_uv``: the skin flattened onto the unit square by a mean-value Tutte
  map, no triangle turned over, +y up). With ``activations``: ``primvars:wface:activation`` (float per vertex per
  frame, max_m w_m a_m over nearby muscles) and a ``displayColor`` heat map (above).
  Without: a constant skin colour.
- ``Markers/Captured`` and ``Markers/Simulated``: one named locator per marker (Xform with a
  time-sampled translate op, hidden in the frames where the marker is missing, and a small
  sphere; red and green), ``wface.io.usd.locators``; the tracked ones named ``<marker>_tracked``.
- ``Bones/Cranium`` and ``Bones/Cranium/Jaw`` (Xforms with one time-sampled transform op
  from the per-frame affines; the jaw's op is relative to the cranium, as the 24 bone
  parameters of ``wface.controls``) holding the model's ``bone_meshes`` at rest position, each
  rewound so that its normals face outward (``wface.mesh.signed_distance.oriented_outward``).
  With ``jaw_frame="world"`` the jaw Xform is ``Bones/Jaw``, a sibling of the cranium.
- ``Muscles`` (Scope): per muscle a time-sampled float ``wface:activation:<muscle>`` (the name
  made a valid identifier; the original names in ``wface:muscleNames``), and all of them as
  a float[] ``wface:activations``.
- ``Rig`` (SkelRoot) when ``rig`` is given: the skin (``SkinRig``) bound to the rig's blend shapes
  and to the cranium and jaw joints, weights from ``rig_weights`` / ``activations`` (``wface.io.usd.rig``); the layer
  metadata then holds ``rig_rms_error_mm`` / ``rig_max_error_mm`` against the point cache.
- ``Basis`` (SkelRoot) when ``basis`` is given: see ``write_blendshape_basis``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.files import save_layer
from wface.io.usd._common import (
    UsdWriteError,
    _as_points,
    _check_finite,
    _check_frames,
    _check_path,
    _identifier,
    _new_stage,
    _set_display_color,
    _set_layer_info,
    _time_codes,
    _vt_float,
    _vt_int,
    _write_float_primvar,
    _write_mesh,
    affine_to_matrix4d,
    as_polygons,
)
from wface.io.usd.locators import write_locators
from wface.io.usd.looks import bind_display_colors
from wface.io.usd.rig import SkinRig, write_skin_rig
from wface.io.usd.skel import BlendShapeBasis, _write_blendshapes
from wface.mesh.signed_distance import oriented_outward
from wface.mesh.surface import vertex_normals
from wface.mesh.uv import skin_uv
from wface.viz.muscles import SKIN_RGB, activation_colors, skin_muscle_influence

CAPTURED_RGB = (0.9, 0.05, 0.05)
SIMULATED_RGB = (0.05, 0.8, 0.1)
BONE_RGB = (0.93, 0.91, 0.84)

__all__ = ["BONE_RGB", "CAPTURED_RGB", "SIMULATED_RGB", "write_take"]


def write_take(
    path: str | Path,
    *,
    model,
    node_positions_m: np.ndarray,
    fps: float,
    captured_markers_m: np.ndarray | None = None,
    simulated_markers_m: np.ndarray | None = None,
    marker_names: list[str] | None = None,
    cranium_affines: np.ndarray | None = None,
    jaw_affines: np.ndarray | None = None,
    jaw_frame: str = "cranium",
    activations: np.ndarray | None = None,
    basis=None,
    basis_weights: np.ndarray | None = None,
    marker_radius_m: float = 0.002,
    muscle_radius_m: float | None = None,
    vertex_colors: bool = True,
    bone_meshes: dict | None = None,
    name: str = "Face",
    up_axis: str = "Y",
    metadata: dict | None = None,
    frames: np.ndarray | None = None,
    rig: SkinRig | None = None,
    rig_weights: np.ndarray | None = None,
    rig_meshes: dict | None = None,
    edit=None,
) -> Path:
    """Write a tracked or simulated take of a ``FaceModel`` as one USD stage.

    Frame i is written at time code ``frames[i]`` (the capture's frame numbers; default i); the
    stage's timeCodesPerSecond is ``fps``, its start/end time codes the first and last frame, and
    customLayerData["wface"]["first_frame"] the first. The prims are listed in the module docstring.

    Args:
        path: ``.usdc`` (binary, default) or ``.usda`` (text).
        model: the ``FaceModel``.
        node_positions_m: (F, n, 3) node positions per frame (n = model.n_nodes), world metres.
        fps: capture rate in frames per second.
        captured_markers_m: (F, k, 3) captured markers in the model's frame; NaN = missing.
        simulated_markers_m: (F, k, 3) markers on the simulated / tracked skin.
        marker_names: k names; default ``model.marker_names`` when it has k entries, else m<i>.
        cranium_affines: (F, 3, 4) per-frame rest-to-world affine [A | t] of the cranium
            (x_world = A x_rest + t).
        jaw_affines: (F, 3, 4) per-frame jaw affine [M | t]; by default in the cranium's frame
            (``wface.controls``: jaw nodes at Mc (Mm X + tm) + tc, b[12:24] -> Mm, tm).
        jaw_frame: "cranium" (default; ``jaw_affines`` relative to the cranium) or "world"
            (``jaw_affines`` map rest to world directly).
        activations: (F, M) muscle activations (M = model.n_muscles), usually in [0, 1].
        basis: an actuation basis (``BlendShapeBasis`` or e.g. ``wface.basis.ActuationBasis``) on
            the model's nodes (n) or on the compact skin vertices.
        basis_weights: (F, B) weights of ``basis`` per frame (required with ``basis``).
        marker_radius_m: marker sphere radius (widths = 2 r).
        muscle_radius_m: falloff radius of the muscle heat map (default: the median tet edge).
        vertex_colors: write the per-frame ``displayColor`` heat map (12 bytes per vertex per
            frame; False keeps a constant skin colour and only the 4-byte activation primvar).
        bone_meshes: {name: BoneMesh} to draw under the bones instead of ``model.bone_meshes``
            (``{}``: none, e.g. to keep a file small).
        name: root prim name.
        up_axis: "Y" (the model's convention) or "Z" (a rotateX(90) on the root prim).
        metadata: small JSON-able dict stored in the layer's customLayerData under "wface".
        frames: (F,) strictly increasing frame numbers, the time codes (default 0..F-1).
        rig: blend shapes and jaw weights on the skin vertices.
        rig_weights: (F, B) weights of the rig's B shapes per frame; default ``activations`` (when
            the rig holds one shape per muscle).
        rig_meshes: {prim name: (SkinRig, counts, indices)}: more meshes under ``Rig`` driven by the
            same joints and weights (a render mesh: ``rig.carried(binding_weights, rest)``).
        edit: callable(stage) run on the stage before its one save (additions such as a reference to
            a render-mesh layer or more time-sampled attributes).

    Returns:
        The path written.

    Raises:
        UsdWriteError: a shape, frame count or value is wrong; the message names it.
    """
    path = _check_path(path)
    x = _checked_positions(model, node_positions_m)
    n_frames = x.shape[0]
    skin_nodes, counts, indices = _skin_polygons(model)
    act = None if activations is None else _check_frames("activations", activations, n_frames, (model.n_muscles,))
    markers = _checked_markers(captured_markers_m, simulated_markers_m, n_frames)
    affines = _checked_affines(cranium_affines, jaw_affines, n_frames)
    basis, bw = _checked_basis(basis, basis_weights, model, skin_nodes, n_frames)
    if jaw_frame not in ("cranium", "world"):
        raise UsdWriteError(f"jaw_frame must be 'cranium' or 'world', got {jaw_frame!r}")
    if not (np.isfinite(marker_radius_m) and marker_radius_m > 0):
        raise UsdWriteError(f"marker_radius_m must be positive, got {marker_radius_m}")
    times = _time_codes(frames, n_frames)
    rw = _checked_rig_weights(rig, rig_weights, act, skin_nodes.size, n_frames)

    stage = _new_stage(path, fps=fps, n_frames=n_frames, up_axis=up_axis, root=name, time_codes=times)
    root = f"/{name}"
    info = {"kind": "take", "frames": int(n_frames), "nodes": int(model.n_nodes), "muscles": int(model.n_muscles)}
    info.update(metadata or {})
    _set_layer_info(stage, info)

    skin_x = x[:, skin_nodes]
    tri = indices.reshape(-1, 3)
    normals = np.stack([vertex_normals(p, tri) for p in skin_x])
    skin = _write_mesh(stage, f"{root}/Skin", skin_x, counts, indices, times=times, normals=normals)
    _write_skin_primvars(skin, model, skin_nodes, act, times, muscle_radius_m, vertex_colors)
    if markers:
        _write_markers(stage, f"{root}/Markers", model, markers, marker_names, marker_radius_m, times)
    _write_bones(stage, root, model.bone_meshes if bone_meshes is None else bone_meshes, affines, jaw_frame, times)
    if act is not None:
        _write_muscles(stage, f"{root}/Muscles", model.muscle_names, act, times)
    if rig is not None:
        topo = (counts, indices, skin_nodes)
        _write_rig(stage, f"{root}/Rig", rig, rw, affines, jaw_frame, skin_x, topo, times, model, rig_meshes)
    if basis is not None:
        _write_blendshapes(stage, f"{root}/Basis", basis, bw, counts, indices, times=times)
    bind_display_colors(stage, root)  # the heat map, markers and bones in a DCC's render
    if edit is not None:
        edit(stage)
    save_layer(stage.GetRootLayer(), path)  # atomic: a temporary file renamed into place
    return path


def joint_pivots(model) -> np.ndarray:
    """(2, 3) the rig's joint pivots at rest: the centroid of the nodes attached to the cranium and the
    jaw joint's condyle midpoint (the hinge)."""
    cranium = model.nodes_of_bone("cranium")
    centre = model.rest_positions_m[cranium].mean(axis=0) if cranium.size else np.zeros(3)
    return np.stack([centre, np.asarray(model.jaw_joint.midpoint_m, dtype=np.float64)])


def _write_rig(stage, prim_path, rig, weights, affines, jaw_frame, skin_x, topo, times, model, rig_meshes):
    """The UsdSkel rig (``wface.io.usd.rig``) and its error against the point cache in the layer metadata."""
    counts, indices, skin_nodes = topo
    n_frames = len(times)
    eye = np.tile(np.hstack([np.eye(3), np.zeros((3, 1))]), (n_frames, 1, 1))
    jaw_rel = affines.get("Jaw", eye)
    if jaw_frame == "world" and "Jaw" in affines:
        jaw_rel = _relative_to(affines.get("Cranium", eye), jaw_rel)
    pts = write_skin_rig(
        stage,
        prim_path,
        rig,
        counts,
        indices,
        weights=weights,
        cranium_affines=affines.get("Cranium", eye),
        jaw_affines=jaw_rel,
        times=times,
        st=_skin_st(model, skin_nodes),
        extra_meshes=rig_meshes,
        pivots_m=joint_pivots(model),
    )
    err_mm = np.linalg.norm(pts - skin_x, axis=2) * 1e3
    info = {"rig_rms_error_mm": float(np.sqrt(np.mean(err_mm**2))), "rig_max_error_mm": float(err_mm.max())}
    _set_layer_info(stage, {**info, "rig_source": rig.source})


def _checked_rig_weights(rig, rig_weights, act, n_skin: int, n_frames: int):
    """The (F, B) weights of the rig's shapes, checked (None without a rig)."""
    if rig is None:
        if rig_weights is not None:
            raise UsdWriteError("rig_weights given without a rig")
        return None
    if rig.rest_m.shape[0] != n_skin:
        raise UsdWriteError(f"the rig has {rig.rest_m.shape[0]} vertices, the skin {n_skin}")
    if rig_weights is None:
        if act is None or act.shape[1] != rig.deltas_m.shape[0]:
            raise UsdWriteError(
                f"the rig has {rig.deltas_m.shape[0]} shapes: pass rig_weights (frames, {rig.deltas_m.shape[0]})"
            )
        return act
    return _check_frames("rig_weights", rig_weights, n_frames, (rig.deltas_m.shape[0],))


def _relative_to(cranium: np.ndarray, jaw_world: np.ndarray) -> np.ndarray:
    """Jaw affines relative to the cranium from world ones: [Mc^-1 Mj | Mc^-1 (tj - tc)]."""
    lin = np.linalg.solve(cranium[:, :, :3], jaw_world[:, :, :3])
    t = np.linalg.solve(cranium[:, :, :3], (jaw_world[:, :, 3] - cranium[:, :, 3])[..., None])
    return np.concatenate([lin, t], axis=2)


def _checked_positions(model, node_positions_m) -> np.ndarray:
    """The (F, n, 3) node positions as float64, checked."""
    x = np.asarray(node_positions_m, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (model.n_nodes, 3) or x.shape[0] == 0:
        raise UsdWriteError(
            f"node_positions_m must have shape (frames, {model.n_nodes}, 3) for this model; got {x.shape}"
        )
    _check_finite("node_positions_m", x)
    return x


def _skin_polygons(model):
    """(skin node ids, face vertex counts, face vertex indices) of the skin renumbered compactly."""
    if model.skin_triangles.size == 0:
        raise UsdWriteError("model has no skin_triangles to write")
    skin_nodes = np.unique(model.skin_triangles)
    remap = np.full(model.n_nodes, -1, dtype=np.int64)
    remap[skin_nodes] = np.arange(skin_nodes.size)
    tri = remap[model.skin_triangles]
    counts, indices = as_polygons(None, tri, skin_nodes.size)
    return skin_nodes, counts, indices


def _checked_markers(captured_markers_m, simulated_markers_m, n_frames: int) -> dict[str, np.ndarray]:
    """{"Captured": (F, k, 3), "Simulated": (F, k, 3)} of the markers given, checked."""
    markers = {}
    for label, arr, nan_ok in (("Captured", captured_markers_m, True), ("Simulated", simulated_markers_m, False)):
        if arr is not None:
            key = "captured_markers_m" if label == "Captured" else "simulated_markers_m"
            markers[label] = _check_frames(key, arr, n_frames, (None, 3), allow_nan=nan_ok)
    ks = {a.shape[1] for a in markers.values()}
    if len(ks) > 1:
        raise UsdWriteError(f"captured and simulated markers differ in count: {sorted(ks)}")
    return markers


def _checked_affines(cranium_affines, jaw_affines, n_frames: int) -> dict[str, np.ndarray]:
    """{"Cranium": (F, 3, 4), "Jaw": (F, 3, 4)} of the affines given, checked."""
    affines = {}
    for label, arr in (("Cranium", cranium_affines), ("Jaw", jaw_affines)):
        if arr is not None:
            affines[label] = _check_frames(f"{label.lower()}_affines", arr, n_frames, (3, 4))
    return affines


def _checked_basis(basis, basis_weights, model, skin_nodes: np.ndarray, n_frames: int):
    """(the basis as a ``BlendShapeBasis`` on the skin vertices, its (F, B) weights), or (None, None)."""
    if basis is not None:
        basis = BlendShapeBasis.coerce(basis)
        if basis_weights is None:
            raise UsdWriteError("basis given without basis_weights (frames, B)")
        bw = _check_frames("basis_weights", basis_weights, n_frames, (basis.n_shapes,))
        nb = basis.neutral_m.shape[0]
        if nb == model.n_nodes:
            basis = basis.restricted(skin_nodes)
        elif nb != skin_nodes.size:
            raise UsdWriteError(
                f"basis has {nb} vertices; expected the model's {model.n_nodes} nodes "
                f"or its {skin_nodes.size} skin vertices"
            )
        return basis, bw
    elif basis_weights is not None:
        raise UsdWriteError("basis_weights given without a basis")
    return None, None


def _skin_st(model, skin_nodes: np.ndarray) -> np.ndarray:
    """(k, 2) texture coordinates of the skin's vertices (``wface.mesh.uv.skin_uv``; ``skin_nodes`` sorted)."""
    return skin_uv(model.rest_positions_m[skin_nodes], np.searchsorted(skin_nodes, model.skin_triangles))


def _write_skin_primvars(skin, model, skin_nodes, act, times, muscle_radius_m, vertex_colors: bool) -> None:
    """The skin Mesh's node ids, texture coordinates, activation primvar and colours."""
    from pxr import Sdf, UsdGeom, Vt

    pv_api = UsdGeom.PrimvarsAPI(skin.GetPrim())
    node_id = pv_api.CreatePrimvar("wface:nodeId", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex)
    node_id.Set(_vt_int(skin_nodes))
    st = pv_api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(_skin_st(model, skin_nodes).astype(np.float32)))
    n_frames = len(times)
    if act is not None:
        influence = skin_muscle_influence(model, skin_nodes, radius_m=muscle_radius_m)
        v_act, rgb = activation_colors(influence, act)
        _write_float_primvar(skin, "wface:activation", v_act, UsdGeom.Tokens.vertex, times=times)
        colours = rgb if vertex_colors else SKIN_RGB
        _set_display_color(skin, colours, n_points=skin_nodes.size, n_frames=n_frames, times=times)
    else:
        _set_display_color(skin, SKIN_RGB, n_points=skin_nodes.size, n_frames=n_frames)


def _write_markers(stage, prim_path: str, model, markers: dict, marker_names, marker_radius_m: float, times) -> None:
    """A Scope with one group of named locators per marker set (captured red, simulated green)."""
    from pxr import UsdGeom

    UsdGeom.Scope.Define(stage, prim_path)
    k = next(iter(markers.values())).shape[1]
    if marker_names is None:
        marker_names = list(model.marker_names) if len(model.marker_names) == k else [f"m{i}" for i in range(k)]
    if len(marker_names) != k:
        raise UsdWriteError(f"{len(marker_names)} marker names for {k} markers")
    colours = {"Captured": CAPTURED_RGB, "Simulated": SIMULATED_RGB}
    for label, arr in markers.items():
        write_locators(
            stage,
            f"{prim_path}/{label}",
            arr,
            list(marker_names),
            times=times,
            radius_m=marker_radius_m,
            rgb=colours[label],
            suffix="" if label == "Captured" else "_tracked",
        )


def _write_bones(stage, root: str, bone_meshes: dict, affines: dict, jaw_frame: str, times) -> None:
    """``Bones/Cranium`` and the jaw Xform (under the cranium or beside it), animated by ``affines``."""
    from pxr import UsdGeom

    bone_groups: dict[str, list[tuple[str, object]]] = {"Cranium": [], "Jaw": []}
    for mesh_name, mesh in bone_meshes.items():
        bone_groups["Jaw" if mesh.bone == "jaw" else "Cranium"].append((mesh_name, mesh))
    has_jaw = bool(bone_groups["Jaw"]) or "Jaw" in affines
    has_cranium = bool(bone_groups["Cranium"]) or "Cranium" in affines or (has_jaw and jaw_frame == "cranium")
    bone_paths = {
        "Cranium": f"{root}/Bones/Cranium",
        "Jaw": f"{root}/Bones/Cranium/Jaw" if jaw_frame == "cranium" else f"{root}/Bones/Jaw",
    }
    if has_cranium or has_jaw:
        UsdGeom.Scope.Define(stage, f"{root}/Bones")
    bone_rgb = np.array(BONE_RGB)
    for label, present in (("Cranium", has_cranium), ("Jaw", has_jaw)):
        if not present:
            continue
        xf = UsdGeom.Xform.Define(stage, bone_paths[label])
        if label in affines:
            op = xf.AddTransformOp()
            for t, a in zip(times, affines[label], strict=True):
                op.Set(affine_to_matrix4d(a), float(t))
        taken: set[str] = {"Jaw"} if label == "Cranium" else set()  # the jaw Xform may live under the cranium
        for mesh_name, mesh in bone_groups[label]:
            ident = _identifier(mesh_name, taken)
            v = _as_points(mesh.vertices_m, f"bone mesh {mesh_name!r} vertices_m")
            tri = oriented_outward(v, np.asarray(mesh.triangles).reshape(-1, 3))
            c, i = as_polygons(None, tri, v.shape[0])
            _write_mesh(stage, f"{bone_paths[label]}/{ident}", v, c, i, colors=bone_rgb)


def _write_muscles(stage, prim_path: str, muscle_names, act: np.ndarray, times) -> None:
    """A Scope with the muscle names and the (F, M) activations, all together and one attribute each."""
    from pxr import Sdf, UsdGeom, Vt

    muscles = UsdGeom.Scope.Define(stage, prim_path).GetPrim()
    muscles.CreateAttribute(
        "wface:muscleNames", Sdf.ValueTypeNames.StringArray, custom=True, variability=Sdf.VariabilityUniform
    ).Set(Vt.StringArray(list(muscle_names)))
    all_attr = muscles.CreateAttribute("wface:activations", Sdf.ValueTypeNames.FloatArray, custom=True)
    taken = set()
    per_muscle = []
    for m_name in muscle_names:
        ident = _identifier(m_name, taken)
        per_muscle.append(muscles.CreateAttribute(f"wface:activation:{ident}", Sdf.ValueTypeNames.Float, custom=True))
    for t, a in zip(times, act, strict=True):
        t = float(t)
        all_attr.Set(_vt_float(a), t)
        for attr, value in zip(per_muscle, a, strict=True):
            attr.Set(float(value), t)
