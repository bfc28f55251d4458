"""Points bound to a tetrahedral mesh, so that they move with it (a render mesh on the FEM face).

A point inside the tet mesh keeps its barycentric weights w in the tet that contains it:
p = sum_j w_j x_j, exact for any affine motion of the mesh. A point outside keeps its closest skin
point c (barycentric weights beta_j in a skin triangle t) and its rest offset o = p0 - c0, carried by
the local deformation gradient of the skin there:

    p = c(x) + F o,    F_S = sum_k x_k g_k^T,    g_k = C^-1 (X_k - Xbar),    C = sum_k (X_k - Xbar)(X_k - Xbar)^T

F_S is the least-squares affine fit of the motion of a node set S (rest positions X_k, current x_k),
so the offset turns and stretches with the flesh, F_S = A exactly under an affine motion
x = A X + b, and F_S = I at rest. Near the skin F is the triangle's own, S the nodes of the tets
that touch its corners (the most local fit). That F jumps from one triangle to the next, and a jump
times a long offset is a fold (a render mesh 25 mm behind the skin: edges shrank to a tenth at a
15 degree jaw opening). So with distance F hands over to a field that is continuous over the skin,
the corners' own fits interpolated at the closest point (S_j the nodes of the tets that touch
vertex j or its skin neighbours):

    F = (1 - s) F_t + s sum_j beta_j F_j,    s = smoothstep(|o| / L),    L = 2 x the skin's median edge

For a point on the skin's normal this is "closest skin point plus normal offset"; points off to the
side (the back of a head beyond the face patch) keep their whole offset, so the rest mesh is
reproduced exactly (every F_S is I at rest, and a convex blend of exact fits stays exact).

Anchors (``anchor_points``): a point far from the skin swings with the local F_t by its whole lever
arm (the base of a neck 100 mm below a chin that opens). It can be handed, wholly or in part, to an
anchor: a node set (a bone's attached nodes) whose least-squares affine motion carries it,

    p = (1 - b) p_skin + b (xbar_a + F_a (p0 - Xbar_a)),    F_a = sum_k x_k g_k^T  over the anchor's nodes,

with a blend weight b in [0, 1]. F_a = A under an affine motion and I at rest, so the binding stays
exact in both cases.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from wface.mesh.closest import SurfaceQuery

__all__ = ["Anchors", "PointBinding", "anchor_points", "bind_points", "containing_tets"]

_INSIDE_TOL = 1e-9  # barycentric slack: a point on a shared face belongs to either tet


@dataclass
class Anchors:
    """Points carried (in part) by the affine motion of node sets (module docstring). c anchored points."""

    nodes: list  # per anchor: (k_a,) node ids
    g: list  # per anchor: (k_a, 3) g_k, 1/m
    mean_m: np.ndarray  # (A, 3) rest centroid of each anchor's nodes
    point: np.ndarray  # (c,) point ids
    anchor_of: np.ndarray  # (c,) anchor index
    weight: np.ndarray  # (c,) blend weight b in (0, 1]
    offset_m: np.ndarray  # (c, 3) p0 - Xbar of the point's anchor

    def positions(self, x: np.ndarray) -> np.ndarray:
        """(c, 3) anchored positions for node positions ``x``."""
        out = np.empty((len(self.point), 3))
        for a, (nodes, g) in enumerate(zip(self.nodes, self.g, strict=True)):
            sel = self.anchor_of == a
            if not sel.any():
                continue
            xa = x[nodes]
            F = xa.T @ g  # sum_k x_k g_k^T (g sums to zero over k)
            out[sel] = xa.mean(axis=0) + self.offset_m[sel] @ F.T
        return out


@dataclass
class PointBinding:
    """Points bound to a tet mesh (module docstring). Shapes: n points, a inside, b outside."""

    n_points: int
    inside: np.ndarray  # (a,) point ids
    tet_nodes: np.ndarray  # (a, 4) node ids of the containing tet
    tet_weights: np.ndarray  # (a, 4) barycentric weights
    outside: np.ndarray  # (b,) point ids
    tri_nodes: np.ndarray  # (b, 3) node ids of the closest skin triangle
    tri_weights: np.ndarray  # (b, 3) barycentric weights of the closest skin point
    offset_m: np.ndarray  # (b, 3) rest offset p0 - c0
    frame_of: np.ndarray  # (b, 4) rows into frame_nodes / frame_g: the triangle's fit, its corners' fits
    frame_weight: np.ndarray  # (b, 4) blend weights of those fits (1 - s, s beta_j), summing to 1
    frame_nodes: np.ndarray  # (f, K) neighbourhood node ids (padded with node 0)
    frame_g: np.ndarray  # (f, K, 3) g_k (zero for padding), 1/m
    anchors: Anchors | None = None  # far points carried by node sets (``anchor_points``)

    @property
    def distance_m(self) -> np.ndarray:
        """(n,) distance of each point to the mesh at rest (0 inside)."""
        d = np.zeros(self.n_points)
        d[self.outside] = np.linalg.norm(self.offset_m, axis=1)
        return d

    def positions(self, x_m: np.ndarray) -> np.ndarray:
        """(n, 3) point positions for node positions ``x_m`` (n_nodes, 3)."""
        x = np.asarray(x_m, dtype=np.float64)
        out = np.empty((self.n_points, 3))
        out[self.inside] = np.einsum("kj,kjd->kd", self.tet_weights, x[self.tet_nodes])
        if len(self.outside):
            c = np.einsum("kj,kjd->kd", self.tri_weights, x[self.tri_nodes])
            F = np.einsum("fkd,fke->fde", x[self.frame_nodes], self.frame_g)  # (f, 3, 3) per node set
            F_point = np.einsum("kj,kjde->kde", self.frame_weight, F[self.frame_of])
            out[self.outside] = c + np.einsum("kde,ke->kd", F_point, self.offset_m)
        if self.anchors is not None and len(self.anchors.point):
            a, b = self.anchors, self.anchors.weight[:, None]
            out[a.point] = (1.0 - b) * out[a.point] + b * a.positions(x)
        return out


@dataclass
class _BoxGrid:
    """A uniform grid of cells over axis-aligned boxes (lo, hi: (m, 3)), each box listed in every cell it covers
    (``box`` sorted by cell ``key``). The cell is the boxes' median size, doubled until the boxes cover at most 64
    cells each on average (a few huge boxes must not fill memory)."""

    lo: np.ndarray
    hi: np.ndarray
    tol: float
    origin: np.ndarray
    h: float
    dims: np.ndarray
    key: np.ndarray
    box: np.ndarray

    @classmethod
    def build(cls, lo: np.ndarray, hi: np.ndarray, tol: float) -> _BoxGrid:
        origin = lo.min(axis=0) - tol
        h = max(float(np.median((hi - lo).max(axis=1))), 1e-12)
        while True:
            i0 = np.floor((lo - tol - origin) / h).astype(np.int64)
            span = np.floor((hi + tol - origin) / h).astype(np.int64) - i0 + 1
            count = span.prod(axis=1)
            if count.sum() <= 64 * len(lo):
                break
            h *= 2.0
        dims = (i0 + span).max(axis=0)
        box = np.repeat(np.arange(len(lo)), count)
        local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        sy, sz = span[box, 1], span[box, 2]
        cell = i0[box] + np.column_stack([local // (sy * sz), (local // sz) % sy, local % sz])
        key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        order = np.argsort(key, kind="stable")
        return cls(lo, hi, tol, origin, h, dims, key[order], box[order])

    def pairs(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point ids, box ids) of every box that holds a point."""
        dims = self.dims
        pc = np.floor((points - self.origin) / self.h).astype(np.int64)
        valid = np.all((pc >= 0) & (pc < dims), axis=1)
        pkey = (pc[:, 0] * dims[1] + pc[:, 1]) * dims[2] + pc[:, 2]
        first = np.searchsorted(self.key, pkey, side="left")
        n = np.where(valid, np.searchsorted(self.key, pkey, side="right") - first, 0)
        pid = np.repeat(np.arange(len(points)), n)
        cand = self.box[np.repeat(first, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)]
        lo, hi, tol = self.lo[cand], self.hi[cand], self.tol
        inside = np.all((points[pid] >= lo - tol) & (points[pid] <= hi + tol), axis=1)
        return pid[inside], cand[inside]


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(k, 4) barycentric weights of (k, 3) points in (k, 4, 3) tets."""
    D = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 0]], axis=2)
    w123 = np.linalg.solve(D, (points - corners[:, 0])[:, :, None])[:, :, 0]
    return np.column_stack([1.0 - w123.sum(axis=1), w123])


def containing_tets(points, x, tets, k: int = 16, *, nearest: bool = False):
    """(tet id or -1, (n, 4) weights) of the tet containing each point: every tet whose bounding box holds the point
    is tested (``_BoxGrid``), so a large tet among small ones is found; a point on a face shared by several tets
    takes the one whose centroid is nearest.

    ``nearest``: a point in no tet takes, among the ``k`` tets with the nearest centroids, the one it is least
    outside of (largest smallest barycentric weight; e.g. a point under a curved face that the tets flatten) instead
    of -1 (its weights are then those in that tet)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x = np.asarray(x, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    corners = x[tets]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    tol = 1e-9 * float(np.max(hi - lo)) if len(tets) else 0.0
    found = np.full(len(points), -1, dtype=np.int64)
    weights = np.zeros((len(points), 4))
    if not len(tets) or not len(points):
        return found, weights
    centroid = corners.mean(axis=1)
    grid = _BoxGrid.build(lo, hi, tol)
    for s in range(0, len(points), 65536):  # bounded memory
        pid, cand = grid.pairs(points[s : s + 65536])
        pid = pid + s
        w = _barycentric(points[pid], corners[cand])
        hit = w.min(axis=1) >= -_INSIDE_TOL
        pid, cand, w = pid[hit], cand[hit], w[hit]
        d2 = np.sum((centroid[cand] - points[pid]) ** 2, axis=1)
        order = np.lexsort((d2, pid))  # per point, the nearest centroid first
        pid, cand, w = pid[order], cand[order], w[order]
        first = np.r_[True, pid[1:] != pid[:-1]][: len(pid)]
        found[pid[first]], weights[pid[first]] = cand[first], w[first]
    out = np.flatnonzero(found < 0)
    if nearest and out.size:
        _, near = cKDTree(centroid).query(points[out], k=min(k, len(tets)))
        near = near.reshape(len(out), -1)
        w = _barycentric(np.repeat(points[out], near.shape[1], axis=0), corners[near.reshape(-1)])
        w = w.reshape(len(out), near.shape[1], 4)
        j = np.argmax(w.min(axis=2), axis=1)
        found[out] = near[np.arange(len(out)), j]
        weights[out] = w[np.arange(len(out)), j]
    return found, weights


def _affine_g(X: np.ndarray, *, check: bool = False) -> np.ndarray | None:
    """g_k = C^-1 (X_k - Xbar) of a node set (module docstring); with ``check``, None if its nodes do not
    span 3D."""
    D = X - X.mean(axis=0)
    C = D.T @ D
    if check:
        s = np.linalg.svd(C, compute_uv=False)
        if len(X) < 4 or s[-1] <= 1e-9 * s[0]:
            return None
    return np.linalg.solve(C, D.T).T


def anchor_points(
    binding: PointBinding,
    points_m: np.ndarray,
    rest_positions_m: np.ndarray,
    anchor_nodes: list,
    anchor_of: np.ndarray,
    weight: np.ndarray,
) -> PointBinding:
    """``binding`` with points handed to anchors (module docstring).

    Args:
        binding: from ``bind_points(points_m, rest_positions_m, ...)``.
        points_m: (n, 3) the bound points at rest.
        rest_positions_m: (N, 3) rest node positions.
        anchor_nodes: per anchor, its node ids (a bone's attached nodes).
        anchor_of: (n,) anchor index per point, -1 for none.
        weight: (n,) blend weight in [0, 1]; 0 leaves a point as bound.

    Returns:
        A new ``PointBinding``; an anchor whose nodes do not span 3D anchors nothing.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    x = np.asarray(rest_positions_m, dtype=np.float64)
    anchor_of = np.asarray(anchor_of, dtype=np.int64).reshape(-1)
    weight = np.clip(np.asarray(weight, dtype=np.float64).reshape(-1), 0.0, 1.0)
    if anchor_of.shape != (binding.n_points,) or weight.shape != (binding.n_points,) or len(p) != binding.n_points:
        raise ValueError(f"anchor_points: expected {binding.n_points} points, anchors and weights")
    nodes = [np.asarray(a, dtype=np.int64) for a in anchor_nodes]
    gs = [_affine_g(x[a], check=True) for a in nodes]
    usable = np.array([g is not None for g in gs] + [False])  # index -1 -> False
    pick = np.flatnonzero((anchor_of >= 0) & (weight > 0) & usable[anchor_of])
    mean = np.array([x[a].mean(axis=0) if len(a) else np.zeros(3) for a in nodes]).reshape(-1, 3)
    anchors = Anchors(
        nodes=nodes,
        g=[g if g is not None else np.zeros((len(a), 3)) for a, g in zip(nodes, gs, strict=True)],
        mean_m=mean,
        point=pick,
        anchor_of=anchor_of[pick],
        weight=weight[pick],
        offset_m=p[pick] - mean[anchor_of[pick]],
    )
    return PointBinding(**{**binding.__dict__, "anchors": anchors})


def _frames(x, tets, skin_triangles, used_tris, used_verts):
    """Node sets and g_k of the fits F_S (module docstring): one per used skin triangle (the tets touching
    its corners), then one per used skin vertex (the tets touching it or its skin neighbours)."""
    n = len(x)
    node_tets = [[] for _ in range(n)]
    for t, row in enumerate(tets):
        for v in row:
            node_tets[v].append(t)
    ring = [[] for _ in range(n)]
    for row in skin_triangles:
        for v in row:
            ring[v].extend(row)
    sets = [skin_triangles[t] for t in used_tris] + [np.unique(ring[v]) for v in used_verts]
    groups = [np.unique(tets[np.unique(np.concatenate([node_tets[u] for u in vs]))].ravel()) for vs in sets]
    K = max(len(g) for g in groups)
    nodes = np.zeros((len(groups), K), dtype=np.int64)
    g_out = np.zeros((len(groups), K, 3))
    for i, g in enumerate(groups):
        nodes[i, : len(g)] = g
        g_out[i, : len(g)] = _affine_g(x[g])
    return nodes, g_out


def bind_points(
    points_m: np.ndarray, rest_positions_m: np.ndarray, tets: np.ndarray, skin_triangles: np.ndarray
) -> PointBinding:
    """Bind (n, 3) points to a tet mesh at rest (module docstring).

    Args:
        points_m: (n, 3) points in the mesh's frame, metres.
        rest_positions_m: (N, 3) rest node positions.
        tets: (m, 4) tets.
        skin_triangles: (t, 3) the skin, for points outside the tets.

    Returns:
        A ``PointBinding``; ``positions(rest_positions_m)`` gives the points back.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    x = np.asarray(rest_positions_m, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    skin = np.asarray(skin_triangles, dtype=np.int64)
    if not np.all(np.isfinite(p)):
        raise ValueError("bind_points: points contain NaN or inf")
    tet, w = containing_tets(p, x, tets)
    inside = np.flatnonzero(tet >= 0)
    outside = np.flatnonzero(tet < 0)
    tri = np.zeros(0, dtype=np.int64)
    bary = np.zeros((0, 3))
    c = np.zeros((0, 3))
    if outside.size:
        query = SurfaceQuery(x, skin)
        hits = [query.closest(p[outside[s : s + 256]]) for s in range(0, outside.size, 256)]  # bounded memory
        tri = np.concatenate([h.triangle for h in hits])
        bary = np.concatenate([h.barycentric for h in hits])
        c = np.concatenate([h.point_m for h in hits])
    used_tris, tri_row = np.unique(tri, return_inverse=True)
    used_verts, vert_row = np.unique(skin[tri], return_inverse=True)
    if tri.size:
        nodes, g = _frames(x, tets, skin, used_tris, used_verts)
    else:
        nodes, g = np.zeros((0, 1), np.int64), np.zeros((0, 1, 3))
    edges = np.linalg.norm(x[skin] - x[np.roll(skin, 1, axis=1)], axis=2)
    s = np.clip(np.linalg.norm(p[outside] - c, axis=1) / (2.0 * np.median(edges)), 0.0, 1.0)[:, None]
    s = s * s * (3.0 - 2.0 * s)  # smoothstep
    return PointBinding(
        n_points=len(p),
        inside=inside,
        tet_nodes=tets[tet[inside]],
        tet_weights=w[inside],
        outside=outside,
        tri_nodes=skin[tri],
        tri_weights=bary,
        offset_m=p[outside] - c,
        frame_of=np.column_stack([tri_row.reshape(-1), len(used_tris) + vert_row.reshape(-1, 3)]),
        frame_weight=np.column_stack([1.0 - s, s * bary]),
        frame_nodes=nodes,
        frame_g=g,
    )
