"""A whole take of a FaceModel: skin, markers, bones, muscle activations, an optional basis."""

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
    _json_safe,
    _new_stage,
    _set_display_color,
    _vt_float,
    _vt_int,
    _vt_vec3f,
    _write_float_primvar,
    _write_mesh,
    affine_to_matrix4d,
    as_polygons,
)
from wface.io.usd.skel import BlendShapeBasis, _write_blendshapes
from wface.viz.muscles import SKIN_RGB, activation_colors, skin_muscle_influence

__all__ = ["write_take"]


def _write_points(stage, prim_path: str, points: np.ndarray, *, radius_m: float, rgb, names: list[str]):
    """UsdGeom.Points per frame; NaN rows (missing markers) are left out and ``ids`` says which remain."""
    from pxr import Sdf, UsdGeom, Vt

    pts = UsdGeom.Points.Define(stage, prim_path)
    pts.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(_vt_vec3f(np.asarray(rgb)[None]))
    w_attr = pts.CreateWidthsAttr()
    pts.SetWidthsInterpolation(UsdGeom.Tokens.vertex)  # one width per point
    pts.GetPrim().CreateAttribute(
        "wface:markerNames", Sdf.ValueTypeNames.StringArray, custom=True, variability=Sdf.VariabilityUniform
    ).Set(Vt.StringArray(list(names)))
    p_attr, i_attr, e_attr = pts.CreatePointsAttr(), pts.CreateIdsAttr(), pts.CreateExtentAttr()
    last_extent = None
    for f, pf in enumerate(points):
        present = np.flatnonzero(np.all(np.isfinite(pf), axis=1))
        p32 = _vt_vec3f(pf[present])
        widths = _vt_float(np.full(present.size, 2.0 * radius_m))
        p_attr.Set(p32, float(f))
        w_attr.Set(widths, float(f))
        i_attr.Set(Vt.Int64Array([int(i) for i in present]), float(f))
        ext = UsdGeom.Points.ComputeExtent(p32, widths) if present.size else None
        if ext is None or len(ext) != 2:
            ext = last_extent if last_extent is not None else _vt_vec3f(np.zeros((2, 3)))
        e_attr.Set(ext, float(f))
        last_extent = ext
    return pts


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
) -> Path:
    """Write a tracked or simulated take of a ``FaceModel`` as one USD stage.

    Frame f (0-based) is time code f; the stage's timeCodesPerSecond is ``fps``. Prims under the
    default prim ``/<name>`` (an Xform):

    - ``Skin`` (Mesh): the nodes used by ``model.skin_triangles``, renumbered compactly (their
      model node ids in the constant primvar ``wface:nodeId``); topology once, points and extent
      per frame. With ``activations``: ``primvars:wface:activation`` (float per vertex per frame,
      max_m w_m a_m over nearby muscles) and a ``displayColor`` heat map (skin; muscles red when
      inactive, yellow when active). Without: a constant skin colour.
    - ``Markers/Captured`` and ``Markers/Simulated`` (Points, red and green, one width per point,
      ``ids`` = marker indices; NaN captured positions, i.e. missing markers, are left out of
      that frame). Marker names in the uniform attribute ``wface:markerNames``.
    - ``Bones/Cranium`` and ``Bones/Cranium/Jaw`` (Xforms with one time-sampled transform op
      from the per-frame affines; the jaw's op is relative to the cranium, as the 24 bone
      parameters of ``wface.controls``) holding the model's ``bone_meshes`` at rest position.
      With ``jaw_frame="world"`` the jaw Xform is ``Bones/Jaw``, a sibling of the cranium.
    - ``Muscles`` (Scope): per muscle a time-sampled float ``wface:activation:<muscle>`` (the name
      made a valid identifier; the original names in ``wface:muscleNames``), and all of them as
      a float[] ``wface:activations``.
    - ``Basis`` (SkelRoot) when ``basis`` is given: see ``write_blendshape_basis``.

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

    stage = _new_stage(path, fps=fps, n_frames=n_frames, up_axis=up_axis, root=name)
    root = f"/{name}"
    info = {"kind": "take", "frames": int(n_frames), "nodes": int(model.n_nodes), "muscles": int(model.n_muscles)}
    info.update({str(k): _json_safe(v) for k, v in (metadata or {}).items()})
    stage.GetRootLayer().customLayerData = {"wface": info}

    skin = _write_mesh(stage, f"{root}/Skin", x[:, skin_nodes], counts, indices)
    _write_skin_primvars(skin, model, skin_nodes, act, n_frames, muscle_radius_m, vertex_colors)
    if markers:
        _write_markers(stage, f"{root}/Markers", model, markers, marker_names, marker_radius_m)
    _write_bones(stage, root, model.bone_meshes if bone_meshes is None else bone_meshes, affines, jaw_frame)
    if act is not None:
        _write_muscles(stage, f"{root}/Muscles", model.muscle_names, act)
    if basis is not None:
        _write_blendshapes(stage, f"{root}/Basis", basis, bw, counts, indices)
    save_layer(stage.GetRootLayer(), path)  # atomic: a temporary file renamed into place
    return path


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


def _write_skin_primvars(skin, model, skin_nodes, act, n_frames: int, muscle_radius_m, vertex_colors: bool) -> None:
    """The skin Mesh's node ids, activation primvar and colours."""
    from pxr import Sdf, UsdGeom

    node_id = UsdGeom.PrimvarsAPI(skin.GetPrim()).CreatePrimvar(
        "wface:nodeId", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex
    )
    node_id.Set(_vt_int(skin_nodes))
    if act is not None:
        influence = skin_muscle_influence(model, skin_nodes, radius_m=muscle_radius_m)
        v_act, rgb = activation_colors(influence, act)
        _write_float_primvar(skin, "wface:activation", v_act, UsdGeom.Tokens.vertex)
        if vertex_colors:
            _set_display_color(skin, rgb, n_points=skin_nodes.size, n_frames=n_frames)
        else:
            _set_display_color(skin, SKIN_RGB, n_points=skin_nodes.size, n_frames=n_frames)
    else:
        _set_display_color(skin, SKIN_RGB, n_points=skin_nodes.size, n_frames=n_frames)


def _write_markers(stage, prim_path: str, model, markers: dict, marker_names, marker_radius_m: float) -> None:
    """A Scope with one Points prim per marker set (captured red, simulated green)."""
    from pxr import UsdGeom

    UsdGeom.Scope.Define(stage, prim_path)
    k = next(iter(markers.values())).shape[1]
    if marker_names is None:
        marker_names = list(model.marker_names) if len(model.marker_names) == k else [f"m{i}" for i in range(k)]
    if len(marker_names) != k:
        raise UsdWriteError(f"{len(marker_names)} marker names for {k} markers")
    colours = {"Captured": (0.9, 0.05, 0.05), "Simulated": (0.05, 0.8, 0.1)}
    for label, arr in markers.items():
        _write_points(
            stage, f"{prim_path}/{label}", arr, radius_m=marker_radius_m, rgb=colours[label], names=marker_names
        )


def _write_bones(stage, root: str, bone_meshes: dict, affines: dict, jaw_frame: str) -> None:
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
    bone_rgb = np.array([0.93, 0.91, 0.84])
    for label, present in (("Cranium", has_cranium), ("Jaw", has_jaw)):
        if not present:
            continue
        xf = UsdGeom.Xform.Define(stage, bone_paths[label])
        if label in affines:
            op = xf.AddTransformOp()
            for f, a in enumerate(affines[label]):
                op.Set(affine_to_matrix4d(a), float(f))
        taken: set[str] = {"Jaw"} if label == "Cranium" else set()  # the jaw Xform may live under the cranium
        for mesh_name, mesh in bone_groups[label]:
            ident = _identifier(mesh_name, taken)
            v = _as_points(mesh.vertices_m, f"bone mesh {mesh_name!r} vertices_m")
            c, i = as_polygons(None, np.asarray(mesh.triangles).reshape(-1, 3), v.shape[0])
            _write_mesh(stage, f"{bone_paths[label]}/{ident}", v, c, i, colors=bone_rgb)


def _write_muscles(stage, prim_path: str, muscle_names, act: np.ndarray) -> None:
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
    for f, a in enumerate(act):
        t = float(f)
        all_attr.Set(_vt_float(a), t)
        for attr, value in zip(per_muscle, a, strict=True):
            attr.Set(float(value), t)
