"""Loop subdivision as a constant linear map: refined positions y = S x of a triangle surface.

Loop (1987): every level splits each triangle into four through its edge midpoints and moves all
points by fixed masks, so the refined points are a fixed linear combination of the coarse ones and S
(sparse, rows summing to 1: affine invariant) is computed once from the connectivity alone:

- new point on an interior edge (a, b) with opposite vertices c, d: 3/8 (a + b) + 1/8 (c + d);
  on a boundary edge: 1/2 (a + b);
- old interior vertex of valence k: (1 - k beta) v + beta sum of its neighbours,
  beta = (5/8 - (3/8 + 1/4 cos(2 pi / k))^2) / k; old boundary vertex: 3/4 v + 1/8 (b0 + b1) with
  its two boundary neighbours (a corner with more than two, e.g. a non-manifold vertex, stays put).

The limit surface is C2 away from extraordinary vertices (C1 there); a few levels approach it. The
refined triangles keep the winding of their parents: (a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["loop_subdivision"]


def _one_level(tri: np.ndarray, n: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """(S (n + e, n), refined triangles) of one Loop level on vertices 0..n-1."""
    t = tri.shape[0]
    half = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 2)  # corner j -> j + 1
    opposite = np.roll(tri, -2, axis=1).reshape(-1)  # the corner opposite each half edge
    key = np.sort(half, axis=1)
    edges, edge_of, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    edge_of = edge_of.reshape(-1)
    e = len(edges)
    boundary = count[edge_of] == 1
    rows, cols, vals = [], [], []
    # edge points: rows n .. n + e - 1
    eb = count == 1
    for k, wt in ((0, 0.375), (1, 0.375)):
        rows.append(n + np.arange(e)[~eb])
        cols.append(edges[~eb, k])
        vals.append(np.full((~eb).sum(), wt))
        rows.append(n + np.arange(e)[eb])
        cols.append(edges[eb, k])
        vals.append(np.full(eb.sum(), 0.5))
    interior_half = ~boundary
    rows.append(n + edge_of[interior_half])
    cols.append(opposite[interior_half])
    vals.append(np.full(interior_half.sum(), 0.125))
    # old vertices
    nb = sp.coo_matrix((np.ones(2 * e), (edges.ravel(), edges[:, ::-1].ravel())), shape=(n, n)).tocsr()
    nb.data[:] = 1.0
    valence = np.asarray(nb.sum(axis=1)).ravel()
    bnb = sp.coo_matrix((np.ones(2 * eb.sum()), (edges[eb].ravel(), edges[eb][:, ::-1].ravel())), shape=(n, n)).tocsr()
    bnb.data[:] = 1.0
    bval = np.asarray(bnb.sum(axis=1)).ravel()
    used = valence > 0
    on_boundary = bval > 0
    inner = used & ~on_boundary
    k = np.maximum(valence, 1)
    beta = (0.625 - (0.375 + 0.25 * np.cos(2 * np.pi / k)) ** 2) / k
    nbc = nb.tocoo()
    sel = inner[nbc.row]
    rows.append(nbc.row[sel])
    cols.append(nbc.col[sel])
    vals.append(beta[nbc.row[sel]])
    regular_b = on_boundary & (bval == 2)
    bc = bnb.tocoo()
    sel = regular_b[bc.row]
    rows.append(bc.row[sel])
    cols.append(bc.col[sel])
    vals.append(np.full(sel.sum(), 0.125))
    self_w = np.where(inner, 1.0 - valence * beta, np.where(regular_b, 0.75, 1.0))
    rows.append(np.arange(n))
    cols.append(np.arange(n))
    vals.append(self_w)
    S = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n + e, n)).tocsr()
    mid = n + edge_of.reshape(t, 3)  # mid[:, j]: the edge from corner j to j + 1
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc_, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    refined = np.concatenate(
        [np.stack([a, ab, ca], 1), np.stack([ab, b, bc_], 1), np.stack([ca, bc_, c], 1), np.stack([ab, bc_, ca], 1)]
    )
    return S, refined


def loop_subdivision(triangles: np.ndarray, levels: int) -> tuple[np.ndarray, sp.csr_matrix, np.ndarray]:
    """Loop-subdivide a triangle surface ``levels`` times (module docstring).

    Args:
        triangles: (t, 3) vertex ids of any numbering (e.g. model node ids).
        levels: number of levels (0: the surface itself).

    Returns:
        (nodes (v,) the vertex ids used, ascending; S (V, v) CSR with y = S @ x[nodes];
        refined triangles (4^levels t, 3) indexing the rows of S).
    """
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if int(levels) != levels or levels < 0:
        raise ValueError(f"levels must be an integer >= 0, got {levels}")
    nodes, local = np.unique(tri, return_inverse=True)
    tri = local.reshape(-1, 3)
    S = sp.identity(len(nodes), format="csr")
    for _ in range(int(levels)):
        step, tri = _one_level(tri, S.shape[0])
        S = (step @ S).tocsr()
    return nodes, S, tri
