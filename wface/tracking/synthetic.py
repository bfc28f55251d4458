"""Synthetic performances with ground truth: smooth activations, jaw and head motion, forward
simulated, markers read off the skin, then corrupted like real capture.

Noise: ``noise_mm`` is the RMS length of the 3D noise vector (per-coordinate sigma = noise_mm / sqrt 3).
Outliers: a fraction of marker samples displaced by 10-30 mm in a random direction.
Dropout: a fraction of marker samples set to NaN (missing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

from wface.controls import IDENTITY_BONES, jaw_from_intuitive, params_from_affine

__all__ = ["SyntheticPerformance", "synthesize_performance", "corrupt_markers", "DEFAULT_PERFORMANCE_MUSCLES"]

# Muscles that move markers strongly on the built-in face (mouth, brows, cheeks).
DEFAULT_PERFORMANCE_MUSCLES = (
    "zygomaticus_major_l",
    "zygomaticus_major_r",
    "frontalis_medial_l",
    "frontalis_medial_r",
    "orbicularis_oris_upper",
    "orbicularis_oris_lower",
    "depressor_anguli_oris_l",
    "depressor_anguli_oris_r",
    "risorius_l",
    "levator_labii_superioris_l",
    "levator_labii_superioris_r",
    "corrugator_l",
    "corrugator_r",
    "mentalis_l",
)


@dataclass
class SyntheticPerformance:
    """A performance with its truth. Shapes: F frames, M muscles, k markers."""

    activations: np.ndarray  # (F, M)
    bones: np.ndarray  # (F, 24)
    jaw_opening_deg: np.ndarray  # (F,)
    clean_markers_m: np.ndarray  # (F, k, 3)
    markers_m: np.ndarray  # (F, k, 3) corrupted (NaN = dropped)
    outlier_mask: np.ndarray  # (F, k) bool
    rate_hz: float
    marker_names: list[str]
    positions_m: np.ndarray  # (F, n, 3) world positions of all nodes (truth)


def _bump(t: np.ndarray, start: float, length: float) -> np.ndarray:
    s = np.clip((t - start) / length, 0.0, 1.0)
    return np.sin(np.pi * s) ** 2


def _rotation_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def corrupt_markers(clean_m, *, noise_mm=0.0, outliers=0.0, dropout=0.0, seed=0):
    """(corrupted (F, k, 3), outlier mask (F, k)) from clean markers; see module docstring."""
    rng = np.random.default_rng(seed + 7919)
    out = np.array(clean_m, dtype=np.float64)
    F, k, _ = out.shape
    if noise_mm > 0:
        out += rng.normal(scale=noise_mm * 1e-3 / np.sqrt(3.0), size=out.shape)
    mask = rng.random((F, k)) < outliers
    if mask.any():
        d = rng.normal(size=(int(mask.sum()), 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        out[mask] += d * rng.uniform(0.010, 0.030, size=(len(d), 1))
    drop = rng.random((F, k)) < dropout
    out[drop] = np.nan
    return out, mask & ~drop


def synthesize_performance(
    rig,
    markers,
    *,
    frames: int = 60,
    rate_hz: float = 30.0,
    seed: int = 0,
    noise_mm: float = 0.0,
    outliers: float = 0.0,
    dropout: float = 0.0,
    muscles: tuple[str, ...] | None = None,
    max_activation: float = 0.8,
    max_jaw_deg: float = 12.0,
    head_motion: bool = True,
    progress: bool = False,
    window: tuple[int, int] | None = None,
) -> SyntheticPerformance:
    """Generate, simulate and corrupt a performance on ``rig`` (a ``FaceRig``) with ``markers`` (a ``MarkerMap``).

    ``window``: (start, stop) simulate and return only these frames of the ``frames``-long performance
    (the motion between frames is then that of the whole take at ``rate_hz``; default: every frame).
    """

    model = rig.model
    rng = np.random.default_rng(seed)
    names = [m for m in (muscles or DEFAULT_PERFORMANCE_MUSCLES) if m in model.muscle_names]
    t = np.arange(frames) / rate_hz
    T = max(t[-1], 1e-9)
    A = np.zeros((frames, model.n_muscles))
    for name in names:
        i = model.muscle_index(name)
        for _ in range(2):  # two smooth bumps per muscle at random times
            length = rng.uniform(0.35, 0.7) * T
            start = rng.uniform(-0.2 * T, T - 0.4 * length)
            A[:, i] = np.maximum(A[:, i], rng.uniform(0.3, 1.0) * max_activation * _bump(t, start, length))
    jaw = max_jaw_deg * _bump(t, rng.uniform(0.0, 0.3) * T, 0.7 * T)
    B = np.tile(IDENTITY_BONES, (frames, 1))
    for f in range(frames):
        if head_motion:
            ang = np.radians(2.0) * np.sin(
                2 * np.pi * (t[f] / T) * np.array([0.5, 0.8, 0.3]) + np.array([0.0, 1.0, 2.0])
            )
            trans = 0.004 * np.sin(2 * np.pi * (t[f] / T) * np.array([0.4, 0.6, 0.5]) + np.array([0.5, 1.5, 2.5]))
            B[f, :12] = params_from_affine(_rotation_xyz(*ang), trans)
        B[f, 12:] = jaw_from_intuitive(model.jaw_joint, jaw[f], 0.0015 * jaw[f] / max(max_jaw_deg, 1e-9), 0.0)
    if window is not None:
        lo, hi = window
        if not 0 <= lo < hi <= frames:
            raise ValueError(f"window {window} is not inside the {frames} frames")
        A, B, jaw = A[lo:hi], B[lo:hi], jaw[lo:hi]
    clean = np.empty((len(A), len(markers.embedding.triangle), 3))
    X = np.empty((len(A), model.n_nodes, 3))
    y = None
    for f in tqdm(range(len(A)), desc="simulating performance", disable=not progress, unit="frame"):
        state = rig.equilibrium(np.concatenate([A[f], B[f]]), y)
        y = state.y_m
        X[f] = state.x_m
        clean[f] = markers.positions(state.x_m)
    noisy, mask = corrupt_markers(clean, noise_mm=noise_mm, outliers=outliers, dropout=dropout, seed=seed)
    return SyntheticPerformance(A, B, jaw, clean, noisy, mask, rate_hz, list(model.marker_names), X)
