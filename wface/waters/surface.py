"""Polygon surface meshes for the Waters tools: read (OBJ, or anything meshio reads), write OBJ and USD.

Positions are metres in memory. Files in other units are converted on read (``units``), with
``"auto"`` guessing from the bounding box of a head-sized object (< 2 -> m, < 100 -> cm, else mm).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import meshio
import numpy as np

from wface.io.usd import write_mesh_animation

__all__ = ["SurfaceMesh", "guess_units", "read_surface", "write_obj", "write_usd"]

_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass
class SurfaceMesh:
    """A polygon mesh: (n, 3) vertices in metres and USD-style flat polygon topology."""

    vertices_m: np.ndarray
    face_vertex_counts: np.ndarray  # (p,) int32
    face_vertex_indices: np.ndarray  # (sum counts,) int32

    def __post_init__(self) -> None:
        self.vertices_m = np.asarray(self.vertices_m, dtype=np.float64)
        self.face_vertex_counts = np.asarray(self.face_vertex_counts, dtype=np.int32).reshape(-1)
        self.face_vertex_indices = np.asarray(self.face_vertex_indices, dtype=np.int32).reshape(-1)
        if self.vertices_m.ndim != 2 or self.vertices_m.shape[1] != 3:
            raise ValueError(f"vertices must have shape (n, 3), got {self.vertices_m.shape}")
        if not np.all(np.isfinite(self.vertices_m)):
            raise ValueError("mesh vertices contain NaN or inf")
        if np.any(self.face_vertex_counts < 3) or self.face_vertex_counts.sum() != self.face_vertex_indices.size:
            raise ValueError("face_vertex_counts must be >= 3 and sum to the number of face vertex indices")
        idx = self.face_vertex_indices
        if idx.size and (idx.min() < 0 or idx.max() >= len(self.vertices_m)):
            raise ValueError(f"faces reference vertices outside [0, {len(self.vertices_m)})")

    @classmethod
    def from_triangles(cls, vertices_m: np.ndarray, triangles: np.ndarray) -> SurfaceMesh:
        t = np.asarray(triangles, dtype=np.int32).reshape(-1, 3)
        return cls(vertices_m, np.full(len(t), 3, np.int32), t.ravel())

    @property
    def n_vertices(self) -> int:
        return int(self.vertices_m.shape[0])

    def triangles(self) -> np.ndarray:
        """(t, 3) int32 fan triangulation of the polygons (vectorised)."""
        counts = self.face_vertex_counts
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        n_tri = counts - 2
        owner = np.repeat(np.arange(len(counts)), n_tri)
        k = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)
        s = starts[owner]
        idx = self.face_vertex_indices
        return np.stack([idx[s], idx[s + k + 1], idx[s + k + 2]], axis=1).astype(np.int32)

    def with_vertices(self, vertices_m: np.ndarray) -> SurfaceMesh:
        """The same topology with new vertex positions (n, 3)."""
        v = np.asarray(vertices_m, dtype=np.float64)
        if v.shape != self.vertices_m.shape:
            raise ValueError(f"new vertices have shape {v.shape}, expected {self.vertices_m.shape}")
        return SurfaceMesh(v, self.face_vertex_counts, self.face_vertex_indices)


def guess_units(vertices: np.ndarray) -> str:
    """Guess the length unit of a head-sized mesh from its bounding-box diagonal."""
    ext = float(np.linalg.norm(np.ptp(np.asarray(vertices, dtype=np.float64), axis=0)))
    return "m" if ext < 2.0 else "cm" if ext < 100.0 else "mm"


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    verts, counts, indices = [], [], []
    with path.open() as f:
        for line in f:
            if line.startswith("v "):
                verts.append(line.split()[1:4])
            elif line.startswith("f "):
                ids = [int(tok.split("/")[0]) for tok in line.split()[1:]]
                counts.append(len(ids))
                indices.extend(ids)
    if not verts:
        raise ValueError(f"{path}: no vertices ('v' lines) found")
    v = np.asarray(verts, dtype=np.float64)
    idx = np.asarray(indices, dtype=np.int64)
    idx = np.where(idx < 0, len(v) + idx, idx - 1)  # OBJ is 1-based; negatives count from the end
    return v, np.asarray(counts, dtype=np.int32), idx.astype(np.int32)


def read_surface(path: str | Path, *, units: str = "auto") -> SurfaceMesh:
    """Read a polygon surface; OBJ by a small reader (keeps polygons and their order), others via meshio.

    Args:
        path: mesh file.
        units: length unit of the file ("m", "cm", "mm") or "auto".
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if path.suffix.lower() == ".obj":
        v, counts, idx = _read_obj(path)
    else:
        m = meshio.read(path)
        v = np.asarray(m.points, dtype=np.float64)[:, :3]
        polys = [c.data for c in m.cells if c.type in ("triangle", "quad") or c.type.startswith("polygon")]
        if not polys:
            raise ValueError(f"{path}: no surface polygons (triangles or quads) found")
        counts = np.concatenate([np.full(len(p), p.shape[1], np.int32) for p in polys])
        idx = np.concatenate([p.ravel() for p in polys]).astype(np.int32)
    if units == "auto":
        units = guess_units(v)
    if units not in _UNITS:
        raise ValueError(f"unknown units {units!r}; use one of m, cm, mm or auto")
    return SurfaceMesh(v * _UNITS[units], counts, idx)


def write_obj(path: str | Path, mesh: SurfaceMesh) -> Path:
    """Write an OBJ (positions in metres, polygons as given)."""
    path = Path(path)
    lines = ["# wface waters output, units: metres"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.vertices_m]
    ends = np.cumsum(mesh.face_vertex_counts)
    for face in np.split(mesh.face_vertex_indices + 1, ends[:-1]):
        lines.append("f " + " ".join(map(str, face.tolist())))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_usd(path: str | Path, mesh: SurfaceMesh, *, frames_m: np.ndarray | None = None, fps: float = 24.0) -> Path:
    """Write the mesh (or an animation, ``frames_m`` (F, n, 3)) to USD via ``wface.io.usd``."""

    points = mesh.vertices_m if frames_m is None else np.asarray(frames_m, dtype=np.float64)
    return write_mesh_animation(
        path,
        points_m=points,
        face_vertex_counts=mesh.face_vertex_counts,
        face_vertex_indices=mesh.face_vertex_indices,
        fps=fps,
        name="WatersFace",
    )
