"""Shared pieces of the USD writers: errors, checks, Vt conversions, stage creation, meshes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["UsdWriteError", "affine_to_matrix4d", "as_polygons"]


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
        raise UsdWriteError(
            f"face_vertex_counts sum to {int(counts.sum())} but there are {idx.size} face vertex indices"
        )
    if idx.size and (idx.min() < 0 or idx.max() >= n_points):
        raise UsdWriteError(
            f"face_vertex_indices reference points outside [0, {n_points}) (range {idx.min()}..{idx.max()})"
        )
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


def _time_codes(frames, n_frames: int) -> np.ndarray:
    """(F,) float time codes of the frames: the frame numbers given (the capture's), else 0..F-1.

    Raises:
        UsdWriteError: wrong length, or numbers that are not finite and strictly increasing.
    """
    if frames is None:
        return np.arange(n_frames, dtype=np.float64)
    tc = np.asarray(frames, dtype=np.float64).reshape(-1)
    if tc.shape != (n_frames,):
        raise UsdWriteError(f"frames must hold one number per frame ({n_frames}); got {tc.shape[0]}")
    if not np.all(np.isfinite(tc)) or np.any(np.diff(tc) <= 0):
        raise UsdWriteError("frames must be finite and strictly increasing (the capture's frame numbers)")
    return tc


def _new_stage(
    path: Path,
    *,
    fps: float,
    n_frames: int,
    up_axis: str,
    root: str,
    root_type: str = "Xform",
    time_codes: np.ndarray | None = None,
    meters_per_unit: float = 1.0,
):
    """Create a stage (replacing any file there) with wface's metadata and a root prim (the default prim).

    ``time_codes`` (F,) are the frames' time codes (default 0..F-1): start/end time codes are the
    first and last, and the layer's customLayerData["wface"]["first_frame"] the first.
    """
    from pxr import Sdf, Usd, UsdGeom, UsdSkel

    if not (np.isfinite(fps) and fps > 0):
        raise UsdWriteError(f"fps must be a positive number, got {fps}")
    if up_axis not in ("Y", "Z"):
        raise UsdWriteError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
    if not Sdf.Path.IsValidIdentifier(root):
        raise UsdWriteError(f"prim name {root!r} is not a valid USD identifier")
    path.parent.mkdir(parents=True, exist_ok=True)
    layer = None
    if path.exists():
        try:
            layer = Sdf.Layer.FindOrOpen(str(path))
        except Exception:  # noqa: BLE001 - an unreadable old file is simply replaced
            layer = None
        if layer is None:
            path.unlink()
    if layer is not None:
        layer.Clear()
        stage = Usd.Stage.Open(layer)
    else:
        stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    tc = (
        _time_codes(time_codes, max(n_frames, 1))
        if time_codes is not None
        else np.arange(max(n_frames, 1), dtype=float)
    )
    stage.SetStartTimeCode(float(tc[0]))
    stage.SetEndTimeCode(float(tc[-1]))
    first = int(tc[0]) if float(tc[0]).is_integer() else float(tc[0])
    stage.GetRootLayer().customLayerData = {"wface": {"first_frame": first}}
    schema = UsdSkel.Root if root_type == "SkelRoot" else UsdGeom.Xform
    root_xf = schema.Define(stage, f"/{root}")
    if up_axis == "Z":  # data stay +y up; the root turns them so that world +z is up (front: -y)
        UsdGeom.Xformable(root_xf.GetPrim()).AddRotateXOp().Set(90.0)
    stage.SetDefaultPrim(root_xf.GetPrim())
    return stage


def _write_mesh(stage, prim_path: str, points: np.ndarray, counts, indices, colors=None, *, times=None, normals=None):
    """Author a UsdGeom.Mesh: topology once; points and extent static (n,3) or per frame (F,n,3).

    ``times``: (F,) time codes of the frames (default 0..F-1). ``normals``: (n, 3) or (F, n, 3)
    unit vertex normals (``normals`` attribute, vertex interpolation), or None.
    """
    from pxr import UsdGeom

    times = np.arange(points.shape[0], dtype=float) if points.ndim == 3 and times is None else times

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
        for t, p in zip(times, points, strict=True):
            pts_attr.Set(_vt_vec3f(p), float(t))
            ext_attr.Set(_vt_vec3f(_extent(p)), float(t))
    if normals is not None:
        n_attr = mesh.CreateNormalsAttr()
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        if normals.ndim == 2:
            n_attr.Set(_vt_vec3f(normals))
        else:
            for t, n in zip(times, normals, strict=True):
                n_attr.Set(_vt_vec3f(n), float(t))
    if colors is not None:
        _set_display_color(
            mesh,
            colors,
            n_points=points.shape[-2],
            n_frames=points.shape[0] if points.ndim == 3 else None,
            times=times,
        )
    return mesh


def _set_display_color(gprim, colors, *, n_points: int, n_frames: int | None, times=None) -> None:
    """displayColor: (3,) constant, (n,3) per vertex, or (F,n,3) per vertex per frame (at ``times``)."""
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
        times = np.arange(len(c), dtype=float) if times is None else times
        for t, cf in zip(times, c, strict=True):
            pv.Set(_vt_vec3f(cf), float(t))
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


# ---------------------------------------------------------------------- names and small writers
def _identifier(name: str, taken: set[str]) -> str:
    """A valid, unique USD identifier for ``name`` (adds it to ``taken``)."""
    from pxr import Tf

    name = str(name)
    base = Tf.MakeValidIdentifier("_" + name if name[:1].isdigit() else name) or "_"  # keep a leading digit
    ident, k = base, 1
    while ident in taken:
        ident, k = f"{base}_{k}", k + 1
    taken.add(ident)
    return ident


def affine_to_matrix4d(affine: np.ndarray):
    """A 3x4 affine ``[A | t]`` (x' = A x + t, column vectors) as USD's row-vector Gf.Matrix4d."""
    from pxr import Gf

    a = np.asarray(affine, dtype=np.float64)
    m = np.eye(4)
    m[:3, :3] = a[:, :3].T
    m[3, :3] = a[:, 3]
    return Gf.Matrix4d(m.tolist())


def _check_frames(name: str, a, n_frames: int, tail: tuple, *, allow_nan: bool = False) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    want = (n_frames, *tail)
    ok = arr.ndim == len(want) and all(w is None or s == w for s, w in zip(arr.shape, want, strict=False))
    if not ok:
        shown = ", ".join("k" if w is None else str(w) for w in want)
        raise UsdWriteError(f"{name} must have shape ({shown}) (frames first, like node_positions_m); got {arr.shape}")
    if allow_nan:
        if np.any(np.isinf(arr)):
            raise UsdWriteError(f"{name} contains inf (use NaN for a missing value)")
    else:
        _check_finite(name, arr)
    return arr


def _write_float_primvar(gprim, name: str, values: np.ndarray, interpolation: str, *, times=None) -> None:
    from pxr import Sdf, UsdGeom

    pv = UsdGeom.PrimvarsAPI(gprim.GetPrim()).CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray, interpolation)
    if values.ndim == 1:
        pv.Set(_vt_float(values))
    else:
        times = np.arange(len(values), dtype=float) if times is None else times
        for t, v in zip(times, values, strict=True):
            pv.Set(_vt_float(v), float(t))


def _set_layer_info(stage, info: dict) -> None:
    """Merge ``info`` into the root layer's customLayerData["wface"] (JSON-safe values)."""
    data = dict(stage.GetRootLayer().customLayerData)
    merged = dict(data.get("wface", {}))
    merged.update({str(k): _json_safe(v) for k, v in info.items()})
    data["wface"] = merged
    stage.GetRootLayer().customLayerData = data


def _json_safe(v):

    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, np.generic):
        return v.item()
    return json.dumps(v, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
