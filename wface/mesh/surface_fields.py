"""Scattered data on a triangle surface: distances along the mesh and the surface thin-plate spline.

Distances along the surface are shortest paths in the edge graph (Dijkstra), edge weight = edge
length; each scattered point is a graph node joined to the three corners of its triangle by the
straight distances. Graph distances overestimate geodesics by a few per cent on regular meshes,
never underestimate them, and, unlike straight distances, are long between parts of the surface
that touch without being connected (the lips across the mouth opening, the eyelids).

The surface thin-plate spline is the discrete biharmonic interpolant: with the cotangent
Laplacian L (the P1 stiffness matrix) and the lumped vertex areas M,

    u = argmin_u  u^T L^T M^-1 L u   subject to   C u = d,

where the rows of C are the barycentric weights of the data points (exact at the points, not at
their nearest vertices). ``int |Lap u|^2 dA`` is the energy the planar thin-plate spline
minimises, here measured on the surface, so data on one lip cannot reach the other lip except
around the mouth corners. Constants are reproduced exactly, affine fields only approximately
(the natural boundary conditions of L^T M^-1 L bend them, by a few per cent of their range on
a small sheet; the Hessian energy of Stein et al. 2018 would reproduce them exactly).
Solved as the saddle-point system [[Q, C^T], [C, -s/q I]] [u; mu] = [0; d] (Q = L^T M^-1 L, q its
mean diagonal, s = smoothing >= 0).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import bmat, coo_matrix, diags, identity
from scipy.sparse.csgraph import dijkstra
from scipy.sparse.linalg import splu

__all__ = ["biharmonic_interpolate", "cotangent_laplacian", "edge_graph", "surface_distances"]


def edge_graph(vertices_m: np.ndarray, triangles: np.ndarray):
    """Symmetric sparse (n, n) CSR matrix of edge lengths of the triangles' edges."""

    x = np.asarray(vertices_m, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    length = np.maximum(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1), 1e-15)  # 0 would mean "no edge"
    n = len(x)
    g = coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n, n))
    return (g + g.T).tocsr()


def surface_distances(
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    point_triangles: np.ndarray,
    barycentric: np.ndarray,
    *,
    limit_m: float = np.inf,
    per_point: bool = False,
) -> np.ndarray:
    """Graph distances along the surface from points embedded in triangles.

    Args:
        vertices_m: (n, 3) vertex positions, metres.
        triangles: (t, 3) vertex ids.
        point_triangles: (k,) triangle of each point.
        barycentric: (k, 3) weights of the point in its triangle.
        limit_m: stop the search at this distance (farther vertices get inf).
        per_point: (k, n) distances from each point; default (n,) distance to the nearest point.

    Returns:
        (n,) or (k, n) distances in metres (inf: farther than ``limit_m`` or not connected).
    """

    x = np.asarray(vertices_m, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    pt = np.asarray(point_triangles, dtype=np.int64)
    w = np.asarray(barycentric, dtype=np.float64)
    n, k = len(x), len(pt)
    corners = tri[pt]  # (k, 3)
    p = np.einsum("kj,kjd->kd", w, x[corners])
    link = np.maximum(np.linalg.norm(x[corners] - p[:, None, :], axis=2), 1e-15)
    pv = coo_matrix((link.ravel(), (np.repeat(np.arange(k), 3), corners.ravel())), shape=(k, n))
    g = bmat([[edge_graph(x, tri), pv.T], [pv, None]], format="csr")  # points are nodes n..n+k-1
    src = np.arange(n, n + k)
    d = dijkstra(g, directed=False, indices=src, limit=limit_m, min_only=not per_point)
    return d[..., :n]


def cotangent_laplacian(vertices_m: np.ndarray, triangles: np.ndarray) -> tuple:
    """Cotangent Laplacian (positive semidefinite P1 stiffness) and lumped vertex areas.

    Returns:
        (L, areas): L sparse (n, n) CSR with L 1 = 0; areas (n,) one third of the adjacent
        triangle areas (m^2), floored so that isolated vertices do not divide by zero.
    """

    x = np.asarray(vertices_m, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    n = len(x)
    area2 = np.linalg.norm(np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]), axis=1)
    scale = float(np.median(area2)) if len(area2) else 1.0
    area2_safe = np.maximum(area2, 1e-9 * scale)  # degenerate triangles: bounded cotangents
    rows, cols, vals = [], [], []
    for a in range(3):
        i, j, o = tri[:, (a + 1) % 3], tri[:, (a + 2) % 3], tri[:, a]
        cot = np.einsum("td,td->t", x[i] - x[o], x[j] - x[o]) / area2_safe  # angle at o, edge ij
        rows += [i, j, i, j]
        cols += [j, i, i, j]
        vals += [-0.5 * cot, -0.5 * cot, 0.5 * cot, 0.5 * cot]
    lap = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    areas = np.bincount(tri.ravel(), weights=np.repeat(area2 / 6.0, 3), minlength=n)
    return lap, np.maximum(areas, 1e-6 * max(scale, 1e-300))


def biharmonic_interpolate(
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    point_triangles: np.ndarray,
    barycentric: np.ndarray,
    values: np.ndarray,
    *,
    smoothing: float = 0.0,
) -> np.ndarray:
    """Surface thin-plate spline through values at points embedded in the triangles.

    Every connected part of the surface needs at least one point (else the field there is
    undetermined); callers restrict the surface to the vertices they want moved.

    Args:
        vertices_m: (n, 3) vertex positions, metres.
        triangles: (t, 3) vertex ids (vertices in no triangle get 0).
        point_triangles: (k,) triangle of each data point.
        barycentric: (k, 3) weights of each point in its triangle.
        values: (k, m) data (any units); m fields are solved at once.
        smoothing: s >= 0; 0 interpolates exactly, s > 0 trades exactness for a smaller bending
            energy: minimises u^T Q u + (q / s) |C u - d|^2 with q the mean diagonal of Q (so s is
            dimensionless; ~1e-2 smooths noticeably). Needed when two points carry the same
            constraint (e.g. two markers at one place).

    Returns:
        (n, m) vertex values.
    """

    x = np.asarray(vertices_m, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    vals = np.asarray(values, dtype=np.float64)
    vals = vals.reshape(len(vals), -1)
    n, k = len(x), len(vals)
    used = np.zeros(n, dtype=bool)
    used[tri.ravel()] = True
    ids = np.flatnonzero(used)
    local = np.full(n, -1, dtype=np.int64)
    local[ids] = np.arange(len(ids))
    lt = local[tri]
    lap, areas = cotangent_laplacian(x[ids], lt)
    q = (lap.T @ diags(1.0 / areas) @ lap).tocsc()
    c = coo_matrix(
        (np.asarray(barycentric, dtype=np.float64).ravel(), (np.repeat(np.arange(k), 3), lt[point_triangles].ravel())),
        shape=(k, len(ids)),
    )
    alpha = float(q.diagonal().mean()) or 1.0  # constraint rows scaled to the size of Q: better pivots
    reg = coo_matrix((k, k)) if smoothing <= 0 else -float(smoothing) * alpha * identity(k)
    kkt = bmat([[q, alpha * c.T], [alpha * c, reg]], format="csc")
    rhs = np.zeros((len(ids) + k, vals.shape[1]))
    rhs[len(ids) :] = alpha * vals
    try:
        lu = splu(kkt)
    except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
        raise ValueError(f"biharmonic_interpolate: the constraints are dependent ({exc}): two data points in the "
                         "same place, or a part of the surface without one; use smoothing > 0") from None  # fmt: skip
    sol = lu.solve(rhs)
    out = np.zeros((n, vals.shape[1]))
    out[ids] = sol[: len(ids)]
    return out
