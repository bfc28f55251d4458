"""Texture coordinates of a face's skin.

``skin_uv`` flattens the skin onto the unit square without turning any triangle over. The skin of
a face is a sphere with holes (the outer edge of the mask, and the mouth, eyes or nostrils where
the flesh turns inward); each inner hole is closed by a fan around a virtual vertex at its
centroid, so the surface is a disk, and the disk is mapped by Floater's mean-value Tutte embedding
(M. S. Floater, "Mean value coordinates", CAGD 20, 2003): the outer edge onto a circle by arc
length, every other vertex at the mean-value average of its neighbours (one sparse linear solve).
Mean-value weights are positive, so with a convex boundary the map is one-to-one and every
triangle keeps its orientation (Floater 2003, Theorem 1 via Tutte 1963), which a cylindrical
projection cannot give where the skin faces up or down (under the chin, the nostrils, the lips'
insides).

The map is then turned so that the face's +y (up) reads upward in v and is not mirrored (triangles
wound counter-clockwise about their outward normal are counter-clockwise in (u, v)), and scaled
uniformly into [0, 1]^2. Skins that are not a single sphere with holes (closed, several pieces, a
handle, or a vertex where two boundary loops touch) get ``cylindrical_uv``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph  # noqa: F401  (sp.csgraph)
import scipy.sparse.linalg as spla

__all__ = ["boundary_loops", "cylindrical_uv", "skin_uv"]


def cylindrical_uv(points: np.ndarray) -> np.ndarray:
    """(n, 2) texture coordinates of a face's skin: u = angle about +y / 2 pi (0.5 at the front, +z),
    v = height in [0, 1] (a cylindrical projection about the points' centroid; surfaces facing
    straight up or down, such as under the chin, are squeezed by it, and some turn over)."""
    points = np.asarray(points, dtype=np.float64)
    c = points.mean(axis=0)
    u = 0.5 + np.arctan2(points[:, 0] - c[0], points[:, 2] - c[2]) / (2 * np.pi)
    lo, hi = points[:, 1].min(), points[:, 1].max()
    v = (points[:, 1] - lo) / max(hi - lo, 1e-12)
    return np.stack([u, v], axis=1)


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray] | None:
    """Ordered vertex loops of an oriented triangle mesh's boundary, each following its half-edges.

    Returns None when the boundary is not a set of simple loops (a vertex with two outgoing boundary
    half-edges, or an edge used twice in the same direction: inconsistent winding).
    """
    tri = np.asarray(triangles, dtype=np.int64)
    half = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    n = int(tri.max()) + 1 if tri.size else 0
    key = half[:, 0] * n + half[:, 1]
    if len(np.unique(key)) != len(key):
        return None
    twin = half[:, 1] * n + half[:, 0]
    border = half[~np.isin(twin, key)]
    nxt: dict[int, int] = {}
    for a, b in border.tolist():
        if a in nxt:
            return None
        nxt[a] = b
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt.get(v)
            if v is None:
                return None
        if v != start:
            return None
        loops.append(np.array(loop, dtype=np.int64))
    return loops


def _is_sphere_with_holes(tri: np.ndarray, n_holes: int) -> bool:
    """One connected piece whose Euler characteristic is that of a sphere with ``n_holes`` holes."""
    used = np.unique(tri)
    edges = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1), axis=0)
    if len(used) - len(edges) + len(tri) != 2 - n_holes:
        return False
    g = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(int(tri.max()) + 1,) * 2)
    _, label = sp.csgraph.connected_components(g, directed=False)
    return len(np.unique(label[used])) == 1


def _mean_value_matrix(x: np.ndarray, tri: np.ndarray) -> sp.csr_matrix:
    """W[i, j] = sum over the triangles at edge ij of tan(theta_i / 2) / |x_i - x_j| (Floater 2003)."""
    rows, cols, vals = [], [], []
    for a in range(3):
        i, j, k = tri[:, a], tri[:, (a + 1) % 3], tri[:, (a + 2) % 3]
        e_ij, e_ik = x[j] - x[i], x[k] - x[i]
        l_ij, l_ik = np.linalg.norm(e_ij, axis=1), np.linalg.norm(e_ik, axis=1)
        cos = np.clip(np.sum(e_ij * e_ik, axis=1) / np.maximum(l_ij * l_ik, 1e-300), -1.0, 1.0)
        half_tan = np.tan(np.arccos(cos) / 2.0)
        rows += [i, i]
        cols += [j, k]
        vals += [half_tan / np.maximum(l_ij, 1e-300), half_tan / np.maximum(l_ik, 1e-300)]
    n = len(x)
    return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()


def _orient(uv: np.ndarray, x: np.ndarray, tri: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Unmirror (counter-clockwise triangles stay so), turn +y upward, scale into [0, 1]^2."""
    p = uv[tri]
    area = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    if area.sum() < 0:
        uv = uv * np.array([-1.0, 1.0])
    design = np.column_stack([uv[used], np.ones(len(used))])
    up = np.linalg.lstsq(design, x[used, 1], rcond=None)[0][:2]  # the direction in (u, v) along which y grows
    angle = np.pi / 2 - np.arctan2(up[1], up[0])
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    uv = uv @ rot.T
    lo, hi = uv[used].min(axis=0), uv[used].max(axis=0)
    size = max(float((hi - lo).max()), 1e-300)
    return (uv - (lo + hi) / 2) / size + 0.5


def skin_uv(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 2) texture coordinates in [0, 1]^2 with no triangle turned over (module docstring).

    Args:
        points: (n, 3) skin points, metres (+y up).
        triangles: (m, 3) outward-wound triangles indexing ``points``.

    Points on no triangle get (0, 0).
    """
    x = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    loops = boundary_loops(tri) if tri.size else None
    if not loops or not _is_sphere_with_holes(tri, len(loops)):
        return cylindrical_uv(x)
    length = [float(np.linalg.norm(x[lp] - x[np.roll(lp, -1)], axis=1).sum()) for lp in loops]
    outer = loops[int(np.argmax(length))]
    fans, centres = [], []
    for lp in loops:
        if lp is outer:
            continue
        c = len(x) + len(centres)  # each inner hole: a virtual vertex at its centroid, fanned to the loop
        centres.append(x[lp].mean(axis=0))
        fans.append(np.stack([np.roll(lp, -1), lp, np.full(len(lp), c)], axis=1))
    xa = np.vstack([x, *centres]) if centres else x
    ta = np.vstack([tri, *fans]) if fans else tri
    n = len(xa)
    seg = np.linalg.norm(xa[outer] - xa[np.roll(outer, -1)], axis=1)
    theta = 2 * np.pi * np.concatenate([[0.0], np.cumsum(seg)[:-1]]) / seg.sum()
    uv = np.zeros((n, 2))
    uv[outer] = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    used = np.zeros(n, dtype=bool)
    used[np.unique(ta)] = True
    free = used.copy()
    free[outer] = False
    w = _mean_value_matrix(xa, ta)
    lap = sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w
    fi = np.flatnonzero(free)
    a = lap[fi][:, fi].tocsc()
    b = -lap[fi][:, outer] @ uv[outer]
    uv[fi] = spla.splu(a).solve(b)
    uv = _orient(uv, xa, ta, np.flatnonzero(used))[: len(x)]
    uv[~used[: len(x)]] = 0.0
    return uv
