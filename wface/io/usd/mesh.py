"""One polygon mesh, static or animated, as a USD stage; a ``wface.mesh.meshfile.SurfaceMesh`` in its own units."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.files import save_layer
from wface.io.usd._common import (
    UsdWriteError,
    _as_points,
    _check_path,
    _identifier,
    _new_stage,
    _vt_vec3f,
    _write_mesh,
    as_polygons,
)
from wface.mesh.materials import material_appearance

__all__ = ["write_mesh_animation", "write_surface_mesh"]


def write_mesh_animation(
    path: str | Path,
    *,
    points_m: np.ndarray,
    face_vertex_counts: np.ndarray | None,
    face_vertex_indices: np.ndarray,
    fps: float = 60.0,
    name: str = "Face",
    up_axis: str = "Y",
    colors: np.ndarray | None = None,
    frames: np.ndarray | None = None,
    meters_per_unit: float = 1.0,
    uv: np.ndarray | None = None,
    uv_indices: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    normal_indices: np.ndarray | None = None,
    material_faces: dict[str, np.ndarray] | None = None,
    material_colors: dict | None = None,
) -> Path:
    """Write one polygon mesh, static or animated, to a new USD stage.

    The stage's default prim is ``/<name>`` (an Xform) with the mesh at ``/<name>/Mesh``.
    Topology is written once; points and extent are time-sampled when ``points_m`` is 3-D
    (frame ``f`` at time code ``f``).

    Args:
        path: output file; ``.usda`` writes text, ``.usdc`` / ``.usd`` binary crate.
        points_m: (n, 3) static or (F, n, 3) per-frame vertex positions in metres.
        face_vertex_counts: (p,) vertices per face, or None when ``face_vertex_indices`` holds
            triangles (t, 3).
        face_vertex_indices: flat USD face vertex indices, or (t, 3) triangles.
        fps: frames per second (the stage's timeCodesPerSecond).
        name: name of the root prim (a valid USD identifier).
        up_axis: "Y" (default, wface's convention) or "Z": the root prim then gets a rotateX(90)
            op so that the model's +y points along world +z (points are written unchanged).
        colors: optional displayColor: (3,) constant, (n, 3) per vertex or (F, n, 3) per vertex
            and frame; linear RGB in [0, 1].
        frames: (F,) frame numbers written as the time codes (default 0..F-1).
        meters_per_unit: the stage's unit (e.g. 0.01 for a centimetre source mesh); points are
            written as ``points_m / meters_per_unit``.
        uv / uv_indices: (k, 2) texture coordinates and one index per face corner: ``primvars:st``,
            face-varying, indexed.
        normals / normal_indices: (j, 3) normals and one index per face corner (face-varying).
        material_faces: {material name: polygon indices}: one ``GeomSubset`` per material (family
            "materialBind") bound to a ``UsdPreviewSurface`` material of that name under
            ``/<name>/Materials``.
        material_colors: {material name: (3,) diffuse colour} for those materials (default: from the
            name, ``wface.mesh.materials``).

    Returns:
        The path written.

    Raises:
        UsdWriteError: wrong shapes, NaN/inf, out-of-range indices or a bad suffix.
    """
    path = _check_path(path)
    if not (np.isfinite(meters_per_unit) and meters_per_unit > 0):
        raise UsdWriteError(f"meters_per_unit must be positive, got {meters_per_unit}")
    p = _as_points(points_m) / meters_per_unit
    counts, indices = as_polygons(face_vertex_counts, face_vertex_indices, p.shape[-2])
    n_frames = p.shape[0] if p.ndim == 3 else 1
    stage = _new_stage(
        path, fps=fps, n_frames=n_frames, up_axis=up_axis, root=name, time_codes=frames, meters_per_unit=meters_per_unit
    )
    times = None if p.ndim == 2 or frames is None else np.asarray(frames, dtype=float)
    mesh = _write_mesh(stage, f"/{name}/Mesh", p, counts, indices, colors=colors, times=times)
    _write_face_varying(mesh, "st", uv, uv_indices, indices.size, 2)
    if normals is not None:
        _write_face_varying(mesh, "normals", normals, normal_indices, indices.size, 3)
    if material_faces:
        _write_materials(stage, f"/{name}", mesh, material_faces, material_colors or {}, counts.size)
    save_layer(stage.GetRootLayer(), path)  # atomic: a temporary file renamed into place
    return path


def write_surface_mesh(
    path: str | Path, mesh, *, frames_m: np.ndarray | None = None, fps: float = 24.0, name: str = "Surface"
) -> Path:
    """Write a ``SurfaceMesh`` (or its animation) keeping what the source has: points in the source's
    units with ``metersPerUnit`` to match, UVs (``primvars:st``, face-varying, indexed), the source
    normals (static only: a posed frame's normals are its own), one material subset per group with
    the ``.mtl`` colours.

    Args:
        path: ``.usda`` / ``.usdc`` / ``.usd``.
        mesh: the ``wface.mesh.meshfile.SurfaceMesh``.
        frames_m: (F, n, 3) vertex positions per frame in metres, or None for the mesh itself.
        fps: frames per second.
        name: the root prim's name (``/<name>/Mesh``).

    Returns:
        The path written.
    """
    points = mesh.points_m if frames_m is None else np.asarray(frames_m, dtype=np.float64)
    static = frames_m is None
    return write_mesh_animation(
        path,
        points_m=points,
        face_vertex_counts=mesh.face_vertex_counts,
        face_vertex_indices=mesh.face_vertex_indices,
        fps=fps,
        name=name,
        meters_per_unit=mesh.meters_per_unit,
        uv=mesh.uv,
        uv_indices=mesh.uv_indices,
        normals=mesh.normals if static else None,
        normal_indices=mesh.normal_indices if static else None,
        material_faces=mesh.face_groups or None,
        material_colors=mesh.material_colors,
    )


def _write_face_varying(mesh, primvar: str, values, corner_indices, n_corners: int, width: int) -> None:
    """An indexed face-varying primvar (``st``: texture coordinates; ``normals``)."""
    from pxr import Sdf, UsdGeom, Vt

    if values is None:
        return
    v = np.asarray(values, dtype=np.float32).reshape(-1, width)
    i = np.asarray(corner_indices, dtype=np.int32).reshape(-1)
    if i.size != n_corners or (i.size and (i.min() < 0 or i.max() >= len(v))):
        raise UsdWriteError(f"{primvar}: one index per face corner ({n_corners}) into {len(v)} values is needed")
    kind = Sdf.ValueTypeNames.TexCoord2fArray if width == 2 else Sdf.ValueTypeNames.Normal3fArray
    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim()).CreatePrimvar(primvar, kind, UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray.FromNumpy(v) if width == 2 else _vt_vec3f(v))
    pv.SetIndices(Vt.IntArray.FromNumpy(i))


def _write_materials(stage, root: str, mesh, material_faces: dict, colors: dict, n_faces: int) -> None:
    """One GeomSubset per material, bound to a UsdPreviewSurface material of the same name: the colour
    given in ``colors``, else the one its name suggests, and opacity 0 for overlays such as an eye
    occlusion shell (``wface.mesh.materials``)."""
    from pxr import Gf, Sdf, UsdShade

    idents = _bind_material_subsets(mesh, material_faces, f"{root}/Materials", n_faces)
    for name, ident in idents.items():
        material = UsdShade.Material.Define(stage, f"{root}/Materials/{ident}")
        shader = UsdShade.Shader.Define(stage, f"{root}/Materials/{ident}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        look = material_appearance(name, colors.get(name))
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*look.rgb))
        if look.opacity < 1.0:
            shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(look.opacity)
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")


def _bind_material_subsets(mesh, material_faces: dict, materials_root: str, n_faces: int) -> dict[str, str]:
    """One GeomSubset (family "materialBind") per material of ``mesh``, bound by path to the material
    ``materials_root/<identifier of its name>``, which may be authored later or in another layer (the
    rig's copy of a render mesh binds to the render mesh layer's materials). A subset whose name is
    taken by a child of ``mesh`` (a blend shape) gets a suffix; its binding does not change. Returns
    {material name: its identifier under ``materials_root``}."""
    from pxr import Sdf, UsdGeom, UsdShade, Vt

    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    taken: set[str] = set()
    children = {c.GetName() for c in mesh.GetPrim().GetChildren()}
    idents = {}
    for name, faces in material_faces.items():
        ident = _identifier(name, taken)
        f = np.asarray(faces, dtype=np.int32).reshape(-1)
        if f.size and (f.min() < 0 or f.max() >= n_faces):
            raise UsdWriteError(f"material {name!r}: face indices outside [0, {n_faces})")
        subset = UsdGeom.Subset.Define(
            mesh.GetPrim().GetStage(), mesh.GetPath().AppendChild(_identifier(ident, children))
        )
        subset.CreateElementTypeAttr(UsdGeom.Tokens.face)
        subset.CreateFamilyNameAttr(UsdShade.Tokens.materialBind)
        subset.CreateIndicesAttr(Vt.IntArray.FromNumpy(f))
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim())
        subset.GetPrim().CreateRelationship("material:binding", False).SetTargets(
            [Sdf.Path(f"{materials_root}/{ident}")]
        )
        idents[name] = ident
    UsdGeom.Subset.SetFamilyType(mesh, UsdShade.Tokens.materialBind, UsdGeom.Tokens.nonOverlapping)
    return idents
