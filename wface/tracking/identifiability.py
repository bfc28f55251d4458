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

__all__ = ["OBSERVABLE_MM", "muscle_identifiability_mm"]

OBSERVABLE_MM = 1.0


def muscle_identifiability_mm(J: np.ndarray, n_muscles: int, *, ridge: float = 1e-12) -> np.ndarray:
    """(M,) identifiability s_i in millimetres per unit activation (module docstring)."""
    JtJ = J.T @ J
    p = JtJ.shape[0]
    JtJ = JtJ + ridge * max(np.trace(JtJ) / p, 1e-30) * np.eye(p)
    inv_diag = np.diag(np.linalg.pinv(JtJ, hermitian=True))[:n_muscles]
    return 1e3 / np.sqrt(np.maximum(inv_diag, 1e-300))
