"""Carry a muscle layout to another face by landmark correspondence.

1. Match the layout's named landmarks with the target's (same names, e.g. AnimFace markers).
2. Warp: a similarity (Umeyama 1991: least-squares s, R, t), optionally followed by a thin-plate
   RBF of the residuals (``scipy.interpolate.RBFInterpolator``) or an affine map.
3. Move every layout point through the warp (bones, insertions, sphincter centres, jaw pivot and
   planes); sphincter axes and jaw directions follow the warp's local linear part; lengths
   (fall-start/finish, spring constants; a sphincter's protrusion with its depth semi-axis)
   scale with each muscle's length change; the per-vertex
   cap scales with s.
4. Snap the skin insertions to the closest point of the target surface (``wface.mesh.closest``).

A layout fitted to its own face under a similarity transform reproduces the transformed layout.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import RBFInterpolator

from wface.mesh.closest import SurfaceQuery
from wface.waters.layout import JawPlane, JawRegion, MuscleLayout
from wface.waters.muscles import LinearMuscle, SphincterMuscle

__all__ = ["LandmarkWarp", "fit_layout", "landmark_warp", "similarity_transform"]

METHODS = ("similarity", "affine", "rbf")


def similarity_transform(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity dst ~ s R src + t (Umeyama 1991), R a proper rotation.

    Args:
        src, dst: (k, 3) matched points, k >= 3 not collinear.

    Returns:
        (s, R (3, 3), t (3,)).
    """
    a = np.asarray(src, dtype=np.float64)
    b = np.asarray(dst, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 3:
        raise ValueError(f"need two matching (k>=3, 3) point sets, got {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("landmarks contain NaN or inf")
    ma, mb = a.mean(0), b.mean(0)
    A, B = a - ma, b - mb
    var_a = (A**2).sum() / len(a)
    if var_a <= 0:
        raise ValueError("source landmarks coincide")
    U, S, Vt = np.linalg.svd(B.T @ A / len(a))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    if S[1] < 1e-12 * max(S[0], 1e-300):
        raise ValueError("landmarks are collinear: a rotation is not determined")
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / var_a)
    return s, R, mb - s * R @ ma


@dataclass
class LandmarkWarp:
    """A map R^3 -> R^3 from matched landmarks: similarity, plus an affine or RBF correction."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    method: str
    affine: np.ndarray | None = None  # (4, 3) for method "affine" (applied instead of the similarity)
    rbf: object | None = None  # RBFInterpolator of residuals after the similarity

    def similarity(self, points_m: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points_m, dtype=np.float64) @ self.rotation.T + self.translation

    def __call__(self, points_m: np.ndarray) -> np.ndarray:
        """Warp (k, 3) points."""
        p = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        if self.affine is not None:
            return np.hstack([p, np.ones((len(p), 1))]) @ self.affine
        q = self.similarity(p)
        if self.rbf is not None:
            q = q + self.rbf(q)
        return q

    def jacobian(self, point_m: np.ndarray, *, step_m: float = 1e-4) -> np.ndarray:
        """(3, 3) local linear part of the warp at a point (central differences)."""
        p = np.asarray(point_m, dtype=np.float64)
        cols = [(self(p + step_m * e)[0] - self(p - step_m * e)[0]) / (2 * step_m) for e in np.eye(3)]
        return np.stack(cols, axis=1)


def landmark_warp(src: np.ndarray, dst: np.ndarray, *, method: str = "rbf", smoothing: float = 0.0) -> LandmarkWarp:
    """Warp taking landmarks ``src`` (k, 3) to ``dst`` (k, 3).

    Args:
        method: "similarity" (7 dof), "affine" (12 dof, least squares; k >= 4) or "rbf"
            (similarity + thin-plate spline of the residuals: exact at the landmarks when
            ``smoothing`` = 0).
        smoothing: RBF smoothing (metres^2 scale; 0 interpolates).
    """
    if method not in METHODS:
        raise ValueError(f"unknown warp method {method!r}; known: {', '.join(METHODS)}")
    s, R, t = similarity_transform(src, dst)
    warp = LandmarkWarp(s, R, t, method)
    a = np.asarray(src, dtype=np.float64)
    b = np.asarray(dst, dtype=np.float64)
    if method == "affine":
        if len(a) < 4:
            raise ValueError("an affine warp needs at least 4 landmarks")
        warp.affine = np.linalg.lstsq(np.hstack([a, np.ones((len(a), 1))]), b, rcond=None)[0]
    elif method == "rbf":
        q = warp.similarity(a)
        resid = b - q
        if len(a) >= 5 and np.max(np.abs(resid)) > 1e-12 * max(1.0, float(np.abs(b).max())):
            warp.rbf = RBFInterpolator(q, resid, kernel="thin_plate_spline", smoothing=smoothing)
    return warp


def _matched(layout: MuscleLayout, target: Mapping[str, np.ndarray]) -> tuple[list[str], np.ndarray, np.ndarray]:
    names = [n for n in layout.landmarks_m if n in target]
    if len(names) < 4:
        raise ValueError(
            f"need at least 4 landmarks shared by layout {layout.name!r} and the target; shared: {names or 'none'} "
            f"(layout has {len(layout.landmarks_m)}, target {len(target)})"
        )
    src = np.stack([layout.landmarks_m[n] for n in names])
    dst = np.stack([np.asarray(target[n], dtype=np.float64).reshape(3) for n in names])
    if not np.all(np.isfinite(dst)):
        raise ValueError("target landmarks contain NaN or inf")
    return names, src, dst


def fit_layout(
    layout: MuscleLayout,
    target_landmarks_m: Mapping[str, np.ndarray],
    *,
    target_vertices_m: np.ndarray | None = None,
    target_triangles: np.ndarray | None = None,
    method: str = "rbf",
    snap: bool = True,
    name: str | None = None,
) -> MuscleLayout:
    """A copy of ``layout`` carried onto a target face.

    Args:
        layout: source layout (metres) with named ``landmarks_m``.
        target_landmarks_m: ``{name: (3,)}`` on the target face; at least 4 names in common.
        target_vertices_m, target_triangles: the target surface, for snapping insertions.
        method: "similarity", "affine" or "rbf" (see ``landmark_warp``).
        snap: snap linear-muscle insertions to the target surface (needs the surface).
        name: name of the new layout (default: source name + "-fitted").
    """
    _, src, dst = _matched(layout, target_landmarks_m)
    warp = landmark_warp(src, dst, method=method)
    query = None
    if snap:
        if target_vertices_m is None or target_triangles is None:
            raise ValueError("snap=True needs target_vertices_m and target_triangles")

        query = SurfaceQuery(target_vertices_m, target_triangles)

    muscles: list[LinearMuscle | SphincterMuscle] = []
    for m in layout.muscles:
        if isinstance(m, LinearMuscle):
            bone, ins = warp(np.stack([m.bone_m, m.insertion_m]))
            if query is not None:
                ins = query.closest(ins[None]).point_m[0]
            ratio = np.linalg.norm(ins - bone) / np.linalg.norm(m.insertion_m - m.bone_m)
            muscles.append(
                LinearMuscle(
                    m.name,
                    bone_m=bone,
                    insertion_m=ins,
                    zone_deg=m.zone_deg,
                    fall_start_m=m.fall_start_m * ratio,
                    fall_finish_m=m.fall_finish_m * ratio,
                    spring_constant_m=m.spring_constant_m * ratio,
                    elasticity=m.elasticity,
                    region=m.region,
                )
            )
        else:
            centre = warp(m.centre_m[None])[0]
            J = warp.jacobian(m.centre_m)
            h = J @ (m.horizontal * m.semi_axes_m[0])
            v = J @ (m.vertical * m.semi_axes_m[1])
            v = v - (v @ h) / (h @ h) * h
            depth = np.linalg.norm(J @ (m.normal * m.semi_axes_m[2]))
            muscles.append(
                SphincterMuscle(
                    m.name,
                    centre_m=centre,
                    horizontal=h,
                    vertical=v,
                    semi_axes_m=[np.linalg.norm(h), np.linalg.norm(v), depth],
                    tension=m.tension,
                    elasticity=m.elasticity,
                    region=m.region,
                    protrusion_m=m.protrusion_m * depth / m.semi_axes_m[2],  # a length along the normal
                    lower_semi_axis_m=m.lower_semi_axis_m * np.linalg.norm(v) / m.semi_axes_m[1],
                )
            )
    jaw = None
    if layout.jaw is not None:
        j = layout.jaw
        Jp = warp.jacobian(j.pivot_m)
        planes = []
        for p in j.planes:
            Jq = warp.jacobian(p.point_m)
            normal = np.linalg.solve(Jq.T, p.normal)  # normals transform by the inverse transpose
            scale = float(np.cbrt(abs(np.linalg.det(Jq))))
            planes.append(
                JawPlane(
                    point_m=warp(p.point_m[None])[0],
                    normal=normal,
                    width_m=p.width_m * scale,
                    width_per_lateral=p.width_per_lateral,
                    lateral_start_m=p.lateral_start_m * scale,
                    curvature_per_m=p.curvature_per_m / scale,
                )
            )
        jaw = JawRegion(pivot_m=warp(j.pivot_m[None])[0], axis=Jp @ j.axis, planes=planes, max_open_deg=j.max_open_deg)
    return replace(
        layout,
        name=name or f"{layout.name}-fitted",
        muscles=muscles,
        jaw=jaw,
        landmarks_m={k: np.asarray(v, dtype=np.float64).reshape(3) for k, v in target_landmarks_m.items()},
        max_displacement_m=layout.max_displacement_m * warp.scale,
        mesh_vertex_count=None if target_vertices_m is None else int(len(target_vertices_m)),
        muscle_vertex_ranges=[],
        notes=(layout.notes + " " if layout.notes else "")
        + f"Fitted by {method} warp from {len(src)} landmarks (similarity scale {warp.scale:.4g}).",
    )
