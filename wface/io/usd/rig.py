"""A take's skin as a UsdSkel rig a DCC animates: one blend shape per muscle plus cranium and jaw joints.

Layout under ``prim_path`` (a SkelRoot, e.g. ``/Face/Rig``)::

    Skel        Skeleton, joints ["cranium", "cranium/jaw"] bound at their pivots P_c and P_j (the
                skull's centre and the jaw's hinge, the condyles' midpoint): bind transforms T(P_c),
                T(P_j), rest transforms T(P_c), T(P_j - P_c), so a DCC shows the jaw bone at the
                hinge and turns it about it
      Anim      SkelAnimation: per frame the joints' local transforms, C T(P_c) and T(-P_c) J T(P_j)
                (C: the cranium's rest-to-world motion, J: the jaw's relative to the cranium, the 24
                bone parameters of ``wface.controls``), and ``blendShapeWeights`` = the muscle
                activation curves, one weight per muscle
    SkinRig     Mesh at the rest skin, SkelBindingAPI: two joint influences per vertex
                (cranium 1 - w, jaw w) and one BlendShape child per muscle (its offsets)

UsdSkel deforms the skin as (linear blend skinning of blend shapes, row vectors in USD, written
here with column vectors)::

    p(t) = (1 - w) C(t) q(t) + w C(t) J(t) q(t),   q(t) = G (p0 + sum_i a_i(t) d_i)

with C, J the cranium and jaw transforms (rotation and translation; the joints' world transforms
times their inverse bind transforms, so the pivots cancel), p0 the rest skin, d_i the
muscle shapes, w the jaw weights and G the mesh's geomBindTransform (identity for the skin; a
render mesh kept in its file's units and frame has its placement there). The rig linearises the face
about rest (Choe & Ko 2001; the
shapes of Sifakis et al. 2005's FEM face, see ``wface.takes.shapes``), so it differs from the exact
point cache beside it by the muscles' interaction and the flesh's nonlinearity; ``rig_points``
evaluates it in numpy so writers can report that difference (docs/design.md, "Take rig", has the
measured errors).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wface.io.usd._common import UsdWriteError, _extent, _identifier, _vt_float, _vt_int, _vt_vec3f, _write_mesh
from wface.io.usd.mesh import _bind_material_subsets, _write_face_varying

__all__ = ["JOINTS", "SkinRig", "rig_points", "write_skin_rig"]

JOINTS = ("cranium", "cranium/jaw")


@dataclass
class SkinRig:
    """What the rig needs beyond the take: rest skin, muscle shapes and jaw weights (on the skin vertices).

    Attributes:
        rest_m: (s, 3) rest positions of the skin vertices, metres.
        deltas_m: (M, s, 3) displacement of each muscle's shape at weight 1, metres.
        names: M shape names (the muscle names).
        jaw_weights: (s,) share of each vertex that follows the jaw, in [0, 1].
        source: how the shapes were made (goes into the stage's metadata).
        info: small JSON-able facts the weights depend on (e.g. the opening that drives a jaw shape to 1).
        bind_transform: (4, 4) the mesh's own coordinates -> the skin's (model metres), column
            vectors, or None (identity): a render mesh kept in its file's frame and units
            (UsdSkel's ``geomBindTransform``; shapes are offsets in the mesh's own coordinates).
    """

    rest_m: np.ndarray
    deltas_m: np.ndarray
    names: list[str]
    jaw_weights: np.ndarray
    source: str = ""
    info: dict = field(default_factory=dict)
    bind_transform: np.ndarray | None = None

    def carried(self, weights, rest_m: np.ndarray) -> SkinRig:
        """The rig carried to another mesh bound to the skin by linear weights (e.g. barycentric).

        Args:
            weights: (r, s) matrix (dense or scipy sparse), rows summing to 1: vertex j of the other
                mesh follows sum_v W_jv (skin vertex v).
            rest_m: (r, 3) the other mesh's rest positions (it keeps its own offsets from the skin).

        Returns:
            A ``SkinRig`` on the r vertices: shapes W d_i, jaw weights W w (clipped into [0, 1]).
        """
        rest = np.asarray(rest_m, dtype=np.float64)
        deltas = np.stack([np.asarray(weights @ d) for d in self.deltas_m])
        jaw = np.clip(np.asarray(weights @ self.jaw_weights).reshape(-1), 0.0, 1.0)
        return SkinRig(rest, deltas, list(self.names), jaw, source=self.source, info=dict(self.info))

    def __post_init__(self):
        self.rest_m = np.asarray(self.rest_m, dtype=np.float64)
        self.deltas_m = np.asarray(self.deltas_m, dtype=np.float64)
        self.jaw_weights = np.asarray(self.jaw_weights, dtype=np.float64).reshape(-1)
        s = self.rest_m.shape[0]
        if self.rest_m.shape != (s, 3) or self.deltas_m.shape[1:] != (s, 3) or self.jaw_weights.shape != (s,):
            raise UsdWriteError(
                f"SkinRig shapes disagree: rest_m {self.rest_m.shape}, deltas_m {self.deltas_m.shape}, "
                f"jaw_weights {self.jaw_weights.shape}"
            )
        if len(self.names) != self.deltas_m.shape[0]:
            raise UsdWriteError(f"{len(self.names)} shape names for {self.deltas_m.shape[0]} shapes")
        if not (np.all(np.isfinite(self.deltas_m)) and np.all((self.jaw_weights >= 0) & (self.jaw_weights <= 1))):
            raise UsdWriteError("SkinRig: deltas must be finite and jaw weights in [0, 1]")
        if self.bind_transform is not None:
            self.bind_transform = np.asarray(self.bind_transform, dtype=np.float64)
            b = self.bind_transform
            if b.shape != (4, 4) or not np.all(np.isfinite(b)) or abs(np.linalg.det(b[:3, :3])) < 1e-300:
                raise UsdWriteError(f"SkinRig: bind_transform must be an invertible (4, 4) matrix, got {b.shape}")

    def bound(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points in the mesh's own coordinates -> the skin's (``bind_transform``)."""
        if self.bind_transform is None:
            return np.asarray(points, dtype=np.float64)
        b = self.bind_transform
        return np.asarray(points, dtype=np.float64) @ b[:3, :3].T + b[:3, 3]


def _rigid(affines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3, 3) nearest rotations and (F, 3) translations of (F, 3, 4) affines."""
    a = np.asarray(affines, dtype=np.float64)
    u, _, vt = np.linalg.svd(a[:, :, :3])
    d = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= d[:, None]
    return u @ vt, a[:, :, 3]


def rig_points(rig: SkinRig, weights: np.ndarray, cranium_affines: np.ndarray, jaw_affines: np.ndarray) -> np.ndarray:
    """(F, s, 3) skin points the rig gives (module docstring), with the affines' nearest rotations,
    in the skin's coordinates (a ``bind_transform`` applied first, as UsdSkel does).

    Args:
        rig: the rig.
        weights: (F, M) blend-shape weights.
        cranium_affines: (F, 3, 4) cranium rest-to-world affines.
        jaw_affines: (F, 3, 4) jaw affines relative to the cranium.
    """
    q = rig.bound(rig.rest_m[None] + np.tensordot(np.asarray(weights, dtype=np.float64), rig.deltas_m, axes=(1, 0)))
    Rc, tc = _rigid(cranium_affines)
    Rj, tj = _rigid(jaw_affines)
    jaw = np.einsum("fij,fsj->fsi", Rj, q) + tj[:, None]
    local = (1.0 - rig.jaw_weights)[None, :, None] * q + rig.jaw_weights[None, :, None] * jaw
    return np.einsum("fij,fsj->fsi", Rc, local) + tc[:, None]


def _matrix(R: np.ndarray, t: np.ndarray):
    """Gf.Matrix4d of x -> R x + t (USD multiplies row vectors: the transpose)."""
    from pxr import Gf

    m = np.eye(4)
    m[:3, :3] = R.T
    m[3, :3] = t
    return Gf.Matrix4d(m.tolist())


def _joint_matrices(cranium_affines, jaw_affines, pivots_m):
    """Per frame, the two joints' local transforms (module docstring) as Gf.Matrix4d (rigid parts only):
    cranium C T(P_c) = [Rc | Rc P_c + tc], jaw T(-P_c) J T(P_j) = [Rj | Rj P_j + tj - P_c]."""
    Rc, tc = _rigid(cranium_affines)
    Rj, tj = _rigid(jaw_affines)
    pc, pj = pivots_m
    return [[_matrix(Rc[f], Rc[f] @ pc + tc[f]), _matrix(Rj[f], Rj[f] @ pj + tj[f] - pc)] for f in range(len(Rc))]


def write_skin_rig(
    stage,
    prim_path: str,
    rig: SkinRig,
    counts,
    indices,
    *,
    weights: np.ndarray,
    cranium_affines: np.ndarray,
    jaw_affines: np.ndarray,
    times: np.ndarray,
    visible: bool = True,
    st: np.ndarray | None = None,
    extra_meshes: dict | None = None,
    pivots_m: np.ndarray | None = None,
) -> np.ndarray:
    """Author the rig (module docstring) and return its (F, s, 3) skin points (``rig_points``).

    Args:
        stage: the open ``Usd.Stage``.
        prim_path: path of the SkelRoot.
        rig: rest skin, muscle shapes, jaw weights.
        counts / indices: the skin's polygon topology over the s vertices.
        weights: (F, B) blend-shape weights per frame (the activation curves).
        cranium_affines / jaw_affines: (F, 3, 4) bone affines (jaw relative to the cranium).
        times: (F,) time codes.
        visible: author the rig's mesh visible (the default: Blender's importer leaves invisible prims
            out); it lies on the exact point cache within the rig's error, so a DCC user hides one.
        st: (s, 2) texture coordinates of the skin vertices (``primvars:st``), or None.
        extra_meshes: {prim name: (SkinRig, counts, indices), (SkinRig, counts, indices, uv,
            uv_indices) or (SkinRig, counts, indices, uv, uv_indices, (material_faces, materials_path))}:
            more meshes bound to the same joints and weights, e.g. a render mesh
            (``wface.takes.shapes.render_mesh_rig``, or one carried by linear weights on the skin,
            ``SkinRig.carried``), with face-varying texture coordinates and one material subset per
            {material name: face indices}, bound to ``materials_path/<name>`` (the render mesh
            layer's materials, ``render_mesh_materials_path``); their shape names must be the skin
            rig's.
        pivots_m: (2, 3) where the cranium and jaw joints sit at rest (module docstring), e.g. the
            skull's centre and the condyles' midpoint, in the skin's coordinates; default the origin.
            The skinned points do not depend on them.
    """
    from pxr import Usd, UsdGeom, UsdSkel, Vt

    root = UsdSkel.Root.Define(stage, prim_path)
    skel = UsdSkel.Skeleton.Define(stage, f"{prim_path}/Skel")
    skel.CreateJointsAttr(Vt.TokenArray(list(JOINTS)))
    pivots = np.zeros((2, 3)) if pivots_m is None else np.asarray(pivots_m, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(pivots)):
        raise UsdWriteError("pivots_m must be finite")
    eye = np.eye(3)
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([_matrix(eye, pivots[0]), _matrix(eye, pivots[1])]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([_matrix(eye, pivots[0]), _matrix(eye, pivots[1] - pivots[0])]))
    anim = UsdSkel.Animation.Define(stage, f"{prim_path}/Skel/Anim")
    anim.CreateJointsAttr(Vt.TokenArray(list(JOINTS)))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    for t, mats in zip(times, _joint_matrices(cranium_affines, jaw_affines, pivots), strict=True):
        anim.SetTransforms(Vt.Matrix4dArray(mats), Usd.TimeCode(float(t)))

    meshes = {"SkinRig": (rig, counts, indices, st, None, None)}
    meshes.update({k: (*v, None, None, None)[:6] for k, v in (extra_meshes or {}).items()})
    boxes = []
    tokens = None
    for name, (mesh_rig, c, i, uv, uv_idx, materials) in meshes.items():
        if mesh_rig.names != rig.names:
            raise UsdWriteError(f"rig mesh {name}: shapes {mesh_rig.names[:3]}... are not the skin rig's")
        tokens = _bind_mesh(stage, f"{prim_path}/{name}", skel, mesh_rig, c, i, visible=visible, st=uv)
        usd_mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"{prim_path}/{name}"))
        if uv_idx is not None:
            _write_face_varying(usd_mesh, "st", uv, uv_idx, len(i), 2)
        if materials is not None and materials[0]:
            _bind_material_subsets(usd_mesh, materials[0], materials[1], len(c))
        pts = rig_points(mesh_rig, weights, cranium_affines, jaw_affines)
        shapes_only = mesh_rig.rest_m[None] + np.tensordot(weights, mesh_rig.deltas_m, axes=(1, 0))  # as validators
        shapes_only = mesh_rig.bound(np.concatenate([shapes_only.reshape(-1, 3), mesh_rig.rest_m]))
        boxes.append(_extent(np.concatenate([pts.reshape(-1, 3), shapes_only])))
        if name == "SkinRig":
            skin_pts = pts
    anim.CreateBlendShapesAttr(Vt.TokenArray(tokens))
    w_attr = anim.CreateBlendShapeWeightsAttr()
    for t, w in zip(times, weights, strict=True):
        w_attr.Set(_vt_float(w), Usd.TimeCode(float(t)))
    UsdGeom.ModelAPI.Apply(root.GetPrim()).SetExtentsHint(_vt_vec3f(_extent(np.concatenate(boxes))))
    return skin_pts


def _bind_mesh(stage, mesh_path: str, skel, rig: SkinRig, counts, indices, *, visible: bool, st) -> list[str]:
    """A Mesh at the rig's rest points bound to ``skel`` (two joint influences per vertex) with one
    BlendShape child per shape; returns the shapes' tokens."""
    from pxr import Gf, Sdf, UsdGeom, UsdSkel, Vt

    mesh = _write_mesh(stage, mesh_path, rig.rest_m, counts, indices)
    if not visible:
        mesh.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    if st is not None:
        UsdGeom.PrimvarsAPI(mesh.GetPrim()).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        ).Set(Vt.Vec2fArray.FromNumpy(np.asarray(st, dtype=np.float32)))
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    s = rig.rest_m.shape[0]
    binding.CreateJointIndicesPrimvar(constant=False, elementSize=2).Set(_vt_int(np.tile([0, 1], s)))
    jw = np.stack([1.0 - rig.jaw_weights, rig.jaw_weights], axis=1).reshape(-1)
    binding.CreateJointWeightsPrimvar(constant=False, elementSize=2).Set(_vt_float(jw))
    bind = np.eye(4) if rig.bind_transform is None else rig.bind_transform
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(bind.T.tolist()))  # USD multiplies row vectors
    taken: set[str] = set()
    tokens, targets = [], []
    for name, delta in zip(rig.names, rig.deltas_m, strict=True):
        ident = _identifier(name, taken)
        shape = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(ident))
        moved = np.flatnonzero(np.max(np.abs(delta), axis=1) > 0.0)
        shape.CreateOffsetsAttr(_vt_vec3f(delta[moved]))
        shape.CreatePointIndicesAttr(_vt_int(moved))
        tokens.append(ident)
        targets.append(shape.GetPath())
    binding.CreateBlendShapesAttr(Vt.TokenArray(tokens))
    binding.CreateBlendShapeTargetsRel().SetTargets(targets)
    return tokens
