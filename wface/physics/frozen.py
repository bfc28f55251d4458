"""Self-contact with frozen closest features: a smooth contact energy for Newton's last iterations.

The signed distance of a contact point to the other lip's surface is only Lipschitz where its
closest feature switches: inside the surface, at the bisector of every convex edge the closest
face changes and the force direction jumps; across faceted (coarse) lip surfaces pressed together,
points sit on such switches. Newton then chatters: a full step moves many points to other
features, the line search cuts it, and the residual stalls (Badin lips: relative residual 0.2
after 40 iterations, 0.019 with the 0.1 mm C2 ramp, 0.009 with the ramp and freezing; see
``wface.physics.contact``).

Freezing: each pair keeps its triangle and closest feature (face, edge or vertex) of the moment it
was frozen, with the distance measured to that feature's plane, line or point as the triangle moves:

    face:   phi = n . (q - x_t0),  n the unit normal of the moving triangle (its side fixed);
    edge:   phi = +-|q - (a + s (b - a))|,  s the projection parameter on the line (a, b);
    vertex: phi = +-|q - x_v|,

each smooth (C-infinity away from phi = 0 for edges and vertices). The gradient keeps the form of
``ContactPairs`` (envelope theorem): dphi/dx_j = -w_j n with w the (possibly out-of-triangle)
barycentric weights of the projection. Pairs up to ``margin_m`` apart are frozen too (they carry no
force until they touch), so points about to touch are caught; a frozen face pair whose projection
has left its triangle by more than ``STALE_WEIGHT`` (barycentric) while carrying force measures to a
"ghost" plane and triggers re-detection. Rigid obstacles are evaluated as usual. The Newton solver
(``wface.physics.newton``) freezes once the residual is small, converges the frozen problem,
re-detects the pairs and repeats until the true (re-detected) residual meets the tolerance (Wriggers
2006, ch. 8: active-set strategies; the frozen feature is the "fixed contact element"
linearisation).

``exact_self_hessian``: the full second derivatives of the self-contact energy with each pair's
feature fixed (normal and projection derivatives with respect to the triangle vertices included),
for the implicit-function Jacobians of ``wface.tracking.rig``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from wface.physics.contact import Contact
from wface.physics.contact_pairs import ContactPairs
from wface.physics.smooth_contact import CombinedPairs

__all__ = ["FrozenContact", "concat_pairs", "exact_self_hessian"]

_ZERO_WEIGHT = 1e-12
STALE_WEIGHT = 0.1  # barycentric overshoot beyond which a frozen face pair is re-detected


def concat_pairs(parts: list[ContactPairs]) -> ContactPairs:
    """One ``ContactPairs`` holding the pairs of several (same contact, same stiffness)."""
    first = parts[0]
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return ContactPairs(
        node=cat("node"),
        others=cat("others"),
        weights=cat("weights"),
        normal=cat("normal"),
        penetration_m=cat("penetration_m"),
        source=cat("source"),
        names=first.names,
        stiffness_n_per_m=first.stiffness_n_per_m,
        n_nodes=first.n_nodes,
        tangential=cat("tangential"),
        edge_direction=cat("edge_direction"),
        point_nodes=cat("point_nodes"),
        point_weights=cat("point_weights"),
        smoothing_m=first.smoothing_m,
        distance_m=cat("distance_m"),
    )


class FrozenContact:
    """The self-contact pairs of ``contact`` at ``x`` with their features frozen (module docstring).

    Has the interface the Newton solver uses (``evaluate``, ``energy``, ``set_pose``).
    """

    def __init__(self, contact: Contact, x: np.ndarray, *, margin_m: float):
        self.contact = contact
        pairs = contact.evaluate(x, margin_m=margin_m)
        sel = pairs.source >= len(contact.rigid)
        self.n_frozen = int(sel.sum())
        self.point_nodes = pairs.point_nodes[sel]
        self.point_weights = pairs.point_weights[sel]
        self.triangles = pairs.others[sel]
        self.source = pairs.source[sel]
        w = pairs.weights[sel]
        zero = w <= _ZERO_WEIGHT
        nz = zero.sum(axis=1)
        self.feature = np.minimum(nz, 2)
        self.corner = np.where(nz >= 2, np.argmax(w, axis=1), (np.argmax(zero, axis=1) + 1) % 3)
        sign = np.sign(pairs.distance_m[sel])
        sign[sign == 0] = 1.0
        N = self._face_normals(np.asarray(x, dtype=np.float64))
        face_side = np.sign(np.einsum("pd,pd->p", N, pairs.normal[sel]))
        face_side[face_side == 0] = 1.0
        self.sign = np.where(self.feature == 0, face_side, sign)
        self._fallback_normal = pairs.normal[sel]
        self.last_stale = 0

    def set_pose(self, attached_positions) -> None:
        """No-op: the bones were placed when the pairs were frozen."""

    def _face_normals(self, x: np.ndarray) -> np.ndarray:
        t = x[self.triangles]
        N = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)

    def _frozen_pairs(self, x: np.ndarray) -> ContactPairs:
        c = self.contact
        P = self.n_frozen
        q = np.einsum("pk,pkd->pd", self.point_weights, x[self.point_nodes])
        t = x[self.triangles]
        r = np.arange(P)
        phi = np.zeros(P)
        normal = np.zeros((P, 3))
        w = np.zeros((P, 3))
        edge_dir = np.zeros((P, 3))
        face = self.feature == 0
        if face.any():
            n = self.sign[face, None] * self._face_normals(x)[face]
            tf = t[face]
            d = np.einsum("pd,pd->p", n, q[face] - tf[:, 0])
            proj = q[face] - d[:, None] * n
            e1, e2, ep = tf[:, 1] - tf[:, 0], tf[:, 2] - tf[:, 0], proj - tf[:, 0]
            d11, d12, d22 = (np.einsum("pd,pd->p", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
            p1, p2 = np.einsum("pd,pd->p", ep, e1), np.einsum("pd,pd->p", ep, e2)
            det = d11 * d22 - d12 * d12
            b1 = (d22 * p1 - d12 * p2) / det
            b2 = (d11 * p2 - d12 * p1) / det
            phi[face], normal[face] = d, n
            w[face] = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
        edge = self.feature == 1
        if edge.any():
            i0, i1 = self.corner[edge], (self.corner[edge] + 1) % 3
            a, b = t[r[edge], i0], t[r[edge], i1]
            e = b - a
            s = np.einsum("pd,pd->p", q[edge] - a, e) / np.einsum("pd,pd->p", e, e)
            d = q[edge] - a - s[:, None] * e
            w[r[edge], i0], w[r[edge], i1] = 1.0 - s, s
            edge_dir[edge] = e / np.linalg.norm(e, axis=1, keepdims=True)
            phi[edge], normal[edge] = self._radial(d, self.sign[edge], self._fallback_normal[edge])
        vert = self.feature == 2
        if vert.any():
            d = q[vert] - t[r[vert], self.corner[vert]]
            w[r[vert], self.corner[vert]] = 1.0
            phi[vert], normal[vert] = self._radial(d, self.sign[vert], self._fallback_normal[vert])
        inside = (self.feature > 0) & (phi < 0)
        # a face pair whose projection has left its triangle measures to the triangle's plane beyond
        # it (a "ghost" plane): the solver re-detects when such a pair carries force
        self.last_stale = int(np.count_nonzero((w.min(axis=1) < -STALE_WEIGHT) & (c.gap_m - phi > 0)))
        return ContactPairs(
            node=self.point_nodes[:, 0].copy(),
            others=self.triangles,
            weights=w,
            normal=normal,
            penetration_m=c.gap_m - phi,
            source=self.source,
            names=c.names,
            stiffness_n_per_m=c.stiffness_n_per_m,
            n_nodes=c.model.n_nodes,
            tangential=inside.astype(np.float64),
            edge_direction=edge_dir,
            point_nodes=self.point_nodes,
            point_weights=self.point_weights,
            smoothing_m=c.smoothing_m,
            distance_m=phi,
        )

    @staticmethod
    def _radial(d: np.ndarray, sign: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.linalg.norm(d, axis=1)
        ok = r > 1e-15
        n = np.where(ok[:, None], sign[:, None] * d / np.where(ok, r, 1.0)[:, None], fallback)
        return sign * r, n

    def evaluate(self, x: np.ndarray) -> ContactPairs:
        """Rigid-obstacle pairs at ``x`` plus the frozen self-contact pairs (those apart carry nothing)."""
        x = np.asarray(x, dtype=np.float64)
        rigid = self.contact.evaluate(x, self_contact=False)
        if not self.n_frozen:
            return rigid
        return concat_pairs([rigid, self._frozen_pairs(x)])

    def energy(self, x: np.ndarray) -> float:
        return self.evaluate(x).energy


# ---------------------------------------------------------------------- exact self-contact Hessian
_HESS_STEP_M = 1e-5  # central second differences of the pair distance: truncation ~(h/L)^2, L ~ mm edges


def _pair_distance(z: np.ndarray, v: np.ndarray, feature: np.ndarray, corner: np.ndarray, sign: np.ndarray):
    """Signed distance phi of contact points to a fixed feature of their triangle, from the 15 coordinates
    z = (x_p1, x_p2, x_t0, x_t1, x_t2) of each pair, (P, 5, 3) -> (P,). ``feature``: 0 face, 1 edge,
    2 vertex; ``corner``: the vertex (feature 2) or the first corner of the edge (feature 1, edge to
    corner + 1); ``sign``: +-1 (side of the surface)."""
    q = v[:, 0, None] * z[:, 0] + v[:, 1, None] * z[:, 1]
    t = z[:, 2:]
    r = np.arange(len(z))
    N = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    face = np.einsum("pd,pd->p", N / np.linalg.norm(N, axis=1, keepdims=True), q - t[:, 0])
    a, b = t[r, corner], t[r, (corner + 1) % 3]
    e = b - a
    s = np.einsum("pd,pd->p", q - a, e) / np.einsum("pd,pd->p", e, e)
    edge = np.linalg.norm(q - a - s[:, None] * e, axis=1)
    vert = np.linalg.norm(q - t[r, corner], axis=1)
    return sign * np.where(feature == 0, face, np.where(feature == 1, edge, vert))


def exact_self_hessian(contact, pairs: ContactPairs, x: np.ndarray, pattern, *, project: bool = False) -> sp.csr_matrix:
    """The contact Hessian over ``pattern``'s unknowns with the exact second derivatives of the
    self-contact pairs (closest feature fixed): k'' dg dg^T + E'(g) d2g, the derivatives of the
    normals and closest-point weights with respect to the triangle vertices included (the Newton
    solves drop them). Not projected: use it where the exact tangent of the equilibrium is needed
    (the implicit-function Jacobians of ``wface.tracking.rig``). Rigid-obstacle pairs keep ``pairs.assemble``.

    d2g comes from central second differences of the pair distance with step ``_HESS_STEP_M``.
    """
    if isinstance(pairs, CombinedPairs):  # smooth lip surfaces: their own exact Hessian
        rigid = exact_self_hessian(contact, pairs.rigid, x, pattern, project=project)
        return (rigid + pairs.smooth.assemble(pattern, exact=not project)).tocsr()
    selfp = pairs.source >= len(contact.rigid)
    rigid_part = _subset(pairs, ~selfp).assemble(pattern)
    if not selfp.any():
        return rigid_part
    feature, corner, sign = _features(pairs, selfp, x)
    return (_fixed_feature_hessian(pairs, selfp, x, pattern, feature, corner, sign, project) + rigid_part).tocsr()


def _features(pairs: ContactPairs, sel: np.ndarray, x: np.ndarray):
    """Closest feature (0 face, 1 edge, 2 vertex), its corner and side (+-1) of the selected pairs,
    read from their closest-point weights."""
    w = pairs.weights[sel]
    zero = w <= _ZERO_WEIGHT
    nz = zero.sum(axis=1)
    feature = np.minimum(nz, 2)
    corner = np.where(nz >= 2, np.argmax(w, axis=1), (np.argmax(zero, axis=1) + 1) % 3)
    sign = np.sign(pairs.distance_m[sel])
    t = np.asarray(x, dtype=np.float64)[pairs.others[sel]]
    N = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    side = np.sign(np.einsum("pd,pd->p", N, pairs.normal[sel]))
    sign = np.where(feature == 0, side, sign)
    sign[sign == 0] = 1.0
    return feature, corner, sign


_STENCIL = ((1, 1), (1, -1), (-1, 1), (-1, -1))
_ROWS_PER_BATCH = 200_000  # pair-distance rows per vectorised call (bounds the batch's memory, ~50 MB)


def _second_differences(flat: np.ndarray, v, feature, corner, sign) -> np.ndarray:
    """(P, 15, 15) d2 phi / dz2 of the pair distances at the coordinates ``flat`` (P, 15), by central
    second differences with step ``_HESS_STEP_M``: (phi(+i+j) - phi(+i-j) - phi(-i+j) + phi(-i-j)) / 4h^2
    for every i <= j. All 120 x 4 stencil points of all pairs go through ``_pair_distance`` in a few
    vectorised calls (row-wise the same arithmetic as one call per stencil point)."""
    P = len(flat)
    h = _HESS_STEP_M
    ii, jj = np.triu_indices(15)
    k = np.arange(len(ii))
    dz = np.zeros((len(ii), 4, 15))
    for s, (a, b) in enumerate(_STENCIL):
        dz[k, s, ii] += a * h
        dz[k, s, jj] += b * h
    val = np.empty((len(ii), P))
    step = max(1, _ROWS_PER_BATCH // max(4 * P, 1))
    for lo in range(0, len(ii), step):
        part = dz[lo : lo + step]  # (C, 4, 15)
        n = part.shape[0] * 4
        z = (flat[None] + part.reshape(n, 1, 15)).reshape(n * P, 5, 3)
        v_n, f_n, c_n, s_n = (np.tile(a, (n,) + (1,) * (a.ndim - 1)) for a in (v, feature, corner, sign))
        phi = _pair_distance(z, v_n, f_n, c_n, s_n).reshape(-1, 4, P)
        val[lo : lo + step] = (phi[:, 0] - phi[:, 1] - phi[:, 2] + phi[:, 3]) / (4 * h * h)
    d2 = np.zeros((P, 15, 15))
    d2[:, ii, jj] = val.T
    d2[:, jj, ii] = val.T
    return d2


def _fixed_feature_hessian(pairs, sel, x, pattern, feature, corner, sign, project: bool) -> sp.csr_matrix:
    """k'' dg dg^T + E'(g) d2g of the selected pairs with their features fixed, over ``pattern``."""
    P = int(sel.sum())
    w = pairs.weights[sel]
    nodes = np.concatenate([pairs.point_nodes[sel], pairs.others[sel]], axis=1)  # (P, 5)
    v = pairs.point_weights[sel]
    z0 = np.asarray(x, dtype=np.float64)[nodes]  # (P, 5, 3)
    if not np.allclose(_pair_distance(z0, v, feature, corner, sign), pairs.distance_m[sel], atol=1e-9):
        raise RuntimeError("contact: the pair distances do not match their features (stale pairs?)")
    d2 = -_second_differences(z0.reshape(P, 15), v, feature, corner, sign)  # g = gap - phi
    coef = np.concatenate([v, -w], axis=1)  # (P, 5): dg/dx_k = -coef_k n
    dg = (-coef[:, :, None] * pairs.normal[sel][:, None, :]).reshape(P, 15)
    kn, fn = pairs.normal_stiffness[sel], pairs.force_magnitude[sel]
    blocks = kn[:, None, None] * dg[:, :, None] * dg[:, None, :] + fn[:, None, None] * d2
    if project:  # each pair's 15 x 15 block clamped to positive semi-definite
        lam, vec = np.linalg.eigh(0.5 * (blocks + blocks.transpose(0, 2, 1)))
        blocks = np.einsum("pik,pk,pjk->pij", vec, np.maximum(lam, 0.0), vec)
    dof = pattern.node_to_dof[nodes]  # (P, 5)
    rows = (3 * dof[:, :, None] + np.arange(3)).reshape(P, 15)
    keep = (np.repeat(dof, 3, axis=1) >= 0) & (np.abs(coef).repeat(3, axis=1) > 0)
    ri = np.broadcast_to(rows[:, :, None], blocks.shape)
    ci = np.broadcast_to(rows[:, None, :], blocks.shape)
    mask = keep[:, :, None] & keep[:, None, :]
    return sp.coo_matrix((blocks[mask], (ri[mask], ci[mask])), shape=pattern.shape).tocsr()


def _subset(pairs: ContactPairs, sel: np.ndarray) -> ContactPairs:
    return ContactPairs(
        node=pairs.node[sel],
        others=pairs.others[sel],
        weights=pairs.weights[sel],
        normal=pairs.normal[sel],
        penetration_m=pairs.penetration_m[sel],
        source=pairs.source[sel],
        names=pairs.names,
        stiffness_n_per_m=pairs.stiffness_n_per_m,
        n_nodes=pairs.n_nodes,
        tangential=pairs.tangential[sel],
        edge_direction=pairs.edge_direction[sel],
        point_nodes=pairs.point_nodes[sel],
        point_weights=pairs.point_weights[sel],
        smoothing_m=pairs.smoothing_m,
        distance_m=pairs.distance_m[sel],
    )
