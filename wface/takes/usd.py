"""The one place that writes a take as USD: tracked, edited, re-simulated and spoken takes alike.

``write_take_usd`` turns a ``wface.takes.take.Take`` and its simulated node positions into the
stage layout of ``wface.io.usd.write_take`` (``/<name>/Skin`` with model node ids,
``Bones/Cranium`` and ``Bones/Cranium/Jaw`` from the take's bones, the ``Muscles`` activation
curves, markers when given), so ``wface.io.usd.read_take`` reads every command's stage back and the
tracked, edited and dynamic stages of one performance line up prim for prim. Activation curves are
min(drive, 1) per muscle (drive = activation x force-length scale); a take with force-length scales
also stores them in the layer metadata. ``mesh_only`` (or a model without skin triangles) writes the
skin alone as ``/<name>/Mesh`` (``write_mesh_animation``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.controls import IDENTITY_AFFINE, bone_affines
from wface.io.usd import write_mesh_animation, write_take
from wface.io.usd.render_mesh import reference_render_mesh, write_render_mesh_layer
from wface.mesh.surface import boundary_faces
from wface.model import FaceModel
from wface.takes.take import Take

__all__ = ["add_render_mesh", "skin_mesh", "write_take_usd"]


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
    render_mesh=None,
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
        render_mesh: a ``wface.faces.render_mesh.RenderMesh`` moved with the frames
            (``add_render_mesh``, which also adds one to a stage already written).
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
        stage = write_mesh_animation(
            path, points_m=positions_m[:, nodes], face_vertex_counts=None, face_vertex_indices=tri, fps=rate, name=name
        )
        return add_render_mesh(stage, render_mesh, positions_m, rate, name)
    T = take.n_frames
    if take.bones is not None:
        cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(b) for b in take.bones), strict=True))
    else:
        cranium = jaw = np.tile(IDENTITY_AFFINE, (T, 1, 1))
    meta = {"source": take.source, **(metadata or {})}
    if take.force_length_scale is not None:
        meta["force_length_scale"] = take.force_length_scale.max(axis=0).tolist()
    stage = write_take(
        path,
        model=model,
        node_positions_m=positions_m,
        fps=rate,
        captured_markers_m=captured_markers_m,
        simulated_markers_m=simulated_markers_m,
        marker_names=marker_names,
        cranium_affines=cranium,
        jaw_affines=jaw,
        activations=np.minimum(take.drives, 1.0),
        bone_meshes=bone_meshes,
        name=name,
        metadata=meta,
    )
    return add_render_mesh(stage, render_mesh, positions_m, rate, name)


def add_render_mesh(path: str | Path, render_mesh, positions_m: np.ndarray, fps: float, name: str = "Face") -> Path:
    """With a render mesh: write it to ``<stem>_render_mesh.usdc`` in its own units and reference it
    as ``/<name>/RenderMesh`` (``wface.io.usd.render_mesh``). Returns the stage's path."""
    if render_mesh is not None:
        layer = Path(path).with_name(f"{Path(path).stem}_render_mesh.usdc")
        write_render_mesh_layer(layer, render_mesh.mesh, render_mesh.source_points(positions_m), fps=fps)
        reference_render_mesh(path, layer, source_to_model=render_mesh.source_to_model, root=name)
    return Path(path)
