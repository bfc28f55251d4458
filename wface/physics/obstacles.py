"""Rigid contact obstacles: spheres, half-spaces and triangle meshes (posed by an affine, optionally
following the cranium or the jaw), and the bone affines implied by attached-node targets.

Each obstacle answers ``signed(points, bone_affines, margin_m)`` with the signed distance phi (positive
outside), its outward unit gradient n, which points were evaluated, and the closest feature (0 face,
1 edge, 2 vertex, with the edge direction) used by ``wface.physics.contact`` for the Hessian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wface.controls import as_affine, bone_affines_from_attached
from wface.mesh.signed_distance import SignedSurface, oriented_outward
from wface.model import BONES

__all__ = ["HalfSpace", "MeshObstacle", "Sphere", "as_affine", "bone_affines_from_attached", "parse_obstacle"]

# (phi (k,), outward unit gradient n (k, 3), evaluated (k,) bool, closest feature (k,) 0 face / 1 edge /
# 2 vertex, edge direction (k, 3)) of k query points against a rigid obstacle.
_Signed = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _vec3(value, what: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{what} must be 3 finite numbers, got {value!r}")
    return v


# ---------------------------------------------------------------------- rigid obstacles
@dataclass(frozen=True)
class Sphere:
    """A rigid ball: phi = |x - center| - radius."""

    center_m: tuple[float, float, float]
    radius_m: float

    def __post_init__(self):
        object.__setattr__(self, "center_m", tuple(_vec3(self.center_m, "sphere center")))
        if not (np.isfinite(self.radius_m) and self.radius_m > 0):
            raise ValueError(f"sphere radius must be finite and > 0, got {self.radius_m}")

    def signed(self, p: np.ndarray, bone_affines: dict, margin_m: float = 0.0) -> _Signed:
        d = p - np.asarray(self.center_m)
        r = np.linalg.norm(d, axis=1)
        n = np.where(r[:, None] > 0, d / np.where(r > 0, r, 1.0)[:, None], np.array([0.0, 0.0, 1.0]))
        return r - self.radius_m, n, np.ones(len(p), dtype=bool), np.zeros(len(p), np.int8), np.zeros_like(p)


@dataclass(frozen=True)
class HalfSpace:
    """The rigid solid {x : (x - point) . normal < 0}; ``normal`` points out of it (toward the face)."""

    point_m: tuple[float, float, float]
    normal: tuple[float, float, float]

    def __post_init__(self):
        n = _vec3(self.normal, "half-space normal")
        if np.linalg.norm(n) == 0:
            raise ValueError("half-space normal must be non-zero")
        object.__setattr__(self, "point_m", tuple(_vec3(self.point_m, "half-space point")))
        object.__setattr__(self, "normal", tuple(n / np.linalg.norm(n)))

    def signed(self, p: np.ndarray, bone_affines: dict, margin_m: float = 0.0) -> _Signed:
        n = np.asarray(self.normal)
        ok = np.ones(len(p), dtype=bool)
        phi = (p - np.asarray(self.point_m)) @ n
        return phi, np.broadcast_to(n, p.shape).copy(), ok, np.zeros(len(p), np.int8), np.zeros_like(p)


class MeshObstacle:
    """A rigid closed triangle mesh, placed by ``affine`` (3x4 [M | t]) and, with ``bone`` set, moved
    further by that bone's world affine (x_world = A_bone (A x_rest)).

    Args:
        vertices_m: (v, 3) rest vertices.
        triangles: (t, 3) vertex ids (either winding; it is made outward from the enclosed volume).
        affine: placement of the mesh (default identity).
        bone: "cranium" or "jaw" to follow that bone during a solve, or None (fixed in space).
        name: label for statistics.
    """

    def __init__(self, vertices_m, triangles, *, affine=None, bone: str | None = None, name: str = "mesh"):
        v = np.asarray(vertices_m, dtype=np.float64)
        t = np.asarray(triangles, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"obstacle {name!r}: vertices must be a finite (v, 3) array, got shape {v.shape}")
        if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0 or t.min() < 0 or t.max() >= len(v):
            raise ValueError(f"obstacle {name!r}: triangles must be a non-empty (t, 3) array of vertex ids")
        if bone is not None and bone not in BONES:
            raise ValueError(f"obstacle {name!r}: unknown bone {bone!r}; known: {BONES}")
        self.vertices_m, self.triangles = v, oriented_outward(v, t)
        self.affine = as_affine(affine, "affine")
        self.bone, self.name = bone, name
        self._cache: tuple[bytes, SignedSurface] | None = None

    def surface(self, bone_affines: dict) -> SignedSurface:
        """The posed surface (cached per pose)."""
        A = self.affine
        if self.bone is not None and self.bone in bone_affines:
            B = bone_affines[self.bone]
            A = np.hstack([B[:, :3] @ A[:, :3], (B[:, :3] @ A[:, 3] + B[:, 3])[:, None]])
        key = A.tobytes()
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, SignedSurface(self.vertices_m @ A[:, :3].T + A[:, 3], self.triangles, orient=False))
        return self._cache[1]

    def signed(self, p: np.ndarray, bone_affines: dict, margin_m: float = 0.0) -> _Signed:
        surf = self.surface(bone_affines)
        near = surf.near_box(p, margin_m)
        phi, n, e = np.full(len(p), np.inf), np.zeros((len(p), 3)), np.zeros((len(p), 3))
        feature = np.zeros(len(p), np.int8)
        if near.any():
            hit = surf.signed(p[near])
            phi[near], n[near], feature[near], e[near] = hit.phi_m, hit.normal, hit.feature, hit.edge_direction
            # on an open mesh (the Badin teeth have small holes, its cranium is a partial skull) the sign
            # at a boundary edge or vertex is meaningless: such points are not in contact
            near[np.flatnonzero(near)[hit.on_boundary]] = False
        return phi, n, near, feature, e


def parse_obstacle(spec: str):
    """An obstacle from a command-line spec (metres):

    - ``sphere:X,Y,Z,R`` -- ball of radius R centred at (X, Y, Z);
    - ``plane:PX,PY,PZ,NX,NY,NZ`` -- half-space through P whose outward normal N points to the face.
    """
    kind, sep, rest = str(spec).partition(":")
    kind = kind.strip().lower()
    if not sep:
        raise ValueError(f"obstacle spec {spec!r}: expected KIND:NUMBERS, e.g. sphere:0,-0.06,0.1,0.02")
    try:
        nums = [float(s) for s in rest.split(",")]
    except ValueError:
        raise ValueError(f"obstacle spec {spec!r}: {rest!r} is not a comma-separated list of numbers") from None
    if not np.all(np.isfinite(nums)):
        raise ValueError(f"obstacle spec {spec!r}: numbers must be finite")
    if kind == "sphere":
        if len(nums) != 4:
            raise ValueError(f"obstacle spec {spec!r}: sphere needs 4 numbers X,Y,Z,R (metres), got {len(nums)}")
        return Sphere(tuple(nums[:3]), nums[3])
    if kind in ("plane", "halfspace"):
        if len(nums) != 6:
            raise ValueError(f"obstacle spec {spec!r}: plane needs 6 numbers PX,PY,PZ,NX,NY,NZ, got {len(nums)}")
        return HalfSpace(tuple(nums[:3]), tuple(nums[3:]))
    raise ValueError(f"obstacle spec {spec!r}: unknown kind {kind!r}; use sphere:X,Y,Z,R or plane:PX,PY,PZ,NX,NY,NZ")
