"""Shape of the built-in face: a lofted bone surface and a soft-tissue layer of varying thickness.

Parameters (theta, y): theta is the azimuth about the vertical axis (0 = front, positive toward
the subject's left, +x), y the height in metres (+y up, +z forward, eye level near y = 0).

Bone surface:   B(theta, y) = (a(y) sin theta, y, zc + c(y) cos theta)
Flesh column:   X(theta, y, w) = B + w t(theta, y) n(theta, y),  w in [0, 1] from bone to skin,
with n the unit bone normal and t the soft-tissue thickness: thin on the forehead (~6.5 mm),
thick at cheeks (~2 cm), lips (~1.5 cm) and nose (~3 cm at the tip). The profiles are
monotone cubic (PCHIP) fits through adult anthropometric values (Farkas 1994 proportions;
soft-tissue depths after Stephan & Simpson 2008), scaled to a generic adult head.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

__all__ = ["FaceShape"]

# Heights (m) of landmarks used throughout the built-in face.
Y_TOP = 0.085  # top of the forehead patch
Y_BOTTOM = -0.125  # below the chin
Y_MOUTH = -0.065  # stomion: the lips meet here
THETA_MAX = 1.75  # rad, the patch wraps to just in front of the ears
THETA_MOUTH = 0.40  # rad, mouth corners (the lip cut runs between -THETA_MOUTH and +THETA_MOUTH)

_Y_KNOTS = np.array([-0.125, -0.11, -0.10, -0.08, -0.065, -0.05, -0.03, -0.005, 0.01, 0.025, 0.05, 0.085])
_HALF_WIDTH = np.array([0.040, 0.045, 0.048, 0.053, 0.056, 0.060, 0.066, 0.065, 0.064, 0.065, 0.065, 0.062])
_FRONT_Z = np.array([0.066, 0.078, 0.083, 0.083, 0.084, 0.083, 0.082, 0.084, 0.086, 0.088, 0.086, 0.079])
_BASE_T = np.array([0.0075, 0.0085, 0.0095, 0.0095, 0.0095, 0.0090, 0.0080, 0.0070, 0.0065, 0.0065, 0.0065, 0.0065])


def _gauss(d: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
    return np.exp(-0.5 * (d / sigma) ** 2)


class FaceShape:
    """Analytic bone surface and tissue thickness; all methods vectorised over arrays of (theta, y)."""

    z_centre_m = 0.0

    def __init__(self) -> None:
        self._a = PchipInterpolator(_Y_KNOTS, _HALF_WIDTH, extrapolate=True)
        self._zf = PchipInterpolator(_Y_KNOTS, _FRONT_Z, extrapolate=True)
        self._t0 = PchipInterpolator(_Y_KNOTS, _BASE_T, extrapolate=True)

    # ------------------------------------------------------------------ bone
    def bone(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(..., 3) bone-surface points."""
        theta, y = np.broadcast_arrays(np.asarray(theta, float), np.asarray(y, float))
        a = self._a(y)
        c = self._zf(y) - self.z_centre_m
        return np.stack([a * np.sin(theta), y, self.z_centre_m + c * np.cos(theta)], axis=-1)

    def bone_normal(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(..., 3) outward unit normals of the bone surface (from analytic partial derivatives)."""
        theta, y = np.broadcast_arrays(np.asarray(theta, float), np.asarray(y, float))
        a, da = self._a(y), self._a(y, 1)
        c, dc = self._zf(y) - self.z_centre_m, self._zf(y, 1)
        d_theta = np.stack([a * np.cos(theta), np.zeros_like(y), -c * np.sin(theta)], axis=-1)
        d_y = np.stack([da * np.sin(theta), np.ones_like(y), dc * np.cos(theta)], axis=-1)
        n = np.cross(d_theta, d_y)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    # ------------------------------------------------------------------ soft tissue
    def thickness(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Soft-tissue thickness t(theta, y) in metres."""
        theta, y = np.broadcast_arrays(np.asarray(theta, float), np.asarray(y, float))
        at = np.abs(theta)
        t = self._t0(y)
        # Cheeks (buccal fat) and the masseter region.
        t = t + 0.010 * _gauss(at - 0.80, 0.32) * _gauss(y + 0.040, 0.022)
        t = t + 0.004 * _gauss(at - 1.30, 0.25) * _gauss(y + 0.075, 0.025)
        # Nose: a ridge from the nasion to the tip, widening to the alae, dropping to the lip.
        ridge = np.interp(y, [-0.048, -0.040, -0.032, -0.020, 0.0, 0.012], [0.0, 0.014, 0.024, 0.017, 0.004, 0.0])
        width = np.interp(y, [-0.048, -0.038, -0.020, 0.012], [0.20, 0.22, 0.13, 0.09])
        t = t + ridge * _gauss(theta, width)
        # Lips: upper and lower vermilion bulges across the mouth.
        lips_across = _gauss(theta, 0.27)
        t = t + 0.006 * lips_across * _gauss(y - (Y_MOUTH + 0.006), 0.006)
        t = t + 0.007 * lips_across * _gauss(y - (Y_MOUTH - 0.007), 0.006)
        t = t + 0.004 * _gauss(theta, 0.5) * _gauss(y - (Y_MOUTH + 0.014), 0.010)  # philtrum / upper lip body
        # Chin pad and the mentolabial sulcus.
        t = t + 0.004 * _gauss(theta, 0.35) * _gauss(y + 0.103, 0.010)
        t = t - 0.002 * _gauss(theta, 0.35) * _gauss(y + 0.088, 0.005)
        # Eyelids over the eyeballs: a slight bulge.
        t = t + 0.002 * _gauss(at - 0.50, 0.14) * _gauss(y - 0.0, 0.010)
        return t

    def point(self, theta: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(..., 3) flesh point at depth fraction w (0 bone, 1 skin)."""
        theta, y, w = np.broadcast_arrays(np.asarray(theta, float), np.asarray(y, float), np.asarray(w, float))
        return self.bone(theta, y) + (w * self.thickness(theta, y))[..., None] * self.bone_normal(theta, y)

    def half_width(self, y: np.ndarray) -> np.ndarray:
        return self._a(y)
