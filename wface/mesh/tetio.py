"""Tetrahedral mesh import/export through meshio (VTU, Gmsh .msh, and anything meshio writes).

Exports carry per-tet cell data (muscle id of the dominant muscle, its fraction and fibre
direction) and per-node point data (attached bone: -1 free, 0 cranium, 1 jaw) so a mesh opened
in ParaView shows the anatomy.
"""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from wface.mesh.quality import signed_volumes

__all__ = ["read_tet_mesh", "write_tet_mesh", "model_cell_data"]


def model_cell_data(model) -> tuple[dict, dict]:
    """(cell_data, point_data) arrays describing a FaceModel's muscles and attachments."""
    m = model.n_tets
    muscle = np.full(m, -1, dtype=np.int32)
    fraction = np.zeros(m)
    direction = np.zeros((m, 3))
    order = np.argsort(model.fibre_fraction, kind="stable")  # larger fractions written last win
    muscle[model.fibre_tet[order]] = model.fibre_muscle[order]
    fraction[model.fibre_tet[order]] = model.fibre_fraction[order]
    direction[model.fibre_tet[order]] = model.fibre_direction[order]
    bone = np.full(model.n_nodes, -1, dtype=np.int32)
    bone[model.attached_nodes] = model.attached_bone
    cell_data = {"muscle_id": [muscle], "muscle_fraction": [fraction], "fibre_direction": [direction]}
    return cell_data, {"attached_bone": bone}


def write_tet_mesh(
    path: str | Path,
    positions_m: np.ndarray,
    tets: np.ndarray,
    *,
    cell_data: dict | None = None,
    point_data: dict | None = None,
    file_format: str | None = None,
) -> Path:
    """Write a tet mesh; the format follows the suffix (.vtu, .msh, ...) unless ``file_format`` is given."""

    path = Path(path)
    mesh = meshio.Mesh(
        np.asarray(positions_m, dtype=np.float64),
        [("tetra", np.asarray(tets, dtype=np.int64))],
        cell_data=cell_data or {},
        point_data=point_data or {},
    )
    if path.suffix == ".msh" and file_format is None:
        file_format = "gmsh22"
        # Gmsh 2.2 wants physical/geometrical tags; drop vector cell data it cannot hold.
        mesh.cell_data = {k: v for k, v in mesh.cell_data.items() if np.asarray(v[0]).ndim == 1}
        mesh.point_data = {}
    path.parent.mkdir(parents=True, exist_ok=True)
    meshio.write(path, mesh, file_format=file_format)
    return path


def read_tet_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read (positions (n,3) float64, tets (m,4) int32, cell_data of the tet block) from any meshio format.

    Tets are re-oriented to positive volume. Raises ValueError naming the file if it holds no tets.
    """

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"mesh file not found: {path}")
    mesh = meshio.read(path)
    blocks = [i for i, c in enumerate(mesh.cells) if c.type == "tetra"]
    if not blocks:
        types = sorted({c.type for c in mesh.cells})
        raise ValueError(f"{path}: no tetrahedra in the file (cell types: {types})")
    tets = np.concatenate([mesh.cells[i].data for i in blocks]).astype(np.int32)
    x = np.asarray(mesh.points, dtype=np.float64)[:, :3]

    neg = signed_volumes(x, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    cell_data = {k: np.concatenate([v[i] for i in blocks]) for k, v in mesh.cell_data.items()}
    return x, tets, cell_data
