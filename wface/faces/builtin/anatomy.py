"""Anatomy of the built-in face: muscle paths, bone attachment regions and skin markers.

Muscles are given on the subject's left side (theta > 0) as paths of control points
(theta [rad], y [m], w [depth fraction: 0 bone, 1 skin]) from origin (on or near bone) to
insertion (in the skin), with a tube radius. Right-side muscles are mirror images; the two
orbicularis oris halves cross the midline. Sphincters are closed loops. Paths follow the
classic descriptions (Gray's Anatomy; Waters 1987 muscle set).

Markers reuse the AnimFace capture's names where the anatomy matches (../shared/data/animface).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wface.faces.builtin.shape import THETA_MOUTH, Y_MOUTH

__all__ = ["MUSCLES", "MARKERS", "VESTIBULE_TOP_M", "MuscleSpec", "muscle_paths", "bone_region"]


@dataclass(frozen=True)
class MuscleSpec:
    """A muscle path in (theta, y, w) parameter space on the left side."""

    name: str  # canonical base name (wface.facs)
    points: tuple[tuple[float, float, float], ...]
    radius_m: float
    bilateral: bool = True
    closed: bool = False  # sphincter loop


def _ellipse(theta_c, y_c, d_theta, d_y, w, n=24):
    s = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return tuple((theta_c + d_theta * np.cos(a), y_c + d_y * np.sin(a), w) for a in s)


def _lip_arc(sign: float, n: int = 13):
    """Orbicularis oris half: an arc from corner to corner above (sign=+1) or below (-1) the mouth."""
    th = np.linspace(-THETA_MOUTH - 0.04, THETA_MOUTH + 0.04, n)
    y = Y_MOUTH + sign * (0.004 + 0.006 * np.sqrt(np.clip(1 - (th / (THETA_MOUTH + 0.06)) ** 2, 0, 1)))
    return tuple((float(a), float(b), 0.55) for a, b in zip(th, y, strict=True))


M = Y_MOUTH
MUSCLES: tuple[MuscleSpec, ...] = (
    MuscleSpec("frontalis_medial", ((0.22, 0.088, 0.35), (0.22, 0.060, 0.55), (0.20, 0.030, 0.70)), 0.012),
    MuscleSpec("frontalis_lateral", ((0.62, 0.088, 0.35), (0.62, 0.060, 0.55), (0.60, 0.032, 0.70)), 0.012),
    MuscleSpec("corrugator", ((0.07, 0.020, 0.15), (0.22, 0.028, 0.45), (0.42, 0.034, 0.70)), 0.005),
    MuscleSpec("procerus", ((0.0, -0.006, 0.20), (0.0, 0.012, 0.50), (0.0, 0.030, 0.70)), 0.006, bilateral=False),
    MuscleSpec("orbicularis_oculi", _ellipse(0.50, 0.0, 0.30, 0.024, 0.5), 0.007, closed=True),
    MuscleSpec("nasalis", ((0.26, -0.036, 0.20), (0.15, -0.030, 0.55), (0.04, -0.016, 0.60)), 0.004),
    MuscleSpec(
        "levator_labii_superioris_alaeque_nasi",
        ((0.12, 0.000, 0.15), (0.15, -0.025, 0.45), (0.19, M + 0.016, 0.70)),
        0.005,
    ),
    MuscleSpec(
        "levator_labii_superioris", ((0.36, -0.012, 0.15), (0.30, -0.035, 0.45), (0.22, M + 0.010, 0.70)), 0.006
    ),
    MuscleSpec("zygomaticus_minor", ((0.72, -0.014, 0.15), (0.50, -0.035, 0.50), (0.31, M + 0.009, 0.70)), 0.005),
    MuscleSpec("zygomaticus_major", ((1.00, -0.022, 0.15), (0.72, -0.045, 0.50), (0.43, M + 0.002, 0.70)), 0.006),
    MuscleSpec("levator_anguli_oris", ((0.38, -0.030, 0.10), (0.41, -0.048, 0.40), (0.43, M + 0.001, 0.60)), 0.005),
    MuscleSpec("risorius", ((1.25, M - 0.004, 0.55), (0.80, M - 0.002, 0.60), (0.44, M, 0.70)), 0.005),
    MuscleSpec("buccinator", ((1.10, M, 0.08), (0.75, M, 0.20), (0.44, M, 0.35)), 0.008),
    MuscleSpec("depressor_anguli_oris", ((0.62, -0.112, 0.15), (0.52, -0.090, 0.45), (0.43, M - 0.003, 0.70)), 0.006),
    MuscleSpec(
        "depressor_labii_inferioris", ((0.32, -0.106, 0.15), (0.24, -0.090, 0.45), (0.15, M - 0.009, 0.70)), 0.006
    ),
    MuscleSpec("mentalis", ((0.08, -0.084, 0.12), (0.09, -0.095, 0.45), (0.10, -0.106, 0.75)), 0.005),
    MuscleSpec("orbicularis_oris_upper", _lip_arc(+1.0), 0.006, bilateral=False),
    MuscleSpec("orbicularis_oris_lower", _lip_arc(-1.0), 0.006, bilateral=False),
    MuscleSpec("platysma", ((0.95, -0.126, 0.50), (0.75, -0.105, 0.60), (0.52, -0.080, 0.70)), 0.012),
)

# Marker name -> (theta, y) on the skin (left side positive theta). Names follow the AnimFace capture.
MARKERS: dict[str, tuple[float, float]] = {
    "Chin": (0.0, -0.106),
    "Chin_L1": (0.30, -0.100),
    "Chin_L2": (0.62, -0.094),
    "Chin_R1": (-0.30, -0.100),
    "Chin_R2": (-0.62, -0.094),
    "Eyebrow_Center": (0.0, 0.030),
    "ForeHead_L": (0.45, 0.065),
    "ForeHead_M": (0.0, 0.068),
    "ForeHead_R": (-0.45, 0.065),
    "Lcheek_Down": (0.68, -0.064),
    "Lcheek_Outside": (1.00, -0.030),
    "Lcheek_Up": (0.62, -0.030),
    "Leye_Down": (0.48, -0.015),
    "Leye_Inside": (0.27, 0.000),
    "Leye_Outside": (0.72, 0.000),
    "Leye_Up": (0.48, 0.016),
    "Leyebrow_Inside": (0.20, 0.032),
    "Leyebrow_M": (0.45, 0.038),
    "Leyebrow_Outside": (0.70, 0.030),
    "Mouth_Down": (0.0, M - 0.011),
    "Mouth_DownL": (0.17, M - 0.009),
    "Mouth_DownR": (-0.17, M - 0.009),
    "Mouth_Lend": (THETA_MOUTH + 0.03, M),
    "Mouth_Rend": (-THETA_MOUTH - 0.03, M),
    "Mouth_Up": (0.0, M + 0.011),
    "Mouth_UpL1": (0.17, M + 0.010),
    "Mouth_UpR1": (-0.17, M + 0.010),
    "NoseHead": (0.0, -0.031),
    "NoseHead_L": (0.19, -0.040),
    "NoseHead_R": (-0.19, -0.040),
    "NoseTop": (0.0, 0.004),
    "Rcheek_Down": (-0.68, -0.064),
    "Rcheek_Outside": (-1.00, -0.030),
    "Rcheek_up": (-0.62, -0.030),
    "Reye_Down": (-0.48, -0.015),
    "Reye_Inside": (-0.27, 0.000),
    "Reye_Outside": (-0.72, 0.000),
    "Reye_Up": (-0.48, 0.016),
    "Reyebrow_Inside": (-0.20, 0.032),
    "Reyebrow_M": (-0.45, 0.038),
    "Reyebrow_Outside": (-0.70, 0.030),
    # Markers beyond the AnimFace set (a denser mouth and jaw line).
    "Mouth_UpL2": (0.32, M + 0.007),
    "Mouth_UpR2": (-0.32, M + 0.007),
    "Mouth_DownL2": (0.32, M - 0.007),
    "Mouth_DownR2": (-0.32, M - 0.007),
    "Ljaw": (1.20, -0.085),
    "Rjaw": (-1.20, -0.085),
}


def muscle_paths(spec: MuscleSpec, n_per_segment: int = 24) -> list[tuple[str, np.ndarray]]:
    """Densely sampled (theta, y, w) paths of a muscle: [(full name, (s, 3))], one or two sides."""
    pts = np.asarray(spec.points, dtype=float)
    if spec.closed:
        pts = np.vstack([pts, pts[:1]])
    segs = [
        pts[i] + (pts[i + 1] - pts[i]) * np.linspace(0, 1, n_per_segment, endpoint=False)[:, None]
        for i in range(len(pts) - 1)
    ]
    path = np.vstack(segs + ([] if spec.closed else [pts[-1:]]))
    if not spec.bilateral:
        return [(spec.name, path)]
    mirrored = path * np.array([-1.0, 1.0, 1.0])
    return [(f"{spec.name}_l", path), (f"{spec.name}_r", mirrored)]


VESTIBULE_TOP_M = 0.018  # the oral vestibule's upper fornix, above the mouth line (m)


def bone_region(theta: np.ndarray, y: np.ndarray, free_to_m: float = VESTIBULE_TOP_M) -> np.ndarray:
    """Bone that the tissue at (theta, y) on the bone surface attaches to: 0 cranium, 1 jaw, -1 free.

    Free: the oral vestibule behind lips and cheeks (tissue over teeth and gums, not bound to bone),
    up to ``free_to_m`` above the mouth line (default the vestibule's fornix; higher frees the deep
    surface of the midface over the maxilla too). Jaw: the mandible below the vestibule and the ramus
    at the sides; cranium: the rest.
    """
    at = np.abs(theta)
    jaw = (y < Y_MOUTH - 0.020) | ((at > 1.05) & (y < -0.035))
    free = ~jaw & (at <= 1.05) & (y <= Y_MOUTH + free_to_m) & (y >= Y_MOUTH - 0.020)
    out = np.zeros(theta.shape, dtype=np.int8)
    out[jaw] = 1
    out[free] = -1
    return out
