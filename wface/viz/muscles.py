"""Muscle colours on the skin: which muscle lies under each skin vertex, and a heat map.

Seed 000's figure convention: active muscles yellow, inactive muscles red, skin elsewhere.
Muscles usually sit under the skin, so a skin vertex takes the muscles whose tets lie near it:
for each muscle m the distance d_m from the vertex to the nearest centroid of m's tets, less the
muscle's depth under the skin D_m = min over skin vertices of d_m, gives an influence
w_m = exp(-(max(d_m - D_m, 0) / r)^2) (r: ``radius_m``): each muscle's footprint on the skin.
Pure numpy + scipy: usable by both the USD writer (``displayColor``) and the pyvista pictures.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "ACTIVE_RGB",
    "INACTIVE_RGB",
    "SKIN_RGB",
    "activation_colors",
    "muscle_centroids",
    "skin_muscle_influence",
]

ACTIVE_RGB = np.array([1.0, 0.86, 0.10])  # yellow: fully active muscle
INACTIVE_RGB = np.array([0.80, 0.10, 0.08])  # red: inactive muscle
SKIN_RGB = np.array([0.87, 0.74, 0.65])  # neutral skin


def muscle_centroids(model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest centroids of the muscle tets.

    Returns:
        ``(centroids_m (e, 3), muscle (e,), fraction (e,))``, one row per fibre entry.
    """
    c = model.rest_positions_m[model.tets[model.fibre_tet]].mean(axis=1)
    return c, model.fibre_muscle.astype(np.int64), model.fibre_fraction


def _default_radius(model) -> float:
    t = model.tets
    x = model.rest_positions_m
    e = np.linalg.norm(x[t[:, 1]] - x[t[:, 0]], axis=1)
    return float(np.median(e)) if e.size else 1e-2


def skin_muscle_influence(model, vertices: np.ndarray | None = None, *, radius_m: float | None = None) -> np.ndarray:
    """Influence of each muscle on each given node, from rest geometry.

    Args:
        model: a ``FaceModel``.
        vertices: node ids (v,); default: the nodes used by ``model.skin_triangles``.
        radius_m: falloff radius r (default: the median tet edge length).

    Returns:
        (v, M) float64 in [0, 1]; column m is exp(-(max(d_m - D_m, 0) / r)^2), 0 for a muscle
        without tets. The depth D_m is measured over the model's skin vertices (not only ``vertices``).
    """

    if vertices is None:
        vertices = np.unique(model.skin_triangles)
    vertices = np.asarray(vertices, dtype=np.int64)
    r = _default_radius(model) if radius_m is None else float(radius_m)
    if not (np.isfinite(r) and r > 0):
        raise ValueError(f"radius_m must be positive, got {radius_m}")
    p = model.rest_positions_m[vertices]
    skin = model.rest_positions_m[np.unique(model.skin_triangles)] if model.skin_triangles.size else p
    cent, mus, frac = muscle_centroids(model)
    out = np.zeros((len(vertices), model.n_muscles))
    for m in range(model.n_muscles):
        sel = (mus == m) & (frac > 0)
        if not np.any(sel):
            continue
        tree = cKDTree(cent[sel])
        depth = float(tree.query(skin, k=1)[0].min())
        d, _ = tree.query(p, k=1)
        out[:, m] = np.exp(-((np.maximum(d - depth, 0.0) / r) ** 2))
    return out


def activation_colors(
    influence: np.ndarray, activations: np.ndarray, *, inactive_tint: float = 0.3
) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex activation and colour: skin where no muscle, a red tint over inactive muscles,
    yellow over active ones.

    Args:
        influence: (v, M) from ``skin_muscle_influence``.
        activations: (M,) or (F, M) activations in [0, 1].
        inactive_tint: opacity of the red over a fully inactive muscle (1: solid red, as in the
            muscle view; the default keeps the skin's shape readable at rest).

    Returns:
        ``(vertex_activation, rgb)``: (v,) / (F, v) = a_v = max_m w_m a_m, and (v, 3) / (F, v, 3)
        colours (1 - o) skin + o lerp(red, yellow, t), with presence p = max_m w_m, t = a_v / p and
        opacity o = p (inactive_tint + (1 - inactive_tint) t).
    """
    w = np.asarray(influence, dtype=np.float64)
    a = np.asarray(activations, dtype=np.float64)
    single = a.ndim == 1
    a2 = a[None] if single else a
    if a2.ndim != 2 or a2.shape[1] != w.shape[1]:
        raise ValueError(f"activations have shape {a.shape}; expected ({w.shape[1]},) or (frames, {w.shape[1]})")
    if not np.all(np.isfinite(a2)):
        raise ValueError("activations contain NaN/inf")
    a2 = np.clip(a2, 0.0, 1.0)
    va = np.zeros((a2.shape[0], w.shape[0]))
    if w.shape[1]:
        chunk = max(1, int(2e7 // max(1, w.size)))  # frames per block: keeps (chunk, v, M) near 160 MB
        for s in range(0, a2.shape[0], chunk):
            va[s : s + chunk] = np.max(w[None] * a2[s : s + chunk, None, :], axis=2)
    presence = w.max(axis=1) if w.shape[1] else np.zeros(w.shape[0])
    t = np.divide(va, presence[None], out=np.zeros_like(va), where=presence[None] > 1e-12)
    muscle_rgb = INACTIVE_RGB + t[..., None] * (ACTIVE_RGB - INACTIVE_RGB)
    opacity = (presence[None] * (inactive_tint + (1.0 - inactive_tint) * t))[..., None]
    rgb = (1 - opacity) * SKIN_RGB + opacity * muscle_rgb
    return (va[0], rgb[0]) if single else (va, rgb)
