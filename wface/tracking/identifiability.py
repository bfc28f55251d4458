"""Which muscles the markers can see (seed 000, section 5: not every muscle moves a marker).

For the marker Jacobian J (3k x p) at an equilibrium, the identifiability of muscle i is
    s_i = 1 / sqrt([(J^T J)^-1]_ii)   (metres of marker motion per unit activation),
the marker displacement that a unit change of a_i causes *after the best compensation by every
other control* (the Schur complement of J^T J onto a_i). A muscle whose effect other controls can
mimic has s_i ~ 0 even if it moves markers. A muscle is called observable when s_i exceeds
``OBSERVABLE_MM`` (1 mm per unit activation: well above sub-millimetre capture noise).
"""

from __future__ import annotations

import numpy as np

__all__ = ["OBSERVABLE_MM", "muscle_identifiability_mm", "rig_identifiability_mm"]

OBSERVABLE_MM = 1.0


def muscle_identifiability_mm(
    J: np.ndarray, n_muscles: int, *, bone_hessian: np.ndarray | None = None, ridge: float = 1e-12
) -> np.ndarray:
    """(M,) identifiability s_i in millimetres per unit activation (module docstring).

    Args:
        J: (3k, M + 24) marker Jacobian.
        n_muscles: M.
        bone_hessian: (24, 24) Hessian of the bone penalties (rigidity, jaw joint). It is added
            with a large weight so that the bones compensate only with rigid, joint-valid
            motions, as they do in tracking (an affine cranium could otherwise mimic a muscle).
    """
    JtJ = J.T @ J
    p = JtJ.shape[0]
    scale = max(np.trace(JtJ) / p, 1e-30)
    if bone_hessian is not None:
        JtJ = JtJ.copy()
        JtJ[n_muscles:, n_muscles:] += 1e4 * scale * bone_hessian / max(np.abs(bone_hessian).max(), 1e-30)
    JtJ = JtJ + ridge * scale * np.eye(p)
    inv_diag = np.diag(np.linalg.pinv(JtJ, hermitian=True))[:n_muscles]
    return 1e3 / np.sqrt(np.maximum(inv_diag, 1e-300))


def rig_identifiability_mm(rig, markers, controls: np.ndarray | None = None) -> np.ndarray:
    """Identifiability of every muscle of a ``FaceRig`` with a ``MarkerMap`` at ``controls`` (default rest)."""
    from wface.controls import bone_penalty

    c = rig.rest_controls() if controls is None else np.asarray(controls, dtype=np.float64)
    state = rig.equilibrium(c)
    J = markers.jacobian(rig.jacobian(state, markers.nodes))
    H = bone_penalty(rig.model.jaw_joint, c[rig.n_muscles :]).hessian
    return muscle_identifiability_mm(J, rig.n_muscles, bone_hessian=H)
