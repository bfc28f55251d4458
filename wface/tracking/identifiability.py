"""Which muscles the markers can see (Sifakis et al. 2005, section 5: not every muscle moves a marker).

For the marker Jacobian J (3k x p) at an equilibrium, the identifiability of muscle i is the part
of its column that no combination of the other controls can reproduce:
    s_i = || (I - P_{-i}) J_i ||,
P_{-i} the orthogonal projection onto the span of the other columns (metres of marker motion per
unit activation). With J of full column rank this equals 1 / sqrt([(J^T J)^-1]_ii), the
conditioning of J^T J restricted to muscle i; unlike that formula it stays meaningful (-> 0) when
the columns are dependent. The bones enter only through their valid motions: rigid cranium
motions (3 rotations, 3 translations) and the jaw's opening, protrusion and lateral yaw. A muscle
is observable when s_i >= ``OBSERVABLE_MM`` (1 mm per unit activation, well above sub-millimetre
capture noise).
"""

from __future__ import annotations

import numpy as np

from wface.controls import jaw_params_unchecked, jaw_to_intuitive

__all__ = ["OBSERVABLE_MM", "bone_motion_basis", "muscle_identifiability_mm", "rig_identifiability_mm"]

OBSERVABLE_MM = 1.0


def muscle_identifiability_mm(J: np.ndarray, n_muscles: int, *, bone_basis: np.ndarray | None = None) -> np.ndarray:
    """(M,) identifiability s_i in millimetres per unit activation (module docstring).

    Args:
        J: (3k, M + q) marker Jacobian: M muscle columns, then q bone columns.
        n_muscles: M.
        bone_basis: (q, r) valid bone motions in bone-parameter space; the bone columns become
            J_b @ bone_basis. None keeps the bone columns as they are.
    """
    J = np.asarray(J, dtype=np.float64)
    Jm, Jb = J[:, :n_muscles], J[:, n_muscles:]
    if bone_basis is not None:
        Jb = Jb @ bone_basis
    out = np.empty(n_muscles)
    for i in range(n_muscles):
        others = np.hstack([np.delete(Jm, i, axis=1), Jb])
        coef, *_ = np.linalg.lstsq(others, Jm[:, i], rcond=None)
        out[i] = np.linalg.norm(Jm[:, i] - others @ coef)
    return out * 1e3


def bone_motion_basis(joint, b: np.ndarray) -> np.ndarray:
    """(24, 9) directions of valid bone motion at bone parameters b: rigid cranium (6), jaw (3)."""

    T = np.zeros((24, 9))
    Mc = b[:9].reshape(3, 3)
    for k in range(3):  # infinitesimal rotations of the cranium about the world axes
        W = np.zeros((3, 3))
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        W[i, j], W[j, i] = -1.0, 1.0
        T[:9, k] = (W @ Mc).ravel()
        T[9:12, k] = W @ b[9:12]
    T[9:12, 3:6] = np.eye(3)
    pose = jaw_to_intuitive(joint, b[12:])
    x0 = np.array([np.radians(pose["opening_deg"]), pose["protrusion_m"], np.radians(pose["lateral_deg"])])
    steps = np.array([1e-5, 1e-6, 1e-5])
    for k in range(3):  # central differences of the (smooth) intuitive jaw map
        xp, xm = x0.copy(), x0.copy()
        xp[k] += steps[k]
        xm[k] -= steps[k]
        T[12:, 6 + k] = (jaw_params_unchecked(joint, *xp) - jaw_params_unchecked(joint, *xm)) / (2 * steps[k])
    return T


def rig_identifiability_mm(rig, markers, controls: np.ndarray | None = None) -> np.ndarray:
    """Identifiability of every muscle of a ``FaceRig`` with a ``MarkerMap`` at ``controls`` (default rest)."""
    c = rig.rest_controls() if controls is None else np.array(controls, dtype=np.float64)
    M = rig.n_muscles
    state = rig.equilibrium(c)
    J = markers.jacobian(rig.jacobian(state, markers.nodes))
    return muscle_identifiability_mm(J, M, bone_basis=bone_motion_basis(rig.model.jaw_joint, c[M:]))
