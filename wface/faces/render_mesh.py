"""A user's render mesh (an artist head with UVs and materials) bound to a face model.

``bind_render_mesh`` places the mesh in the model's frame and binds every vertex to the tet mesh
(``wface.mesh.embed.bind_points``: barycentric weights in the containing tet, or the closest skin
point plus its offset). Placement: a model fitted to this very mesh (``wface model fit
--surface``) carries the transform from the mesh's file coordinates to the model
(``metadata["fit"]["target_to_model"]``), used once the face's skin is checked to lie on the mesh so
placed (a file of the same name in other units or shape is not that mesh). Any other mesh is
converted from its units and rigidly aligned: the face's skin is fitted onto the mesh (closest-point
iterations; every skin point has its counterpart on a whole head, where most of a head has none on a
face patch), starting from the file's own axes taken as the model's (+y up, +z forward: the OBJ, glTF
and USD convention) with the two noses' tips together. It warns when the alignment turned the mesh
by more than ``_TURN_WARN_DEG`` (a file with other axes) and when the mesh lies far from the flesh
(a head that is not the model's shape moves like the nearest skin, not like itself).

Points far from the skin (the back of a head, a neck, beyond ``_ANCHOR_FROM_M``) are handed
gradually to the cranium's motion, wholly beyond ``_ANCHOR_TO_M`` (``wface.mesh.embed.anchor_points``):
carried by the local skin alone they swing by their whole lever arm when the jaw opens. A part of
the mesh apart from its largest (a tooth, an eye) moves rigidly with a bone: with the arch of the
nearer teeth mesh when one lies within ``_TEETH_REACH_M`` (median over the part; a back molar is
often nearer the other bone than its own arch), else with the nearer bone mesh's bone within
``_PART_REACH_M``: upper teeth and eyes with the cranium, lower teeth with the jaw, where the lips'
tets would bend them. ``RenderMesh.source_points`` gives the
mesh's vertices for simulated node positions in the file's own frame and units, which is how the
USD writer stores them (``wface.io.usd.render_mesh``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse.csgraph import connected_components

from wface.mesh.align import Similarity, align_to_surface
from wface.mesh.closest import SurfaceQuery
from wface.mesh.embed import PointBinding, anchor_points, bind_points
from wface.mesh.meshfile import SurfaceMesh, read_surface_mesh
from wface.mesh.surface_fields import edge_graph
from wface.model import BONES, FaceModel

__all__ = ["RenderMesh", "bind_render_mesh", "placement_for"]

_FIT_CHECK_MM = 2.0  # a face's skin on its own mesh: median skin-to-mesh distance within this
_TURN_WARN_DEG = 30.0  # an alignment that turns the file's axes more than this is suspicious
_ANCHOR_FROM_M = 0.020  # points this far off the skin start to follow the cranium ...
_ANCHOR_TO_M = 0.080  # ... and follow it wholly from here (a wide band: a narrow one shears the neck)
_ALIGN_SAMPLES = 2000  # skin points used to align a mesh
_SIZE_RATIO = (0.1, 5.0)  # a render mesh's extent over the skin's: an eye to head and shoulders
_PART_PROBES = 64  # vertices of a separate part whose median distance to the bones places it
_PART_REACH_M = 0.010  # a separate part this near a bone mesh (median) moves with that bone ...
_TEETH_REACH_M = 0.030  # ... and one this near a teeth mesh with that arch's bone


@dataclass
class RenderMesh:
    """A render mesh bound to a face model.

    Attributes:
        mesh: the mesh as read (file units and frame).
        binding: its vertices bound to the model's tets.
        source_to_model: (4, 4) file coordinates -> model metres.
        placement: "fit" (the model was fitted to this mesh) or "aligned".
    """

    mesh: SurfaceMesh
    binding: PointBinding
    source_to_model: np.ndarray
    placement: str

    @property
    def name(self) -> str:
        return Path(self.mesh.source).stem or "render_mesh"

    def model_points(self, x_m: np.ndarray) -> np.ndarray:
        """(n, 3) vertices in the model's frame (metres) for node positions (N, 3)."""
        return self.binding.positions(x_m)

    def source_points(self, x_m: np.ndarray) -> np.ndarray:
        """(n, 3) or (T, n, 3) vertices in the file's frame and units for node positions (N, 3) or (T, N, 3)."""
        x = np.asarray(x_m, dtype=np.float64)
        inv = np.linalg.inv(self.source_to_model)
        if x.ndim == 3:
            return np.stack([self.source_points(f) for f in x])
        return self.binding.positions(x) @ inv[:3, :3].T + inv[:3, 3]


def _skin_points(model: FaceModel, n: int) -> np.ndarray:
    skin = np.unique(model.skin_triangles)
    rng = np.random.default_rng(0)
    return model.rest_positions_m[rng.choice(skin, size=min(n, len(skin)), replace=False)]


def _fit_placement(model: FaceModel, mesh: SurfaceMesh) -> np.ndarray | None:
    """The fit's placement if the model was fitted to this mesh (name, vertex count and geometry), else None."""
    fit = model.metadata.get("fit") or {}
    if not (fit.get("surface") and Path(fit["surface"]).name == Path(mesh.source).name):
        return None
    if int(fit.get("surface_vertices") or mesh.n_points) != mesh.n_points:
        return None
    m = np.asarray(fit["target_to_model"], dtype=np.float64)
    fit_units = float(fit.get("surface_meters_per_unit") or mesh.meters_per_unit)
    m = m @ np.diag([mesh.meters_per_unit / fit_units] * 3 + [1.0])  # this file's units -> the fit's
    placed = mesh.points @ m[:3, :3].T + m[:3, 3]
    off = SurfaceQuery(placed, mesh.triangles()).closest(_skin_points(model, _ALIGN_SAMPLES)).distance_m
    off_mm = float(np.median(off)) * 1e3
    if off_mm > _FIT_CHECK_MM:
        warnings.warn(
            f"{mesh.source}: the face was fitted to a mesh of this name, but its skin lies {off_mm:.1f} mm "
            "(median) off this file placed as fitted (another shape, or other units: --render-mesh-units); "
            "aligning it instead",
            stacklevel=3,
        )
        return None
    return m


def placement_for(model: FaceModel, mesh: SurfaceMesh) -> tuple[np.ndarray, str]:
    """(source -> model 4x4, "fit" | "aligned") for a mesh on a model (module docstring)."""
    m = _fit_placement(model, mesh)
    if m is not None:
        return m, "fit"
    p = _skin_points(model, _ALIGN_SAMPLES)
    q = mesh.points_m
    start = Similarity(1.0, np.eye(3), q[np.argmax(q[:, 2])] - p[np.argmax(p[:, 2])])  # skin -> mesh, tips met
    al = align_to_surface(p, q, mesh.triangles(), with_scale=False, trim_fraction=0.2, iterations=50, initial=start)
    r, t = al.transform.rotation, al.transform.translation_m
    turn = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))
    if turn > _TURN_WARN_DEG:
        warnings.warn(
            f"{mesh.source}: aligning the render mesh turned it {turn:.0f} degrees from its file's axes; wface takes "
            "+y as up and +z as forward (the model's frame): check the mesh's orientation",
            stacklevel=3,
        )
    off_mm = float(np.nanmedian(al.distance_m)) * 1e3
    if off_mm > _FIT_CHECK_MM:
        warnings.warn(
            f"{mesh.source}: this face's skin lies {off_mm:.1f} mm (median) from the render mesh aligned to it: the "
            "mesh is not the face's shape and will move like the nearest skin. Fit the face to it first: wface model "
            "fit --surface MESH",
            stacklevel=3,
        )
    inv = np.eye(4)  # mesh -> skin frame: the inverse of the fitted skin -> mesh transform
    inv[:3, :3], inv[:3, 3] = r.T, -r.T @ t
    return inv @ np.diag([mesh.meters_per_unit] * 3 + [1.0]), "aligned"


def _components(mesh: SurfaceMesh) -> np.ndarray:
    """(n,) connected-component label of each vertex, 0 for the largest component."""
    _, lab = connected_components(edge_graph(mesh.points, mesh.triangles()), directed=False)
    order = np.argsort(-np.bincount(lab))
    return np.argsort(order)[lab]


def _anchors(model: FaceModel, mesh: SurfaceMesh, points_m: np.ndarray, binding: PointBinding) -> PointBinding:
    """Hand far points to the cranium and separate parts near a bone to that bone (module docstring)."""
    anchor = np.full(len(points_m), -1)
    weight = np.zeros(len(points_m))
    out = binding.outside
    t = np.clip((binding.distance_m[out] - _ANCHOR_FROM_M) / (_ANCHOR_TO_M - _ANCHOR_FROM_M), 0.0, 1.0)
    anchor[out], weight[out] = BONES.index("cranium"), t * t * (3.0 - 2.0 * t)  # smoothstep
    lab = _components(mesh)
    parts = [np.flatnonzero(lab == c) for c in range(1, lab.max() + 1)]  # all but the largest: teeth, eyes
    if parts:
        rng = np.random.default_rng(0)
        probe = [v if len(v) <= _PART_PROBES else rng.choice(v, _PART_PROBES, replace=False) for v in parts]
        q = points_m[np.concatenate(probe)]
        ends = np.cumsum([len(v) for v in probe])[:-1]
        names = list(model.bone_meshes)
        d = [
            np.split(SurfaceQuery(bm.vertices_m, bm.triangles).closest(q).distance_m, ends)
            for bm in model.bone_meshes.values()
        ]
        teeth = [i for i, n in enumerate(names) if "teeth" in n]
        for k, v in enumerate(parts):
            med = np.array([np.median(d[i][k]) for i in range(len(names))])
            if teeth and med[teeth].min() < _TEETH_REACH_M:  # a tooth: its arch decides, not the nearer bone
                i = teeth[int(np.argmin(med[teeth]))]
            elif len(med) and med.min() < _PART_REACH_M:
                i = int(np.argmin(med))
            else:
                continue
            anchor[v], weight[v] = BONES.index(model.bone_meshes[names[i]].bone), 1.0
    nodes = [model.attached_nodes[model.attached_bone == b] for b in range(len(BONES))]
    return anchor_points(binding, points_m, model.rest_positions_m, nodes, anchor, weight)


def _check_size(model: FaceModel, mesh: SurfaceMesh) -> None:
    """Refuse a mesh whose size, in metres as read, is not within 0.1 to 5 times the face's skin (a
    millimetre file read as metres, a mesh of one point or one triangle), before binding it."""
    size_m = float(np.ptp(mesh.points_m, axis=0).max())
    skin_m = float(np.ptp(model.rest_positions_m[np.unique(model.skin_triangles)], axis=0).max())
    lo, hi = _SIZE_RATIO
    if not lo * skin_m <= size_m <= hi * skin_m:
        raise ValueError(
            f"{mesh.source or 'the render mesh'} is {size_m:.3g} m across read at {mesh.meters_per_unit:g} m per "
            f"unit, where the face's skin is {skin_m:.3g} m (a render mesh is {lo:g} to {hi:g} times that): check "
            "--render-mesh-units and that the file is the head's mesh"
        )


def bind_render_mesh(
    model: FaceModel, mesh: SurfaceMesh | str | Path, *, units: str | float = "auto", source_to_model=None
) -> RenderMesh:
    """Bind a render mesh to ``model`` (module docstring).

    Args:
        model: the face that will move it.
        mesh: a ``SurfaceMesh`` or a mesh file (``read_surface_mesh``).
        units: units of a mesh file ("auto", "m", "cm", "mm" or metres per unit).
        source_to_model: (4, 4) placement to use instead of ``placement_for``.

    Returns:
        A ``RenderMesh``; ``model_points(model.rest_positions_m)`` reproduces the placed mesh.
    """
    if not isinstance(mesh, SurfaceMesh):
        mesh = read_surface_mesh(mesh, units=units)
    _check_size(model, mesh)
    if source_to_model is None:
        m, how = placement_for(model, mesh)
    else:
        m, how = np.asarray(source_to_model, dtype=np.float64), "given"
    pts = mesh.points @ m[:3, :3].T + m[:3, 3]
    binding = bind_points(pts, model.rest_positions_m, model.tets, model.skin_triangles)
    binding = _anchors(model, mesh, pts, binding)
    return RenderMesh(mesh, binding, m, how)
