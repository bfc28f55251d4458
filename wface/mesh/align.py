"""Capture-to-surface alignment: similarity transforms, marker embedding, head-motion removal.

Similarity transform (Umeyama 1991, "Least-squares estimation of transformation parameters
between two point patterns"): for weighted point pairs (x_k, y_k) minimise
    sum_k w_k |s R x_k + t - y_k|^2
with mu_x, mu_y the weighted means, C = sum_k w_k (y_k - mu_y)(x_k - mu_x)^T / W = U D V^T,
S = diag(1, 1, sign(det U det V)):  R = U S V^T,  s = tr(D S) / var_x,  t = mu_y - s R mu_x.

Alignment of a capture frame to a face surface (Choe & Ko 2001, sec. 4.1.1): start from a
similarity fit to named landmark vertices (or centroid / principal axes), then alternate
projecting the transformed markers onto the surface and refitting the similarity to the
projections until the RMS distance stops falling. Each marker keeps its surface embedding:
triangle, barycentric weights, signed offset along the interpolated normal and the rest of its
offset (the part off the normal where the closest point lies on an edge or a vertex of a ridge,
up to millimetres for a marker a centimetre off a coarse nose) in the triangle's tangent frame,
so that the embedded marker sits exactly where it was at rest and turns with the skin.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from wface.mesh.closest import SurfaceQuery
from wface.mesh.surface import vertex_normals

__all__ = [
    "FACE_SCALE_RANGE",
    "MarkerEmbedding",
    "Similarity",
    "SurfaceAlignment",
    "align_to_surface",
    "embed_markers",
    "landmark_array",
    "remove_head_motion",
    "tangent_frame",
    "umeyama",
    "STABLE_MARKERS",
]

#: Plausible scales of a similarity that brings one face onto another (an actor's capture onto a model or a
#: basis): outside it the alignment failed, or a file's length units are wrong.
FACE_SCALE_RANGE = (0.5, 2.0)

#: AnimFace markers that move (nearly) rigidly with the skull.
STABLE_MARKERS: tuple[str, ...] = ("ForeHead_L", "ForeHead_M", "ForeHead_R", "NoseTop")


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation_m.

    Attributes:
        scale: positive scale factor (1 for a rigid transform).
        rotation: (3, 3) proper rotation matrix.
        translation_m: (3,) translation in metres.
    """

    scale: float = 1.0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation_m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, points_m: np.ndarray) -> np.ndarray:
        """Transform (..., 3) points; NaN stays NaN."""
        p = np.asarray(points_m, dtype=np.float64)
        return self.scale * p @ self.rotation.T + self.translation_m

    def apply_vectors(self, vectors: np.ndarray) -> np.ndarray:
        """Transform (..., 3) displacement vectors (no translation)."""
        return self.scale * np.asarray(vectors, dtype=np.float64) @ self.rotation.T

    def inverse(self) -> Similarity:
        r_t = self.rotation.T
        return Similarity(1.0 / self.scale, r_t, -(r_t @ self.translation_m) / self.scale)

    def compose(self, first: Similarity) -> Similarity:
        """The transform ``self(first(x))``."""
        return Similarity(
            self.scale * first.scale,
            self.rotation @ first.rotation,
            self.scale * self.rotation @ first.translation_m + self.translation_m,
        )

    def as_matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation_m
        return m


def umeyama(
    source_m: np.ndarray,
    target_m: np.ndarray,
    *,
    weights: np.ndarray | None = None,
    with_scale: bool = True,
) -> Similarity:
    """Weighted least-squares similarity (or rigid) transform taking source onto target.

    Rows with NaN in either set, or zero weight, are ignored.

    Args:
        source_m: (k, 3) points.
        target_m: (k, 3) corresponding points.
        weights: (k,) non-negative weights (default 1).
        with_scale: False for a rigid transform (scale fixed at 1).

    Returns:
        The :class:`Similarity` minimising sum_k w_k |s R x_k + t - y_k|^2.

    Raises:
        ValueError: shapes differ, weights are negative, or fewer than 3 usable pairs, or the
            usable source points are all coincident.
    """
    x = np.asarray(source_m, dtype=np.float64).reshape(-1, 3)
    y = np.asarray(target_m, dtype=np.float64).reshape(-1, 3)
    if x.shape != y.shape:
        raise ValueError(f"umeyama: source {x.shape} and target {y.shape} differ in shape")
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (len(x),):
        raise ValueError(f"umeyama: weights have shape {w.shape}, expected ({len(x)},)")
    if np.any(w < 0):
        raise ValueError("umeyama: weights must be non-negative")
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1) & (w > 0)
    if ok.sum() < 3:
        raise ValueError(f"umeyama: needs at least 3 valid point pairs, got {int(ok.sum())}")
    x, y, w = x[ok], y[ok], w[ok]
    w = w / w.sum()
    mu_x, mu_y = w @ x, w @ y
    xc, yc = x - mu_x, y - mu_y
    var_x = float(w @ np.einsum("ij,ij->i", xc, xc))
    if var_x <= 1e-30:
        raise ValueError(
            f"the {len(x)} points to align all lie at one place (landmarks naming one vertex, or a mesh of one point)"
        )
    cov = (yc * w[:, None]).T @ xc
    u, d, vt = np.linalg.svd(cov)
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    rot = (u * sign) @ vt
    scale = float((d * sign).sum() / var_x) if with_scale else 1.0
    return Similarity(scale, rot, mu_y - scale * rot @ mu_x)


@dataclass
class MarkerEmbedding:
    """Markers embedded in a triangle surface (rest pose).

    Attributes:
        triangle: (k,) triangle index per marker (-1: not embedded, e.g. missing at rest).
        barycentric: (k, 3) weights of the triangle's vertices.
        normal_offset_m: (k,) signed distance along the interpolated unit normal.
        tangent_residual_m: (k, 3) part of (marker - surface point) not along the normal, at rest.
        tangent_offset_m: (k, 2) the same part in the triangle's tangent frame (``tangent_frame``),
            carried with the skin by ``marker_positions``; None: dropped (a marker sits off its
            rest place by its ``tangent_residual_m``).
    """

    triangle: np.ndarray
    barycentric: np.ndarray
    normal_offset_m: np.ndarray
    tangent_residual_m: np.ndarray
    tangent_offset_m: np.ndarray | None = None

    def surface_points(self, vertices_m: np.ndarray, triangles: np.ndarray) -> np.ndarray:
        """(k, 3) surface points of the embedding on a deformed surface (NaN where not embedded)."""
        out = np.full((len(self.triangle), 3), np.nan)
        ok = self.triangle >= 0
        corners = np.asarray(vertices_m)[np.asarray(triangles)[self.triangle[ok]]]
        out[ok] = np.einsum("kj,kjd->kd", self.barycentric[ok], corners)
        return out

    def marker_positions(
        self, vertices_m: np.ndarray, triangles: np.ndarray, *, ring: np.ndarray | None = None
    ) -> np.ndarray:
        """(k, 3) marker positions: surface point plus the rest offset in the current normal and tangent frame.

        ``ring``: the ids of the triangles touching the embedding's vertices (``ring_triangles``),
        when the caller keeps them: the vertex normals are then summed over those alone, the same
        sums in the same order as over the whole surface (a tracker calls this every solve)."""

        v = np.asarray(vertices_m, dtype=np.float64)
        p = self.surface_points(v, triangles)
        ok = self.triangle >= 0
        triangles = np.asarray(triangles)
        tris = triangles[self.triangle[ok]]
        used = np.unique(tris)
        ring = _touching(triangles, used) if ring is None else ring
        normals = np.zeros((len(v), 3))
        normals[used] = vertex_normals(v, triangles[ring])[used]
        n = np.einsum("kj,kjd->kd", self.barycentric[ok], normals[tris])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        p[ok] += self.normal_offset_m[ok, None] * n
        if self.tangent_offset_m is not None and self.tangent_offset_m[ok].any():  # markers on the skin: none
            t1, t2 = tangent_frame(v[tris], n)
            p[ok] += self.tangent_offset_m[ok, :1] * t1 + self.tangent_offset_m[ok, 1:] * t2
        return p

    def ring_triangles(self, triangles: np.ndarray) -> np.ndarray:
        """Sorted ids of the triangles that share a vertex with an embedding triangle."""
        triangles = np.asarray(triangles)
        return _touching(triangles, np.unique(triangles[self.triangle[self.triangle >= 0]]))


TANGENT_ROUNDING_M = 1e-9  # tangent offsets below a nanometre are the closest-point query's rounding


def tangent_frame(corners_m: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents (t1, t2) of (k, 3, 3) triangles about (k, 3) unit normals: t1 along the first
    edge with its normal part removed, t2 = n x t1. Both turn with a rigid motion of the triangle."""
    e = corners_m[:, 1] - corners_m[:, 0]
    t1 = e - np.einsum("kd,kd->k", e, normals)[:, None] * normals
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    return t1, np.cross(normals, t1)


def _touching(triangles: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Sorted ids of the triangles with a corner among ``vertices``."""
    return np.flatnonzero(np.isin(triangles, vertices).any(axis=1))


def embed_markers(
    markers_m: np.ndarray, vertices_m: np.ndarray, triangles: np.ndarray, *, query=None
) -> MarkerEmbedding:
    """Embed (k, 3) markers (already in the surface frame) in the closest triangles.

    Args:
        markers_m: (k, 3) marker positions; NaN rows get triangle -1.
        vertices_m: (n, 3) surface vertices.
        triangles: (t, 3) triangle vertex ids.
        query: an existing :class:`wface.mesh.closest.SurfaceQuery` on the same surface.
    """

    m = np.asarray(markers_m, dtype=np.float64).reshape(-1, 3)
    tris = np.asarray(triangles, dtype=np.int64)
    q = query if query is not None else SurfaceQuery(vertices_m, tris)
    k = len(m)
    tri = np.full(k, -1, dtype=np.int64)
    bary = np.zeros((k, 3))
    off = np.full(k, np.nan)
    tang = np.full((k, 3), np.nan)
    local = np.zeros((k, 2))
    ok = np.isfinite(m).all(axis=1)
    if ok.any():
        hit = q.closest(m[ok])
        v = np.asarray(vertices_m, dtype=np.float64)
        normals = vertex_normals(v, tris)
        n = np.einsum("kj,kjd->kd", hit.barycentric, normals[tris[hit.triangle]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        delta = m[ok] - hit.point_m
        along = np.einsum("ij,ij->i", delta, n)
        tri[ok], bary[ok], off[ok] = hit.triangle, hit.barycentric, along
        tang[ok] = delta - along[:, None] * n
        t1, t2 = tangent_frame(v[tris[hit.triangle]], n)
        local[ok] = np.stack([np.einsum("kd,kd->k", tang[ok], t1), np.einsum("kd,kd->k", tang[ok], t2)], axis=1)
        local[np.abs(local) < TANGENT_ROUNDING_M] = 0.0  # a marker on the skin: rounding, kept out of the sums
    return MarkerEmbedding(tri, bary, off, tang, local)


@dataclass
class SurfaceAlignment:
    """Result of :func:`align_to_surface`.

    Attributes:
        transform: capture frame -> surface frame similarity.
        embedding: per-marker surface embedding of the transformed markers.
        aligned_m: (k, 3) transformed markers.
        distance_m: (k,) distance of each transformed marker to the surface (NaN if missing).
        rms_history_m: RMS marker-to-surface distance after each iteration (first entry: start).
        landmark_residual_m: (k,) distance to the marker's landmark vertex (NaN when it has none).
    """

    transform: Similarity
    embedding: MarkerEmbedding
    aligned_m: np.ndarray
    distance_m: np.ndarray
    rms_history_m: list[float]
    landmark_residual_m: np.ndarray


def _principal_frame(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    mu = p.mean(axis=0)
    u, s, vt = np.linalg.svd(p - mu, full_matrices=False)
    return mu, vt, float(np.sqrt((s**2).sum() / len(p)))


def _initial_guesses(markers: np.ndarray, vertices: np.ndarray, landmarks: np.ndarray | None) -> list[Similarity]:
    """Start transforms; ``landmarks``: (k, 3) target point per marker, NaN where unknown."""
    ok = np.isfinite(markers).all(axis=1)
    if landmarks is not None:
        use = ok & np.isfinite(landmarks).all(axis=1)
        if use.sum() >= 3:
            return [umeyama(markers[use], landmarks[use])]
    # Centroid and principal axes; axis signs are ambiguous, so try the four proper flips.
    mu_m, ax_m, r_m = _principal_frame(markers[ok])
    mu_v, ax_v, r_v = _principal_frame(vertices)
    out = []
    for signs in ((1, 1, 1), (-1, -1, 1), (-1, 1, -1), (1, -1, -1)):
        rot = ax_v.T @ np.diag(signs) @ ax_m
        if np.linalg.det(rot) < 0:
            rot = ax_v.T @ np.diag(np.array(signs) * np.array([1, 1, -1])) @ ax_m
        s = r_v / r_m
        out.append(Similarity(s, rot, mu_v - s * rot @ mu_m))
    return out


def align_to_surface(
    markers_m: np.ndarray,
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    *,
    landmark_vertices: np.ndarray | Sequence[int] | None = None,
    landmark_points_m: np.ndarray | None = None,
    with_scale: bool = True,
    iterations: int = 30,
    tolerance_m: float = 1e-7,
    landmark_weight: float = 0.0,
    trim_fraction: float = 0.0,
    initial: Similarity | None = None,
) -> SurfaceAlignment:
    """Align one capture frame to a surface: similarity fit iterated with surface projection.

    Args:
        markers_m: (k, 3) marker positions in the capture frame (metres; NaN = missing).
        vertices_m: (n, 3) surface vertices.
        triangles: (t, 3) surface triangles.
        landmark_vertices: (k,) vertex id per marker, -1 where unknown; gives the start
            transform and, with ``landmark_weight`` > 0, keeps pulling towards the landmarks.
        landmark_points_m: (k, 3) landmark position per marker (e.g. the model's own marker,
            which lies between vertices), NaN rows where unknown; instead of ``landmark_vertices``
            (a marker pulled to its nearest vertex is pulled off its true place by up to half an
            edge, which biases the similarity on a coarse mesh).
        with_scale: fit a similarity (True) or a rigid transform.
        iterations: maximum projection / refit rounds.
        tolerance_m: stop once the RMS distance falls by less than this.
        landmark_weight: weight of the landmark pairs relative to the projection pairs.
        trim_fraction: fraction of markers with the largest distances left out of each refit
            (robustness to markers far from any skin, e.g. on the eyes).
        initial: the one start transform to use (instead of the landmarks' or the principal axes').

    Returns:
        :class:`SurfaceAlignment`.
    """

    m = np.asarray(markers_m, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(vertices_m, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    ok = np.isfinite(m).all(axis=1)
    if ok.sum() < 3:
        raise ValueError(f"align_to_surface: needs at least 3 present markers, got {int(ok.sum())}")
    lm = None  # (k, 3) landmark target per marker, NaN where unknown
    if landmark_vertices is not None and landmark_points_m is not None:
        raise ValueError("align_to_surface: give landmark_vertices or landmark_points_m, not both")
    if landmark_vertices is not None:
        ids = np.asarray(landmark_vertices, dtype=np.int64).reshape(-1)
        if ids.shape != (len(m),):
            raise ValueError(f"align_to_surface: landmark_vertices has {ids.shape[0]} entries for {len(m)} markers")
        if ids.max(initial=-1) >= len(v):
            raise ValueError("align_to_surface: a landmark vertex id is out of range")
        lm = np.where((ids >= 0)[:, None], v[np.maximum(ids, 0)], np.nan)
    if landmark_points_m is not None:
        lm = np.asarray(landmark_points_m, dtype=np.float64)
        if lm.shape != (len(m), 3):
            raise ValueError(f"align_to_surface: landmark_points_m has shape {lm.shape}, expected ({len(m)}, 3)")
    query = SurfaceQuery(v, tris)
    best = None
    for start in [initial] if initial is not None else _initial_guesses(m, v, lm):
        tf = start
        history = []
        for _ in range(iterations + 1):
            a = tf.apply(m[ok])
            hit = query.closest(a)
            rms = float(np.sqrt(np.mean(hit.distance_m**2)))
            history.append(rms)
            if len(history) > 1 and history[-2] - rms < tolerance_m:
                break
            w = np.ones(ok.sum())
            if trim_fraction > 0:
                cut = np.quantile(hit.distance_m, 1.0 - trim_fraction)
                w[hit.distance_m > cut] = 0.0
            src, dst = m[ok], hit.point_m
            if lm is not None and landmark_weight > 0:
                use = np.isfinite(lm[ok]).all(axis=1)
                src = np.vstack([src, m[ok][use]])
                dst = np.vstack([dst, lm[ok][use]])
                w = np.concatenate([w, np.full(use.sum(), landmark_weight)])
            tf = umeyama(src, dst, weights=w, with_scale=with_scale)
        if best is None or history[-1] < best[1][-1]:
            best = (tf, history)
    tf, history = best
    aligned = tf.apply(m)
    emb = embed_markers(aligned, v, tris, query=query)
    dist = np.full(len(m), np.nan)
    dist[ok] = query.closest(aligned[ok]).distance_m
    lres = np.full(len(m), np.nan)
    if lm is not None:
        use = ok & np.isfinite(lm).all(axis=1)
        lres[use] = np.linalg.norm(aligned[use] - lm[use], axis=1)
    return SurfaceAlignment(tf, emb, aligned, dist, history, lres)


def landmark_array(marker_names: Sequence[str], landmarks: Mapping[str, int]) -> np.ndarray:
    """(k,) vertex id per marker name from a {name: vertex} map, -1 for names it lacks."""
    return np.array([int(landmarks.get(n, -1)) for n in marker_names], dtype=np.int64)


def remove_head_motion(
    positions_m: np.ndarray,
    stable_indices: Sequence[int],
    *,
    reference_frame: int = 0,
    reference_m: np.ndarray | None = None,
) -> tuple[np.ndarray, list[Similarity]]:
    """Remove rigid head motion frame by frame, using markers that move with the skull.

    Each frame f gets the rigid transform T_f fitted (Umeyama, no scale) from its stable markers
    to the same markers in the reference; all of the frame's markers are mapped through T_f.

    Args:
        positions_m: (frames, k, 3) marker positions; NaN = missing.
        stable_indices: indices of (nearly) rigid markers, at least 3.
        reference_frame: frame whose stable markers define the head pose (if ``reference_m``
            is None).
        reference_m: (k, 3) reference marker positions (overrides ``reference_frame``).

    Returns:
        (stabilised positions (frames, k, 3), per-frame transforms). Frames with fewer than 3
        present stable markers are returned all-NaN with an identity transform.
    """
    p = np.asarray(positions_m, dtype=np.float64)
    idx = np.asarray(stable_indices, dtype=np.int64)
    if len(idx) < 3:
        raise ValueError(f"remove_head_motion: needs at least 3 stable markers, got {len(idx)}")
    ref = p[reference_frame] if reference_m is None else np.asarray(reference_m, dtype=np.float64)
    out = np.full_like(p, np.nan)
    transforms = []
    for f in range(p.shape[0]):
        src = p[f, idx]
        if (np.isfinite(src).all(axis=1) & np.isfinite(ref[idx]).all(axis=1)).sum() < 3:
            transforms.append(Similarity())
            continue
        tf = umeyama(src, ref[idx], with_scale=False)
        out[f] = tf.apply(p[f])
        transforms.append(tf)
    return out, transforms
