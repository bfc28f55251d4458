"""Polygon surface meshes from files (OBJ, PLY, STL, OFF, ...), read by maintained libraries.

OBJ goes through tinyobjloader, which keeps what a render mesh needs: polygons as authored
(quads and triangles, no triangulation), per-corner texture coordinates with their own indices
(the UV seams of an artist's layout), and the ``usemtl`` material of every face. Every other
format goes through meshio. A ``SurfaceMesh`` holds the file's vertices in the file's own units
and ``meters_per_unit`` says what they are (read from the extent unless given: a head is about
0.25 m tall, so an extent under 3 is metres, under 150 centimetres, else millimetres).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import meshio
import numpy as np
import tinyobjloader

__all__ = ["UNITS", "SurfaceMesh", "guess_meters_per_unit", "read_surface_mesh"]

#: unit name -> metres per unit
UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "in": 0.0254}


@dataclass
class SurfaceMesh:
    """A polygon mesh as authored (USD-style flat topology).

    Attributes:
        points: (n, 3) float64 vertex positions in the file's units.
        face_vertex_counts: (p,) int32 corners per face (3 or more).
        face_vertex_indices: (sum counts,) int32 vertex ids, corners in order.
        meters_per_unit: metres per file unit (0.01 for centimetres).
        uv: (u, 2) float64 texture coordinates, or None.
        uv_indices: (sum counts,) int32 index into ``uv`` per face corner (faceVarying), or None.
        face_groups: {material name: (f,) int32 face ids} in file order; empty without materials.
        source: the file it came from.
    """

    points: np.ndarray
    face_vertex_counts: np.ndarray
    face_vertex_indices: np.ndarray
    meters_per_unit: float = 1.0
    uv: np.ndarray | None = None
    uv_indices: np.ndarray | None = None
    face_groups: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.face_vertex_counts.shape[0])

    @property
    def points_m(self) -> np.ndarray:
        """(n, 3) vertex positions in metres (file frame)."""
        return self.points * self.meters_per_unit

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """Fan triangulation: ((t, 3) vertex ids, (t,) face id of each triangle)."""
        counts = self.face_vertex_counts.astype(np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        n_tri = counts - 2
        face = np.repeat(np.arange(len(counts)), n_tri)
        k = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)  # fan index within its face
        s = starts[face]
        idx = self.face_vertex_indices
        tri = np.stack([idx[s], idx[s + k + 1], idx[s + k + 2]], axis=1)
        return tri.astype(np.int32), face.astype(np.int32)

    def faces_of(self, groups) -> np.ndarray:
        """Sorted face ids of the named material groups (KeyError naming the known groups)."""
        ids = []
        for g in groups:
            if g not in self.face_groups:
                raise KeyError(
                    f"{self.source}: no material group {g!r}; it has {', '.join(self.face_groups) or 'none'}"
                )
            ids.append(self.face_groups[g])
        return np.unique(np.concatenate(ids)) if ids else np.zeros(0, dtype=np.int32)


def guess_meters_per_unit(points: np.ndarray) -> float:
    """Metres per unit of a head-sized mesh from its largest bounding-box extent (module docstring)."""
    extent = float(np.max(np.ptp(np.asarray(points, dtype=np.float64), axis=0)))
    if extent < 3.0:
        return UNITS["m"]
    if extent < 150.0:
        return UNITS["cm"]
    return UNITS["mm"]


def _meters_per_unit(units: str | float, points: np.ndarray) -> float:
    if units == "auto":
        return guess_meters_per_unit(points)
    if isinstance(units, str):
        if units not in UNITS:
            raise ValueError(f"unknown units {units!r}; known: auto, {', '.join(UNITS)}")
        return UNITS[units]
    if not (np.isfinite(units) and units > 0):
        raise ValueError(f"meters per unit must be a positive number, got {units}")
    return float(units)


def _read_obj(path: Path) -> tuple:
    text = path.read_text(errors="replace")
    # tinyobjloader gives a face the material of its ``usemtl`` only when the .mtl file defines it;
    # a head shipped without its .mtl still names its groups, so the reader gets a stub library
    # that defines each name (the parsing itself is tinyobjloader's).
    names = list(dict.fromkeys(re.findall(r"^\s*usemtl\s+(\S+)", text, flags=re.MULTILINE)))
    stub = "".join(f"newmtl {n}\n" for n in names)
    if names and not re.search(r"^\s*mtllib\b", text, flags=re.MULTILINE):
        text = "mtllib stub.mtl\n" + text  # the stub library is read only where the file asks for one
    reader = tinyobjloader.ObjReader()
    cfg = tinyobjloader.ObjReaderConfig()
    cfg.triangulate = False
    if not reader.ParseFromString(text, stub, cfg):
        raise ValueError(f"{path}: not a readable OBJ file ({reader.Error().strip()})")
    attrib = reader.GetAttrib()
    points = np.asarray(attrib.vertices, dtype=np.float64).reshape(-1, 3)
    counts, vidx, tidx, mat = [], [], [], []
    for shape in reader.GetShapes():
        m = shape.mesh
        # the list accessors: the numpy_* views of tinyobjloader 2.0.0rc13 misread their dtypes
        counts.append(np.asarray(m.num_face_vertices, dtype=np.int32))
        vidx.append(np.asarray(m.vertex_indices(), dtype=np.int64))
        tidx.append(np.asarray(m.texcoord_indices(), dtype=np.int64))
        mat.append(np.asarray(m.material_ids, dtype=np.int64))
    if not counts or sum(len(c) for c in counts) == 0:
        raise ValueError(f"{path}: the OBJ file has no faces")
    counts, vidx, tidx, mat = (np.concatenate(a) for a in (counts, vidx, tidx, mat))
    uv = np.asarray(attrib.texcoords, dtype=np.float64).reshape(-1, 2)
    uv_idx = None
    if len(uv) and np.all(tidx >= 0):
        uv_idx = tidx.astype(np.int32)
    else:
        uv = None
    materials = [m.name for m in reader.GetMaterials()]
    groups = {name: np.flatnonzero(mat == k).astype(np.int32) for k, name in enumerate(materials)}
    return points, counts, vidx.astype(np.int32), uv, uv_idx, {k: v for k, v in groups.items() if v.size}


def _read_meshio(path: Path) -> tuple:
    try:
        mesh = meshio.read(path)
    except Exception as exc:  # noqa: BLE001 - report any reader failure the same way
        raise ValueError(f"{path}: not a readable surface mesh ({exc})") from exc
    counts, idx = [], []
    for block in mesh.cells:
        if block.type in ("triangle", "quad"):
            data = np.asarray(block.data, dtype=np.int64)
            counts.append(np.full(len(data), data.shape[1], dtype=np.int32))
            idx.append(data.ravel())
        elif block.type == "polygon":
            for poly in block.data:
                counts.append(np.array([len(poly)], dtype=np.int32))
                idx.append(np.asarray(poly, dtype=np.int64))
    if not counts:
        raise ValueError(f"{path}: no triangles, quads or polygons in the file")
    return np.asarray(mesh.points, dtype=np.float64)[:, :3], np.concatenate(counts), np.concatenate(idx), None, None, {}


def read_surface_mesh(path: str | Path, *, units: str | float = "auto") -> SurfaceMesh:
    """Read a surface mesh (OBJ with UVs and material groups; PLY, STL, OFF, ... through meshio).

    Args:
        path: the mesh file.
        units: "auto" (from the extent, module docstring), a unit name ("m", "cm", "mm", ...) or
            metres per unit.

    Returns:
        A ``SurfaceMesh`` in the file's units, with ``meters_per_unit`` set.

    Raises:
        FileNotFoundError: no such file.
        ValueError: unreadable file, no faces, or indices out of range.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    reader = _read_obj if path.suffix.lower() == ".obj" else _read_meshio
    points, counts, idx, uv, uv_idx, groups = reader(path)
    if np.any(counts < 3):
        raise ValueError(f"{path}: a face has fewer than 3 corners")
    if idx.size and (idx.min() < 0 or idx.max() >= len(points)):
        raise ValueError(f"{path}: face indices outside the {len(points)} vertices")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{path}: vertices contain NaN or inf")
    return SurfaceMesh(
        points=points,
        face_vertex_counts=counts.astype(np.int32),
        face_vertex_indices=idx.astype(np.int32),
        meters_per_unit=_meters_per_unit(units, points),
        uv=uv,
        uv_indices=uv_idx,
        face_groups=groups,
        source=str(path),
    )
