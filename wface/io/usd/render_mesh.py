"""A render mesh as USD: its own layer in the source's units, referenced beside the FEM skin.

``write_render_mesh_layer`` writes ``<name>.usdc``: a stage whose ``metersPerUnit`` is the source
file's (0.01 for a head modelled in centimetres), upAxis Y, timeCodesPerSecond = fps, the default
prim ``/<name>`` (Xform) with ``/<name>/RenderMeshCache`` (so named because Blender merges an Xform
with its one child into an object named after the child): the authored topology (faceVertexCounts /
faceVertexIndices, quads kept), points, extent and vertex normals time-sampled (frame f at time
code f, in the file's own frame and units), the texture coordinates as the indexed faceVarying
primvar ``st`` (texCoord2f, seams kept), and one ``UsdGeom.Subset`` per material group (family
``materialBind``, faces) bound to a ``UsdPreviewSurface`` material of that name under
``/<name>/Materials`` (the ``.mtl`` diffuse colour where the source has one, else skin or grey).
The layer opens alone in Blender, usdview or Houdini in the asset's own
coordinates.

``reference_render_mesh`` adds ``/<root>/RenderMesh`` to a take's stage (metersPerUnit 1): an
Xform whose transform is the source-to-model placement (units included), referencing that layer,
so the render mesh lies on the FEM skin there.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from wface.files import save_layer
from wface.io.usd._common import _vt_vec3f
from wface.io.usd.mesh import _write_face_varying, _write_materials
from wface.mesh.surface import vertex_normals

__all__ = [
    "CACHE_PRIM",
    "add_render_mesh_reference",
    "recorded_render_mesh",
    "reference_render_mesh",
    "write_render_mesh_layer",
]

CACHE_PRIM = "RenderMeshCache"  # the point cache's prim under the layer's root (a DCC object name)


def _absolute(source) -> str:
    """The mesh file's absolute path (a later ``--take`` run may start elsewhere), or "" for none."""
    return str(Path(source).resolve()) if source else ""


def recorded_render_mesh(layer_path: str | Path) -> tuple[str, float] | None:
    """(the mesh file, its metres per unit) a render-mesh layer was written from, or None when
    ``layer_path`` is no such layer (``wface resim --take`` and ``wface edit --take`` carry the take's
    render mesh on with it)."""
    from pxr import Usd, UsdGeom

    if not Path(layer_path).is_file():
        return None
    stage = Usd.Stage.Open(str(layer_path))
    info = dict(stage.GetRootLayer().customLayerData).get("wface") or {}
    if info.get("kind") != "render_mesh" or not info.get("source"):
        return None
    return str(info["source"]), float(UsdGeom.GetStageMetersPerUnit(stage))


def write_render_mesh_layer(
    path: str | Path,
    mesh,
    points: np.ndarray,
    *,
    fps: float,
    name: str = "RenderMesh",
    frames: np.ndarray | None = None,
) -> Path:
    """Write a render mesh's animation as its own USD layer (module docstring).

    Args:
        path: ``.usdc`` or ``.usda``.
        mesh: the ``wface.mesh.meshfile.SurfaceMesh`` (topology, UVs, groups, meters_per_unit).
        points: (T, n, 3) vertex positions per frame in the mesh file's frame and units.
        fps: frame rate (timeCodesPerSecond).
        frames: (T,) the frames' time codes (default 0..T-1), as on the take's stage.
        name: the default prim's name.

    Returns:
        The path written.
    """
    from pxr import Sdf, Usd, UsdGeom, Vt

    path = Path(path)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[1:] != (mesh.n_points, 3):
        raise ValueError(f"points must have shape (frames, {mesh.n_points}, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("render mesh points contain NaN or inf")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps}")
    times = np.arange(len(pts), dtype=float) if frames is None else np.asarray(frames, dtype=float)
    if times.shape != (len(pts),):
        raise ValueError(f"frames must have shape ({len(pts)},), got {times.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = Usd.Stage.CreateInMemory(path.name)
    UsdGeom.SetStageMetersPerUnit(stage, float(mesh.meters_per_unit))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(float(times[0]))
    stage.SetEndTimeCode(float(times[-1]))
    root = f"/{Sdf.Path.IsValidIdentifier(name) and name or 'RenderMesh'}"
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, root).GetPrim())
    geom = UsdGeom.Mesh.Define(stage, f"{root}/{CACHE_PRIM}")
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(mesh.face_vertex_counts, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(mesh.face_vertex_indices, np.int32)))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    tri = mesh.triangles()
    p_attr, n_attr, e_attr = geom.CreatePointsAttr(), geom.CreateNormalsAttr(), geom.CreateExtentAttr()
    geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    for t, p in zip(times, pts, strict=True):
        p_attr.Set(_vt_vec3f(p), t)
        n_attr.Set(_vt_vec3f(vertex_normals(p, tri)), t)
        e_attr.Set(_vt_vec3f(np.stack([p.min(axis=0), p.max(axis=0)])), t)
    if mesh.uv is not None and mesh.uv_indices is not None:
        _write_face_varying(geom, "st", mesh.uv, mesh.uv_indices, mesh.face_vertex_indices.size, 2)
    if mesh.face_groups:
        _write_materials(stage, root, geom, mesh.face_groups, mesh.material_colors, int(mesh.n_faces))
    stage.GetRootLayer().customLayerData = {
        "wface": {"kind": "render_mesh", "source": _absolute(mesh.source), "first_frame": int(times[0])}
    }
    save_layer(stage.GetRootLayer(), path)  # atomic: a temporary file renamed into place
    return path


def reference_render_mesh(
    stage_path: str | Path, layer_path: str | Path, *, source_to_model: np.ndarray, root: str = "Face"
) -> None:
    """Reference a render-mesh layer from a take's stage as ``/<root>/RenderMesh`` (module docstring).

    Args:
        stage_path: the take's stage (metersPerUnit 1), edited in place.
        layer_path: the layer ``write_render_mesh_layer`` wrote.
        source_to_model: (4, 4) mesh file coordinates -> model metres (column vectors).
        root: the stage's root prim name.
    """
    from pxr import Usd

    stage = Usd.Stage.Open(str(stage_path))
    add_render_mesh_reference(stage, stage_path, layer_path, source_to_model=source_to_model, root=root)
    save_layer(stage.GetRootLayer(), stage_path)


def _render_mesh_prim(root: str) -> str:
    """The prim a take's stage references the render-mesh layer at: ``/<root>/RenderMesh``."""
    return f"/{root}/RenderMesh"


def render_mesh_materials_path(root: str = "Face") -> str:
    """Where a take's stage sees the render mesh's materials once ``add_render_mesh_reference`` has
    referenced its layer (the layer keeps them under its root's Materials)."""
    return f"{_render_mesh_prim(root)}/Materials"


def add_render_mesh_reference(
    stage, stage_path: str | Path, layer_path: str | Path, *, source_to_model: np.ndarray, root: str = "Face"
) -> None:
    """``reference_render_mesh`` on an open ``stage`` that will be saved at ``stage_path`` (the
    reference is relative to it), without saving it."""
    from pxr import Gf, UsdGeom

    xf = UsdGeom.Xform.Define(stage, _render_mesh_prim(root))
    rel = os.path.relpath(Path(layer_path).resolve(), Path(stage_path).resolve().parent)
    xf.GetPrim().GetReferences().AddReference(Path(rel).as_posix())
    m = np.asarray(source_to_model, dtype=np.float64)
    xf.AddTransformOp().Set(Gf.Matrix4d(m.T.tolist()))  # USD multiplies row vectors: the transpose
