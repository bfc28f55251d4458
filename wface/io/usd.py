"""USD output for DCC tools (Blender, Houdini, usdview): meshes, takes, bases, validation.

Stages are written with usd-core (``pxr``), imported inside the functions that need it. Every
stage says its units and axes in its metadata: ``metersPerUnit = 1`` (positions are metres, as
everywhere in wface), ``upAxis`` (``"Y"`` by default, matching the model's +y up),
``timeCodesPerSecond`` = the capture rate, and start/end time codes covering the frames. Frame
``f`` of an animation is written at time code ``f`` (0-based).

The path's suffix picks the format: ``.usdc`` (binary crate, the default for ``.usd`` too) or
``.usda`` (text, diff-able).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "UsdWriteError",
    "as_polygons",
    "write_mesh_animation",
]


class UsdWriteError(ValueError):
    """Inputs to a USD writer are inconsistent; the message names the problem."""


_SUFFIXES = (".usda", ".usdc", ".usd")


# ---------------------------------------------------------------------- small checks
def _check_finite(name: str, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))
        raise UsdWriteError(f"{name} contains NaN/inf ({len(bad)} value(s), first at index {tuple(bad[0].tolist())})")


def _check_path(path: str | Path) -> Path:
    path = Path(path)
    if path.suffix not in _SUFFIXES:
        raise UsdWriteError(f"USD path must end in one of {_SUFFIXES}, got {path.name!r}")
    return path


def as_polygons(
    face_vertex_counts: np.ndarray | None, face_vertex_indices: np.ndarray, n_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """Normalise polygon topology to USD's flat arrays and check it.

    Args:
        face_vertex_counts: (p,) vertices per face, or None when ``face_vertex_indices`` is a
            triangle array (t, 3).
        face_vertex_indices: flat (sum(counts),) vertex ids, or (t, 3) triangles.
        n_points: number of points the ids index.

    Returns:
        ``(counts, indices)`` as int32 1-D arrays.
    """
    idx = np.asarray(face_vertex_indices)
    if face_vertex_counts is None:
        if idx.ndim != 2 or idx.shape[1] != 3:
            raise UsdWriteError(
                f"face_vertex_counts is None, so face_vertex_indices must be triangles (t, 3); got shape {idx.shape}"
            )
        counts = np.full(idx.shape[0], 3, dtype=np.int32)
    else:
        counts = np.asarray(face_vertex_counts).astype(np.int32).reshape(-1)
        if np.any(counts < 3):
            raise UsdWriteError(f"face_vertex_counts must be >= 3 (found {int(counts.min())})")
    idx = idx.astype(np.int64).reshape(-1)
    if int(counts.sum()) != idx.size:
        raise UsdWriteError(f"face_vertex_counts sum to {int(counts.sum())} but there are {idx.size} face vertex indices")
    if idx.size and (idx.min() < 0 or idx.max() >= n_points):
        raise UsdWriteError(f"face_vertex_indices reference points outside [0, {n_points}) (range {idx.min()}..{idx.max()})")
    return counts, idx.astype(np.int32)


def _extent(points: np.ndarray) -> np.ndarray:
    return np.stack([points.min(axis=0), points.max(axis=0)])


def _vt_vec3f(a: np.ndarray):
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _vt_int(a: np.ndarray):
    from pxr import Vt

    return Vt.IntArray.FromNumpy(np.ascontiguousarray(a, dtype=np.int32))


def _vt_float(a: np.ndarray):
    from pxr import Vt

    return Vt.FloatArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _new_stage(path: Path, *, fps: float, n_frames: int, up_axis: str, root: str):
    """Create a stage (replacing any file there) with wface's metadata and a root Xform."""
    from pxr import Sdf, Usd, UsdGeom

    if not (np.isfinite(fps) and fps > 0):
        raise UsdWriteError(f"fps must be a positive number, got {fps}")
    if up_axis not in ("Y", "Z"):
        raise UsdWriteError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
    if not Sdf.Path.IsValidIdentifier(root):
        raise UsdWriteError(f"prim name {root!r} is not a valid USD identifier")
    path.parent.mkdir(parents=True, exist_ok=True)
    layer = Sdf.Layer.FindOrOpen(str(path)) if path.exists() else None
    if layer is not None:
        layer.Clear()
        stage = Usd.Stage.Open(layer)
    else:
        stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(float(max(n_frames - 1, 0)))
    root_prim = UsdGeom.Xform.Define(stage, f"/{root}").GetPrim()
    stage.SetDefaultPrim(root_prim)
    return stage


def _write_mesh(stage, prim_path: str, points: np.ndarray, counts, indices, colors=None):
    """Author a UsdGeom.Mesh: topology once; points and extent static (n,3) or per frame (F,n,3)."""
    from pxr import Sdf, UsdGeom

    mesh = UsdGeom.Mesh.Define(stage, prim_path)
    mesh.CreateFaceVertexCountsAttr(_vt_int(counts))
    mesh.CreateFaceVertexIndicesAttr(_vt_int(indices))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    pts_attr, ext_attr = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
    if points.ndim == 2:
        pts_attr.Set(_vt_vec3f(points))
        ext_attr.Set(_vt_vec3f(_extent(points)))
    else:
        for f, p in enumerate(points):
            pts_attr.Set(_vt_vec3f(p), float(f))
            ext_attr.Set(_vt_vec3f(_extent(p)), float(f))
    if colors is not None:
        _set_display_color(mesh, colors, n_points=points.shape[-2], n_frames=points.shape[0] if points.ndim == 3 else None)
    del Sdf
    return mesh


def _set_display_color(gprim, colors, *, n_points: int, n_frames: int | None) -> None:
    """displayColor: (3,) constant, (n,3) per vertex, or (F,n,3) per vertex per frame."""
    from pxr import UsdGeom

    c = np.asarray(colors, dtype=np.float64)
    _check_finite("colors", c)
    pv = gprim.CreateDisplayColorPrimvar()
    if c.shape == (3,):
        pv.SetInterpolation(UsdGeom.Tokens.constant)
        pv.Set(_vt_vec3f(c[None]))
    elif c.shape == (n_points, 3):
        pv.SetInterpolation(UsdGeom.Tokens.vertex)
        pv.Set(_vt_vec3f(c))
    elif c.ndim == 3 and c.shape[1:] == (n_points, 3) and n_frames is not None and c.shape[0] == n_frames:
        pv.SetInterpolation(UsdGeom.Tokens.vertex)
        for f, cf in enumerate(c):
            pv.Set(_vt_vec3f(cf), float(f))
    else:
        raise UsdWriteError(
            f"colors must have shape (3,), ({n_points}, 3) or (frames, {n_points}, 3) with frames = {n_frames}; "
            f"got {c.shape}"
        )


def _as_points(points_m, label: str = "points_m") -> np.ndarray:
    p = np.asarray(points_m, dtype=np.float64)
    if not (p.ndim in (2, 3) and p.shape[-1] == 3 and p.shape[-2] > 0 and (p.ndim == 2 or p.shape[0] > 0)):
        raise UsdWriteError(f"{label} must have shape (n, 3) or (frames, n, 3) with n > 0; got {p.shape}")
    _check_finite(label, p)
    return p


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
        up_axis: "Y" (default, wface's convention) or "Z". Only metadata: points are not rotated.
        colors: optional displayColor: (3,) constant, (n, 3) per vertex or (F, n, 3) per vertex
            and frame; linear RGB in [0, 1].

    Returns:
        The path written.

    Raises:
        UsdWriteError: wrong shapes, NaN/inf, out-of-range indices or a bad suffix.
    """
    path = _check_path(path)
    p = _as_points(points_m)
    counts, indices = as_polygons(face_vertex_counts, face_vertex_indices, p.shape[-2])
    n_frames = p.shape[0] if p.ndim == 3 else 1
    stage = _new_stage(path, fps=fps, n_frames=n_frames, up_axis=up_axis, root=name)
    _write_mesh(stage, f"/{name}/Mesh", p, counts, indices, colors=colors)
    stage.GetRootLayer().Save()
    return path
