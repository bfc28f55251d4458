"""A synthetic head (an ellipsoid) with landmarks, for tests and data-free fallbacks.

The landmarks are the packaged ICT layout's landmark names, projected radially onto the
ellipsoid, so the ICT layout can be fitted to it (``wface.waters.fit``) without any real data.
"""

from __future__ import annotations

import numpy as np

from wface.mesh.meshfile import SurfaceMesh
from wface.waters.layout import MuscleLayout

__all__ = ["ELLIPSOID_CENTRE_M", "ELLIPSOID_SEMI_AXES_M", "synthetic_head", "synthetic_landmarks"]

ELLIPSOID_CENTRE_M = np.array([0.0, -0.01, 0.01])
ELLIPSOID_SEMI_AXES_M = np.array([0.08, 0.12, 0.105])


def synthetic_head(n_lat: int = 120, n_lon: int = 240) -> SurfaceMesh:
    """Ellipsoid quad mesh of about n_lat * n_lon vertices (metres, +y up, +z forward); poles are fans."""
    if n_lat < 3 or n_lon < 3:
        raise ValueError(f"n_lat and n_lon must be >= 3, got {n_lat}, {n_lon}")
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]  # polar angle from +y, poles excluded
    phi = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1).reshape(-1, 3)
    ring = unit * ELLIPSOID_SEMI_AXES_M + ELLIPSOID_CENTRE_M
    top = ELLIPSOID_CENTRE_M + [0, ELLIPSOID_SEMI_AXES_M[1], 0]
    bottom = ELLIPSOID_CENTRE_M - [0, ELLIPSOID_SEMI_AXES_M[1], 0]
    v = np.vstack([ring, top, bottom])
    rows = n_lat - 1
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(n_lon), indexing="ij")
    a = i * n_lon + j
    b = i * n_lon + (j + 1) % n_lon
    quads = np.stack([a, (a + n_lon), (b + n_lon), b], axis=-1).reshape(-1, 4)
    jj = np.arange(n_lon)
    top_tri = np.stack([np.full(n_lon, len(ring)), (jj + 1) % n_lon, jj], axis=1)
    last = (rows - 1) * n_lon
    bot_tri = np.stack([np.full(n_lon, len(ring) + 1), last + jj, last + (jj + 1) % n_lon], axis=1)
    counts = np.concatenate([np.full(len(quads), 4), np.full(2 * n_lon, 3)])
    idx = np.concatenate([quads.ravel(), top_tri.ravel(), bot_tri.ravel()])
    return SurfaceMesh(v, counts, idx)


def synthetic_landmarks(layout: MuscleLayout) -> dict[str, np.ndarray]:
    """The layout's landmarks projected radially (from the ellipsoid centre) onto the synthetic head."""
    out = {}
    for name, p in layout.landmarks_m.items():
        d = p - ELLIPSOID_CENTRE_M
        s = 1.0 / np.linalg.norm(d / ELLIPSOID_SEMI_AXES_M)
        out[name] = ELLIPSOID_CENTRE_M + s * d
    return out
