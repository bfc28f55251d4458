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

Gradient and Hessian (Wriggers, "Computational Contact Mechanics", 2006, ch. 6): ``wface.physics.contact_pairs``.
The active set (g > 0) and closest points are recomputed at every configuration the Newton solver
evaluates, so the line search sees the exact, C1 contact energy.

Penalty stiffness k (N/m, per node): default ``DEFAULT_STIFFNESS_FACTOR`` x the stiffness of a
surface node of the flesh, k = 100 * E * h with E = 6 (mu10 + mu01) the small-strain Young's modulus
of the incompressible Mooney-Rivlin flesh and h the median rest edge length of the tets. A node
then penetrates about 1/100 of the distance it would have moved without contact (measured in
``tests/test_contact.py``); raise it for less penetration at the price of a stiffer system.

Smoothed penalty (``smoothing_m = d``): the C2 ramp of ``penalty_profile``, whose normal stiffness rises
from 0 at contact to k at g = d; about d/2 more penetration.

Convergence on coarse lip surfaces (the ArtiSynth Badin face, lips pressed): with the C1 penalty on the
faceted lips Newton stalls (relative residual 0.2 after 40 iterations): the active set chatters, the
signed distance to a faceted surface is not smooth inside it and the Gauss-Newton Hessian misses the
normals' derivatives. The C2 ramp and freezing the closest features (``freeze_below``,
``wface.physics.frozen``) help (0.003 after 80); ``surface="smooth"`` removes the last two causes (a C2
blend of the planes of the other lip's Loop refinement with an exact Hessian,
``wface.physics.smooth_contact``), and with Newton restarted every 5 iterations
(``wface.physics.contact_solve.solve_restarted``) the pose converges to 6e-9 in 56 iterations,
quadratically at the end (docs/design.md, "Contact" and "Smooth lip surfaces", for the measurements).

Teeth and bones of the model move with their bone. Nodes already inside one of those meshes at rest
are left out of its contact (``inside_at_rest="ignore"``, the default): the Badin face's gum-side surface
runs through ArtiSynth's teeth by up to 8.7 mm in the source data (winding number 1, checked in
``tests/test_badin_contact.py``; ArtiSynth uses the teeth for display and lets the lip collision
surfaces hit the jaw and maxilla). Closest points on an open mesh's boundary are no contact.
``"push"`` pushes them out like any other, as ArtiSynth's collisions do beyond their penetration
tolerance; ``"hold"`` gives node i the gap min(gap, phi_i at rest), so the penalty acts only deeper than
at rest, as ArtiSynth's contact does within the tolerance (docs/design.md, "Face-skull contact").
The "skull" region is ArtiSynth's lip-skull contact: the face against the jaw and maxilla meshes only
(``SKULL_MESHES``; docs/design.md, "Contact", "Face-skull contact"); on Badin 139 flesh nodes lie up to
0.58 mm inside the maxilla and 126 up to 0.05 mm inside the jaw at rest.
"""

from __future__ import annotations

import numpy as np

from wface.mesh.signed_distance import SignedSurface
from wface.mesh.surface import boundary_faces
from wface.model import BONES, FaceModel
from wface.physics.contact_pairs import ContactPairs
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
    "INSIDE_AT_REST",
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
# What becomes of flesh nodes inside a bone or teeth mesh at rest (``Contact(inside_at_rest=...)``).
INSIDE_AT_REST = ("ignore", "push", "hold")
# The bone meshes of the "skull" region: ArtiSynth's lip-skull contact (BadinFaceDemo.enableLipSkullContact:
# the face collides with the jaw and maxilla rigid bodies, not the teeth or cranium; docs/design.md, "Contact").
SKULL_MESHES = ("jaw", "maxilla")
# Surface groups holding the upper / lower lip contact surfaces, first match wins.
LIP_GROUPS = (("upper_lip", "lower_lip"), ("upper_lip_contact", "lower_lip_contact"))


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
        inside_at_rest: what becomes of the contact nodes already inside one of the model's bone and
            teeth meshes at rest (bones at rest), one of ``INSIDE_AT_REST``: "ignore" (default) leaves
            them out of that mesh's contact. The Badin face's inner (gum-side) surface runs through
            the ArtiSynth teeth meshes by up to 8.7 mm in the source data (ArtiSynth uses the teeth
            for display; its lip-skull contact is against the jaw and maxilla): those nodes are not
            in contact in the rest state, which stays an equilibrium. "push": pushed out like any
            other node; "hold": in contact from their rest depth on. ``ignored_at_rest`` /
            ``held_at_rest`` count them per mesh. User obstacles are never filtered.
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
        inside_at_rest: str = "ignore",
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
        if inside_at_rest not in INSIDE_AT_REST:
            raise ValueError(f"inside_at_rest must be one of {', '.join(INSIDE_AT_REST)}, got {inside_at_rest!r}")
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
        self.inside_at_rest = inside_at_rest
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

        self._add_obstacles(obstacles, nodes)
        # Nodes that may touch each rigid source and their gaps (all contact nodes at ``gap_m``; for the
        # model's bone and teeth meshes, see ``inside_at_rest``).
        self.rigid_nodes: list[np.ndarray] = [nodes] * len(self.rigid)
        self.rigid_gaps_m: list[np.ndarray] = [np.full(len(nodes), self.gap_m)] * len(self.rigid)
        self.ignored_at_rest: dict[str, int] = {}
        self.held_at_rest: dict[str, int] = {}
        self._add_model_meshes(model, nodes)

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

    def _add_obstacles(self, obstacles, nodes: np.ndarray) -> None:
        """The user's rigid obstacles (objects or spec strings), refused where one holds most of the skin."""
        self.rigid: list[tuple[str, object]] = []
        for i, spec in enumerate(obstacles):
            ob = parse_obstacle(spec) if isinstance(spec, str) else spec
            if not isinstance(ob, Sphere | HalfSpace | MeshObstacle):
                raise TypeError(f"obstacle {i} is a {type(ob).__name__}; use Sphere, HalfSpace or MeshObstacle")
            label = getattr(ob, "name", None) or type(ob).__name__.lower()
            self.rigid.append((f"{label}{i}" if label in ("sphere", "halfspace") else label, ob))
            phi = ob.signed(self.model.rest_positions_m[nodes], {}, 0.0)[0]
            inside = int(np.count_nonzero(phi < 0))
            if nodes.size and inside > nodes.size // 2:  # it would push the face out through itself
                shown = spec if isinstance(spec, str) else self.rigid[-1][0]
                raise ValueError(
                    f"obstacle {shown} holds {inside} of the face's {nodes.size} surface nodes at rest (down to "
                    f"{-phi.min() * 1e3:.1f} mm inside): an obstacle is a solid the skin is pushed out of; place "
                    "it against the skin (a sphere's centre outside the face)"
                )

    def _add_model_meshes(self, model: FaceModel, nodes: np.ndarray) -> None:
        """The model's bone and teeth meshes that ``regions`` names, as rigid sources with the nodes
        that may touch them and their gaps (see ``inside_at_rest`` in the class docstring)."""
        rest_affines = bone_affines_from_attached(model, None)
        for name, mesh in model.bone_meshes.items():
            is_teeth = "teeth" in name.lower()
            if (
                ("teeth" in self.regions and is_teeth)
                or ("bones" in self.regions and not is_teeth)
                or ("skull" in self.regions and name in SKULL_MESHES)
            ):
                ob = MeshObstacle(mesh.vertices_m, mesh.triangles, bone=mesh.bone, name=name)
                keep, gaps = nodes, np.full(len(nodes), self.gap_m)
                if self.inside_at_rest != "push":
                    phi, _, valid, _, _ = ob.signed(model.rest_positions_m[nodes], rest_affines, 0.0)
                    inside = valid & (phi < self.gap_m)
                    if self.inside_at_rest == "ignore":
                        keep, gaps = nodes[~inside], gaps[~inside]
                        self.ignored_at_rest[name] = int(inside.sum())
                    else:
                        gaps[inside] = phi[inside]
                        self.held_at_rest[name] = int(inside.sum())
                self.rigid.append((name, ob))
                self.rigid_nodes.append(keep)
                self.rigid_gaps_m.append(gaps)
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
            ids, gaps = self.rigid_nodes[s], self.rigid_gaps_m[s]
            phi, n, valid, feature, e = ob.signed(x[ids], self.bone_affines, reach)
            act = valid & (phi <= gaps + margin_m)
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
                    gaps[act] - phi[act],
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
