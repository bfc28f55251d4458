"""Waters muscles on a ``wface.model.FaceModel`` (e.g. the built-in face).

The skin triangles become the surface mesh; the packaged ICT layout is fitted to the model by its
named markers (AnimFace names); the jaw pivot and axis come from the model's jaw joint; and the
per-vertex jaw weights come from the model's bone attachments: a harmonic field on the tet mesh's
edge graph, 1 on jaw-attached nodes and 0 on cranium-attached nodes (graph Laplacian, Dirichlet
solve). The field follows the mesh topology, so lips that touch at the mouth slit still separate.
Skin nodes attached to a bone (the patch border) are not moved by muscles.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

from wface.faces.builtin import build_face
from wface.mesh.meshfile import SurfaceMesh
from wface.mesh.uv import skin_uv
from wface.waters.fit import fit_layout
from wface.waters.layout import JawRegion, MuscleLayout, load_layout
from wface.waters.rig import WatersRig

__all__ = ["builtin_face_layout", "face_model_rig", "fit_layout_to_face_model", "harmonic_jaw_weights", "skin_surface"]


def skin_surface(model) -> tuple[SurfaceMesh, np.ndarray]:
    """The model's outer skin as a compact surface mesh, and the model node id of each surface vertex."""
    tri = np.asarray(model.skin_triangles, dtype=np.int64)
    if tri.size == 0:
        raise ValueError("the face model has no skin triangles")
    nodes, local = np.unique(tri, return_inverse=True)
    x = model.rest_positions_m[nodes]
    local = local.reshape(-1, 3)
    uv = skin_uv(x, local)  # the take's skin's texture coordinates, so a texture fits both
    mesh = SurfaceMesh(x, np.full(len(local), 3), local.ravel(), uv=uv, uv_indices=local.ravel())
    return mesh, nodes


def harmonic_jaw_weights(model) -> np.ndarray:
    """(n_nodes,) jaw weight per model node: harmonic on the tet edge graph, 1 on the jaw, 0 on the cranium."""

    n = model.n_nodes
    jaw, cranium = model.nodes_of_bone("jaw"), model.nodes_of_bone("cranium")
    if len(jaw) == 0:
        raise ValueError("the face model has no jaw-attached nodes")
    t = np.asarray(model.tets, dtype=np.int64)
    pairs = np.concatenate([t[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
    a = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)
    lap = sparse.diags(np.asarray(a.sum(axis=1)).ravel()) - a
    w = np.zeros(n)
    fixed = np.zeros(n, dtype=bool)
    fixed[jaw], fixed[cranium] = True, True
    w[jaw] = 1.0
    free = np.flatnonzero(~fixed)
    if free.size:
        rhs = -lap[free][:, np.flatnonzero(fixed)] @ w[fixed]
        w[free] = spsolve(lap[free][:, free].tocsc(), rhs)
    return np.clip(w, 0.0, 1.0)


def fit_layout_to_face_model(model, layout: MuscleLayout | None = None, *, method: str = "rbf") -> MuscleLayout:
    """Fit a layout (default: the packaged ICT layout) to a FaceModel by its markers, snapping insertions
    to its skin. The jaw pivot and axis come from the model's jaw joint (condyle midpoint, u axis)."""
    layout = layout if layout is not None else load_layout("ict")
    names = list(model.marker_names)
    if not names:
        raise ValueError("the face model has no markers to fit a layout by")
    marks = dict(zip(names, np.asarray(model.marker_positions_m), strict=True))
    skin, _ = skin_surface(model)
    fitted = fit_layout(
        layout,
        marks,
        target_vertices_m=skin.vertices_m,
        target_triangles=skin.triangles(),
        method=method,
        name=f"{layout.name}-on-{model.metadata.get('name', 'face-model')}",
    )
    joint = getattr(model, "jaw_joint", None)
    if joint is not None and fitted.jaw is not None:
        fitted.jaw = JawRegion(
            pivot_m=np.asarray(joint.midpoint_m, dtype=np.float64),
            axis=np.asarray(joint.u, dtype=np.float64),
            planes=fitted.jaw.planes,
            max_open_deg=fitted.jaw.max_open_deg,
        )
    fitted.mesh_vertex_count = None
    return fitted


def face_model_rig(model, layout: MuscleLayout | None = None) -> tuple[WatersRig, SurfaceMesh, np.ndarray]:
    """A Waters rig on the model's skin: (rig, skin surface, model node id per skin vertex).

    Args:
        model: a ``FaceModel`` with skin triangles, markers, bone attachments and a jaw joint.
        layout: a layout already fitted to the model (default: ``fit_layout_to_face_model(model)``).
    """
    layout = layout if layout is not None else fit_layout_to_face_model(model)
    skin, nodes = skin_surface(model)
    attached = np.zeros(model.n_nodes, dtype=bool)
    attached[model.attached_nodes] = True
    weights = harmonic_jaw_weights(model)[nodes]
    rig = WatersRig(layout, skin.vertices_m, muscle_mask=~attached[nodes], jaw_weights=weights)
    return rig, skin, nodes


BUILTIN_LAYOUT_TETS = 20_000


def builtin_face_layout(target_tets: int = BUILTIN_LAYOUT_TETS) -> MuscleLayout:
    """The layout packaged as ``waters_builtin.json``: the ICT layout fitted to ``build_face(target_tets)``.

    Regenerate the packaged file after changing the ICT layout or the built-in face::

        save_layout(builtin_face_layout(), "wface/data/waters_builtin.json")
    """

    lay = fit_layout_to_face_model(build_face(target_tets))
    lay.name = "builtin"
    lay.notes = (
        "The packaged ICT layout (waters_ict.json) fitted to wface's built-in face "
        f"(wface.faces.builtin.build_face({target_tets})) by its AnimFace markers: similarity + thin-plate RBF warp, "
        "insertions snapped to the skin, jaw pivot/axis from the model's jaw joint. Regenerate with "
        "wface.waters.face_model.builtin_face_layout()."
    )
    return lay
