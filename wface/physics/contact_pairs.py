"""The active contact pairs of ``wface.physics.contact.Contact`` at one configuration: penalty energy,
forces and Hessian of E_c(x) = sum_p k/2 max(0, g_p(x))^2, g_p = gap - phi_p(x) (the ramp of
``penalty_profile`` when smoothed).

Gradient (exact away from closest-feature switches, by the envelope theorem):
    f_i = -dE/dx_i = k g n,   f_j = -k g w_j n   (triangle vertices; the pair's forces sum to zero).
Hessian (positive semi-definite): k C^T Q C with C = [I, -w_1 I, -w_2 I, -w_3 I] (3 x 12) and
Q = n n^T + c (I - n n^T - e e^T). With c = 0 this is the Gauss-Newton k J^T J, J = n^T C (Wriggers,
"Computational Contact Mechanics", 2006, ch. 6). When a node is inside and its closest point lies on
an edge (unit direction e) or a vertex (e = 0), the curvature of the distance to that feature is
(I - n n^T - e e^T) / |phi|, positive for the penalty energy: c = min(1, g / |phi|) keeps it (c = 1 at
gap 0, where k/2 g^2 is then exactly the spring k/2 |Q (x_i - c)|^2). Without it, nodes pressed on
a mesh vertex (the coincident lip nodes of the built-in face) make Newton crawl. Derivatives of
n, w and e with respect to the triangle's vertices are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from wface.physics.penalty import penalty_profile

__all__ = ["ContactPairs"]

_ROUND_OFF_M = 1e-12  # penetrations below this are round-off (lips coincide at rest), not contact


@dataclass
class ContactPairs:
    """The active contact pairs at one configuration (g >= 0: touching pairs carry no force but join the
    Hessian, which keeps a Newton step from driving lips that touch at rest into each other), with
    energy, forces and Hessian.

    Attributes:
        node: (P,) contact node of each pair (the first node of its contact point).
        point_nodes, point_weights: (P, 2) the contact point x_p = sum_k v_k x_k: a node (v = (1, 0)) or,
            for self-contact, also the midpoint of a surface edge (v = (1/2, 1/2)), which catches lips
            that cross edge-on between their nodes on coarse meshes.
        others: (P, 3) triangle vertices (self-contact) or the node itself with zero weights (rigid).
        weights: (P, 3) barycentric weights w_j of the closest point (zero for rigid obstacles).
        normal: (P, 3) unit n (gradient of phi with respect to x_i).
        penetration_m: (P,) g = gap - phi > 0.
        source: (P,) index into ``names``.
        names: labels of the contact sources (regions and obstacles).
        stiffness_n_per_m: penalty stiffness k.
    """

    node: np.ndarray
    others: np.ndarray
    weights: np.ndarray
    normal: np.ndarray
    penetration_m: np.ndarray
    source: np.ndarray
    names: list
    stiffness_n_per_m: float
    n_nodes: int
    tangential: np.ndarray | None = None
    edge_direction: np.ndarray | None = None
    point_nodes: np.ndarray | None = None
    point_weights: np.ndarray | None = None
    smoothing_m: float = 0.0
    distance_m: np.ndarray | None = None

    def __post_init__(self):
        if self.tangential is None:
            self.tangential = np.zeros(len(self.node))
        if self.edge_direction is None:
            self.edge_direction = np.zeros((len(self.node), 3))
        if self.point_nodes is None:
            self.point_nodes = np.repeat(np.asarray(self.node)[:, None], 2, axis=1)
            self.point_weights = np.tile([1.0, 0.0], (len(self.node), 1))
        if self.distance_m is None:
            self.distance_m = -np.asarray(self.penetration_m, dtype=np.float64)
        e, fn, kn = penalty_profile(self.penetration_m, self.stiffness_n_per_m, self.smoothing_m)
        self.pair_energy, self.force_magnitude, self.normal_stiffness = e, fn, kn

    def _projector(self) -> np.ndarray:
        """(P, 3, 3) k Q = k'' n n^T + c (I - n n^T - e e^T) of each pair in N/m (module docstring):
        k'' = d2E/dg2 and c = min(k, E'(g) / |phi|) for points inside whose closest feature is an edge
        or a vertex (the curvature of the distance to that feature), else 0."""
        n, e = self.normal, self.edge_direction
        nn = np.einsum("pd,pe->pde", n, n)
        tang = np.eye(3) - nn - np.einsum("pd,pe->pde", e, e)
        inside = self.tangential > 0
        c = np.where(
            inside,
            np.minimum(self.stiffness_n_per_m, self.force_magnitude / np.maximum(np.abs(self.distance_m), 1e-300)),
            0.0,
        )
        return self.normal_stiffness[:, None, None] * nn + c[:, None, None] * tang

    @property
    def energy(self) -> float:
        """E_c in joules."""
        return float(np.sum(self.pair_energy))

    def forces(self) -> np.ndarray:
        """f = -dE_c/dx, (n, 3) newtons."""
        f = np.zeros((self.n_nodes, 3))
        fn = self.force_magnitude[:, None] * self.normal
        nodes, coef = self._coefficients()
        for a in range(nodes.shape[1]):
            np.add.at(f, nodes[:, a], coef[:, a, None] * fn)
        return f

    def force_on_face(self, source: str | None = None) -> np.ndarray:
        """Net force (3,) in newtons that the obstacles exert on the face (self-contact sums to 0)."""
        sel = slice(None) if source is None else self.source == self.names.index(source)
        fn = self.force_magnitude[sel, None] * self.normal[sel]
        return (fn * (1.0 - self.weights[sel].sum(axis=1))[:, None]).sum(axis=0)

    def _coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        nodes = np.concatenate([self.point_nodes, self.others], axis=1)  # (P, 5)
        coef = np.concatenate([self.point_weights, -self.weights], axis=1)  # C = [v_1 I, v_2 I, -w_1 I, ...]
        return nodes, coef

    def matvec(self, v: np.ndarray, *, exact: bool = False) -> np.ndarray:
        """H v with H = k J^T J (Gauss-Newton), v and the result (n, 3); ``exact`` is accepted for the
        interface of ``wface.physics.smooth_contact.CombinedPairs`` (this Hessian has one form)."""
        v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        out = np.zeros_like(v)
        if not len(self.node):
            return out
        nodes, coef = self._coefficients()
        u = np.einsum("pa,pad->pd", coef, v[nodes])
        qu = np.einsum("pde,pe->pd", self._projector(), u)
        for a in range(nodes.shape[1]):
            np.add.at(out, nodes[:, a], coef[:, a, None] * qu)
        return out

    def diagonal(self, *, exact: bool = False) -> np.ndarray:
        """diag(H) as (n, 3)."""
        out = np.zeros((self.n_nodes, 3))
        nodes, coef = self._coefficients()
        q = np.einsum("pdd->pd", self._projector())
        for a in range(nodes.shape[1]):
            np.add.at(out, nodes[:, a], coef[:, a, None] ** 2 * q)
        return out

    def assemble(self, pattern, *, exact: bool = False) -> sp.csr_matrix:
        """H restricted to the unknowns of a ``BlockPattern``, CSR (3k, 3k)."""
        nodes, coef = self._coefficients()
        dof = pattern.node_to_dof[nodes]  # (P, 5), -1 for Dirichlet nodes
        nn = self._projector()
        blocks = coef[:, :, None, None, None] * coef[:, None, :, None, None] * nn[:, None, None]  # (P,5,5,3,3)
        shape = (len(dof), nodes.shape[1], nodes.shape[1])
        ra = np.broadcast_to(dof[:, :, None], shape)
        cb = np.broadcast_to(dof[:, None, :], shape)
        keep = (ra >= 0) & (cb >= 0) & (coef[:, :, None] * coef[:, None, :] != 0)
        d3 = np.arange(3)
        rows = (3 * ra[keep])[:, None, None] + d3[None, :, None]
        cols = (3 * cb[keep])[:, None, None] + d3[None, None, :]
        rows, cols = np.broadcast_arrays(rows, cols)
        H = sp.coo_matrix((blocks[keep].ravel(), (rows.ravel(), cols.ravel())), shape=pattern.shape)
        return H.tocsr()

    def stats(self) -> dict:
        """active_nodes (nodes with g > 1e-12 m: touching pairs carry no force and are not counted, nor
        round-off on surfaces that coincide at rest),
        max_penetration_m, force_n (sum of normal force magnitudes), per source."""
        g = self.penetration_m
        pressing = g > _ROUND_OFF_M
        per = {}
        for s, name in enumerate(self.names):
            sel = (self.source == s) & pressing
            per[name] = {
                "active_nodes": int(np.unique(self.node[sel]).size),
                "max_penetration_m": max(float(g[sel].max()), 0.0) if sel.any() else 0.0,
                "force_n": float(self.force_magnitude[sel].sum()),
            }
        return {
            "active_nodes": int(np.unique(self.node[pressing]).size),
            "max_penetration_m": max(float(g.max()), 0.0) if g.size else 0.0,
            "force_n": float(self.force_magnitude.sum()),
            "sources": per,
        }
