"""Boundary surfaces of tetrahedral meshes.

A tet face is on the boundary when no other tet shares it. Faces are oriented outward: for a
positively oriented tet (x0, x1, x2, x3) the outward faces are (1,2,3), (0,3,2), (0,1,3), (0,2,1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["boundary_faces", "surface_vertices", "triangle_normals", "vertex_normals"]

_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """(k, 3) int32 outward-oriented boundary triangles of a tet mesh with positive orientation."""
    tets = np.asarray(tets)
    faces = tets[:, _TET_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1].astype(np.int32)


def surface_vertices(triangles: np.ndarray) -> np.ndarray:
    """Sorted unique vertex ids used by a triangle list."""
    return np.unique(np.asarray(triangles).ravel())


def triangle_normals(vertices: np.ndarray, triangles: np.ndarray, *, normalize: bool = True) -> np.ndarray:
    """(t, 3) triangle normals (area-weighted when ``normalize`` is False)."""
    p = vertices[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    if normalize:
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return n


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 3) area-weighted unit vertex normals (zero for vertices not on any triangle)."""
    n = triangle_normals(vertices, triangles, normalize=False)
    out = np.zeros_like(np.asarray(vertices, dtype=np.float64))
    for j in range(3):
        np.add.at(out, triangles[:, j], n)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)
