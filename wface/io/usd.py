"""USD output for DCC tools (Blender, Houdini, usdview): meshes, takes, bases, validation.

Stages are written with usd-core (``pxr``), imported inside the functions that need it. Every
stage says its units and axes in its metadata: ``metersPerUnit = 1`` (positions are metres, as
everywhere in wface), ``upAxis`` (``"Y"`` by default, matching the model's +y up),
``timeCodesPerSecond`` = the capture rate, and start/end time codes covering the frames. Frame
``f`` of an animation is written at time code ``f`` (0-based).

With ``up_axis="Z"`` the data stay as they are and the root prim gets a rotateX(90) op, so the
model's +y points up in a Z-up world.

The path's suffix picks the format: ``.usdc`` (binary crate, the default for ``.usd`` too) or
``.usda`` (text, diff-able).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "BlendShapeBasis",
    "UsdValidationFailed",
    "UsdWriteError",
    "affine_to_matrix4d",
    "as_polygons",
    "assert_stage_valid",
    "blendshape_points",
    "check_extents",
    "compare_stages",
    "validate_stage",
    "write_blendshape_basis",
    "write_mesh_animation",
    "write_take",
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


def _new_stage(path: Path, *, fps: float, n_frames: int, up_axis: str, root: str, root_type: str = "Xform"):
    """Create a stage (replacing any file there) with wface's metadata and a root prim (the default prim)."""
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
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(float(max(n_frames - 1, 0)))
    schema = UsdSkel.Root if root_type == "SkelRoot" else UsdGeom.Xform
    root_xf = schema.Define(stage, f"/{root}")
    if up_axis == "Z":  # data stay +y up; the root turns them so that world +z is up (front: -y)
        UsdGeom.Xformable(root_xf.GetPrim()).AddRotateXOp().Set(90.0)
    stage.SetDefaultPrim(root_xf.GetPrim())
    return stage


def _write_mesh(stage, prim_path: str, points: np.ndarray, counts, indices, colors=None):
    """Author a UsdGeom.Mesh: topology once; points and extent static (n,3) or per frame (F,n,3)."""
    from pxr import UsdGeom

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
        _set_display_color(
            mesh, colors, n_points=points.shape[-2], n_frames=points.shape[0] if points.ndim == 3 else None
        )
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
        up_axis: "Y" (default, wface's convention) or "Z": the root prim then gets a rotateX(90)
            op so that the model's +y points along world +z (points are written unchanged).
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


# ---------------------------------------------------------------------- names and small writers
def _identifier(name: str, taken: set[str]) -> str:
    """A valid, unique USD identifier for ``name`` (adds it to ``taken``)."""
    from pxr import Tf

    base = Tf.MakeValidIdentifier(str(name)) or "_"
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


def _write_float_primvar(gprim, name: str, values: np.ndarray, interpolation: str) -> None:
    from pxr import Sdf, UsdGeom

    pv = UsdGeom.PrimvarsAPI(gprim.GetPrim()).CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray, interpolation)
    if values.ndim == 1:
        pv.Set(_vt_float(values))
    else:
        for f, v in enumerate(values):
            pv.Set(_vt_float(v), float(f))


# ---------------------------------------------------------------------- blend shapes (UsdSkel)
class BlendShapeBasis:
    """A linear actuation basis E = E0 + sum_i x_i e_i (seed 003) to write as UsdSkel blend shapes.

    Args:
        neutral_m: (n, 3) rest shape E0 in metres.
        deltas_m: (B, n, 3) basis displacements e_i in metres.
        names: B names (made into unique USD identifiers on write); default ``shape_<i>``.
    """

    def __init__(self, neutral_m: np.ndarray, deltas_m: np.ndarray, names: list[str] | None = None):
        self.neutral_m = _as_points(neutral_m, "neutral_m")
        if self.neutral_m.ndim != 2:
            raise UsdWriteError(f"neutral_m must have shape (n, 3); got {self.neutral_m.shape}")
        n = self.neutral_m.shape[0]
        d = np.asarray(deltas_m, dtype=np.float64)
        if d.ndim != 3 or d.shape[1:] != (n, 3):
            raise UsdWriteError(f"deltas_m must have shape (B, {n}, 3) like neutral_m (n = {n}); got {d.shape}")
        _check_finite("deltas_m", d)
        self.deltas_m = d
        self.names = [f"shape_{i}" for i in range(d.shape[0])] if names is None else [str(s) for s in names]
        if len(self.names) != d.shape[0]:
            raise UsdWriteError(f"{len(self.names)} basis names for {d.shape[0]} deltas")

    @property
    def n_shapes(self) -> int:
        return int(self.deltas_m.shape[0])

    def synthesize(self, weights: np.ndarray) -> np.ndarray:
        """E0 + sum_i x_i e_i for weights (B,) -> (n, 3) or (F, B) -> (F, n, 3)."""
        return self.neutral_m + np.tensordot(np.asarray(weights, dtype=np.float64), self.deltas_m, axes=(-1, 0))

    def restricted(self, vertices: np.ndarray) -> BlendShapeBasis:
        """The basis on a subset of its vertices (e.g. the skin nodes of a volumetric model)."""
        return BlendShapeBasis(self.neutral_m[vertices], self.deltas_m[:, vertices], self.names)


def _write_blendshapes(
    stage,
    root_path: str,
    basis: BlendShapeBasis,
    weights: np.ndarray | None,
    counts,
    indices,
    *,
    sparse_tol_m: float = 0.0,
):
    """SkelRoot with a one-joint Skeleton, a SkelAnimation (blendShapeWeights per frame) and a bound Mesh.

    What Blender's USD importer needs is here: the Skeleton's ``skel:animationSource`` names the
    SkelAnimation; the mesh has SkelBindingAPI, ``skel:skeleton``, and ``skel:blendShapes`` /
    ``skel:blendShapeTargets`` of equal length; the animation's ``blendShapes`` tokens match.
    """
    from pxr import Gf, UsdGeom, UsdSkel, Vt

    root = UsdSkel.Root.Define(stage, root_path)
    skel = UsdSkel.Skeleton.Define(stage, f"{root_path}/Skel")
    skel.CreateJointsAttr(Vt.TokenArray(["root"]))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0)]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0)]))
    anim = UsdSkel.Animation.Define(stage, f"{root_path}/Skel/Anim")
    anim.CreateJointsAttr(Vt.TokenArray(["root"]))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(0.0)]))
    anim.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(1.0)]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0)]))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])

    mesh = _write_mesh(stage, f"{root_path}/Mesh", basis.neutral_m, counts, indices)
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(constant=True, elementSize=1).Set(Vt.IntArray([0]))
    binding.CreateJointWeightsPrimvar(constant=True, elementSize=1).Set(Vt.FloatArray([1.0]))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))

    taken: set[str] = set()
    tokens, targets = [], []
    for name, delta in zip(basis.names, basis.deltas_m, strict=True):
        ident = _identifier(name, taken)
        shape = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(ident))
        moved = np.flatnonzero(np.max(np.abs(delta), axis=1) > sparse_tol_m)
        shape.CreateOffsetsAttr(_vt_vec3f(delta[moved]))
        shape.CreatePointIndicesAttr(_vt_int(moved))
        tokens.append(ident)
        targets.append(shape.GetPath())
    binding.CreateBlendShapesAttr(Vt.TokenArray(tokens))
    binding.CreateBlendShapeTargetsRel().SetTargets(targets)
    anim.CreateBlendShapesAttr(Vt.TokenArray(tokens))
    w_attr = anim.CreateBlendShapeWeightsAttr()
    if weights is None:
        w_attr.Set(_vt_float(np.zeros(basis.n_shapes)))
    else:
        for f, w in enumerate(weights):
            w_attr.Set(_vt_float(w), float(f))
    # The skinned points move with the weights: give the SkelRoot a bound over all frames.
    if weights is not None and len(weights):
        all_pts = basis.synthesize(weights).reshape(-1, 3)
        all_pts = np.concatenate([all_pts, basis.neutral_m])
    else:
        all_pts = basis.neutral_m
    UsdGeom.ModelAPI.Apply(root.GetPrim()).SetExtentsHint(_vt_vec3f(_extent(all_pts)))
    return root


def write_blendshape_basis(
    path: str | Path,
    *,
    basis: BlendShapeBasis,
    face_vertex_counts: np.ndarray | None,
    face_vertex_indices: np.ndarray,
    weights: np.ndarray | None = None,
    fps: float = 60.0,
    name: str = "Face",
    up_axis: str = "Y",
) -> Path:
    """Write an actuation basis as UsdSkel blend shapes, optionally animated by per-frame weights.

    Layout: ``/<name>`` (SkelRoot, default prim) with ``Skel`` (Skeleton, one identity joint),
    ``Skel/Anim`` (SkelAnimation with ``blendShapes`` and time-sampled ``blendShapeWeights``) and
    ``Mesh`` (the neutral E0, SkelBindingAPI) whose BlendShape children hold the sparse offsets
    e_i. A DCC tool (Blender, usdview, Maya) then shows E0 + sum_i x_i e_i per frame.

    Args:
        path: ``.usda`` or ``.usdc`` file.
        basis: neutral shape, deltas and names.
        face_vertex_counts / face_vertex_indices: mesh topology (see ``write_mesh_animation``).
        weights: (F, B) per-frame weights x_i; None writes static zero weights (the neutral).
        fps: frames per second.
        name: root prim name.
        up_axis: "Y" or "Z" (see ``write_mesh_animation``).

    Returns:
        The path written.
    """
    path = _check_path(path)
    counts, indices = as_polygons(face_vertex_counts, face_vertex_indices, basis.neutral_m.shape[0])
    w = None if weights is None else _check_frames("weights", weights, np.asarray(weights).shape[0], (basis.n_shapes,))
    stage = _new_stage(
        path, fps=fps, n_frames=1 if w is None else len(w), up_axis=up_axis, root=name, root_type="SkelRoot"
    )
    _write_blendshapes(stage, f"/{name}", basis, w, counts, indices)
    stage.GetRootLayer().Save()
    return path


# ---------------------------------------------------------------------- a whole take
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
    activations: np.ndarray | None = None,
    basis: BlendShapeBasis | None = None,
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
    - ``Bones/Cranium`` and ``Bones/Jaw`` (Xforms with one time-sampled transform op from the
      per-frame affines) holding the model's ``bone_meshes`` at rest position.
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
        jaw_affines: (F, 3, 4) per-frame rest-to-world affine of the jaw (world, not relative
            to the cranium: the two Xforms are siblings).
        activations: (F, M) muscle activations (M = model.n_muscles), usually in [0, 1].
        basis: an actuation basis on the model's nodes (n) or on the compact skin vertices.
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
    from pxr import Sdf, UsdGeom, Vt

    from wface.viz.muscles import SKIN_RGB, activation_colors, skin_muscle_influence

    path = _check_path(path)
    x = np.asarray(node_positions_m, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (model.n_nodes, 3) or x.shape[0] == 0:
        raise UsdWriteError(
            f"node_positions_m must have shape (frames, {model.n_nodes}, 3) for this model; got {x.shape}"
        )
    _check_finite("node_positions_m", x)
    n_frames = x.shape[0]
    if model.skin_triangles.size == 0:
        raise UsdWriteError("model has no skin_triangles to write")
    skin_nodes = np.unique(model.skin_triangles)
    remap = np.full(model.n_nodes, -1, dtype=np.int64)
    remap[skin_nodes] = np.arange(skin_nodes.size)
    tri = remap[model.skin_triangles]
    counts, indices = as_polygons(None, tri, skin_nodes.size)

    act = None if activations is None else _check_frames("activations", activations, n_frames, (model.n_muscles,))
    markers = {}
    for label, arr, nan_ok in (("Captured", captured_markers_m, True), ("Simulated", simulated_markers_m, False)):
        if arr is not None:
            key = "captured_markers_m" if label == "Captured" else "simulated_markers_m"
            markers[label] = _check_frames(key, arr, n_frames, (None, 3), allow_nan=nan_ok)
    ks = {a.shape[1] for a in markers.values()}
    if len(ks) > 1:
        raise UsdWriteError(f"captured and simulated markers differ in count: {sorted(ks)}")
    affines = {}
    for label, arr in (("Cranium", cranium_affines), ("Jaw", jaw_affines)):
        if arr is not None:
            affines[label] = _check_frames(f"{label.lower()}_affines", arr, n_frames, (3, 4))
    if basis is not None:
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
    elif basis_weights is not None:
        raise UsdWriteError("basis_weights given without a basis")
    if not (np.isfinite(marker_radius_m) and marker_radius_m > 0):
        raise UsdWriteError(f"marker_radius_m must be positive, got {marker_radius_m}")

    stage = _new_stage(path, fps=fps, n_frames=n_frames, up_axis=up_axis, root=name)
    root = f"/{name}"
    info = {"kind": "take", "frames": int(n_frames), "nodes": int(model.n_nodes), "muscles": int(model.n_muscles)}
    info.update({str(k): _json_safe(v) for k, v in (metadata or {}).items()})
    stage.GetRootLayer().customLayerData = {"wface": info}

    skin = _write_mesh(stage, f"{root}/Skin", x[:, skin_nodes], counts, indices)
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

    if markers:
        UsdGeom.Scope.Define(stage, f"{root}/Markers")
        k = next(iter(markers.values())).shape[1]
        if marker_names is None:
            marker_names = list(model.marker_names) if len(model.marker_names) == k else [f"m{i}" for i in range(k)]
        if len(marker_names) != k:
            raise UsdWriteError(f"{len(marker_names)} marker names for {k} markers")
        colours = {"Captured": (0.9, 0.05, 0.05), "Simulated": (0.05, 0.8, 0.1)}
        for label, arr in markers.items():
            _write_points(
                stage, f"{root}/Markers/{label}", arr, radius_m=marker_radius_m, rgb=colours[label], names=marker_names
            )

    bone_groups: dict[str, list[tuple[str, object]]] = {"Cranium": [], "Jaw": []}
    for mesh_name, mesh in (model.bone_meshes if bone_meshes is None else bone_meshes).items():
        bone_groups["Jaw" if mesh.bone == "jaw" else "Cranium"].append((mesh_name, mesh))
    if any(bone_groups.values()) or affines:
        UsdGeom.Scope.Define(stage, f"{root}/Bones")
    bone_rgb = np.array([0.93, 0.91, 0.84])
    for label, meshes in bone_groups.items():
        if not meshes and label not in affines:
            continue
        xf = UsdGeom.Xform.Define(stage, f"{root}/Bones/{label}")
        if label in affines:
            op = xf.AddTransformOp()
            for f, a in enumerate(affines[label]):
                op.Set(affine_to_matrix4d(a), float(f))
        taken: set[str] = set()
        for mesh_name, mesh in meshes:
            ident = _identifier(mesh_name, taken)
            v = _as_points(mesh.vertices_m, f"bone mesh {mesh_name!r} vertices_m")
            c, i = as_polygons(None, np.asarray(mesh.triangles).reshape(-1, 3), v.shape[0])
            _write_mesh(stage, f"{root}/Bones/{label}/{ident}", v, c, i, colors=bone_rgb)

    if act is not None:
        muscles = UsdGeom.Scope.Define(stage, f"{root}/Muscles").GetPrim()
        muscles.CreateAttribute(
            "wface:muscleNames", Sdf.ValueTypeNames.StringArray, custom=True, variability=Sdf.VariabilityUniform
        ).Set(Vt.StringArray(list(model.muscle_names)))
        all_attr = muscles.CreateAttribute("wface:activations", Sdf.ValueTypeNames.FloatArray, custom=True)
        taken = set()
        per_muscle = []
        for m_name in model.muscle_names:
            ident = _identifier(m_name, taken)
            per_muscle.append(
                muscles.CreateAttribute(f"wface:activation:{ident}", Sdf.ValueTypeNames.Float, custom=True)
            )
        for f, a in enumerate(act):
            t = float(f)
            all_attr.Set(_vt_float(a), t)
            for attr, value in zip(per_muscle, a, strict=True):
                attr.Set(float(value), t)

    if basis is not None:
        _write_blendshapes(stage, f"{root}/Basis", basis, bw, counts, indices)
    stage.GetRootLayer().Save()
    return path


def _json_safe(v):
    import json

    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, np.generic):
        return v.item()
    return json.dumps(v, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


# ---------------------------------------------------------------------- validation
class UsdValidationFailed(AssertionError):
    """A stage failed a UsdValidation validator, the extent check, or the blend-shape check."""


def _open(stage_or_path):
    from pxr import Usd

    if isinstance(stage_or_path, (str, Path)):
        p = Path(stage_or_path)
        if not p.exists():
            raise FileNotFoundError(f"USD file not found: {p}")
        stage = Usd.Stage.Open(str(p))
        if stage is None:
            raise UsdValidationFailed(f"{p}: USD could not open it")
        return stage
    return stage_or_path


def validate_stage(stage_or_path, *, keywords: list[str] | None = None) -> list[str]:
    """Run USD's registered validators (``UsdValidation``) on a stage.

    Args:
        stage_or_path: a ``Usd.Stage`` or a file path.
        keywords: only validators with one of these keywords (e.g. ``["UsdGeomValidators"]``);
            default: every registered validator (usd-core >= 24.11).

    Returns:
        One line per error or warning: ``"<validator>: <message>"``; empty when the stage passes.
    """
    from pxr import UsdValidation

    stage = _open(stage_or_path)
    registry = UsdValidation.ValidationRegistry()
    if keywords is None:
        validators = registry.GetOrLoadAllValidators()
    else:
        names = [m.name for m in registry.GetValidatorMetadataForKeywords(keywords)]
        validators = registry.GetOrLoadValidatorsByName(names)
    if not validators:
        raise UsdValidationFailed("no USD validators are registered (usd-core too old?)")
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return [
        f"{e.GetName() or e.GetValidator().GetMetadata().name}: {e.GetErrorAsString()}"
        for e in errors
        if not e.HasNoError()
    ]


def _outside(p: np.ndarray, e: np.ndarray, rtol: float) -> float | None:
    """How far points p (n, 3) lie outside the box e (2, 3), or None when inside up to rtol x size."""
    tol = rtol * max(float(np.max(e[1] - e[0])), 1e-12)
    worst = max(float(np.max(e[0] - p)), float(np.max(p - e[1])))
    return worst if worst > tol else None


def check_extents(stage_or_path, *, rtol: float = 1e-6) -> list[str]:
    """Check that every authored extent contains its prim's points at each time sample.

    For each UsdGeom.PointBased prim with an authored extent, at the union of the time samples of
    ``points`` and ``extent`` (or the default time when neither is animated), the points must lie
    inside [min, max] up to ``rtol`` x the extent's size (float32 storage). For each SkelRoot with
    an ``extentsHint``, the blend-shape meshes under it, deformed by UsdSkel at every time sample
    of their animation's weights (``blendshape_points``), must lie inside the hint.

    Returns:
        One line per violation (prim, time, how far outside); empty when all is well.
    """
    from pxr import Usd, UsdGeom

    stage = _open(stage_or_path)
    problems = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.PointBased):
            continue
        geom = UsdGeom.PointBased(prim)
        ext_attr, pts_attr = geom.GetExtentAttr(), geom.GetPointsAttr()
        if not ext_attr.HasAuthoredValue():
            if pts_attr.HasAuthoredValue():
                problems.append(f"{prim.GetPath()}: points authored without an extent")
            continue
        times = sorted(set(pts_attr.GetTimeSamples()) | set(ext_attr.GetTimeSamples()))
        for t in times or [Usd.TimeCode.Default()]:
            pts = pts_attr.Get(t)
            ext = ext_attr.Get(t)
            if pts is None or len(pts) == 0:
                continue
            label = "default" if not times else f"{t:g}"
            if ext is None or len(ext) != 2:
                problems.append(f"{prim.GetPath()} at time {label}: extent missing or malformed")
                continue
            worst = _outside(np.asarray(pts, dtype=np.float64), np.asarray(ext, dtype=np.float64), rtol)
            if worst is not None:
                problems.append(f"{prim.GetPath()} at time {label}: points lie {worst:.3g} m outside the extent")
    problems += _check_skel_extents_hints(stage, rtol)
    return problems


def _check_skel_extents_hints(stage, rtol: float) -> list[str]:
    from pxr import Usd, UsdGeom, UsdSkel

    problems = []
    xf = UsdGeom.XformCache()
    for root in stage.Traverse():
        if not root.IsA(UsdSkel.Root):
            continue
        hint_attr = UsdGeom.ModelAPI(root).GetExtentsHintAttr()
        if not hint_attr.HasAuthoredValue():
            continue
        hint = np.asarray(hint_attr.Get(), dtype=np.float64)[:2]  # the default purpose's box
        for prim in Usd.PrimRange(root):
            if not (prim.IsA(UsdGeom.Mesh) and prim.HasAPI(UsdSkel.BindingAPI)):
                continue
            binding = UsdSkel.BindingAPI(prim)
            if not binding.GetBlendShapeTargetsRel().GetTargets():
                continue
            skel = binding.GetInheritedSkeleton()
            src = UsdSkel.BindingAPI(skel.GetPrim()).GetAnimationSourceRel().GetTargets() if skel else []
            anim = UsdSkel.Animation(stage.GetPrimAtPath(src[0])) if src else None
            times = anim.GetBlendShapeWeightsAttr().GetTimeSamples() if anim else []
            m = np.asarray(xf.ComputeRelativeTransform(prim, root)[0])
            for t in times or [Usd.TimeCode.Default().GetValue()]:
                pts = blendshape_points(stage, str(prim.GetPath()), t)
                worst = _outside(pts @ m[:3, :3] + m[3, :3], hint, rtol)
                if worst is not None:
                    problems.append(
                        f"{prim.GetPath()} at time {t:g}: blend-shape points lie {worst:.3g} m outside "
                        f"{root.GetPath()}.extentsHint"
                    )
    return problems


def blendshape_points(stage_or_path, mesh_path: str, time: float) -> np.ndarray:
    """Points of a blend-shape mesh at ``time`` as USD itself computes them (UsdSkel queries).

    Uses UsdSkel.Cache -> SkinningQuery -> the SkelAnimation's blendShapeWeights, remapped to the
    mesh's ``skel:blendShapes`` order, and UsdSkel.BlendShapeQuery.ComputeDeformedPoints.

    Returns:
        (n, 3) float64 deformed points (neutral + sum of weighted offsets).
    """
    from pxr import Usd, UsdSkel, Vt

    stage = _open(stage_or_path)
    prim = stage.GetPrimAtPath(mesh_path)
    if not prim:
        raise UsdValidationFailed(f"no prim at {mesh_path}")
    skel_root = UsdSkel.Root.Find(prim)
    if not skel_root:
        raise UsdValidationFailed(f"{mesh_path} is not under a SkelRoot")
    cache = UsdSkel.Cache()
    cache.Populate(skel_root, Usd.PrimDefaultPredicate)
    skinning = cache.GetSkinningQuery(prim)
    if not skinning:
        raise UsdValidationFailed(f"{mesh_path}: no skinning query (SkelBindingAPI / skel:skeleton missing)")
    skel_query = cache.GetSkelQuery(UsdSkel.BindingAPI(prim).GetInheritedSkeleton())
    anim_query = skel_query.GetAnimQuery()
    if not anim_query:
        raise UsdValidationFailed(f"{mesh_path}: skeleton has no animationSource")
    weights = anim_query.ComputeBlendShapeWeights(Usd.TimeCode(time))
    mapper = skinning.GetBlendShapeMapper()
    if mapper is not None and not mapper.IsNull():
        weights = mapper.Remap(weights)
    query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(prim))
    sub_w, shape_idx, sub_idx = query.ComputeSubShapeWeights(weights)
    points = Vt.Vec3fArray(prim.GetAttribute("points").Get(Usd.TimeCode(time)))
    ok = query.ComputeDeformedPoints(
        sub_w, shape_idx, sub_idx, query.ComputeBlendShapePointIndices(), query.ComputeSubShapePointOffsets(), points
    )
    if not ok:
        raise UsdValidationFailed(f"{mesh_path}: UsdSkel.BlendShapeQuery.ComputeDeformedPoints failed")
    return np.asarray(points, dtype=np.float64)


def assert_stage_valid(stage_or_path) -> None:
    """Raise ``UsdValidationFailed`` listing every UsdValidation error and extent violation."""
    problems = validate_stage(stage_or_path) + check_extents(stage_or_path)
    if problems:
        name = stage_or_path if isinstance(stage_or_path, (str, Path)) else "stage"
        raise UsdValidationFailed(f"{name}: {len(problems)} problem(s):\n  " + "\n  ".join(problems))


def _numeric(v):
    """A float array for numeric USD values (arrays, vectors, matrices, quaternions), else None."""
    from pxr import Gf

    if isinstance(v, (bool, str)) or v is None:
        return None
    if isinstance(v, (Gf.Quatf, Gf.Quatd, Gf.Quath)):
        return np.array([v.GetReal(), *v.GetImaginary()], dtype=np.float64)
    try:
        if hasattr(v, "__len__") and len(v) and isinstance(v[0], (Gf.Quatf, Gf.Quatd, Gf.Quath)):
            return np.array([[q.GetReal(), *q.GetImaginary()] for q in v], dtype=np.float64)
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return a


def compare_stages(a, b, *, rtol: float = 1e-5, atol: float = 1e-7, max_report: int = 20) -> list[str]:
    """Differences in authored content between two stages (e.g. a committed scene and a fresh one).

    Compares stage metadata (timeCodesPerSecond, start/end, upAxis, metersPerUnit, defaultPrim,
    customLayerData), the prim paths and types, applied API schemas, attribute names, time samples
    and values (numbers with ``rtol`` / ``atol``: float32 round-off across platforms), and
    relationship targets.

    Returns:
        Up to ``max_report`` lines describing differences; empty when the stages match.
    """
    from pxr import UsdGeom

    sa, sb = _open(a), _open(b)
    out: list[str] = []

    def note(msg: str) -> bool:
        out.append(msg)
        return len(out) >= max_report

    for label, get in (
        ("timeCodesPerSecond", lambda s: s.GetTimeCodesPerSecond()),
        ("startTimeCode", lambda s: s.GetStartTimeCode()),
        ("endTimeCode", lambda s: s.GetEndTimeCode()),
        ("upAxis", UsdGeom.GetStageUpAxis),
        ("metersPerUnit", UsdGeom.GetStageMetersPerUnit),
        ("defaultPrim", lambda s: str(s.GetDefaultPrim().GetPath()) if s.GetDefaultPrim() else None),
        ("customLayerData", lambda s: dict(s.GetRootLayer().customLayerData)),
    ):
        if get(sa) != get(sb) and note(f"stage {label}: {get(sa)!r} != {get(sb)!r}"):
            return out
    prims_a = {str(p.GetPath()): p for p in sa.TraverseAll()}
    prims_b = {str(p.GetPath()): p for p in sb.TraverseAll()}
    for path in sorted(set(prims_a) ^ set(prims_b)):
        if note(f"prim {path} only in {'first' if path in prims_a else 'second'} stage"):
            return out
    for path in sorted(set(prims_a) & set(prims_b)):
        pa, pb = prims_a[path], prims_b[path]
        if pa.GetTypeName() != pb.GetTypeName() and note(f"{path}: type {pa.GetTypeName()} != {pb.GetTypeName()}"):
            return out
        if list(pa.GetAppliedSchemas()) != list(pb.GetAppliedSchemas()) and note(f"{path}: applied schemas differ"):
            return out
        ra = {r.GetName(): r.GetTargets() for r in pa.GetRelationships() if r.HasAuthoredTargets()}
        rb = {r.GetName(): r.GetTargets() for r in pb.GetRelationships() if r.HasAuthoredTargets()}
        if ra != rb and note(f"{path}: relationships differ ({sorted(ra)} vs {sorted(rb)})"):
            return out
        aa = {x.GetName(): x for x in pa.GetAttributes() if x.HasAuthoredValue()}
        ab = {x.GetName(): x for x in pb.GetAttributes() if x.HasAuthoredValue()}
        for name in sorted(set(aa) ^ set(ab)):
            if note(f"{path}.{name} authored only in {'first' if name in aa else 'second'} stage"):
                return out
        for name in sorted(set(aa) & set(ab)):
            xa, xb = aa[name], ab[name]
            ta, tb = xa.GetTimeSamples(), xb.GetTimeSamples()
            if ta != tb:
                if note(f"{path}.{name}: time samples differ ({len(ta)} vs {len(tb)})"):
                    return out
                continue
            for t in ta or [None]:
                va, vb = (xa.Get(t), xb.Get(t)) if t is not None else (xa.Get(), xb.Get())
                na, nb = _numeric(va), _numeric(vb)
                when = "" if t is None else f" at time {t:g}"
                if na is not None and nb is not None:
                    if na.shape != nb.shape:
                        same, why = False, f"shape {na.shape} != {nb.shape}"
                    else:
                        same = bool(np.allclose(na, nb, rtol=rtol, atol=atol, equal_nan=True))
                        why = "" if same else f"max |difference| {np.max(np.abs(na - nb)):.3g}"
                else:
                    same, why = va == vb, f"{str(va)[:60]!r} != {str(vb)[:60]!r}"
                if not same:
                    if note(f"{path}.{name}{when}: {why}"):
                        return out
                    break
    return out
