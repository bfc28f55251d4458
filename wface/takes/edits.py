"""Edits in activation space: interpolate, blend, exaggerate, layer, retime (Sifakis et al. 2005, section 9).

Every edit maps valid poses to valid poses, so the re-simulated face stays anatomically
attainable: activations stay in [0, 1], the cranium stays a rotation, the jaw stays on its
joint. The rules, shared by all edits:

- muscles mix linearly in their drive e = s a (activation times per-muscle force-length scale;
  e = a for ordinary poses, so this *is* linear activation interpolation there), split back per
  muscle as a = min(e, 1), s = max(e, 1);
- cranium rotations by slerp (two poses) or the weighted chordal mean (``blend``); translations
  linearly;
- the jaw through its intuitive parameters (opening, protrusion, lateral yaw), linearly, then
  clamped into the joint limits when a ``joint`` is given.

Exaggeration (``exaggerate``) scales the change from a neutral pose: e' = e + (f - 1)(e - e_n),
so f = 1 is the identity, f < 1 de-emphasises, f > 1 exaggerates. A drive below 0 is clipped to 0
(a muscle cannot push); a pressure actuator's drive is signed (suction), so a channel negative in
any of the poses an edit combines keeps its sign. A drive above 1 is never an activation above 1: with
``scale_mode="muscle"`` (default) that muscle gets a = 1 and s = e' (its force-length curve is
scaled by e', docs/design.md "Muscle fibres"); with ``scale_mode="global"`` all muscles share
S = max(1, max e') and a = e'/S. Both give exactly the same forces (the active tension is linear
in s a), so the same equilibrium; they differ only in how the numbers are stored. The jaw opening,
protrusion and yaw are exaggerated the same way and clamped to the joint; the cranium (head
motion, not expression) is kept.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from wface.model import JawJoint
from wface.takes.pose import Pose, clamp_jaw, rest_pose
from wface.takes.take import Take

__all__ = ["SCALE_MODES", "blend", "exaggerate", "interpolate", "layer", "retime"]

SCALE_MODES = ("muscle", "global")
_WEIGHT_SUM_TOL = 1e-9  # blend weights must sum to 1 up to round-off of a user's decimal weights
_FRAME_TOL = 1e-9  # a retimed sample this close to a source frame takes that frame as is


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return v


def _same_muscles(*poses: Pose) -> None:
    sizes = {p.n_muscles for p in poses}
    if len(sizes) > 1:
        raise ValueError(f"poses have different muscle counts: {sorted(sizes)}")


def _finish(pose: Pose, joint: JawJoint | None) -> Pose:
    return pose if joint is None else clamp_jaw(pose, joint)


def interpolate(a: Pose, b: Pose, t: float, *, joint: JawJoint | None = None) -> Pose:
    """The pose a fraction ``t`` in [0, 1] of the way from ``a`` to ``b`` (module rules).

    Drives linear, cranium rotation by slerp, translation linear, jaw linear in its intuitive
    parameters. ``t = 0`` gives ``a`` and ``t = 1`` gives ``b`` (to round-off).
    """
    t = _finite("t", t)
    if not 0.0 <= t <= 1.0:
        raise ValueError(f"t must lie in [0, 1], got {t} (use exaggerate to go past a pose)")
    _same_muscles(a, b)
    drive = (1.0 - t) * a.drive + t * b.drive
    rel = Rotation.from_matrix(a.cranium_rotation.T @ b.cranium_rotation).as_rotvec()
    R = a.cranium_rotation @ Rotation.from_rotvec(t * rel).as_matrix()
    pose = Pose(
        np.zeros(a.n_muscles),
        R,
        (1.0 - t) * a.cranium_translation_m + t * b.cranium_translation_m,
    )
    pose = pose.with_drive(drive).with_jaw((1.0 - t) * a.jaw + t * b.jaw)
    return _finish(pose, joint)


def blend(weights: Sequence[float], poses: Sequence[Pose], *, joint: JawJoint | None = None) -> Pose:
    """Convex combination sum_k w_k pose_k: weights finite, >= 0 and summing to 1.

    Drives, translations and jaw parameters mix linearly; cranium rotations by the weighted chordal
    L2 mean (``scipy.spatial.transform.Rotation.mean``), which for two poses lies on their slerp arc.
    """
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    poses = list(poses)
    if not poses:
        raise ValueError("blend needs at least one pose")
    if w.size != len(poses):
        raise ValueError(f"{w.size} weights for {len(poses)} poses")
    if not np.all(np.isfinite(w)):
        raise ValueError("blend weights must be finite")
    if np.any(w < 0):
        raise ValueError(f"blend weights must be >= 0 (a convex combination), got {w.tolist()}")
    if abs(w.sum() - 1.0) > _WEIGHT_SUM_TOL:
        raise ValueError(f"blend weights must sum to 1, they sum to {w.sum():.12g}")
    _same_muscles(*poses)
    drive = sum(wk * p.drive for wk, p in zip(w, poses, strict=True))
    rotations = Rotation.from_matrix(np.stack([p.cranium_rotation for p in poses]))
    R = rotations.mean(weights=w).as_matrix()
    t = sum(wk * p.cranium_translation_m for wk, p in zip(w, poses, strict=True))
    jaw = sum(wk * p.jaw for wk, p in zip(w, poses, strict=True))
    return _finish(Pose(np.zeros(poses[0].n_muscles), R, t).with_drive(drive).with_jaw(jaw), joint)


def exaggerate(
    pose: Pose,
    factor: float,
    neutral: Pose | None = None,
    *,
    joint: JawJoint | None = None,
    scale_mode: str = "muscle",
) -> Pose:
    """Scale a pose's change from ``neutral`` (default: the rest pose) by ``factor`` >= 0.

    e' = max(0, e + (factor - 1)(e - e_n)) per muscle; drives above 1 go into the force-length
    scale (per muscle, or one global scale: see the module docstring); activations stay in [0, 1].
    The jaw's intuitive parameters scale the same way about the neutral's (clamped to the joint
    when ``joint`` is given); the cranium is the pose's own.
    """
    f = _finite("factor", factor)
    if f < 0:
        raise ValueError(f"factor must be >= 0, got {f} (0: neutral, 1: unchanged, > 1: exaggerated)")
    if scale_mode not in SCALE_MODES:
        raise ValueError(f"scale_mode must be one of {SCALE_MODES}, got {scale_mode!r}")
    neutral = neutral or rest_pose(pose.n_muscles)
    _same_muscles(pose, neutral)
    if f == 1.0:
        return _finish(pose, joint)
    e, e_n = pose.drive, neutral.drive
    drive = e + (f - 1.0) * (e - e_n)
    drive = np.where(_signed(e, e_n), drive, np.maximum(0.0, drive))  # a signed channel has no floor
    jaw = pose.jaw + (f - 1.0) * (pose.jaw - neutral.jaw)
    out = pose.with_jaw(jaw)
    if scale_mode == "muscle":
        out = out.with_drive(drive)
    else:
        top = max(1.0, float(np.abs(drive).max(initial=0.0)))
        scale = None if top == 1.0 else np.full(drive.shape, top)
        out = replace(out, activations=np.clip(drive / top, -1.0, 1.0), force_length_scale=scale)
    return _finish(out, joint)


def _signed(e: np.ndarray, *others: np.ndarray) -> np.ndarray:
    """(M,) bool: channels negative in any of the poses an edit combines. A muscle's drive is never
    negative (it cannot push), so those are pressure actuators, whose drive may go down to suction;
    every other channel's drive stays >= 0."""
    return np.minimum.reduce([e, *others]) < 0


def _weights_per_frame(weight, n: int) -> np.ndarray:
    w = np.asarray(weight, dtype=np.float64)
    w = np.full(n, float(w)) if w.ndim == 0 else w.reshape(-1)
    if w.shape != (n,):
        raise ValueError(f"layer weight must be a number or one value per frame ({n}), got shape {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ValueError("layer weight must be finite")
    return w


def layer(
    take: Take | Sequence[Pose],
    offset: Pose,
    weight: float | np.ndarray = 1.0,
    *,
    neutral: Pose | None = None,
    joint: JawJoint | None = None,
) -> Take | list[Pose]:
    """Add ``weight`` x (``offset`` - ``neutral``) on top of every frame of a take, within bounds.

    Per frame: drives e' = clip(e + w (e_off - e_n), 0, max(1, e)) (an offset never pushes a muscle
    past full activation; a take's own exaggeration is kept), jaw parameters e.g. opening' =
    opening + w (opening_off - opening_n) clamped to the joint (with ``joint``), cranium rotated by
    the offset's rotation relative to the neutral raised to the power w, translation + w dt.
    ``weight`` is a number or one value per frame (an envelope: fade an expression in and out).
    A negative weight removes an expression. Returns the same kind as ``take``.
    """
    poses = list(take.poses) if isinstance(take, Take) else list(take)
    if not poses:
        raise ValueError("layer needs at least one frame")
    neutral = neutral or rest_pose(offset.n_muscles)
    _same_muscles(offset, neutral, *poses[:1])
    w = _weights_per_frame(weight, len(poses))
    d_drive = offset.drive - neutral.drive
    d_jaw = offset.jaw - neutral.jaw
    d_rot = Rotation.from_matrix(neutral.cranium_rotation.T @ offset.cranium_rotation).as_rotvec()
    d_t = offset.cranium_translation_m - neutral.cranium_translation_m
    out = []
    for wk, p in zip(w, poses, strict=True):
        e = p.drive
        top = np.maximum(1.0, np.abs(e))
        floor = np.where(_signed(e, offset.drive, neutral.drive), -top, 0.0)
        drive = np.clip(e + wk * d_drive, floor, top)
        R = p.cranium_rotation @ Rotation.from_rotvec(wk * d_rot).as_matrix()
        q = replace(p, cranium_rotation=R, cranium_translation_m=p.cranium_translation_m + wk * d_t)
        out.append(_finish(q.with_drive(drive).with_jaw(p.jaw + wk * d_jaw), joint))
    return take.with_poses(out, source=f"{take.source} + layer") if isinstance(take, Take) else out


def retime(take: Take, *, speed: float = 1.0, fps_out: float | None = None, joint: JawJoint | None = None) -> Take:
    """Resample a take in time: play it ``speed`` times faster, sampled at ``fps_out`` (default: its fps).

    Output frame k shows source time k * speed / fps_out after the first frame (source frame i lies at
    (frames[i] - frames[0]) / fps: a take of every S-th capture frame keeps its true timing), i.e. source
    frame index s_k = k * speed * fps / fps_out for consecutive frames, for every s_k within the take; between frames
    the poses are interpolated with ``interpolate`` (same rules as every edit). Speed 1 at the same
    rate returns the frames themselves; speed 2 keeps every other frame (ceil(F / 2) frames).
    """
    speed = _finite("speed", speed)
    if speed <= 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    fps_out = take.fps if fps_out is None else _finite("fps_out", fps_out)
    if fps_out <= 0:
        raise ValueError(f"fps_out must be > 0, got {fps_out}")
    n_in = len(take.poses)
    times = (take.frames - take.frames[0]) / take.fps  # source frame i's time (strided takes: gaps of S / fps)
    index = np.arange(n_in, dtype=np.float64)
    n_out = int(math.floor(times[-1] * fps_out / speed + _FRAME_TOL)) + 1
    poses = []
    for k in range(n_out):
        s = min(float(np.interp(k * speed / fps_out, times, index)), n_in - 1.0)
        i = int(math.floor(s + _FRAME_TOL))
        frac = s - i
        if abs(frac) <= _FRAME_TOL or i >= n_in - 1:
            poses.append(take.poses[min(i, n_in - 1)])
        else:
            poses.append(interpolate(take.poses[i], take.poses[i + 1], frac, joint=joint))
    src = f"{take.source} retimed x{speed:g} at {fps_out:g} fps"
    return take.with_poses(poses, fps=fps_out, source=src, info={**take.info, "retime_speed": speed})
