"""A linear actuation basis as UsdSkel blend shapes (what Blender turns into shape keys)."""

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
    _extent,
    _identifier,
    _new_stage,
    _vt_float,
    _vt_int,
    _vt_vec3f,
    _write_mesh,
    as_polygons,
)

__all__ = ["BlendShapeBasis", "write_blendshape_basis"]


class BlendShapeBasis:
    """A linear actuation basis E = E0 + sum_i x_i e_i (Choe & Ko 2001) to write as UsdSkel blend shapes.

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

    @classmethod
    def coerce(cls, basis) -> BlendShapeBasis:
        """A ``BlendShapeBasis`` from any object with ``neutral_m``, ``deltas_m`` or ``shapes_m``
        (e.g. ``wface.basis.ActuationBasis``) and ``names``."""
        if isinstance(basis, cls):
            return basis
        deltas = getattr(basis, "deltas_m", None)
        if deltas is None:
            deltas = getattr(basis, "shapes_m", None)
        if deltas is None or not hasattr(basis, "neutral_m"):
            raise UsdWriteError(
                f"cannot use a {type(basis).__name__} as a basis: it needs neutral_m and deltas_m (or shapes_m)"
            )
        return cls(basis.neutral_m, deltas, getattr(basis, "names", None))

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
    times=None,
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
        times = np.arange(len(weights), dtype=float) if times is None else times
        for t, w in zip(times, weights, strict=True):
            w_attr.Set(_vt_float(w), float(t))
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
    basis,
    face_vertex_counts: np.ndarray | None = None,
    face_vertex_indices: np.ndarray | None = None,
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
        basis: a ``BlendShapeBasis``, or any object ``BlendShapeBasis.coerce`` takes (e.g.
            ``wface.basis.ActuationBasis``).
        face_vertex_counts / face_vertex_indices: mesh topology (see ``write_mesh_animation``);
            when ``face_vertex_indices`` is None, the basis's own ``face_counts`` /
            ``face_indices`` are used.
        weights: (F, B) per-frame weights x_i; None writes static zero weights (the neutral).
        fps: frames per second.
        name: root prim name.
        up_axis: "Y" or "Z" (see ``write_mesh_animation``).

    Returns:
        The path written.
    """
    path = _check_path(path)
    if face_vertex_indices is None:
        if getattr(basis, "face_indices", None) is None:
            raise UsdWriteError("no topology: pass face_vertex_indices (and counts) or a basis with face_indices")
        face_vertex_counts, face_vertex_indices = basis.face_counts, basis.face_indices
    basis = BlendShapeBasis.coerce(basis)
    counts, indices = as_polygons(face_vertex_counts, face_vertex_indices, basis.neutral_m.shape[0])
    w = None if weights is None else _check_frames("weights", weights, np.asarray(weights).shape[0], (basis.n_shapes,))
    stage = _new_stage(
        path, fps=fps, n_frames=1 if w is None else len(w), up_axis=up_axis, root=name, root_type="SkelRoot"
    )
    _write_blendshapes(stage, f"/{name}", basis, w, counts, indices)
    save_layer(stage.GetRootLayer(), path)  # atomic: a temporary file renamed into place
    return path
