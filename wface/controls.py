"""Controls of the face, c = (a, b): muscle activations and bone kinematics (Sifakis et al. 2005, sections 5-8).

b holds 24 numbers: the cranium affine (Mc, tc) and the jaw affine (Mm, tm) *relative to the
cranium*. Parameter order: b[0:9] = Mc row-major, b[9:12] = tc, b[12:21] = Mm row-major,
b[21:24] = tm. The face is simulated in the cranium frame (cranium nodes at rest, jaw nodes at
Mm X + tm); world positions are X = Mc Y + tc. For a rigid Mc this is exact (the flesh energy is
rotation invariant), and it makes a pure cranium motion move every node rigidly.

Penalties phi_p (all with analytic gradient and Hessian):
- activation bounds: sum_i (min{0, a_i - l_i, 1 - a_i})^2 (l_i = 0, or -1 for a pressure actuator);
- rigidity: ||M^T M - I||_F^2 for Mc and Mm (Hessian projected to PSD);
- jaw joint (docs/design.md, "Controls and the jaw joint"): psi1 = w.Mm u = 0; psi2 = w.(Mm m + tm - m) = 0;
  psi3 = u.(Mm m + tm - m) = 0; psi4 = v.[Mm (m - l/2 u) + tm - m] in [0, d];
  psi5 = v.[Mm (m + l/2 u) + tm - m] in [0, d]; psi6 = w.Mm v in [-s, 0]; squared, one-sided for ranges.
  Each psi is linear in (Mm, tm), so its Hessian is constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from wface.model import BONES, FaceModel, JawJoint

__all__ = [
    "bone_affines_from_attached",
    "N_BONE_PARAMS",
    "IDENTITY_AFFINE",
    "IDENTITY_BONES",
    "apply_affine",
    "as_affine",
    "attached_positions_from_affines",
    "interpolate_bones",
    "jaw_opening_affine",
    "nearest_rotation",
    "polar_decomposition",
    "rotation_about_axis",
    "Penalty",
    "activation_penalty",
    "attached_positions",
    "attached_positions_jacobian",
    "bone_affines",
    "affine_from_params",
    "jaw_from_intuitive",
    "jaw_to_intuitive",
    "jaw_joint_penalty",
    "jaw_params_unchecked",
    "params_from_affine",
    "rigidity_penalty",
    "bone_penalty",
]

N_BONE_PARAMS = 24
IDENTITY_BONES = np.concatenate([np.eye(3).ravel(), np.zeros(3), np.eye(3).ravel(), np.zeros(3)])
IDENTITY_AFFINE = np.hstack([np.eye(3), np.zeros((3, 1))])


# ---------------------------------------------------------------------- affines and rotations
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


def rotation_about_axis(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Right-handed rotation matrix (Rodrigues) about a unit axis."""
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def polar_decomposition(M: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """M = R P with R orthogonal and P symmetric positive semi-definite (SVD M = U S V^T: R = U V^T,
    P = V S V^T). R is None when det M <= 0 (an improper or singular matrix has no rotation factor)."""
    U, S, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    R = U @ Vt
    if np.linalg.det(R) <= 0:
        return None, M
    return R, Vt.T @ np.diag(S) @ Vt


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to a 3x3 matrix in the Frobenius norm (the rotation factor of the polar
    decomposition, with the sign of the smallest singular direction flipped when det M < 0)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def interpolate_bones(b0: np.ndarray, b1: np.ndarray, s: float) -> np.ndarray:
    """Bone controls (24,) at the fraction ``s`` of the way from ``b0`` to ``b1``.

    Each 3x3 part M = R P (``polar_decomposition``) has its rotation R interpolated by slerp and its
    stretch P and the translation linearly, so a rigid bone stays rigid between frames (a linear
    blend of positions or matrices would shrink it along the chord of each rotation).
    """
    out = (1.0 - s) * b0 + s * b1
    for off in (0, 12):
        R0, P0 = polar_decomposition(b0[off : off + 9].reshape(3, 3))
        R1, P1 = polar_decomposition(b1[off : off + 9].reshape(3, 3))
        if R0 is None or R1 is None:
            continue  # an improper matrix: keep the linear blend
        R = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([R0, R1])))([s]).as_matrix()[0]
        out[off : off + 9] = (R @ ((1.0 - s) * P0 + s * P1)).ravel()
    return out


def affine_from_params(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M (3,3), t (3,)) from 12 parameters (M row-major, then t)."""
    p = np.asarray(p, dtype=np.float64)
    return p[:9].reshape(3, 3), p[9:12]


def params_from_affine(M: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.concatenate([np.asarray(M, float).ravel(), np.asarray(t, float)])


# ---------------------------------------------------------------------- constrained nodes X_C(b)
def attached_positions_from_affines(
    model: FaceModel, cranium: np.ndarray | None = None, jaw: np.ndarray | None = None
) -> np.ndarray:
    """Positions (a, 3) of ``model.attached_nodes`` for the given bone affines.

    A cranium node goes to Mc X0 + tc, a jaw node to Mc (Mm X0 + tm) + tc (Sifakis et al. 2005,
    section 8). Axes: +x is the subject's left, +y up, +z forward.

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


def bone_affines_from_attached(model: FaceModel, attached_positions: np.ndarray | None) -> dict[str, np.ndarray]:
    """World affines (3x4) of cranium and jaw that best map the rest positions of their attached
    nodes onto ``attached_positions`` (least squares; exact for positions from
    ``wface.controls.attached_positions_from_affines``). A bone whose nodes do not span 3D gets the best
    rigid fit (Kabsch); a bone with fewer than 3 nodes keeps the identity."""
    out = {}
    for b, bone in enumerate(BONES):
        sel = model.attached_bone == b
        X = model.rest_positions_m[model.attached_nodes[sel]]
        if attached_positions is None or sel.sum() < 3:
            out[bone] = np.hstack([np.eye(3), np.zeros((3, 1))])
            continue
        Y = np.asarray(attached_positions, dtype=np.float64)[sel]
        c0, c1 = X.mean(axis=0), Y.mean(axis=0)
        s = np.linalg.svd(X - c0, compute_uv=False)
        if s[-1] > 1e-6 * s[0]:
            M = np.linalg.lstsq(X - c0, Y - c1, rcond=None)[0].T
        else:
            U, _, Vt = np.linalg.svd((Y - c1).T @ (X - c0))
            D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
            M = U @ D @ Vt
        out[bone] = np.hstack([M, (c1 - M @ c0)[:, None]])
    return out


def jaw_opening_affine(model: FaceModel, opening_deg: float) -> np.ndarray:
    """Jaw affine (relative to the cranium) for a pure rotation about the condyle axis.

    Rotation by ``opening_deg`` about the joint axis u (right -> left condyle) through the condyle
    midpoint m. Positive opens the mouth: with u = +x (the subject's left), a right-handed rotation
    by a positive angle moves points in front of the axis (+z) downwards (-y).

    Returns:
        3x4 affine [R | m - R m].

    Raises:
        ValueError: ``opening_deg`` outside the joint's range [-asin(max_closing_sine),
            asin(max_opening_sine)] (negative: closed past the rest pose).
    """
    jj = model.jaw_joint
    lo_deg, limit_deg = jaw_limits(jj)["opening_deg"]
    if not (np.isfinite(opening_deg) and lo_deg - 1e-9 <= opening_deg <= limit_deg + 1e-9):
        raise ValueError(
            f"jaw opening {opening_deg:g} deg is outside this model's jaw range [{lo_deg:.1f}, {limit_deg:.1f}] deg"
        )
    R = rotation_about_axis(np.asarray(jj.u), np.deg2rad(opening_deg))
    m = np.asarray(jj.midpoint_m, dtype=np.float64)
    return np.hstack([R, (m - R @ m)[:, None]])


def bone_affines(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cranium, jaw) 3x4 affines [M | t] from the 24 bone parameters (the jaw relative to the cranium)."""
    b = _check_b(b)
    return _affine_3x4(b[:12]), _affine_3x4(b[12:])


def _affine_3x4(p: np.ndarray) -> np.ndarray:
    M, t = affine_from_params(p)
    return np.hstack([M, t[:, None]])


def attached_positions(model: FaceModel, b: np.ndarray, *, frame: str = "cranium") -> np.ndarray:
    """Positions (a, 3) of ``model.attached_nodes`` for bone parameters b (24,).

    Args:
        frame: "cranium" (cranium nodes at rest, jaw nodes at Mm X + tm: what the simulator solves)
            or "world" (everything mapped by Mc, tc).
    """
    cranium, jaw = bone_affines(b)
    if frame not in ("cranium", "world"):
        raise ValueError(f"frame must be 'cranium' or 'world', got {frame!r}")
    return attached_positions_from_affines(model, cranium if frame == "world" else None, jaw)


def attached_positions_jacobian(model: FaceModel) -> np.ndarray:
    """d X_C / d b_jaw in the cranium frame: (a, 3, 12); constant (X_C is affine in the jaw parameters)."""
    X = model.rest_positions_m[model.attached_nodes]
    jaw = model.attached_bone == BONES.index("jaw")
    J = np.zeros((len(X), 3, 12))
    for r in range(3):
        J[jaw, r, 3 * r : 3 * r + 3] = X[jaw]  # d(M X)_r / dM_rc = X_c
        J[jaw, r, 9 + r] = 1.0
    return J


def _check_b(b) -> np.ndarray:
    b = np.asarray(b, dtype=np.float64).reshape(-1)
    if b.shape != (N_BONE_PARAMS,):
        raise ValueError(f"bone parameters must have {N_BONE_PARAMS} entries, got {b.shape}")
    if not np.all(np.isfinite(b)):
        raise ValueError("bone parameters contain NaN or inf")
    return b


# ---------------------------------------------------------------------- penalties
@dataclass
class Penalty:
    """A penalty value with its gradient (p,) and PSD Hessian (p, p) over some parameters."""

    value: float
    gradient: np.ndarray
    hessian: np.ndarray


def activation_penalty(a: np.ndarray, lower: np.ndarray | float = 0.0) -> Penalty:
    """sum_i (min{0, a_i - lower_i, 1 - a_i})^2 with gradient and (diagonal) Hessian; ``lower`` is 0
    for a muscle, -1 for a pressure actuator (``FaceModel.activation_lower_bounds``)."""
    a = np.asarray(a, dtype=np.float64)
    low, high = np.minimum(a - lower, 0.0), np.minimum(1.0 - a, 0.0)
    g = 2.0 * low - 2.0 * high
    h = 2.0 * ((a < lower) | (a > 1)).astype(float)
    return Penalty(float(np.sum(low**2 + high**2)), g, np.diag(h))


def rigidity_penalty(M: np.ndarray, *, project: bool = True) -> Penalty:
    """||M^T M - I||_F^2 over the 9 entries of M (row-major), Hessian projected to PSD by default."""
    M = np.asarray(M, dtype=np.float64).reshape(3, 3)
    E = M.T @ M - np.eye(3)
    g = 4.0 * M @ E
    # Hessian: d/dM_kl of g_ij = 4 [delta_ik E_lj + (M^T... )]: built from the directional derivative.
    H = np.zeros((9, 9))
    for col in range(9):
        dM = np.zeros(9)
        dM[col] = 1.0
        dM = dM.reshape(3, 3)
        dE = dM.T @ M + M.T @ dM
        H[:, col] = (4.0 * (dM @ E + M @ dE)).ravel()
    H = 0.5 * (H + H.T)
    if project:
        w, V = np.linalg.eigh(H)
        H = (V * np.maximum(w, 0.0)) @ V.T
    return Penalty(float(np.sum(E**2)), g.ravel(), H)


def _joint_rows(joint: JawJoint) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """psi = A p + c for the jaw parameters p = (Mm row-major, tm); bounds lo <= psi <= hi."""
    u, v = np.asarray(joint.u, float), np.asarray(joint.v, float)
    w = np.cross(v, u)
    m = np.asarray(joint.midpoint_m, float)
    half = 0.5 * joint.condyle_distance_m
    d, s = joint.track_length_m, joint.max_opening_sine

    def row_M(a, x):  # a . (Mm x) = sum_rc a_r M_rc x_c
        return np.concatenate([np.outer(a, x).ravel(), np.zeros(3)])

    def row_t(a):
        return np.concatenate([np.zeros(9), a])

    A = np.stack(
        [
            row_M(w, u),
            row_M(w, m) + row_t(w),
            row_M(u, m) + row_t(u),
            row_M(v, m - half * u) + row_t(v),
            row_M(v, m + half * u) + row_t(v),
            row_M(w, v),
        ]
    )
    c = np.array([0.0, -w @ m, -u @ m, -v @ m, -v @ m, 0.0])
    lo = np.array([0.0, 0.0, 0.0, 0.0, 0.0, -s])
    hi = np.array([0.0, 0.0, 0.0, d, d, joint.max_closing_sine])
    return A, c, lo, hi


def jaw_joint_values(joint: JawJoint, jaw_params: np.ndarray) -> np.ndarray:
    """psi1..psi6 for the 12 jaw parameters."""
    A, c, _, _ = _joint_rows(joint)
    return A @ np.asarray(jaw_params, float) + c


def jaw_joint_penalty(joint: JawJoint, jaw_params: np.ndarray) -> Penalty:
    """Sum of squared violations of the jaw joint constraints (equalities and one-sided ranges)."""
    A, c, lo, hi = _joint_rows(joint)
    psi = A @ np.asarray(jaw_params, float) + c
    viol = np.where(psi < lo, psi - lo, np.where(psi > hi, psi - hi, 0.0))
    active = (psi < lo) | (psi > hi) | (lo == hi)
    Aa = A[active]
    return Penalty(float(np.sum(viol**2)), 2.0 * A.T @ viol, 2.0 * Aa.T @ Aa)


def bone_penalty(joint: JawJoint, b: np.ndarray) -> Penalty:
    """Rigidity of cranium and jaw plus the jaw joint, over all 24 bone parameters."""
    b = _check_b(b)
    g = np.zeros(24)
    H = np.zeros((24, 24))
    rc = rigidity_penalty(b[:9].reshape(3, 3))
    rm = rigidity_penalty(b[12:21].reshape(3, 3))
    jj = jaw_joint_penalty(joint, b[12:])
    g[:9] += rc.gradient
    H[:9, :9] += rc.hessian
    g[12:21] += rm.gradient
    H[12:21, 12:21] += rm.hessian
    g[12:] += jj.gradient
    H[12:, 12:] += jj.hessian
    return Penalty(rc.value + rm.value + jj.value, g, H)


# ---------------------------------------------------------------------- intuitive jaw controls
def jaw_limits(joint: JawJoint) -> dict:
    """Opening range (deg; negative: closed past the rest pose), protrusion range (m) and largest yaw
    (deg) allowed by the joint."""
    return {
        "opening_deg": (
            0.0 - float(np.degrees(np.arcsin(joint.max_closing_sine))),  # 0.0, not -0.0, without a closing range
            float(np.degrees(np.arcsin(joint.max_opening_sine))),
        ),
        "protrusion_m": (0.0, float(joint.track_length_m)),
        "lateral_deg": float(np.degrees(np.arcsin(min(1.0, joint.track_length_m / joint.condyle_distance_m)))),
    }


def jaw_from_intuitive(
    joint: JawJoint,
    opening_deg: float = 0.0,
    protrusion_m: float = 0.0,
    lateral_deg: float = 0.0,
    *,
    clamp: bool = True,
) -> np.ndarray:
    """12 jaw parameters from opening angle, protrusion and lateral yaw, inside the joint limits.

    The jaw rotates by ``opening_deg`` about the condyle axis u (chin down; negative: closed past the
    rest pose, down to -asin(``max_closing_sine``)), yaws by ``lateral_deg``
    about w (the chin moves toward the subject's left for positive values), and both condyles slide
    forward along the tracks by ``protrusion_m`` on average (each condyle stays within [0, d]).
    With ``clamp`` the numbers are clipped into the joint's range; without it, out-of-range values raise.
    """
    for name, value in (("opening_deg", opening_deg), ("protrusion_m", protrusion_m), ("lateral_deg", lateral_deg)):
        if not np.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value}")
    half, d = 0.5 * joint.condyle_distance_m, joint.track_length_m
    alpha, beta, p = np.radians(opening_deg), np.radians(lateral_deg), float(protrusion_m)
    a_min, a_max = -np.arcsin(joint.max_closing_sine), np.arcsin(joint.max_opening_sine)
    b_max = np.arcsin(min(1.0, d / (2 * half)))
    if clamp:
        alpha = float(np.clip(alpha, a_min, a_max))
        beta = float(np.clip(beta, -b_max, b_max))
        slack = half * abs(np.sin(beta))
        p = float(np.clip(p, slack, d - slack))
    else:
        slack = half * abs(np.sin(beta))
        inside = a_min - 1e-12 <= alpha <= a_max + 1e-12 and abs(beta) <= b_max + 1e-12
        if not (inside and slack - 1e-12 <= p <= d - slack + 1e-12):
            raise ValueError(
                f"jaw pose outside the joint limits: opening {opening_deg} deg "
                f"(allowed [{np.degrees(a_min):.1f}, {np.degrees(a_max):.1f}]), "
                f"lateral {lateral_deg} deg (max {np.degrees(b_max):.1f}), protrusion {protrusion_m} m "
                f"(allowed [{slack:.4f}, {d - slack:.4f}])"
            )
    return jaw_params_unchecked(joint, alpha, p, beta)


def jaw_params_unchecked(joint: JawJoint, opening_rad: float, protrusion_m: float, lateral_rad: float) -> np.ndarray:
    """The jaw parameters of ``jaw_from_intuitive`` without limit checks (for derivatives at a limit)."""
    u, v = np.asarray(joint.u, float), np.asarray(joint.v, float)
    w = np.cross(v, u)
    m = np.asarray(joint.midpoint_m, float)
    # Opening: rotate about u by +alpha (the forward track direction v tips down, toward -w); yaw about w.
    Mm = rotation_about_axis(w, lateral_rad) @ rotation_about_axis(u, opening_rad)
    tm = m - Mm @ m + protrusion_m * v
    return params_from_affine(Mm, tm)


def jaw_to_intuitive(joint: JawJoint, jaw_params: np.ndarray) -> dict:
    """Inverse of ``jaw_from_intuitive``: {"opening_deg", "protrusion_m", "lateral_deg"}."""
    u, v = np.asarray(joint.u, float), np.asarray(joint.v, float)
    w = np.cross(v, u)
    m = np.asarray(joint.midpoint_m, float)
    Mm, tm = affine_from_params(jaw_params)
    opening = np.degrees(np.arcsin(np.clip(-(w @ Mm @ v), -1, 1)))
    lateral = np.degrees(np.arcsin(np.clip(-(v @ Mm @ u), -1, 1)))
    protrusion = float(v @ (Mm @ m + tm - m))
    return {"opening_deg": float(opening), "protrusion_m": protrusion, "lateral_deg": float(lateral)}
