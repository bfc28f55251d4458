"""Bone placement: positions of the attached (Dirichlet) nodes from cranium and jaw affines.

Seed 000, section 8: the cranium moves by an affine (Mc, tc) and the jaw by (Mm, tm) relative to
the cranium. A cranium node goes to Mc X0 + tc, a jaw node to Mc (Mm X0 + tm) + tc. Affines are
3x4 matrices [M | t]. Axes: +x is the subject's left, +y up, +z forward.
"""

from __future__ import annotations

import numpy as np

from wface.model import BONES, FaceModel

__all__ = [
    "IDENTITY_AFFINE",
    "apply_affine",
    "as_affine",
    "attached_positions",
    "jaw_opening_affine",
    "rotation_about_axis",
]

IDENTITY_AFFINE = np.hstack([np.eye(3), np.zeros((3, 1))])


def as_affine(affine: np.ndarray | None, what: str) -> np.ndarray:
    """A finite 3x4 [M | t] affine from a 3x4 or 4x4 matrix (None: the identity); ``what`` names it
    in the error."""
    if affine is None:
        return IDENTITY_AFFINE
    A = np.asarray(affine, dtype=np.float64)
    if A.shape == (4, 4):
        A = A[:3]
    if A.shape != (3, 4) or not np.all(np.isfinite(A)):
        raise ValueError(f"{what} must be a finite 3x4 [M | t] (or 4x4) matrix, got shape {A.shape}")
    return A


def apply_affine(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    """M p + t for points (k, 3) and a 3x4 affine [M | t]."""
    A = as_affine(affine, "affine")
    return np.asarray(points, dtype=np.float64) @ A[:, :3].T + A[:, 3]


def attached_positions(
    model: FaceModel, cranium: np.ndarray | None = None, jaw: np.ndarray | None = None
) -> np.ndarray:
    """Positions (a, 3) of ``model.attached_nodes`` for the given bone affines.

    Args:
        model: the face.
        cranium: 3x4 affine [Mc | tc] of the cranium (default identity).
        jaw: 3x4 affine [Mm | tm] of the jaw relative to the cranium (default identity).

    Returns:
        (a, 3) float64 metres, in the order of ``model.attached_nodes``.
    """
    Ac, Am = as_affine(cranium, "cranium affine"), as_affine(jaw, "jaw affine")
    X0 = model.rest_positions_m[model.attached_nodes]
    out = np.empty_like(X0)
    on_jaw = model.attached_bone == BONES.index("jaw")
    out[~on_jaw] = apply_affine(Ac, X0[~on_jaw])
    out[on_jaw] = apply_affine(Ac, apply_affine(Am, X0[on_jaw]))
    return out


def rotation_about_axis(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Right-handed rotation matrix (Rodrigues) about a unit axis."""
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def jaw_opening_affine(model: FaceModel, opening_deg: float) -> np.ndarray:
    """Jaw affine (relative to the cranium) for a pure rotation about the condyle axis.

    Rotation by ``opening_deg`` about the joint axis u (right -> left condyle) through the condyle
    midpoint m. Positive opens the mouth: with u = +x (the subject's left), a right-handed rotation
    by a positive angle moves points in front of the axis (+z) downwards (-y).

    Returns:
        3x4 affine [R | m - R m].
    """
    jj = model.jaw_joint
    R = rotation_about_axis(np.asarray(jj.u), np.deg2rad(opening_deg))
    m = np.asarray(jj.midpoint_m, dtype=np.float64)
    return np.hstack([R, (m - R @ m)[:, None]])
