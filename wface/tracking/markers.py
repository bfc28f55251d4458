"""Markers embedded in the skin as the tracker sees them (docs/design.md, "Tracking")."""

from __future__ import annotations

import numpy as np


class MarkerMap:
    """Markers embedded in the skin: positions m(X) and the node set their Jacobian needs."""

    def __init__(self, model, embedding):
        self.model = model
        self.embedding = embedding
        tri = model.skin_triangles[embedding.triangle]
        self.nodes, inverse = np.unique(tri.ravel(), return_inverse=True)
        self._local = inverse.reshape(-1, 3)  # corner -> index into self.nodes
        self._offset = np.nan_to_num(embedding.normal_offset_m)
        self._bary = embedding.barycentric
        self._ring = embedding.ring_triangles(model.skin_triangles)  # the normals' triangles

    def positions(self, x_m: np.ndarray) -> np.ndarray:
        """(k, 3) marker positions on the deformed skin for node positions ``x_m`` (n, 3)."""
        n = self.model.n_nodes
        if np.shape(x_m) != (n, 3):
            raise ValueError(f"positions have shape {np.shape(x_m)}, expected ({n}, 3)")
        return self.embedding.marker_positions(x_m, self.model.skin_triangles, ring=self._ring)

    def jacobian(self, node_jacobian: np.ndarray) -> np.ndarray:
        """(3k, p) marker Jacobian from (len(nodes), 3, p) node Jacobians (offsets held fixed in direction)."""
        Jn = node_jacobian[self._local]  # (k, 3 corners, 3, p)
        return np.einsum("kj,kjdp->kdp", self._bary, Jn).reshape(-1, node_jacobian.shape[-1])
