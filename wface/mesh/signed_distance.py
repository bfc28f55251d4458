"""Signed distance to triangle surfaces with angle-weighted pseudonormals.

The sign of p - c (c the closest surface point) against the pseudonormal of the feature that holds
c (the face normal inside a face, the sum of the two face normals on an edge, the angle-weighted
vertex normal at a vertex) is exact for closed, consistently oriented manifold meshes
(Baerentzen & Aanaes 2005, "Signed distance computation using the angle weighted pseudonormal").
For open surfaces it is the usual local test; closest points on a boundary edge or vertex are
flagged (``on_boundary``) so that callers can ignore them (the sign is meaningless there).

Orientation: the mesh is made outward-facing from the sign of its enclosed volume (measured from
its centroid), so inward-wound meshes (and open, cup-shaped ones) need no care from the caller.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from wface.mesh.closest import SurfaceQuery

__all__ = ["SignedHit", "SignedSurface", "oriented_outward"]

_ZERO_WEIGHT = 1e-12  # barycentric weights below this mark the closest point as on an edge / vertex


@dataclass
class SignedHit:
    """Signed closest-point result for k points.

    Attributes:
        phi_m: (k,) signed distance, positive outside.
        normal: (k, 3) unit outward direction: the gradient of phi (sign * (p - c) / |p - c|, or the
            feature's pseudonormal when p lies on the surface).
        triangle: (k,) closest triangle.
        barycentric: (k, 3) weights of the closest point on it.
        point_m: (k, 3) closest point.
        on_boundary: (k,) the closest point lies on an open boundary edge or vertex.
        feature: (k,) 0 when the closest point is inside a face, 1 on an edge, 2 at a vertex.
        edge_direction: (k, 3) unit direction of that edge (zero for faces and vertices).
    """

    phi_m: np.ndarray
    normal: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    point_m: np.ndarray
    on_boundary: np.ndarray
    feature: np.ndarray
    edge_direction: np.ndarray


def oriented_outward(vertices_m: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Triangles rewound consistently (neighbours across a manifold edge traverse it in opposite
    directions), each connected piece facing outward (positive enclosed volume from its centroid)."""

    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    nt = len(t)
    a, b = t.reshape(-1), np.roll(t, -1, axis=1).reshape(-1)
    owner = np.repeat(np.arange(nt), 3)
    key = np.minimum(a, b) * (int(t.max()) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    _, start, counts = np.unique(ks, return_index=True, return_counts=True)
    manifold = start[counts == 2]
    h1, h2 = order[manifold], order[manifold + 1]
    same = (a[h1] == a[h2]).astype(np.int8)  # 1: both traverse the edge the same way -> one must flip
    t1, t2 = owner[h1], owner[h2]
    # weights 1 (keep relative winding) / 2 (flip); symmetric adjacency
    w = np.concatenate([same, same]) + 1
    adj = coo_matrix((w, (np.concatenate([t1, t2]), np.concatenate([t2, t1]))), shape=(nt, nt)).tocsr()
    n_comp, label = connected_components(adj, directed=False)
    flip = np.zeros(nt, dtype=bool)
    for c in range(n_comp):
        root = int(np.flatnonzero(label == c)[0])
        visit, pred = breadth_first_order(adj, root, directed=False, return_predecessors=True)
        for node in visit[1:]:
            flip[node] = flip[pred[node]] ^ (adj[pred[node], node] == 2)
    t = np.where(flip[:, None], t[:, ::-1], t)
    v = np.asarray(vertices_m, dtype=np.float64)
    for c in range(n_comp):
        sel = label == c
        p = v[t[sel]] - v[np.unique(t[sel])].mean(axis=0)
        if np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() < 0:
            t[sel] = t[sel][:, ::-1]
    return np.ascontiguousarray(t)


@dataclass(frozen=True)
class _Topology:
    """What a surface's triangles alone fix: edge ids, open boundary, the vertices in use."""

    edge_of: np.ndarray  # (t, 3) edge id of local edge j (corners j, j+1; opposite corner j+2)
    boundary_edge: np.ndarray  # (e,) bool: the edge has one triangle
    boundary_vertices: np.ndarray  # ids of the vertices on a boundary edge
    vertices: np.ndarray  # sorted ids of the vertices the triangles use


_TOPOLOGY_CACHE: dict[bytes, _Topology] = {}
_TOPOLOGY_CACHE_SIZE = 64  # triangle sets kept (contact rebuilds the lips' surfaces at every evaluation)


def _topology(t: np.ndarray) -> _Topology:
    """The ``_Topology`` of (t, 3) int64 triangles, computed once per distinct triangle array: contact
    rebuilds a ``SignedSurface`` of the same triangles at new positions on every evaluation."""
    key = t.tobytes()
    hit = _TOPOLOGY_CACHE.get(key)
    if hit is not None:
        return hit
    pairs = np.sort(np.stack([t, np.roll(t, -1, axis=1)], axis=2), axis=2).reshape(-1, 2)
    _, edge_id, counts = np.unique(pairs, axis=0, return_inverse=True, return_counts=True)
    edge_id = edge_id.reshape(-1)
    boundary = counts == 1
    topo = _Topology(
        edge_of=edge_id.reshape(-1, 3),
        boundary_edge=boundary,
        boundary_vertices=np.unique(pairs[boundary[edge_id]]),
        vertices=np.unique(t),
    )
    for a in (topo.edge_of, topo.boundary_edge, topo.boundary_vertices, topo.vertices):
        a.flags.writeable = False  # shared by every surface of these triangles
    if len(_TOPOLOGY_CACHE) >= _TOPOLOGY_CACHE_SIZE:
        _TOPOLOGY_CACHE.pop(next(iter(_TOPOLOGY_CACHE)))
    _TOPOLOGY_CACHE[key] = topo
    return topo


class SignedSurface:
    """Signed distance queries on a triangle surface (positions fixed at construction).

    Args:
        vertices_m: (v, 3) positions.
        triangles: (t, 3) vertex ids.
        orient: flip the winding when the enclosed volume is negative (outward normals).
    """

    def __init__(self, vertices_m: np.ndarray, triangles: np.ndarray, *, orient: bool = True):
        v = np.asarray(vertices_m, dtype=np.float64)
        t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"surface vertices must be a finite (v, 3) array, got shape {v.shape}")
        if orient:
            t = oriented_outward(v, t)
        self.vertices_m, self.triangles = v, t
        self.query = SurfaceQuery(v, t, engine="bvh")
        p = v[t]
        fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        self.face_normals = fn
        # Angle-weighted vertex pseudonormals.
        vn = np.zeros_like(v)
        for j in range(3):
            e1 = p[:, (j + 1) % 3] - p[:, j]
            e2 = p[:, (j + 2) % 3] - p[:, j]
            cos = np.einsum("ij,ij->i", e1, e2) / np.maximum(
                np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300
            )
            np.add.at(vn, t[:, j], np.arccos(np.clip(cos, -1.0, 1.0))[:, None] * fn)
        self.vertex_normals = vn
        topo = _topology(t)
        en = np.zeros((topo.boundary_edge.size, 3))
        np.add.at(en, topo.edge_of.reshape(-1), np.repeat(fn, 3, axis=0))
        self._edge_of = topo.edge_of
        self.edge_normals = en
        self.boundary_edge = topo.boundary_edge
        self.boundary_vertex = np.zeros(len(v), dtype=bool)
        self.boundary_vertex[topo.boundary_vertices] = True
        self.closed = not bool(topo.boundary_edge.any())
        used = v[topo.vertices]
        self.lower_m = used.min(axis=0)
        self.upper_m = used.max(axis=0)

    def near_box(self, points_m: np.ndarray, margin_m: float) -> np.ndarray:
        """(k,) bool: points inside the surface's bounding box grown by ``margin_m``."""
        p = np.asarray(points_m, dtype=np.float64)
        return np.all((p >= self.lower_m - margin_m) & (p <= self.upper_m + margin_m), axis=1)

    def signed(self, points_m: np.ndarray) -> SignedHit:
        """Signed distance, outward gradient and closest feature for (k, 3) points."""
        p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
        k = len(p)
        if k == 0:
            z, z3 = np.zeros(0), np.zeros((0, 3))
            return SignedHit(z, z3, z.astype(np.int64), z3, z3, z > 0, z.astype(np.int8), z3)
        hit = self.query.closest(p)
        tri, w = hit.triangle, hit.barycentric
        zero = w <= _ZERO_WEIGHT
        nz = zero.sum(axis=1)
        pseudo = self.face_normals[tri].copy()
        on_boundary = np.zeros(k, dtype=bool)
        feature = np.minimum(nz, 2).astype(np.int8)
        edge_direction = np.zeros((k, 3))
        edge = nz == 1
        if edge.any():
            # the zero weight's corner is opposite the edge: local edge (corner + 1) % 3
            local = (np.argmax(zero[edge], axis=1) + 1) % 3
            eid = self._edge_of[tri[edge], local]
            pseudo[edge] = self.edge_normals[eid]
            on_boundary[edge] = self.boundary_edge[eid]
            ends = self.triangles[tri[edge]]
            e = (
                self.vertices_m[ends[np.arange(len(local)), (local + 1) % 3]]
                - self.vertices_m[ends[np.arange(len(local)), local]]
            )
            edge_direction[edge] = e / np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
        vert = nz >= 2
        if vert.any():
            vid = self.triangles[tri[vert], np.argmax(w[vert], axis=1)]
            pseudo[vert] = self.vertex_normals[vid]
            on_boundary[vert] = self.boundary_vertex[vid]
        d = p - hit.point_m
        sign = np.where(np.einsum("ij,ij->i", d, pseudo) < 0.0, -1.0, 1.0)
        dist = hit.distance_m
        normal = self.face_normals[tri].copy()
        far = dist > 1e-14 * max(float(np.abs(self.vertices_m).max()), 1e-300)
        normal[far] = sign[far, None] * d[far] / dist[far, None]
        return SignedHit(sign * dist, normal, tri, w, hit.point_m, on_boundary, feature, edge_direction)
