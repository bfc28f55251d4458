"""The one place that writes a take as USD: tracked, edited, re-simulated and spoken takes alike.

``write_take_usd`` turns a ``wface.takes.take.Take`` and its simulated node positions into the
stage layout of ``wface.io.usd.write_take`` (``/<name>/Skin``: the exact point cache with model node
ids, ``Bones/Cranium`` and ``Bones/Cranium/Jaw`` from the take's bones, the ``Muscles`` activation
curves, named marker locators when given, and the ``Rig``: the skin as UsdSkel blend shapes, one
per muscle from the FEM face itself (``wface.takes.shapes``), with cranium and jaw joints, driven by
the activation curves, and a render mesh's own shapes beside it when one is given), so
``wface.io.usd.read_take`` reads every command's stage back and the
tracked, edited and dynamic stages of one performance line up prim for prim. Time codes are the
take's frame numbers (the capture's for a tracked take). Activation curves are min(drive, 1) per
muscle (drive = activation x force-length scale); a take with force-length scales also stores them
in the layer metadata. ``mesh_only`` (or a model without skin triangles) writes the skin alone as
``/<name>/Mesh`` (``write_mesh_animation``).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from wface.controls import IDENTITY_AFFINE, bone_affines, jaw_to_intuitive, params_from_affine
from wface.files import save_layer
from wface.io.usd import rig_points, write_mesh_animation, write_take
from wface.io.usd.render_mesh import (
    add_render_mesh_reference,
    reference_render_mesh,
    render_mesh_materials_path,
    write_render_mesh_layer,
)
from wface.mesh.surface import boundary_faces
from wface.model import FaceModel
from wface.takes.shapes import JAW_SHAPE, render_mesh_rig, shape_weights, skin_rig
from wface.takes.take import Take

__all__ = ["ACTIVE_WEIGHT", "add_render_mesh", "render_mesh_layer_path", "skin_mesh", "write_take_usd"]

# A shape whose weight exceeds this in some frame is "used" by the take and gets a blend shape. Below
# it a shape moves the skin by less than 0.1 % of its full motion (~0.01 mm on the built-in face), and
# the tracker's round-off (a resting muscle or the pressure at +-5e-4) neither adds nor drops one.
ACTIVE_WEIGHT = 1e-3


def skin_mesh(model: FaceModel) -> tuple[np.ndarray, np.ndarray]:
    """(node ids (s,), triangles (t, 3) over those s points) of the skin, or the boundary of the
    tet mesh when the model has no skin triangles."""
    tri = model.skin_triangles if model.skin_triangles.size else boundary_faces(model.tets)
    nodes, local = np.unique(tri.ravel(), return_inverse=True)
    return nodes, local.reshape(-1, 3).astype(np.int32)


def write_take_usd(
    path: str | Path,
    model: FaceModel,
    positions_m: np.ndarray,
    *,
    take: Take | None = None,
    fps: float | None = None,
    captured_markers_m: np.ndarray | None = None,
    simulated_markers_m: np.ndarray | None = None,
    marker_names: list[str] | None = None,
    metadata: dict | None = None,
    mesh_only: bool = False,
    bone_meshes: dict | None = None,
    name: str = "Face",
    rig: bool | str = "active",
    simulator=None,
    progress: bool = False,
    render_mesh=None,
    edit=None,
) -> Path:
    """Write a take's frames as one USD stage (module docstring); time code f = frame f.

    Args:
        path: ``.usdc`` (binary) or ``.usda`` (text).
        model: the face.
        positions_m: (T, n, 3) world node positions, metres.
        take: the take played (activations, bones, force-length scales, source); None writes the
            skin mesh alone.
        fps: frame rate (default: the take's).
        captured_markers_m, simulated_markers_m, marker_names: optional markers (``write_take``).
        metadata: small JSON-able dict for the layer's customLayerData["wface"] (with the take's
            ``source``).
        mesh_only: write the skin alone (``/<name>/Mesh``).
        bone_meshes: {name: BoneMesh} to draw instead of ``model.bone_meshes`` (``{}``: none).
        name: the root prim's name.
        rig: the UsdSkel ``Rig`` (``wface.takes.shapes``: one quasistatic solve per muscle shape, two
            for the jaw, each once per model object): "active" (default) gives shapes to the muscles
            the take uses (curve above 1e-6) and the jaw shapes when the jaw moves; "all" or True
            to every muscle and the jaw; False writes no rig.
        simulator: a ``Simulator`` of ``model`` to reuse for the rig's solves.
        progress: show a progress bar over the rig's solves.
        render_mesh: a ``wface.faces.render_mesh.RenderMesh`` moved with the frames
            (``add_render_mesh``, which also adds one to a stage already written); with a rig it
            also joins the rig as ``Rig/RenderMesh`` (``wface.takes.shapes.render_mesh_rig``: its
            own shapes, in its file's units, placed by its transform), its error against the exact
            point cache in the layer metadata (``render_mesh_rig_rms_error_mm``, ``..._max_...``).
        edit: callable(stage) run on the take's stage before its one save (``write_take``'s).

    A rig whose solve fails (a muscle alone at activation 1 inverts tets) is left out with a
    ``RuntimeWarning``, its reason in the layer metadata (``rig_skipped``); the rest of the stage is
    written, so no take is lost to its rig.
    """
    positions_m = np.asarray(positions_m)
    if positions_m.ndim != 3 or positions_m.shape[1:] != (model.n_nodes, 3):
        raise ValueError(f"positions_m must have shape (frames, {model.n_nodes}, 3), got {positions_m.shape}")
    if take is not None and take.n_frames != positions_m.shape[0]:
        raise ValueError(f"take has {take.n_frames} frames, positions_m {positions_m.shape[0]}")
    rate = fps if fps is not None else (take.fps if take is not None else None)
    if rate is None:
        raise ValueError("write_take_usd needs fps when no take is given")
    if take is None or mesh_only or not model.skin_triangles.size:
        nodes, tri = skin_mesh(model)
        frames = None if take is None else take.frames
        written = write_mesh_animation(
            path,
            points_m=positions_m[:, nodes],
            face_vertex_counts=None,
            face_vertex_indices=tri,
            fps=rate,
            name=name,
            frames=frames,
        )
        run = _edits(written, render_mesh, positions_m, rate, name, frames, edit)
        if run is not None:  # a mesh alone has no edit hook in its writer: edit the saved stage once
            from pxr import Usd

            saved = Usd.Stage.Open(str(written))
            run(saved)
            save_layer(saved.GetRootLayer(), written)
        return Path(written)
    if take.bones is not None:
        cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(b) for b in take.bones), strict=True))
    else:
        cranium = jaw = np.tile(IDENTITY_AFFINE, (take.n_frames, 1, 1))
    meta = _take_metadata(take, metadata)
    activations = np.clip(take.drives, -1.0, 1.0)  # a pressure actuator may be negative (suction)
    rig_meshes = None
    try:
        skel, rig_weights = _rig(model, take, activations, jaw, rig, simulator, progress)
        if skel is not None and render_mesh is not None:
            rig_meshes, errors = _render_mesh_in_rig(
                model, render_mesh, skel, rig_weights, positions_m, (cranium, jaw), name
            )
            meta.update(errors)
    except RuntimeError as exc:  # a muscle's shape inverts tets: the exact cache still goes out, without a rig
        warnings.warn(f"{path}: written without the UsdSkel rig ({exc})", RuntimeWarning, stacklevel=2)
        skel, rig_weights, rig_meshes = None, None, None
        meta["rig_skipped"] = str(exc)
    written = write_take(
        path,
        edit=_edits(path, render_mesh, positions_m, rate, name, take.frames, edit),
        frames=take.frames,
        rig=skel,
        rig_weights=rig_weights,
        rig_meshes=rig_meshes,
        model=model,
        node_positions_m=positions_m,
        fps=rate,
        captured_markers_m=captured_markers_m,
        simulated_markers_m=simulated_markers_m,
        marker_names=marker_names,
        cranium_affines=cranium,
        jaw_affines=jaw,
        activations=activations,
        bone_meshes=bone_meshes,
        name=name,
        metadata=meta,
    )
    return Path(written)


def _edits(path, render_mesh, positions_m, fps, name, frames, edit):
    """The edits of a take's stage before its one save: the render mesh's reference (its layer written
    first, ``add_render_mesh``'s), then ``edit``; None when there are none."""
    layer = _render_mesh_layer(path, render_mesh, positions_m, fps, frames)
    if layer is None and edit is None:
        return None

    def run(stage) -> None:
        if layer is not None:
            add_render_mesh_reference(stage, path, layer, source_to_model=render_mesh.source_to_model, root=name)
        if edit is not None:
            edit(stage)

    return run


def _rig(model: FaceModel, take: Take, activations: np.ndarray, jaw: np.ndarray, rig, simulator, progress: bool):
    """(the take's ``SkinRig`` or None, its (T, B) weights): muscle curves, then the jaw corrective's
    opening / the opening that makes it 1."""
    if rig is False:
        return None, None
    if rig not in (True, "all", "active"):
        raise ValueError(f"rig must be 'active', 'all', True or False; got {rig!r}")
    names, weights = shape_weights(model, activations, active=ACTIVE_WEIGHT if rig == "active" else None)
    jaw_moves = bool(np.abs(jaw - IDENTITY_AFFINE).max() > 1e-12) if rig == "active" else True
    if not names and not jaw_moves:
        return None, None
    skel = skin_rig(model, muscles=names, jaw=jaw_moves, simulator=simulator, progress=progress)
    columns = [weights]
    if jaw_moves:
        params = (params_from_affine(j[:, :3], j[:, 3]) for j in jaw)
        opening = np.array([jaw_to_intuitive(model.jaw_joint, p)["opening_deg"] for p in params])
        # clipped at 0 for a jaw closed past rest: DCCs clamp blend shape weights to [0, 1] (Blender's
        # shape keys), and the rig must play the same everywhere (docs/design.md, "Controls and the jaw joint")
        columns.append(np.clip(opening / skel.info["jaw_open_full_deg"], 0.0, 1.0)[:, None])
    return skel, np.concatenate(columns, axis=1)


def _take_metadata(take: Take, metadata: dict | None) -> dict:
    """The stage's layer metadata: the take's source, ``metadata``, and the muscles' largest force-length
    scale when the take has one."""
    meta = {"source": take.source, **(metadata or {})}
    if take.force_length_scale is not None:
        meta["force_length_scale"] = take.force_length_scale.max(axis=0).tolist()
    return meta


def _render_mesh_in_rig(model, render_mesh, skel, weights, positions_m, bones, name: str) -> tuple[dict, dict]:
    """({"RenderMesh": the render mesh's rig entry for ``write_take``}, its error against the exact
    point cache, mm): shapes from ``render_mesh_rig``, in the file's units, placed by its transform
    (``bones``: the (F, 3, 4) cranium and jaw affines),
    its material groups bound to the render mesh layer's materials (``/<name>/RenderMesh/Materials``)."""
    muscles = [n for n in skel.names if n != JAW_SHAPE]
    rm_rig = render_mesh_rig(model, render_mesh, muscles=muscles, jaw=JAW_SHAPE in skel.names)
    mesh = render_mesh.mesh
    exact = np.stack([render_mesh.model_points(x) for x in positions_m])
    err_mm = np.linalg.norm(rig_points(rm_rig, weights, *bones) - exact, axis=2) * 1e3
    materials = (mesh.face_groups, render_mesh_materials_path(name)) if mesh.face_groups else None
    entry = (rm_rig, mesh.face_vertex_counts, mesh.face_vertex_indices, mesh.uv, mesh.uv_indices, materials)
    errors = {
        "render_mesh_rig_rms_error_mm": float(np.sqrt(np.mean(err_mm**2))),
        "render_mesh_rig_max_error_mm": float(err_mm.max()),
    }
    return {"RenderMesh": entry}, errors


def render_mesh_layer_path(stage_path: str | Path) -> Path:
    """Where ``add_render_mesh`` writes a stage's render-mesh layer: ``<stem>_render_mesh.usdc`` beside it."""
    return Path(stage_path).with_name(f"{Path(stage_path).stem}_render_mesh.usdc")


def add_render_mesh(
    path: str | Path,
    render_mesh,
    positions_m: np.ndarray,
    fps: float,
    name: str = "Face",
    *,
    frames: np.ndarray | None = None,
) -> Path:
    """With a render mesh: write it to ``<stem>_render_mesh.usdc`` in its own units and reference it
    as ``/<name>/RenderMesh`` (``wface.io.usd.render_mesh``), time codes ``frames`` (default 0..T-1)
    as on the take's stage. Returns the stage's path."""
    layer = _render_mesh_layer(path, render_mesh, positions_m, fps, frames)
    if layer is not None:
        reference_render_mesh(path, layer, source_to_model=render_mesh.source_to_model, root=name)
    return Path(path)


def _render_mesh_layer(path, render_mesh, positions_m: np.ndarray, fps: float, frames) -> Path | None:
    """Write the render mesh's layer beside the stage at ``path`` (``render_mesh_layer_path``), its
    points moved with ``positions_m``; its path, or None without a render mesh."""
    if render_mesh is None:
        return None
    layer = render_mesh_layer_path(path)
    write_render_mesh_layer(layer, render_mesh.mesh, render_mesh.source_points(positions_m), fps=fps, frames=frames)
    return layer
