"""Contact for the quasistatic face: lips on lips, flesh on teeth and bones, rigid objects on the skin.

One-sided quadratic penalty on the signed distance phi of surface nodes to a surface:

    E_c(x) = sum_p k/2 max(0, g_p(x))^2,   g_p = gap - phi_p(x)   (penetration, metres)

over contact pairs p: a surface node i against
- a rigid obstacle (sphere, half-space, closed triangle mesh under a rigid/affine transform, the
  model's bone and teeth meshes moving with the cranium / jaw): phi = signed distance of x_i,
  positive outside, with outward unit gradient n (``wface.mesh.signed_distance``);
- a triangle of another region of the same face (self-contact, node-to-triangle, both ways):
  phi = n . (x_i - sum_j w_j x_j) with c = sum_j w_j x_j the closest point on the triangle
  (barycentric w) and n its outward normal direction.

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
The active set (g > 0) and closest points are recomputed at every configuration the Newton solver
evaluates, so the line search sees the exact, C1 contact energy.

Penalty stiffness k (N/m, per node): default ``DEFAULT_STIFFNESS_FACTOR`` x the stiffness of a
surface node of the flesh, k = 100 * E * h with E = 6 (mu10 + mu01) the small-strain Young's modulus
of the incompressible Mooney-Rivlin flesh and h the median rest edge length of the tets. A node
then penetrates about 1/100 of the distance it would have moved without contact (measured in
``tests/test_contact.py``); raise it for less penetration at the price of a stiffer system.

Smoothed penalty (``smoothing_m = d``, ``penalty_profile``): E = k g^3 / (6 d) for 0 < g < d, then
k/2 (g - d/2)^2 + k d^2 / 24: C2, the normal stiffness rises from 0 at contact to k at g = d, so a
pair entering contact no longer switches k on at once; about d/2 more penetration.

Convergence on coarse lip surfaces (the ArtiSynth Badin face): with full OOP + MENT the lips overlap
6.7 mm without contact. With the C1 penalty Newton stalls at a relative residual of 0.2 after 40
iterations (0.018 after 80), although the overlap drops to 0.02-0.05 mm. Measured causes: (1) the
active set chatters, about 100 of 150 pairs change at every full Newton step, and the step lengths
fall to 1/16-1/64; (2) the signed distance to a faceted surface is not smooth for points inside it:
at the bisector of every convex edge the closest face changes and the force direction jumps by
the dihedral angle (median 9-12, 90th percentile 27-34 degrees on the reduced collision
surfaces, 2.4-2.8 mm edges), a jump of force x angle, a few mN per point (contact forces of
0.01-0.02 N) against a tolerance of 1.3 mN (1e-4 x 12.7 N); (3) the Gauss-Newton
contact Hessian misses the derivatives of the normals (3-6 % of the contact stiffness, which is
100 x the flesh's, so O(1) of the elastic stiffness). Neither the stiffness (k / 10), the exact
pair Hessian (``wface.physics.frozen.exact_self_hessian``, projected), one-pass (one lip's points
only), leaving out the edge midpoints nor a penalty gap fixed the stall by itself. What helps:
the C2 ramp (0.1 mm: 0.019 after 40) and freezing the closest features (``freeze_below``,
``wface.physics.frozen``) on top of it: 0.009 after 40, 0.003 after 80 (minimum 2.7e-4); a
tolerance of 1e-4 is not reached that way. ``surface="smooth"`` removes cause (2) and (3): the
other lip's distance is a C2 blend of the planes of its Loop refinement with an exact Hessian
(``wface.physics.smooth_contact``); with Newton restarted every 5 iterations
(``wface.physics.contact_solve.solve_restarted``) the pose converges to 6e-9 in 56 iterations,
quadratically at the end (docs/design.md, "Smooth lip surfaces").

Teeth and bones of the model move with their bone. Nodes already inside one of those meshes at rest
are left out of its contact (``ignore_inside_at_rest``): the Badin face's gum-side surface runs
through ArtiSynth's teeth by up to 8.7 mm in the source data (winding number 1, checked in
``tests/test_badin_contact.py``; ArtiSynth uses the teeth for display and lets the lip collision
surfaces hit the jaw and maxilla). Closest points on an open mesh's boundary are no contact.
``ignore_inside_at_rest=False`` pushes those nodes out like any other, as ArtiSynth's collisions do.
The "skull" region is ArtiSynth's lip-skull contact: the face against the jaw and maxilla meshes only
(``SKULL_MESHES``; docs/design.md, "Contact", "Face-skull contact"); on Badin 139 flesh nodes lie up to
0.58 mm inside the maxilla and 126 up to 0.05 mm inside the jaw at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from wface.mesh.signed_distance import SignedSurface
from wface.mesh.surface import boundary_faces
from wface.model import BONES, FaceModel
from wface.physics.obstacles import (
    HalfSpace,
    MeshObstacle,
    Sphere,
    as_affine,
    bone_affines_from_attached,
    parse_obstacle,
)
from wface.physics.penalty import (
    DEFAULT_STIFFNESS_FACTOR,
    contact_points,
    default_contact_stiffness,
    median_edge_length,
    penalty_profile,
)
from wface.physics.smooth_contact import CombinedPairs, SmoothSelfContact

__all__ = [
    "DEFAULT_STIFFNESS_FACTOR",
    "LIP_GROUPS",
    "REGIONS",
    "SKULL_MESHES",
    "SURFACES",
    "Contact",
    "ContactPairs",
    "HalfSpace",
    "MeshObstacle",
    "Sphere",
    "bone_affines_from_attached",
    "default_contact_stiffness",
    "parse_obstacle",
    "penalty_profile",
]

REGIONS = ("lips", "teeth", "bones", "skull")
SURFACES = ("faceted", "smooth", "smooth_through_nodes")  # the self-contact surfaces (``Contact(surface=...)``)
# The bone meshes of the "skull" region: ArtiSynth's lip-skull contact (BadinFaceDemo.enableLipSkullContact:
# the face collides with the jaw and maxilla rigid bodies, not the teeth or cranium; docs/design.md, "Contact").
SKULL_MESHES = ("jaw", "maxilla")
_ROUND_OFF_M = 1e-12  # penetrations below this are round-off (lips coincide at rest), not contact
# Surface groups holding the upper / lower lip contact surfaces, first match wins.
LIP_GROUPS = (("upper_lip", "lower_lip"), ("upper_lip_contact", "lower_lip_contact"))


# ---------------------------------------------------------------------- active pairs
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


# ---------------------------------------------------------------------- the contact model
class Contact:
    """Contact sources of a face for ``Simulator.solve(..., contact=...)``.

    Args:
        model: the face.
        regions: any of ``REGIONS``: "lips" (self-contact between the upper and lower lip surface
            groups, see ``LIP_GROUPS``), "teeth" (bone meshes whose name contains "teeth"), "bones"
            (the other bone meshes), "skull" (the ``SKULL_MESHES``, jaw and maxilla: ArtiSynth's
            lip-skull contact). Teeth and bones move with their bone (cranium / jaw).
        obstacles: user ``Sphere`` / ``HalfSpace`` / ``MeshObstacle`` objects (or spec strings,
            see ``parse_obstacle``).
        self_pairs: extra self-contact pairs of surface group names [(group_a, group_b)].
        stiffness_n_per_m: penalty stiffness k (default ``default_contact_stiffness``).
        gap_m: contact offset: nodes are pushed out to phi >= gap_m (default 0: the lips of the
            built-in face touch at rest).
        smoothing_m: width d of the C2 penalty ramp (``penalty_profile``; default 0: the C1 penalty).
        freeze_below: relative residual below which the Newton solver freezes the self-contact
            features (``wface.physics.frozen``) and re-detects them only once the frozen problem has
            converged; None (default): re-detect at every evaluation. 1.0 freezes from the start.
        freeze_margin_m: frozen pairs include those up to this far apart (default 0.1 x the median
            rest tet edge length).
        self_max_depth_m: self-contact pairs deeper than this are ignored (a node that far "inside"
            the other lip's surface is on the far side of it, not in contact).
        bone_affines: fixed world affines {"cranium": 3x4, "jaw": 3x4} of the bones; by default the
            solver fits them to the attached-node targets of each solve.
        nodes: node ids that may touch rigid obstacles (default: the free boundary nodes).
        ignore_inside_at_rest: leave out, for each of the model's bone and teeth meshes, the contact
            nodes already inside it at rest (bones at rest). The Badin face's inner (gum-side)
            surface runs through the ArtiSynth teeth meshes by up to 8.7 mm in the source data
            (ArtiSynth uses the teeth for display; its lip-skull contact is against the jaw and
            maxilla): those nodes are not in contact in the rest state, which must stay an
            equilibrium. ``ignored_at_rest`` counts them per mesh. User obstacles are never filtered.
        surface: self-contact against the "faceted" surfaces (default) or "smooth" ones
            (``wface.physics.smooth_contact``: C2 in the positions, exact Hessian, quadratic Newton;
            not combined with ``freeze_below``); "smooth_through_nodes": smooth ones whose planes are
            offset at rest to pass through the lip nodes, as the faceted surfaces do
            (``SmoothSurface(through_nodes=True)``).
        smooth_levels, smooth_radius_factor: the smooth surfaces' Loop levels and support radii
            (``wface.mesh.smooth_distance.SmoothSurface``).
        edge_midpoints: self-contact points at the surface edges' midpoints as well as the nodes (False:
            nodes only, as ArtiSynth's vertex penetrations).
    """

    def __init__(
        self,
        model: FaceModel,
        *,
        regions=(),
        obstacles=(),
        self_pairs=(),
        stiffness_n_per_m: float | None = None,
        gap_m: float = 0.0,
        smoothing_m: float = 0.0,
        freeze_below: float | None = None,
        freeze_margin_m: float | None = None,
        self_max_depth_m: float = 0.01,
        bone_affines: dict | None = None,
        nodes: np.ndarray | None = None,
        ignore_inside_at_rest: bool = True,
        surface: str = "faceted",
        smooth_levels: int = 2,
        smooth_radius_factor: float = 1.5,
        edge_midpoints: bool = True,
    ):
        if isinstance(regions, str):
            regions = [r for r in (s.strip() for s in regions.split(",")) if r]
        unknown = [r for r in regions if r not in REGIONS]
        if unknown:
            raise ValueError(f"unknown contact region(s) {unknown}; known: {', '.join(REGIONS)}")
        k = default_contact_stiffness(model) if stiffness_n_per_m is None else float(stiffness_n_per_m)
        if not (np.isfinite(k) and k > 0):
            raise ValueError(f"contact stiffness must be finite and > 0 N/m, got {stiffness_n_per_m}")
        if not (np.isfinite(gap_m) and gap_m >= 0):
            raise ValueError(f"gap_m must be finite and >= 0, got {gap_m}")
        if not (np.isfinite(smoothing_m) and smoothing_m >= 0):
            raise ValueError(f"smoothing_m must be finite and >= 0, got {smoothing_m}")
        if not (np.isfinite(self_max_depth_m) and self_max_depth_m > 0):
            raise ValueError(f"self_max_depth_m must be finite and > 0, got {self_max_depth_m}")
        self.model = model
        self.regions = tuple(regions)
        self.stiffness_n_per_m = k
        self.gap_m = float(gap_m)
        self.smoothing_m = float(smoothing_m)
        self.freeze_below = None if freeze_below is None else float(freeze_below)
        self.freeze_margin_m = 0.1 * median_edge_length(model) if freeze_margin_m is None else float(freeze_margin_m)
        self.self_max_depth_m = float(self_max_depth_m)
        self.fixed_bone_affines = None
        if bone_affines is not None:
            self.fixed_bone_affines = {b: as_affine(A, f"{b} affine") for b, A in bone_affines.items()}
            bad = [b for b in self.fixed_bone_affines if b not in BONES]
            if bad:
                raise ValueError(f"bone_affines names unknown bone(s) {bad}; known: {BONES}")
        self.bone_affines = dict(self.fixed_bone_affines or bone_affines_from_attached(model, None))

        if nodes is None:
            free = np.ones(model.n_nodes, dtype=bool)
            free[model.attached_nodes] = False
            nodes = np.unique(boundary_faces(model.tets))
            nodes = nodes[free[nodes]]
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1)
        if nodes.size and (nodes.min() < 0 or nodes.max() >= model.n_nodes):
            raise ValueError(f"contact nodes must lie in [0, {model.n_nodes})")
        self.nodes = nodes

        self.rigid: list[tuple[str, object]] = []
        for i, spec in enumerate(obstacles):
            ob = parse_obstacle(spec) if isinstance(spec, str) else spec
            if not isinstance(ob, Sphere | HalfSpace | MeshObstacle):
                raise TypeError(f"obstacle {i} is a {type(ob).__name__}; use Sphere, HalfSpace or MeshObstacle")
            label = getattr(ob, "name", None) or type(ob).__name__.lower()
            self.rigid.append((f"{label}{i}" if label in ("sphere", "halfspace") else label, ob))
            phi = ob.signed(model.rest_positions_m[nodes], {}, 0.0)[0]
            inside = int(np.count_nonzero(phi < 0))
            if nodes.size and inside > nodes.size // 2:  # it would push the face out through itself
                shown = spec if isinstance(spec, str) else self.rigid[-1][0]
                raise ValueError(
                    f"obstacle {shown} holds {inside} of the face's {nodes.size} surface nodes at rest (down to "
                    f"{-phi.min() * 1e3:.1f} mm inside): an obstacle is a solid the skin is pushed out of; place "
                    "it against the skin (a sphere's centre outside the face)"
                )
        # Nodes that may touch each rigid source (all contact nodes; for the model's bone and teeth
        # meshes, those already inside at rest are left out, see ``ignore_inside_at_rest``).
        self.rigid_nodes: list[np.ndarray] = [nodes] * len(self.rigid)
        self.ignored_at_rest: dict[str, int] = {}
        self._add_model_meshes(model, nodes, ignore_inside_at_rest)

        pairs = list(self_pairs)
        if "lips" in self.regions:
            found = [p for p in LIP_GROUPS if all(g in model.surface_groups for g in p)]
            if not found:
                raise ValueError(
                    "contact region 'lips': the model has no lip surface groups "
                    f"({' / '.join('+'.join(p) for p in LIP_GROUPS)}); it has {list(model.surface_groups)}"
                )
            pairs.append(found[0])
        self.self_contact: list[tuple[str, np.ndarray, np.ndarray]] = []
        for a, b in pairs:
            for g in (a, b):
                if g not in model.surface_groups:
                    raise ValueError(f"unknown surface group {g!r}; the model has {list(model.surface_groups)}")
            ta, tb = model.surface_groups[a], model.surface_groups[b]
            # point-to-triangle both ways
            self.self_contact.append((f"{a}/{b}", *contact_points(ta, tb, edge_midpoints), tb))
            self.self_contact.append((f"{b}/{a}", *contact_points(tb, ta, edge_midpoints), ta))
        self.names = [n for n, _ in self.rigid] + [n for n, *_ in self.self_contact]
        if not self.names:
            raise ValueError("contact has nothing to do: give regions and/or obstacles")
        if surface not in SURFACES:
            raise ValueError(f"surface must be one of {', '.join(SURFACES)}, got {surface!r}")
        if surface != "faceted" and self.freeze_below is not None:
            raise ValueError("freeze_below freezes faceted features; smooth lip surfaces need no freezing")
        self.surface = surface
        self.smooth = None
        if surface != "faceted" and self.self_contact:
            self.smooth = SmoothSelfContact(
                model,
                self.self_contact,
                levels=smooth_levels,
                radius_factor=smooth_radius_factor,
                through_nodes=surface == "smooth_through_nodes",
            )

    def _add_model_meshes(self, model: FaceModel, nodes: np.ndarray, ignore_inside_at_rest: bool) -> None:
        """The model's bone and teeth meshes that ``regions`` names, as rigid sources with the nodes
        that may touch them (see ``ignore_inside_at_rest`` in the class docstring)."""
        rest_affines = bone_affines_from_attached(model, None)
        for name, mesh in model.bone_meshes.items():
            is_teeth = "teeth" in name.lower()
            if (
                ("teeth" in self.regions and is_teeth)
                or ("bones" in self.regions and not is_teeth)
                or ("skull" in self.regions and name in SKULL_MESHES)
            ):
                ob = MeshObstacle(mesh.vertices_m, mesh.triangles, bone=mesh.bone, name=name)
                keep = nodes
                if ignore_inside_at_rest:
                    phi, _, valid, _, _ = ob.signed(model.rest_positions_m[nodes], rest_affines, 0.0)
                    inside = valid & (phi < self.gap_m)
                    keep = nodes[~inside]
                    self.ignored_at_rest[name] = int(inside.sum())
                self.rigid.append((name, ob))
                self.rigid_nodes.append(keep)
        if "skull" in self.regions and not any(n in model.bone_meshes for n in SKULL_MESHES):
            raise ValueError(
                f"contact region 'skull': the model has no {' or '.join(SKULL_MESHES)} mesh "
                f"(bone meshes: {list(model.bone_meshes)})"
            )
        if "teeth" in self.regions and not any("teeth" in n.lower() for n in model.bone_meshes):
            raise ValueError(
                f"contact region 'teeth': the model has no teeth mesh (bone meshes: {list(model.bone_meshes)})"
            )

    @classmethod
    def from_spec(cls, model: FaceModel, regions: str = "", obstacles=(), **kwargs) -> Contact:
        """``Contact(model, regions="lips,teeth", obstacles=["sphere:0,-0.06,0.1,0.02"])``."""
        return cls(model, regions=regions, obstacles=list(obstacles), **kwargs)

    def set_pose(self, attached_positions: np.ndarray | None) -> None:
        """Place the bone-following meshes for a solve whose attached nodes go to ``attached_positions``
        (ignored when fixed ``bone_affines`` were given)."""
        if self.fixed_bone_affines is None:
            self.bone_affines = bone_affines_from_attached(self.model, attached_positions)

    def evaluate(self, x: np.ndarray, *, margin_m: float = 0.0, self_contact: bool = True) -> ContactPairs:
        """The active pairs at positions ``x`` (n, 3).

        Args:
            margin_m: also return pairs up to this much farther apart (no force; for freezing).
            self_contact: include the self-contact pairs (False: rigid obstacles only).
        """
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.model.n_nodes, 3):
            raise ValueError(f"positions have shape {x.shape}, expected ({self.model.n_nodes}, 3)")
        if not np.all(np.isfinite(x)):
            raise ValueError("contact: positions contain NaN or inf")
        parts = []
        reach = self.gap_m + margin_m  # pairs with phi <= reach carry force or stiffness
        for s, (_, ob) in enumerate(self.rigid):
            ids = self.rigid_nodes[s]
            phi, n, valid, feature, e = ob.signed(x[ids], self.bone_affines, reach)
            act = valid & (phi <= reach)
            m = int(act.sum())
            node = ids[act]
            c = self._tangential(phi[act], feature[act])
            point = (np.repeat(node[:, None], 2, 1), np.tile([1.0, 0.0], (m, 1)))
            parts.append(
                (
                    node,
                    np.repeat(node[:, None], 3, 1),
                    np.zeros((m, 3)),
                    n[act],
                    self.gap_m - phi[act],
                    s,
                    c,
                    e[act],
                    *point,
                    phi[act],
                )
            )
        for s, (_, pn, pw, tri) in enumerate(self.self_contact, start=len(self.rigid)):
            if not len(pn) or not self_contact or self.smooth is not None:
                continue
            surf = SignedSurface(x, tri, orient=False)
            q = np.einsum("pk,pkd->pd", pw, x[pn])
            near = np.flatnonzero(surf.near_box(q, reach + self.self_max_depth_m))
            if not near.size:
                continue
            hit = surf.signed(q[near])
            act = ~hit.on_boundary & (hit.phi_m <= reach) & (hit.phi_m > -self.self_max_depth_m)
            sel = near[act]
            phi = hit.phi_m[act]
            parts.append(
                (
                    pn[sel, 0],
                    surf.triangles[hit.triangle[act]],
                    hit.barycentric[act],
                    hit.normal[act],
                    self.gap_m - phi,
                    s,
                    self._tangential(phi, hit.feature[act]),
                    hit.edge_direction[act],
                    pn[sel],
                    pw[sel],
                    phi,
                )
            )
        cat = lambda i, shape: np.concatenate([q[i] for q in parts]) if parts else np.zeros(shape)  # noqa: E731
        pairs = ContactPairs(
            node=cat(0, (0,)).astype(np.int64),
            others=cat(1, (0, 3)).astype(np.int64).reshape(-1, 3),
            weights=cat(2, (0, 3)).reshape(-1, 3),
            normal=cat(3, (0, 3)).reshape(-1, 3),
            penetration_m=cat(4, (0,)),
            source=np.concatenate([np.full(len(q[0]), q[5]) for q in parts]) if parts else np.zeros(0, int),
            tangential=cat(6, (0,)),
            edge_direction=cat(7, (0, 3)).reshape(-1, 3),
            point_nodes=cat(8, (0, 2)).astype(np.int64).reshape(-1, 2),
            point_weights=cat(9, (0, 2)).reshape(-1, 2),
            distance_m=cat(10, (0,)),
            smoothing_m=self.smoothing_m,
            names=self.names,
            stiffness_n_per_m=self.stiffness_n_per_m,
            n_nodes=self.model.n_nodes,
        )
        if self.smooth is None or not self_contact:
            return pairs
        return CombinedPairs(pairs, self.smooth.evaluate(self, x, len(self.rigid)))

    def self_distance_m(self, x: np.ndarray) -> float:
        """Smallest signed distance (m) between the self-contact surfaces at ``x``: the gap between the
        lips where positive, minus the deepest overlap where negative (points whose closest feature
        is on the other surface's open boundary, or deeper than ``self_max_depth_m``, are skipped).
        NaN without self-contact."""
        x = np.asarray(x, dtype=np.float64)
        best = np.inf
        for _, pn, pw, tri in self.self_contact:
            if not len(pn):
                continue
            hit = SignedSurface(x, tri, orient=False).signed(np.einsum("pk,pkd->pd", pw, x[pn]))
            ok = ~hit.on_boundary & (hit.phi_m > -self.self_max_depth_m)
            if ok.any():
                best = min(best, float(hit.phi_m[ok].min()))
        return best if np.isfinite(best) else float("nan")

    def _tangential(self, phi: np.ndarray, feature: np.ndarray) -> np.ndarray:
        """1 for points inside the surface whose closest point is on an edge or vertex (the Hessian
        gets the curvature of the distance to that feature, ``ContactPairs._projector``), else 0."""
        return ((feature > 0) & (phi < 0)).astype(np.float64)

    def energy(self, x: np.ndarray) -> float:
        """E_c(x) in joules."""
        return self.evaluate(x).energy

    def forces(self, x: np.ndarray) -> np.ndarray:
        """-dE_c/dx, (n, 3) newtons."""
        return self.evaluate(x).forces()

    def penetration(self, x: np.ndarray) -> dict:
        """``ContactPairs.stats`` at x: active nodes, max penetration (m), force (N), per source."""
        return self.evaluate(x).stats()
