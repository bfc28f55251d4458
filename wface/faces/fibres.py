"""Embed muscle fibres given as polylines into a tet mesh: per-tet volume fractions and directions.

A muscle is a set of polylines (fibres). The muscle occupies the tube of radius r around its fibres.
The volume fraction of a tet is the fraction of the tet inside that tube, estimated by quadrature:
the share of ``_LATTICE`` barycentric sample points (a uniform lattice of 35 points, the vertices
included) whose distance to the nearest fibre segment is at most r. The fibre direction of a tet is
the unit tangent of the fibre segment closest to the tet's centroid (a fibre's sign is immaterial:
the fibre stress depends on d d^T).
"""

from __future__ import annotations

import numpy as np

__all__ = ["embed_fibres", "point_segment_distance"]


def _lattice(level: int) -> np.ndarray:
    pts = [
        (i, j, k, level - i - j - k)
        for i in range(level + 1)
        for j in range(level + 1 - i)
        for k in range(level + 1 - i - j)
    ]
    return np.asarray(pts, dtype=np.float64) / level


_LATTICE = _lattice(4)  # (35, 4) barycentric weights


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances (k, s) from points p (k, 3) to segments a-b (s, 3 each), and the nearest segment (k,)."""
    ab = b - a
    len2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    ap = p[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("ksj,sj->ks", ap, ab) / len2[None, :], 0.0, 1.0)
    d = np.linalg.norm(ap - t[..., None] * ab[None, :, :], axis=2)
    return d, np.argmin(d, axis=1)


def embed_fibres(
    x: np.ndarray, tets: np.ndarray, fibres: list[np.ndarray], radius_m: float, *, chunk: int = 4096
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tets a muscle acts in, with volume fractions and unit fibre directions.

    Args:
        x: (n, 3) node positions, metres.
        tets: (m, 4) node ids.
        fibres: polylines, each (p_i, 3) with p_i >= 2 points.
        radius_m: tube radius around the fibres.

    Returns:
        (tet ids (e,) int32 ascending, fractions (e,) in (0, 1], directions (e, 3) unit).
    """
    segs_a = np.concatenate([f[:-1] for f in fibres if len(f) >= 2])
    segs_b = np.concatenate([f[1:] for f in fibres if len(f) >= 2])
    keep = np.linalg.norm(segs_b - segs_a, axis=1) > 1e-12
    segs_a, segs_b = segs_a[keep], segs_b[keep]
    tangents = (segs_b - segs_a) / np.linalg.norm(segs_b - segs_a, axis=1, keepdims=True)
    p = x[tets]  # (m, 4, 3)
    centroid = p.mean(axis=1)
    reach = np.linalg.norm(p - centroid[:, None, :], axis=2).max(axis=1)  # circumscribing radius about the centroid
    d_c, _ = point_segment_distance(centroid, segs_a, segs_b)
    cand = np.flatnonzero(d_c.min(axis=1) <= radius_m + reach)
    out_t, out_f, out_d = [], [], []
    for s in range(0, len(cand), chunk):
        ids = cand[s : s + chunk]
        samples = np.einsum("qv,mvj->mqj", _LATTICE, p[ids]).reshape(-1, 3)
        d, _ = point_segment_distance(samples, segs_a, segs_b)
        inside = (d.min(axis=1) <= radius_m).reshape(len(ids), len(_LATTICE))
        frac = inside.mean(axis=1)
        hit = frac > 0
        _, nearest = point_segment_distance(centroid[ids[hit]], segs_a, segs_b)
        out_t.append(ids[hit])
        out_f.append(frac[hit])
        out_d.append(tangents[nearest])
    if not out_t:
        return np.zeros(0, np.int32), np.zeros(0), np.zeros((0, 3))
    return (np.concatenate(out_t).astype(np.int32), np.concatenate(out_f), np.concatenate(out_d))
