"""A user's render mesh (an artist head with UVs and materials) bound to a face model.

``bind_render_mesh`` places the mesh in the model's frame and binds every vertex to the tet mesh
(``wface.mesh.embed.bind_points``: barycentric weights in the containing tet, or the closest skin
point plus its offset). Placement: a model fitted to this very mesh (``wface model fit
--surface``) carries the transform from the mesh's file coordinates to the model
(``metadata["fit"]["target_to_model"]``); any other mesh is converted from its units and rigidly
aligned to the skin (closest-point iterations), with a warning, since a head that is not the
model's shape moves like the nearest skin, not like itself. ``RenderMesh.source_points`` gives the
mesh's vertices for simulated node positions in the file's own frame and units, which is how the
USD writer stores them (``wface.io.usd.render_mesh``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wface.mesh.align import align_to_surface
from wface.mesh.embed import PointBinding, bind_points
from wface.mesh.meshfile import SurfaceMesh, read_surface_mesh
from wface.model import FaceModel

__all__ = ["RenderMesh", "bind_render_mesh", "placement_for"]

_FAR_MM = 5.0  # a bound mesh whose median distance to the flesh exceeds this is not the model's shape


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


def placement_for(model: FaceModel, mesh: SurfaceMesh) -> tuple[np.ndarray, str]:
    """(source -> model 4x4, "fit" | "aligned") for a mesh on a model (module docstring)."""
    fit = model.metadata.get("fit") or {}
    same = (
        fit.get("surface")
        and Path(fit["surface"]).name == Path(mesh.source).name
        and int(fit.get("surface_vertices", mesh.n_points)) == mesh.n_points
    )
    if same:
        return np.asarray(fit["target_to_model"], dtype=np.float64), "fit"
    pts = mesh.points_m
    rng = np.random.default_rng(0)
    sub = pts[rng.choice(len(pts), size=min(2000, len(pts)), replace=False)]
    al = align_to_surface(
        sub, model.rest_positions_m, model.skin_triangles, with_scale=False, trim_fraction=0.5, iterations=50
    )
    m = al.transform.as_matrix() @ np.diag([mesh.meters_per_unit] * 3 + [1.0])
    return m, "aligned"


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
    if source_to_model is None:
        m, how = placement_for(model, mesh)
    else:
        m, how = np.asarray(source_to_model, dtype=np.float64), "given"
    pts = mesh.points @ m[:3, :3].T + m[:3, 3]
    binding = bind_points(pts, model.rest_positions_m, model.tets, model.skin_triangles)
    far = float(np.median(binding.distance_m)) * 1e3
    if how == "aligned" and far > _FAR_MM:
        warnings.warn(
            f"{mesh.source}: the render mesh lies {far:.1f} mm (median) from this face's flesh; it will move like "
            "the nearest skin. Fit the face to it first: wface model fit --surface MESH",
            stacklevel=2,
        )
    return RenderMesh(mesh, binding, m, how)
