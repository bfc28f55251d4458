"""Poses and takes in activation space: the values that expression editing works on.

A ``Pose`` is one frame of controls in the form edits need (Sifakis et al. 2005, section 9):
- ``activations`` (M,) in [0, 1];
- ``force_length_scale`` (M,) or None: per-muscle scale of the active force-length curve, the only
  way past full activation (T = sigma_max (s a f_L + f_P), docs/design.md "Muscle fibres"). Its product with
  the activations is the muscle's *drive* e = s a >= 0, which is what the physics sees (the force
  is linear in s a); a drive is split back as a = min(e, 1), s = max(e, 1);
- the cranium as a rotation matrix and a translation (metres): rigid by construction;
- the jaw in its intuitive parameters (opening deg, protrusion m, lateral yaw deg, as
  ``wface.controls.jaw_from_intuitive``), so any mix of poses stays on the joint's manifold.

``Pose.bones(joint)`` gives the 24 bone parameters of ``wface.controls`` (the jaw clamped into
the joint's limits); ``pose_from_controls`` goes the other way, projecting a tracked cranium
affine onto the nearest rotation (polar decomposition) and the jaw affine onto its intuitive
parameters. A ``wface.takes.take.Take`` holds a performance; ``Take.poses`` reads it as poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from wface.controls import (
    N_BONE_PARAMS,
    affine_from_params,
    attached_positions,
    jaw_from_intuitive,
    jaw_limits,
    jaw_to_intuitive,
    nearest_rotation,
    params_from_affine,
)
from wface.model import FaceModel, JawJoint

__all__ = [
    "Pose",
    "bone_projection_error_m",
    "clamp_jaw",
    "pose_from_bones",
    "pose_from_controls",
    "rest_pose",
    "split_drives",
]

_ROTATION_TOL = 1e-9  # |R^T R - I| and |det R - 1| accepted as a rotation (float64 round-off of composed rotations)


def split_drives(drives: np.ndarray, *, per: str = "frame") -> tuple[np.ndarray, np.ndarray | None]:
    """Muscle drives e = s a -> (activations, force-length scales or None when all 1).

    A muscle's drive is >= 0; a pressure actuator's may be negative (suction), so the split is by
    magnitude: the activation keeps the drive's sign and |a| <= 1.

    Args:
        drives: (M,) or (T, M) drives.
        per: "frame" (s = max(|e|, 1), a = e / s, same shape as ``drives``) or "take"
            (one scale per muscle over all frames, S = max(1, max_t |e|) of shape (M,), a = e / S).
    """
    e = np.asarray(drives, dtype=np.float64)
    if not np.all(np.isfinite(e)):
        raise ValueError("muscle drives must be finite")
    if per == "frame":
        s = np.maximum(np.abs(e), 1.0)
        return np.clip(e / s, -1.0, 1.0), (None if np.all(s == 1.0) else s)
    if per == "take":
        mag = np.abs(e)
        S = np.maximum(1.0, mag.max(axis=0, initial=0.0)) if e.ndim == 2 else np.maximum(1.0, mag)
        return np.clip(e / S, -1.0, 1.0), (None if np.all(S == 1.0) else S)
    raise ValueError(f"per must be 'frame' or 'take', got {per!r}")


@dataclass(frozen=True)
class Pose:
    """One frame of face controls for editing (module docstring). Arrays are float64 copies."""

    activations: np.ndarray  # (M,) in [0, 1] ([-1, 1] for a pressure actuator; the model checks which)
    cranium_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # (3, 3) proper rotation
    cranium_translation_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,)
    jaw_opening_deg: float = 0.0
    jaw_protrusion_m: float = 0.0
    jaw_lateral_deg: float = 0.0
    force_length_scale: np.ndarray | None = None  # (M,) >= 0 per-muscle scale; None: all 1

    def __post_init__(self) -> None:
        a = np.array(self.activations, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(a)):
            raise ValueError("pose activations contain NaN or inf")
        if np.any(a < -1) or np.any(a > 1):  # the model checks each channel's own range in a simulation
            raise ValueError(f"pose activations must lie in [-1, 1], got range [{a.min():.4g}, {a.max():.4g}]")
        R = np.array(self.cranium_rotation, dtype=np.float64).reshape(3, 3)
        if not (
            np.all(np.isfinite(R))
            and np.abs(R.T @ R - np.eye(3)).max() < _ROTATION_TOL
            and abs(np.linalg.det(R) - 1) < _ROTATION_TOL
        ):
            raise ValueError("cranium_rotation must be a proper rotation matrix (use nearest_rotation)")
        t = np.array(self.cranium_translation_m, dtype=np.float64).reshape(3)
        jaw = (self.jaw_opening_deg, self.jaw_protrusion_m, self.jaw_lateral_deg)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(jaw))):
            raise ValueError("cranium translation and jaw parameters must be finite")
        s = self.force_length_scale
        if s is not None:
            s = np.array(s, dtype=np.float64).reshape(-1)
            if s.shape != a.shape or not np.all(np.isfinite(s)) or np.any(s < 0):
                raise ValueError(f"force_length_scale must be ({a.size},) finite and >= 0")
        for name, value in (("activations", a), ("cranium_rotation", R), ("cranium_translation_m", t)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        if s is not None:
            s.flags.writeable = False
        object.__setattr__(self, "force_length_scale", s)
        for name in ("jaw_opening_deg", "jaw_protrusion_m", "jaw_lateral_deg"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def n_muscles(self) -> int:
        return int(self.activations.size)

    @property
    def drive(self) -> np.ndarray:
        """(M,) drive e = s a of each muscle (what the force sees; > 1 only through the force-length scale)."""
        return self.activations if self.force_length_scale is None else self.activations * self.force_length_scale

    @property
    def jaw(self) -> np.ndarray:
        """(opening_deg, protrusion_m, lateral_deg)."""
        return np.array([self.jaw_opening_deg, self.jaw_protrusion_m, self.jaw_lateral_deg])

    def with_drive(self, drive: np.ndarray) -> Pose:
        """This pose with the muscles set from drives (split per muscle, see ``split_drives``)."""
        a, s = split_drives(drive)
        return replace(self, activations=a, force_length_scale=s)

    def with_jaw(self, jaw: np.ndarray) -> Pose:
        o, p, lat = (float(v) for v in jaw)
        return replace(self, jaw_opening_deg=o, jaw_protrusion_m=p, jaw_lateral_deg=lat)

    def simulator_scale(self) -> float | np.ndarray:
        """What to give ``Simulator.force_length_scale``: 1.0 when unscaled, else the (M,) array."""
        return 1.0 if self.force_length_scale is None else self.force_length_scale

    def jaw_params(self, joint: JawJoint) -> np.ndarray:
        """12 jaw parameters (Mm row-major, tm) relative to the cranium, clamped into the joint limits."""
        return jaw_from_intuitive(joint, self.jaw_opening_deg, self.jaw_protrusion_m, self.jaw_lateral_deg)

    def bones(self, joint: JawJoint) -> np.ndarray:
        """The 24 bone parameters of ``wface.controls`` (cranium affine, then jaw relative to it)."""
        return np.concatenate(
            [params_from_affine(self.cranium_rotation, self.cranium_translation_m), self.jaw_params(joint)]
        )

    def controls(self, model: FaceModel) -> np.ndarray:
        """c = (a, b), (M + 24,), as ``wface.tracking.rig.FaceRig`` takes them (activations only: no scale)."""
        self._check_model(model)
        return np.concatenate([self.activations, self.bones(model.jaw_joint)])

    def _check_model(self, model: FaceModel) -> None:
        if model.n_muscles != self.n_muscles:
            raise ValueError(f"pose has {self.n_muscles} muscles, the model {model.n_muscles}")


def rest_pose(n_muscles: int) -> Pose:
    """All muscles relaxed, head at rest, jaw closed."""
    return Pose(np.zeros(int(n_muscles)))


def clamp_jaw(pose: Pose, joint: JawJoint) -> Pose:
    """The pose with its jaw parameters clipped into the joint's limits (what ``Pose.bones`` simulates)."""
    lim = jaw_limits(joint)
    lo, hi = lim["opening_deg"]
    opening = float(np.clip(pose.jaw_opening_deg, lo, hi))
    lateral = float(np.clip(pose.jaw_lateral_deg, -lim["lateral_deg"], lim["lateral_deg"]))
    slack = 0.5 * joint.condyle_distance_m * abs(np.sin(np.radians(lateral)))
    protrusion = float(np.clip(pose.jaw_protrusion_m, slack, joint.track_length_m - slack))
    return pose.with_jaw((opening, protrusion, lateral))


def pose_from_bones(joint: JawJoint, activations: np.ndarray, bones: np.ndarray, *, force_length_scale=None) -> Pose:
    """A pose from activations (M,) and the 24 bone parameters of ``wface.controls``.

    Activations are clipped into [-1, 1] (a tracker's penalty lets them stray by round-off; the
    rig clips each channel into its own range: ``FaceModel.clip_activations``). The cranium affine
    is projected onto the nearest rotation and the jaw onto its intuitive parameters (clamped into
    the joint limits), so a pose holds only the rigid, on-joint part of tracked bones;
    ``bone_projection_error_m`` measures what is lost.
    """
    b = np.asarray(bones, dtype=np.float64).reshape(-1)
    if b.shape != (N_BONE_PARAMS,):
        raise ValueError(f"bone parameters have shape {b.shape}, expected ({N_BONE_PARAMS},)")
    Mc, tc = affine_from_params(b[:12])
    jaw = jaw_to_intuitive(joint, b[12:])
    pose = Pose(
        np.clip(np.asarray(activations, dtype=np.float64).reshape(-1), -1.0, 1.0),
        nearest_rotation(Mc),
        tc,
        jaw["opening_deg"],
        jaw["protrusion_m"],
        jaw["lateral_deg"],
        force_length_scale,
    )
    return clamp_jaw(pose, joint)


def pose_from_controls(model: FaceModel, controls: np.ndarray, *, force_length_scale=None) -> Pose:
    """A pose from tracked controls c = (a, b) (M + 24,): ``pose_from_bones`` of the model's joint."""
    c = np.asarray(controls, dtype=np.float64).reshape(-1)
    M = model.n_muscles
    if c.shape != (M + N_BONE_PARAMS,):
        raise ValueError(f"controls have shape {c.shape}, expected ({M + N_BONE_PARAMS},)")
    return pose_from_bones(model.jaw_joint, c[:M], c[M:], force_length_scale=force_length_scale)


def bone_projection_error_m(model: FaceModel, controls: np.ndarray, pose: Pose) -> float:
    """Largest distance (m) between the attached nodes placed by ``controls`` and by ``pose``."""
    b = np.asarray(controls, dtype=np.float64)[model.n_muscles :]
    ref = attached_positions(model, b, frame="world")
    got = attached_positions(model, pose.bones(model.jaw_joint), frame="world")
    return float(np.linalg.norm(ref - got, axis=1).max()) if len(ref) else 0.0
