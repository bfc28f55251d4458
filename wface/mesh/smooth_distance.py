"""A smooth signed distance to a triangle surface: blended face planes on its Loop refinement.

The distance to a faceted surface is only Lipschitz inside it: at the bisector of every edge the
closest face changes and the gradient jumps by the dihedral angle, which stalls Newton's method on
pressed lips (``wface.physics.contact``). This surface replaces it by an implicit moving-least-squares
blend of the planes of the refined triangles t (Shen, O'Brien & Shewchuk 2004, with the planes of
the triangles as constraints; Kolluri 2005):

    phi(q) = sum_t w_t(q) d_t(q) / W(q),   W = sum_t w_t,   d_t = n_t . (q - c_t),
    w_t(q) = A_t psi(|q - c_t| / R_t),     psi(r) = (1 - r)^4 (4 r + 1) for r < 1, else 0,

with c_t, n_t, A_t the centroid, unit normal and area of triangle t, R_t its support radius (a
constant per triangle, ``radius_factor`` x its longest rest edge) and psi Wendland's C2 function
(Wendland 1995). phi is C2 in q and in the vertices wherever W > 0 (within about R_t of the surface);
it is exact on a plane and, on a curved surface, lies within O(kappa R^2) of it (kappa the
curvature), which is why the planes are those of the Loop-refined surface
(``wface.mesh.subdivision``, y = S x): one level halves the edges and quarters the bias. The
refined surface is itself a smoothing of the faceted one (its points lie 0.02-0.03 mm inside on the
Badin lips, median).

Derivatives (``SmoothSurface.evaluate``): with f_t = w_t (d_t - phi) (phi held fixed),

    grad phi = sum_t grad f_t / W,
    hess phi = (sum_t hess f_t - grad phi grad W^T - grad W grad phi^T) / W,

where each grad f_t and grad w_t involves only q and the three corners of t (closed form below, in
``_entry_terms``); hess f_t (12 x 12) comes from central differences of the closed-form grad f_t
(step ``_FD_STEP_M``, truncation ~(h / L)^2 ~ 1e-8 relative for L ~ 1 mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from wface.mesh.subdivision import loop_subdivision

__all__ = ["SmoothHits", "SmoothSurface"]

_FD_STEP_M = 1e-7  # central differences of the closed-form entry gradients
_OFFSET_FIT_STEPS = 12  # Richardson steps of the through-the-nodes offsets


def _entry_terms(q, y0, y1, y2, R, phi=None, offset=0.0):
    """Per entry (a query point q and a triangle (y0, y1, y2) of support radius R), all (E, 3) / (E,):
    (w, d, grad f (E, 4, 3) or None, grad w (E, 4, 3)); slot 0 of the gradients is q, 1-3 the
    corners; f = w (d - phi) with ``phi`` (E,) held fixed (no grad f when phi is None); d = n . (q - c)
    - ``offset``, the distance to the triangle's plane moved out by a constant ``offset`` (E,) m."""
    e1, e2 = y1 - y0, y2 - y0
    N = np.cross(e1, e2)
    nN = np.linalg.norm(N, axis=1)
    n = N / np.maximum(nN, 1e-300)[:, None]
    area = 0.5 * nN
    c = (y0 + y1 + y2) / 3.0
    r = q - c
    rho = np.linalg.norm(r, axis=1) / R
    inside = rho < 1.0
    om = np.where(inside, 1.0 - rho, 0.0)
    psi = om**4 * (4.0 * rho + 1.0)
    chi = -20.0 * om**3  # psi'(rho) / rho
    w = area * psi
    d_plane = np.einsum("ij,ij->i", n, r)
    d = d_plane - offset
    dw_dq = (area * chi / R**2)[:, None] * r
    # through the triangle: dw = psi dA + A psi' drho, dA = n . dN / 2, drho = -r . dc / (R |r|)
    gN_w = 0.5 * psi[:, None] * n

    def to_corners(g_c, g_N):
        """Gradients with respect to the corners from those with respect to c and N."""
        g1 = np.cross(e2, g_N)
        g2 = np.cross(g_N, e1)
        return np.stack([g_c / 3.0 - g1 - g2, g_c / 3.0 + g1, g_c / 3.0 + g2], axis=1)

    grad_w = np.concatenate([dw_dq[:, None], to_corners(-dw_dq, gN_w)], axis=1)
    if phi is None:
        return w, d, None, grad_w
    s = d - phi
    # f = w s: df = s dw + w dd, dd = n . dq - n . dc + r . (I - n n^T) dN / |N|
    g_q = s[:, None] * dw_dq + w[:, None] * n
    g_c = -s[:, None] * dw_dq - w[:, None] * n
    tang = r - d_plane[:, None] * n
    g_N = s[:, None] * gN_w + (w / np.maximum(nN, 1e-300))[:, None] * tang
    grad_f = np.concatenate([g_q[:, None], to_corners(g_c, g_N)], axis=1)
    return w, d, grad_f, grad_w


@dataclass
class SmoothHits:
    """Smooth signed distances of k query points (module docstring).

    Attributes:
        phi_m: (k,) phi, NaN where no triangle supports the point (W = 0).
        weight: (k,) W (m^2).
        entry_point, entry_triangle: (E,) the (query, refined triangle) pairs with w > 0.
        grad_phi: (E, 4, 3) per entry, its share of grad phi: slot 0 with respect to the query point
            (summed over the entries of a point it is d phi / d q), slots 1-3 the triangle's corners.
        grad_weight: (E, 4, 3) the same for W.
        corners: (E, 3) refined vertex ids (rows of ``SmoothSurface.S``) of each entry's triangle.
        interior: (k,) iota = sum_t w_t i_t / W, i_t = 0 for a refined triangle touching the surface's
            open boundary, else 1: about 1 well inside the surface, falling to 0 beyond its rim.
        grad_interior: (E, 4, 3) per entry, its share of grad iota, (i_t - iota) grad w_t / W.
    """

    phi_m: np.ndarray
    weight: np.ndarray
    entry_point: np.ndarray
    entry_triangle: np.ndarray
    grad_phi: np.ndarray
    grad_weight: np.ndarray
    corners: np.ndarray
    interior: np.ndarray | None = None
    grad_interior: np.ndarray | None = None
    _data: tuple | None = None

    def grad_q(self) -> np.ndarray:
        """(k, 3) d phi / d q (zero where unsupported)."""
        out = np.zeros((len(self.phi_m), 3))
        np.add.at(out, self.entry_point, self.grad_phi[:, 0])
        return out

    def hessian_blocks(self, entries: np.ndarray | None = None) -> np.ndarray:
        """(E, 12, 12) the share hess f_t / W of each entry (slots as ``grad_phi``; ``entries``: a
        subset); the global rank-2 part of hess phi is built by the caller from ``grad_phi`` and
        ``grad_weight``."""
        q, y, R, phi_e, W_e, off = self._data
        if entries is not None:
            q, y, R, phi_e, W_e, off = q[entries], y[entries], R[entries], phi_e[entries], W_e[entries], off[entries]
        E = len(q)
        z = np.concatenate([q[:, None], y], axis=1).reshape(E, 12)
        H = np.zeros((E, 12, 12))
        h = _FD_STEP_M
        for j in range(12):
            zp, zm = z.copy(), z.copy()
            zp[:, j] += h
            zm[:, j] -= h
            gp = _entry_terms(*_split(zp), R, phi_e, off)[2].reshape(E, 12)
            gm = _entry_terms(*_split(zm), R, phi_e, off)[2].reshape(E, 12)
            H[:, :, j] = (gp - gm) / (2 * h)
        H = 0.5 * (H + H.transpose(0, 2, 1))
        return H / W_e[:, None, None]


def _split(z):
    z = z.reshape(len(z), 4, 3)
    return z[:, 0], z[:, 1], z[:, 2], z[:, 3]


class SmoothSurface:
    """The smooth surface of a triangle group (module docstring), its refinement fixed at construction.

    Args:
        triangles: (t, 3) node ids (e.g. a model's lip surface group), wound outward.
        rest_positions_m: (n, 3) rest positions (for the support radii).
        levels: Loop subdivision levels of the refinement.
        radius_factor: R_t = radius_factor x the longest rest edge of refined triangle t.
        through_nodes: move each refined triangle's plane out along its normal by a constant offset,
            fitted on the rest surface so that phi = 0 at the surface's own nodes (module docstring,
            "Through the nodes"); False keeps the plain blend, which lies inside convex parts.

    Attributes:
        offset_m: (T,) each refined triangle's plane offset (zero without ``through_nodes``).
        rest_node_phi_m: (n_s,) phi at the surface's own nodes on the rest surface (after the fit).
    """

    def __init__(
        self, triangles, rest_positions_m, *, levels: int = 1, radius_factor: float = 1.5, through_nodes: bool = False
    ):
        if not (np.isfinite(radius_factor) and radius_factor > 0):
            raise ValueError(f"radius_factor must be finite and > 0, got {radius_factor}")
        self.nodes, self.S, self.triangles = loop_subdivision(triangles, levels)
        self.levels, self.radius_factor = int(levels), float(radius_factor)
        y = self.refined(rest_positions_m)
        p = y[self.triangles]
        edge = np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2).max(axis=1)
        self.radius_m = radius_factor * edge
        self.max_radius_m = float(self.radius_m.max())
        # triangles touching the open boundary (edges of one triangle) of the refined surface
        e = np.sort(
            np.concatenate([self.triangles[:, [0, 1]], self.triangles[:, [1, 2]], self.triangles[:, [2, 0]]]), 1
        )
        uniq, count = np.unique(e, axis=0, return_counts=True)
        rim = np.zeros(len(y), bool)
        rim[uniq[count == 1].ravel()] = True
        self.interior = (~rim[self.triangles].any(axis=1)).astype(np.float64)
        self.offset_m = np.zeros(len(self.triangles))
        self.rest_node_phi_m = self._node_phi(rest_positions_m)
        if through_nodes:
            self._fit_offsets(rest_positions_m)

    def _node_phi(self, x_m: np.ndarray) -> np.ndarray:
        """phi at the surface's own nodes (0 where unsupported)."""
        x = np.asarray(x_m, dtype=np.float64)
        return np.nan_to_num(self.evaluate(x[self.nodes], x).phi_m)

    def _fit_offsets(self, rest_m: np.ndarray) -> None:
        """Offsets b per node, carried to the refined vertices by S and to each refined triangle as the
        mean of its corners, fitted by Richardson steps b <- b + phi(nodes): the blend of the offsets
        is a local average of b, so each step removes most of the smooth part of the remaining phi."""
        b = np.zeros(len(self.nodes))
        phi = self.rest_node_phi_m
        for _ in range(_OFFSET_FIT_STEPS):
            b += phi
            self.offset_m = (self.S @ b)[self.triangles].mean(axis=1)
            phi = self._node_phi(rest_m)
        self.rest_node_phi_m = phi

    def refined(self, x_m: np.ndarray) -> np.ndarray:
        """(V, 3) refined vertex positions y = S x[nodes]."""
        return self.S @ np.asarray(x_m, dtype=np.float64)[self.nodes]

    def evaluate(self, points_m: np.ndarray, x_m: np.ndarray) -> SmoothHits:
        """phi and its per-entry derivatives at (k, 3) points, the surface at positions ``x_m`` (n, 3)."""
        q = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
        y = self.refined(x_m)
        tri = self.triangles
        cent = y[tri].mean(axis=1)
        near = cKDTree(cent).query_ball_point(q, self.max_radius_m)
        counts = np.fromiter((len(a) for a in near), dtype=np.int64, count=len(q))
        ep = np.repeat(np.arange(len(q)), counts)
        et = np.fromiter((i for a in near for i in a), dtype=np.int64, count=int(counts.sum()))
        corners = tri[et]
        R = self.radius_m[et]
        off = self.offset_m[et]
        w, d, _, _ = _entry_terms(q[ep], *(y[corners[:, j]] for j in range(3)), R, offset=off)
        keep = w > 0
        ep, et, corners, R, w, d, off = ep[keep], et[keep], corners[keep], R[keep], w[keep], d[keep], off[keep]
        W = np.bincount(ep, weights=w, minlength=len(q))
        num = np.bincount(ep, weights=w * d, minlength=len(q))
        safe = np.where(W > 0, W, 1.0)
        phi = np.where(W > 0, num / safe, np.nan)
        it = self.interior[et]
        iota = np.bincount(ep, weights=w * it, minlength=len(q)) / safe
        yc = np.stack([y[corners[:, j]] for j in range(3)], axis=1)
        _, _, gf, gw = _entry_terms(q[ep], yc[:, 0], yc[:, 1], yc[:, 2], R, phi[ep], off)
        gi = (it - iota[ep])[:, None, None] * gw / W[ep, None, None]
        hits = SmoothHits(phi, W, ep, et, gf / W[ep, None, None], gw, corners, iota, gi)
        hits._data = (q[ep], yc, R, phi[ep], W[ep], off)
        return hits
