"""Synthetic takes with a known answer, for the dynamic replay: rest, then an expression held.

``step_take`` is the sudden smile of ``wface resim`` without ``--take``: its quasistatic answer is
the held expression's equilibrium, so the dynamic replay's overshoot and ringing are measured
against it (``wface.takes.dynamic.step_overshoot_mm``).
"""

from __future__ import annotations

import numpy as np

from wface.controls import IDENTITY_BONES, jaw_opening_affine, params_from_affine, rotation_about_axis
from wface.model import FaceModel
from wface.takes.take import Take

__all__ = ["step_take"]


def step_take(
    model: FaceModel,
    *,
    frames: int,
    fps: float,
    activations: dict,
    jaw_opening_deg: float = 0.0,
    onset_frame: int = 1,
    ramp: str = "step",
    head_shake: tuple[float, float] | None = None,
) -> Take:
    """Rest before ``onset_frame``, then the activations (and jaw opening) held: a ``Take``.

    ``ramp="step"`` switches the activations on in the first time step after frame
    ``onset_frame - 1``; ``"linear"`` ramps them over that frame interval. The jaw always
    moves linearly over the interval. ``head_shake=(amplitude_deg, frequency_hz)`` turns the
    head from the onset on, yaw(t) = A sin(2 pi f t) about the vertical axis through the
    condyle midpoint."""
    if frames < 2:
        raise ValueError(f"a synthetic take needs at least 2 frames, got {frames}")
    if not 1 <= onset_frame < frames:
        raise ValueError(f"--onset-frame must lie in [1, {frames - 1}], got {onset_frame}")
    a = model.activation_vector(activations)
    on = (np.arange(frames) >= onset_frame).astype(float)
    bones = np.tile(IDENTITY_BONES, (frames, 1))
    if jaw_opening_deg:
        A = jaw_opening_affine(model, jaw_opening_deg)
        bones[on > 0, 12:] = params_from_affine(A[:, :3], A[:, 3])
    if head_shake is not None:
        amplitude_deg, frequency_hz = head_shake
        pivot = np.asarray(model.jaw_joint.midpoint_m, dtype=np.float64)
        for k in range(onset_frame, frames):
            yaw = np.radians(amplitude_deg) * np.sin(2 * np.pi * frequency_hz * (k - onset_frame) / fps)
            R = rotation_about_axis(np.array([0.0, 1.0, 0.0]), yaw)
            bones[k, :12] = params_from_affine(R, pivot - R @ pivot)
    return Take(
        activations=on[:, None] * a[None, :],
        fps=fps,
        bones=bones,
        muscle_names=list(model.muscle_names),
        source="synthetic",
        activation_ramp=ramp,
        joint=model.jaw_joint,
    )
