"""A render mesh as USD: its own layer in the source's units, referenced beside the FEM skin.

``write_render_mesh_layer`` writes ``<name>.usdc``: a stage whose ``metersPerUnit`` is the source
file's (0.01 for a head modelled in centimetres), upAxis Y, timeCodesPerSecond = fps, the default
prim ``/<name>`` (Xform) with ``/<name>/Mesh``: the authored topology (faceVertexCounts /
faceVertexIndices, quads kept), points, extent and vertex normals time-sampled (frame f at time
code f, in the file's own frame and units), the texture coordinates as the indexed faceVarying
primvar ``st`` (texCoord2f, seams kept), and one ``UsdGeom.Subset`` per material group (family
``materialBind``, faces) bound to a ``UsdPreviewSurface`` material of that name under
``/<name>/Materials``. The layer opens alone in Blender, usdview or Houdini in the asset's own
coordinates.

``reference_render_mesh`` adds ``/<root>/RenderMesh`` to a take's stage (metersPerUnit 1): an
Xform whose transform is the source-to-model placement (units included), referencing that layer,
so the render mesh lies on the FEM skin there.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from wface.mesh.surface import vertex_normals

__all__ = ["reference_render_mesh", "write_render_mesh_layer"]

_SKIN_RGB = (0.80, 0.62, 0.52)
_OTHER_RGB = (0.55, 0.55, 0.58)


def _vec3f(a):
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _ints(a):
    from pxr import Vt

    return Vt.IntArray.FromNumpy(np.ascontiguousarray(a, dtype=np.int32))


def _identifier(name: str, taken: set[str]) -> str:
    from pxr import Tf

    base = Tf.MakeValidIdentifier(("_" + name) if name[:1].isdigit() else name) or "_"
    ident, k = base, 1
    while ident in taken:
        ident, k = f"{base}_{k}", k + 1
    taken.add(ident)
    return ident


def _materials(stage, mesh_prim, root: str, groups: dict[str, np.ndarray]) -> None:
    from pxr import Gf, Sdf, UsdGeom, UsdShade

    geom = UsdGeom.Imageable(mesh_prim)
    UsdShade.MaterialBindingAPI.Apply(mesh_prim)
    taken: set[str] = set()
    for name, faces in groups.items():
        ident = _identifier(name, taken)
        mat = UsdShade.Material.Define(stage, f"{root}/Materials/{ident}")
        shader = UsdShade.Shader.Define(stage, f"{root}/Materials/{ident}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        skin = any(w in name.lower() for w in ("face", "head", "skin", "body"))
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(
            Gf.Vec3f(*(_SKIN_RGB if skin else _OTHER_RGB))
        )
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        subset = UsdGeom.Subset.Define(stage, f"{mesh_prim.GetPath()}/{ident}")
        subset.CreateElementTypeAttr(UsdGeom.Tokens.face)
        subset.CreateFamilyNameAttr("materialBind")
        subset.CreateIndicesAttr(_ints(np.sort(faces)))
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
    if groups:
        UsdGeom.Subset.SetFamilyType(geom, "materialBind", UsdGeom.Tokens.nonOverlapping)


def write_render_mesh_layer(
    path: str | Path, mesh, points: np.ndarray, *, fps: float, name: str = "RenderMesh"
) -> Path:
    """Write a render mesh's animation as its own USD layer (module docstring).

    Args:
        path: ``.usdc`` or ``.usda``.
        mesh: the ``wface.mesh.meshfile.SurfaceMesh`` (topology, UVs, groups, meters_per_unit).
        points: (T, n, 3) vertex positions per frame in the mesh file's frame and units.
        fps: frame rate (timeCodesPerSecond).
        name: the default prim's name.

    Returns:
        The path written.
    """
    from pxr import Sdf, Usd, UsdGeom

    path = Path(path)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[1:] != (mesh.n_points, 3):
        raise ValueError(f"points must have shape (frames, {mesh.n_points}, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("render mesh points contain NaN or inf")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, float(mesh.meters_per_unit))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(float(len(pts) - 1))
    root = f"/{Sdf.Path.IsValidIdentifier(name) and name or 'RenderMesh'}"
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, root).GetPrim())
    geom = UsdGeom.Mesh.Define(stage, f"{root}/Mesh")
    geom.CreateFaceVertexCountsAttr(_ints(mesh.face_vertex_counts))
    geom.CreateFaceVertexIndicesAttr(_ints(mesh.face_vertex_indices))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    tri, _ = mesh.triangles()
    p_attr, n_attr, e_attr = geom.CreatePointsAttr(), geom.CreateNormalsAttr(), geom.CreateExtentAttr()
    geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    for f, p in enumerate(pts):
        p_attr.Set(_vec3f(p), float(f))
        n_attr.Set(_vec3f(vertex_normals(p, tri)), float(f))
        e_attr.Set(_vec3f(np.stack([p.min(axis=0), p.max(axis=0)])), float(f))
    if mesh.uv is not None and mesh.uv_indices is not None:
        st = UsdGeom.PrimvarsAPI(geom.GetPrim()).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
        )
        from pxr import Vt

        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(mesh.uv, dtype=np.float32)))
        st.SetIndices(_ints(mesh.uv_indices))
    _materials(stage, geom.GetPrim(), root, mesh.face_groups)
    stage.GetRootLayer().customLayerData = {"wface": {"kind": "render_mesh", "source": str(mesh.source)}}
    stage.GetRootLayer().Save()
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
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.Open(str(stage_path))
    xf = UsdGeom.Xform.Define(stage, f"/{root}/RenderMesh")
    rel = os.path.relpath(Path(layer_path).resolve(), Path(stage_path).resolve().parent)
    xf.GetPrim().GetReferences().AddReference(Path(rel).as_posix())
    m = np.asarray(source_to_model, dtype=np.float64)
    xf.AddTransformOp().Set(Gf.Matrix4d(m.T.tolist()))  # USD multiplies row vectors: the transpose
    stage.GetRootLayer().Save()
