"""Trilinear hexahedra on wface's tet kernels: each 2x2x2 Gauss point of a hex as a quadrature tet.

An 8-node hex (ANSYS SOLID185 / ArtiSynth order: corners I J K L then M N O P, natural coordinates
(-1,-1,-1), (1,-1,-1), (1,1,-1), (-1,1,-1), then the same at +1) has the deformation gradient
F_g = sum_a x_a (dN_a/dX)(xi_g)^T at Gauss point g. The linear tet with nodes

    y0 = sum_a N_a(xi_g) x_a,    y_k = y0 + s_g sum_a (dN_a/dX_k)(xi_g) x_a    (k = 1, 2, 3)

and rest edges y_k - y0 = s_g e_k has Dm = s_g I, so its deformation gradient is exactly F_g, and
with s_g = (6 w_g det J_g)^(1/3) its rest volume s_g^3 / 6 is the Gauss weight times the Jacobian.
The hex energy sum_g w_g det J_g psi(F_g) is therefore the energy of a tet mesh on the virtual nodes
y = T x, a fixed sparse linear map of the hex nodes: forces T^T f_y, stiffness T^T K_y T. The flesh
law, fibres, inversion clamp and projected tangent of ``wface.kernels.fem`` serve the hexes
unchanged (each Gauss point's tangent is projected on its own, so the sum stays PSD).

This is the element of ArtiSynth's face models (full 2x2x2 integration, ``HexElement``). A degenerate
hex whose two parallel edges collapse (a wedge: the Badin face's 318 hexes with K = L and O = P) is
integrated as a collapsed hex by default; ``wedges="wedge"`` integrates it as ArtiSynth's
``WedgeElement`` does: the collapsed hex's field is the wedge's (Duffy: in each layer the bilinear
functions of a quad with one edge collapsed are the triangle's barycentric coordinates), so only the
points differ, the 3-point triangle rule (barycentric 2/3, 1/6, 1/6) times 2-point Gauss across, weight
1/6 each, placed in the hex's natural coordinates with weight (1/6) / det(ds/dxi) (``wedge_rule``). Its 6
points fill the hex's 8 slots, two of them twice at half weight. Used to set wface's split tets beside the
original's hexes (README, "Speech gestures"; docs/design.md, "Hexes beside tets").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from wface.mesh.embed import containing_tets
from wface.model import FaceModel

__all__ = [
    "WEDGE_RULES",
    "HexQuadrature",
    "embedding_matrix",
    "hex_quadrature",
    "quadrature_model",
    "trilinear_points",
    "wedge_rule",
]

CORNERS = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]],
    dtype=np.float64,
)
GAUSS_POINTS = CORNERS / np.sqrt(3.0)  # 2x2x2 Gauss-Legendre, weight 1 each
_MIRROR = np.array([0, 3, 2, 1, 4, 7, 6, 5])  # the same hex with the opposite handedness
WEDGE_RULES = ("collapsed", "wedge")  # how a hex collapsed to a wedge is integrated (``hex_quadrature``)
_TRIANGLE_RULE = ((2 / 3, 1 / 6, 1 / 6), (1 / 6, 2 / 3, 1 / 6), (1 / 6, 1 / 6, 2 / 3))  # (L0, L1, L_apex)


def shape_functions(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N (g, 8), dN/dxi (g, 8, 3)) of the trilinear hex at natural coordinates ``xi`` (g, 3)."""
    xi = np.atleast_2d(np.asarray(xi, dtype=np.float64))
    f = 1.0 + xi[:, None, :] * CORNERS[None]  # (g, 8, 3) factors 1 + c_i xi_i
    N = 0.125 * f.prod(axis=2)
    dN = np.empty(f.shape)
    for i in range(3):
        others = [j for j in range(3) if j != i]
        dN[:, :, i] = 0.125 * CORNERS[None, :, i] * f[:, :, others[0]] * f[:, :, others[1]]
    return N, dN


@dataclass(frozen=True)
class HexQuadrature:
    """The Gauss points of a hex mesh as quadrature tets (module docstring). G = 8 m points, 4 G virtual nodes."""

    hexes: np.ndarray  # (m, 8) int node ids, right-handed (mirrored where the input was not)
    rest_m: np.ndarray  # (n_nodes, 3) rest positions of the hex mesh's nodes (the map's columns)
    map: sp.csr_matrix  # (4 G, n_nodes): virtual node positions y = map @ x
    virtual_rest_m: np.ndarray  # (4 G, 3) rest positions of the virtual nodes
    virtual_tets: np.ndarray  # (G, 4) int32
    gauss_points_m: np.ndarray  # (G, 3) rest positions of the Gauss points
    gauss_volume_m3: np.ndarray  # (G,) w_g det J_g
    hex_of_point: np.ndarray  # (G,) row of ``hexes``
    shape_gradients_per_m: np.ndarray  # (G, 8, 3) dN_a/dX at each Gauss point, of its hex's 8 nodes
    shape_values: np.ndarray  # (G, 8) N_a at each Gauss point

    @property
    def n_nodes(self) -> int:
        return len(self.rest_m)

    @property
    def volume_m3(self) -> float:
        return float(self.gauss_volume_m3.sum())

    def virtual_positions(self, x_m: np.ndarray) -> np.ndarray:
        """(4 G, 3) virtual node positions of hex-node positions ``x_m`` (n_nodes, 3)."""
        return np.asarray(self.map @ np.asarray(x_m, dtype=np.float64))

    def node_forces(self, virtual_forces: np.ndarray) -> np.ndarray:
        """(n_nodes, 3) hex-node forces T^T f_y of virtual-node forces (4 G, 3)."""
        return np.asarray(self.map.T @ virtual_forces)

    def dof_map(self, dofs: np.ndarray | None = None) -> sp.csr_matrix:
        """(12 G, k) the map T per coordinate, restricted to the columns of hex-node ``dofs`` (3 node +
        axis; None: all 3 n)."""
        T3 = sp.kron(self.map, sp.identity(3), format="csr")
        return T3 if dofs is None else T3[:, dofs].tocsr()

    def node_stiffness(self, virtual_stiffness: sp.spmatrix, dof_map: sp.csr_matrix | None = None) -> sp.csr_matrix:
        """T^T K_y T of the virtual nodes' (12 G, 12 G) stiffness over the columns of ``dof_map``
        (``self.dof_map(dofs)``; None: all hex-node coordinates, (3 n, 3 n))."""
        T3 = self.dof_map() if dof_map is None else dof_map
        return (T3.T @ virtual_stiffness @ T3).tocsr()


def wedge_rule(hex_nodes) -> tuple[np.ndarray, np.ndarray] | None:
    """ArtiSynth's ``WedgeElement`` rule in the natural coordinates of a hex whose two parallel edges
    collapse (8 node ids, two pairs equal): (8, 3) points and (8,) weights (module docstring), or None
    for any other hex. The triangles lie in the plane of the collapsed edges' axis d and the axis e they
    collapse at (e = sigma); with eta = sigma xi_e, the triangle's barycentric coordinates are
    L_apex = (1 + eta) / 2 and L0, L1 = (1 -+ xi_d)(1 - eta) / 4, so det(ds/dxi) = (1 - eta) / 8."""
    h = np.asarray(hex_nodes).reshape(8)
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if h[a] == h[b]]
    if len(pairs) != 2:
        return None
    (a0, _), (a1, _) = pairs
    axes = [np.flatnonzero(CORNERS[a] != CORNERS[b]) for a, b in pairs]
    if any(len(k) != 1 for k in axes) or axes[0][0] != axes[1][0]:
        return None
    d = int(axes[0][0])
    same = [k for k in range(3) if k != d and CORNERS[a0, k] == CORNERS[a1, k]]
    if len(same) != 1:  # the two collapsed edges must lie on one face, across the third axis
        return None
    e = same[0]
    across, sigma = 3 - d - e, CORNERS[a0, e]
    points, weights = [], []
    for z in (-1.0, 1.0):
        for l0, l1, apex in _TRIANGLE_RULE:
            eta = 2.0 * apex - 1.0
            p = np.empty(3)
            p[d], p[e], p[across] = (l1 - l0) / (l0 + l1), sigma * eta, z / np.sqrt(3.0)
            points.append(p)
            weights.append((1.0 / 6.0) / ((1.0 - eta) / 8.0))
    slots = [0, 0, 1, 1, 2, 3, 4, 5]  # 6 points in 8 slots: the first two twice, at half weight
    w = np.array(weights)[slots] * np.array([0.5, 0.5, 0.5, 0.5, 1, 1, 1, 1])
    return np.array(points)[slots], w


def hex_quadrature(x_rest_m: np.ndarray, hexes: np.ndarray, *, wedges: str = "collapsed") -> HexQuadrature:
    """The quadrature tets of the hexes ``hexes`` (m, 8) over nodes ``x_rest_m`` (n, 3).

    A hex whose Jacobian is negative at its centre is mirrored (its node order is left-handed);
    a hex whose Jacobian is not positive at every Gauss point after that is an error naming it.
    ``wedges``: a hex collapsed to a wedge gets the 2x2x2 rule ("collapsed", default) or ArtiSynth's
    wedge rule ("wedge", ``wedge_rule``).
    """
    if wedges not in WEDGE_RULES:
        raise ValueError(f"wedges must be one of {', '.join(WEDGE_RULES)}, got {wedges!r}")
    x = np.asarray(x_rest_m, dtype=np.float64)
    hexes = np.array(hexes, dtype=np.int64).reshape(-1, 8)
    if hexes.size and (hexes.min() < 0 or hexes.max() >= len(x)):
        raise ValueError(f"hex node ids must lie in [0, {len(x)})")
    _, dN_c = shape_functions(np.zeros((1, 3)))
    det_c = np.linalg.det(np.einsum("mad,ae->mde", x[hexes], dN_c[0]))
    hexes[det_c < 0] = hexes[det_c < 0][:, _MIRROR]
    m = len(hexes)
    xi = np.broadcast_to(GAUSS_POINTS, (m, 8, 3)).copy()  # each hex's points and weights
    wts = np.ones((m, 8))
    if wedges == "wedge":
        for i in np.flatnonzero([len(set(h)) == 6 for h in hexes.tolist()]):
            rule = wedge_rule(hexes[i])
            if rule is not None:
                xi[i], wts[i] = rule
    N, dN = shape_functions(xi.reshape(-1, 3))  # (G, 8), (G, 8, 3)
    X = x[hexes]  # (m, 8, 3)
    J = np.einsum("mad,mgae->mgde", X, dN.reshape(m, 8, 8, 3))  # (m, g, 3, 3): dX_d / dxi_e
    det = np.linalg.det(J)
    bad = np.flatnonzero((det <= 0).any(axis=1))
    if bad.size:
        raise ValueError(
            f"{bad.size} hexes have a non-positive Jacobian at a Gauss point (rows {bad[:5].tolist()}): "
            "twisted or inverted elements"
        )
    dNdX = np.einsum("mgae,mged->mgad", dN.reshape(m, 8, 8, 3), np.linalg.inv(J))  # (m, g, 8, 3)
    G = 8 * m
    volume = (wts * det).reshape(G)  # w_g det J_g
    s = np.cbrt(6.0 * volume)
    w_centre = N
    w_edge = dNdX.reshape(G, 8, 3) * s[:, None, None]
    # rows of the virtual nodes 4 p + k: y0 = sum N x; y_k = y0 + s dN/dX_k . x
    W = np.empty((G, 4, 8))
    W[:, 0] = w_centre
    W[:, 1:] = w_centre[:, None, :] + np.transpose(w_edge, (0, 2, 1))
    cols = np.repeat(hexes, 8, axis=0)  # (G, 8)
    T = sp.csr_matrix(
        (W.reshape(-1), (np.repeat(np.arange(4 * G), 8), np.repeat(cols[:, None, :], 4, axis=1).reshape(-1))),
        shape=(4 * G, len(x)),
    )
    T.sum_duplicates()  # repeated nodes of a degenerate hex
    y0 = np.einsum("pa,pad->pd", w_centre, np.repeat(X, 8, axis=0))
    rest = np.repeat(y0[:, None, :], 4, axis=1)
    rest[:, 1:] += s[:, None, None] * np.eye(3)[None]
    return HexQuadrature(
        hexes=hexes,
        rest_m=x,
        map=T,
        virtual_rest_m=rest.reshape(-1, 3),
        virtual_tets=np.arange(4 * G, dtype=np.int32).reshape(G, 4),
        gauss_points_m=y0,
        gauss_volume_m3=volume,
        hex_of_point=np.repeat(np.arange(m), 8),
        shape_gradients_per_m=dNdX.reshape(G, 8, 3),
        shape_values=N,
    )


def trilinear_points(quad: HexQuadrature, x_rest_m: np.ndarray, points_m: np.ndarray, *, iterations: int = 20):
    """(hex row (k,), natural coordinates (k, 3)) of rest points in the hexes (nearest hex centroids tried
    in turn, Newton on the trilinear map); a point in no hex is an error."""
    x = np.asarray(x_rest_m, dtype=np.float64)
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    X = x[quad.hexes]
    _, cand = cKDTree(X.mean(axis=1)).query(p, k=min(12, len(X)))
    cand = cand.reshape(len(p), -1)
    owner = np.full(len(p), -1)
    xi_out = np.zeros((len(p), 3))
    for j in range(cand.shape[1]):
        todo = np.flatnonzero(owner < 0)
        if not todo.size:
            break
        h = cand[todo, j]
        xi = np.zeros((len(todo), 3))
        for _ in range(iterations):
            N, dN = shape_functions(xi)
            r = np.einsum("ka,kad->kd", N, X[h]) - p[todo]
            Jk = np.einsum("kad,kae->kde", X[h], dN)
            xi = np.clip(xi - np.linalg.solve(Jk, r[:, :, None])[:, :, 0], -2.0, 2.0)
        N, _ = shape_functions(xi)
        close = np.linalg.norm(np.einsum("ka,kad->kd", N, X[h]) - p[todo], axis=1) < 1e-9
        hit = close & (np.abs(xi) <= 1.0 + 1e-6).all(axis=1)
        owner[todo[hit]] = h[hit]
        xi_out[todo[hit]] = xi[hit]
    if np.any(owner < 0):
        raise ValueError(f"{int(np.sum(owner < 0))} points lie in no hex (first {np.flatnonzero(owner < 0)[:5]})")
    return owner, xi_out


def embedding_matrix(quad: HexQuadrature, points_m: np.ndarray) -> sp.csr_matrix:
    """(k, n_nodes) trilinear weights of rest points ``points_m`` (k, 3) in their hexes: the points' positions
    are ``embedding_matrix(...) @ x`` for hex-node positions x (each row sums to 1; a point in no hex is an
    error, ``trilinear_points``)."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    owner, xi = trilinear_points(quad, quad.rest_m, p)
    N, _ = shape_functions(xi)
    W = sp.csr_matrix(
        (N.reshape(-1), (np.repeat(np.arange(len(p)), 8), quad.hexes[owner].reshape(-1))), shape=(len(p), quad.n_nodes)
    )
    W.sum_duplicates()
    return W


def quadrature_model(model: FaceModel, quad: HexQuadrature) -> FaceModel:
    """The quadrature tets of ``quad`` as a ``FaceModel`` for ``wface.physics.Simulator``: ``model``'s
    material and muscles, each Gauss point carrying the fibre entries (muscle, fraction, direction) of
    the tet of ``model`` that holds it at rest, so the hexes see the tet model's muscle field.

    Only the energy, forces and tangent of the result are meaningful (it has no skin, bones or
    markers); the hex nodes are ``model``'s first ``quad.n_nodes`` nodes.
    """
    if model.pressure_actuators:
        raise ValueError("quadrature_model: pressure actuators act on the tet model's surface; not carried")
    # a Gauss point under a hex's curved bilinear face, which the split tets flatten, lies just outside
    # every tet: it takes the one it is least outside of
    tet, _ = containing_tets(quad.gauss_points_m, model.rest_positions_m, model.tets, k=64, nearest=True)
    start = np.searchsorted(model.fibre_tet, np.arange(model.n_tets + 1))
    counts = start[tet + 1] - start[tet]
    point = np.repeat(np.arange(len(tet)), counts)
    entry = np.concatenate([np.arange(start[t], start[t + 1]) for t in tet]) if counts.sum() else np.zeros(0, int)
    return replace(
        model,
        rest_positions_m=quad.virtual_rest_m,
        tets=quad.virtual_tets,
        skin_triangles=np.zeros((0, 3), np.int32),
        fibre_tet=point.astype(np.int32),
        fibre_muscle=model.fibre_muscle[entry],
        fibre_fraction=model.fibre_fraction[entry],
        fibre_direction=model.fibre_direction[entry],
        attached_nodes=np.zeros(0, np.int32),
        attached_bone=np.zeros(0, np.int8),
        bone_meshes={},
        surface_groups={},
        marker_names=[],
        marker_positions_m=np.zeros((0, 3)),
        metadata={**model.metadata, "hex_quadrature": {"hexes": int(len(quad.hexes))}},
    )
