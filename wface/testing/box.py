"""Structured tetrahedral meshes of a box (for tests and benchmarks).

Each hexahedral cell is split into six tetrahedra around its main diagonal (Kuhn / Freudenthal
split), which conforms across cells. All tets are returned positively oriented
(det[x1 - x0, x2 - x0, x3 - x0] > 0).
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_tet_mesh", "box_tet_mesh_with_count"]

# The six Kuhn simplices of the unit cube: paths 0 -> 7 through the corners (bit 0 = x, 1 = y, 2 = z).
_KUHN = np.array(
    [
        [0, 1, 3, 7],
        [0, 1, 5, 7],
        [0, 2, 3, 7],
        [0, 2, 6, 7],
        [0, 4, 5, 7],
        [0, 4, 6, 7],
    ]
)


def box_tet_mesh(
    cells: tuple[int, int, int], size_m: tuple[float, float, float] = (1.0, 1.0, 1.0), *, origin_m=(0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """A box of ``cells = (nx, ny, nz)`` hexahedra, each cut into 6 tets.

    Args:
        cells: number of cells along x, y, z (each >= 1).
        size_m: box edge lengths in metres.
        origin_m: position of the box corner with the smallest coordinates.

    Returns:
        positions (n, 3) float64 with n = (nx+1)(ny+1)(nz+1), and tets (6 nx ny nz, 4) int32,
        positively oriented.
    """
    nx, ny, nz = (int(c) for c in cells)
    if min(nx, ny, nz) < 1:
        raise ValueError(f"box_tet_mesh needs at least one cell per axis, got {cells}")
    gx = np.linspace(0.0, size_m[0], nx + 1) + origin_m[0]
    gy = np.linspace(0.0, size_m[1], ny + 1) + origin_m[1]
    gz = np.linspace(0.0, size_m[2], nz + 1) + origin_m[2]
    X, Y, Z = np.meshgrid(gx, gy, gz, indexing="ij")
    positions = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)

    def node(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    corners = np.stack([node(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)) for c in range(8)], axis=1)
    tets = corners[:, _KUHN].reshape(-1, 4).astype(np.int32)
    p = positions[tets]
    vol = np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]))
    neg = vol < 0
    tets[neg, 1], tets[neg, 2] = tets[neg, 2].copy(), tets[neg, 1].copy()
    return positions, tets


def box_tet_mesh_with_count(target_tets: int, size_m=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """A box mesh with about ``target_tets`` tets, cells as close to cubes as the box allows."""
    volume = float(np.prod(size_m))
    h = (6.0 * volume / max(target_tets, 6)) ** (1.0 / 3.0)
    cells = tuple(max(1, round(s / h)) for s in size_m)
    return box_tet_mesh(cells, size_m)
