"""The take: a performance of one face, one row of controls per frame, at a frame rate.

A ``Take`` is what tracking produces, what edits change, what the quasistatic and the dynamic
replays play and what the take store (``wface.takes.store``) writes and reads:

- ``activations`` (T, M) in [0, 1] and, optionally, a per-frame, per-muscle ``force_length_scale``
  (T, M): the only way past full activation (the active tension is T = sigma_max (s a f_L + f_P),
  docs/design.md "Muscle fibres"). Their product is the muscle *drive* e = s a >= 0, which is what
  the physics sees (the force is linear in s a);
- ``bones`` (T, 24): cranium affine and jaw affine relative to the cranium (``wface.controls``), or
  ``attached_positions_m`` (T, a, 3) given directly, or neither (bones at rest);
- ``frames``: the frame numbers (those of the capture for a tracked take), ``fps``, ``source``,
  ``info`` (JSON-able notes), ``muscle_names`` and the model's ``joint`` (needed to read the frames
  as editing ``Pose`` values: the jaw in intuitive parameters).

``Take.from_poses`` builds a take from edited poses and keeps them (``take.poses`` returns the
same objects); ``take.poses`` of any other take is computed once from its controls
(``wface.takes.pose.pose_from_controls``: cranium projected onto the nearest rotation, jaw onto its
joint).

Drives split back into activations and scales in two ways (``split_drives``): per frame,
a = min(e, 1), s = max(e, 1) (an edited pose), or per take, S = max(1, max_t e), a = e / S (the
dynamic replay, whose simulator holds one scale per muscle while activations are interpolated
between frames).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wface.controls import IDENTITY_BONES
from wface.model import JawJoint
from wface.takes.pose import Pose, pose_from_bones

__all__ = ["ACTIVATION_RAMPS", "Take", "frame_step"]

ACTIVATION_RAMPS = ("linear", "step")


def _as_frames(name: str, value, T: int, tail: tuple) -> np.ndarray | None:
    if value is None:
        return None
    a = np.asarray(value, dtype=np.float64)
    if (
        a.ndim != len(tail) + 1
        or a.shape[0] != T
        or any(t is not None and a.shape[1 + i] != t for i, t in enumerate(tail))
    ):
        want = ", ".join(["T" if i == 0 else ("?" if t is None else str(t)) for i, t in enumerate((T, *tail))])
        raise ValueError(f"{name} must have shape ({want}) with T = {T} frames, got {a.shape}")
    return a


@dataclass
class Take:
    """Controls of a performance, one row per frame (module docstring).

    Attributes:
        activations: (T, M) muscle activations in [0, 1].
        fps: frame rate, frames per second.
        bones: (T, 24) bone controls (``wface.controls``), or None.
        muscle_names: the M muscle names (None: unnamed, e.g. a synthetic take).
        frames: (T,) frame numbers (default 0..T-1).
        force_length_scale: (T, M) per-frame, per-muscle scale of the active force-length curve,
            or None (all 1). An (M,) array is one scale per muscle for every frame.
        attached_positions_m: (T, a, 3) positions of ``model.attached_nodes`` (in the simulation
            frame), or None (computed from ``bones``).
        reference_positions_m: (T, n, 3) quasistatic world positions of the same frames (e.g. the
            tracked equilibria), or None.
        source: where the take came from.
        info: JSON-able notes (e.g. ``bone_projection_error_mm`` of a loaded tracked take).
        activation_ramp: how a dynamic replay takes activations from one frame to the next:
            "linear" (default) or "step" (the next frame's values from the first substep on).
        joint: the jaw joint of the face the take belongs to (needed for ``poses``), or None.
    """

    activations: np.ndarray
    fps: float
    bones: np.ndarray | None = None
    muscle_names: list[str] | None = None
    frames: np.ndarray | None = None
    force_length_scale: np.ndarray | None = None
    attached_positions_m: np.ndarray | None = None
    reference_positions_m: np.ndarray | None = None
    source: str = ""
    info: dict = field(default_factory=dict)
    activation_ramp: str = "linear"
    joint: JawJoint | None = None
    _poses: list[Pose] | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        if self.activation_ramp not in ACTIVATION_RAMPS:
            raise ValueError(f"activation_ramp must be 'linear' or 'step', got {self.activation_ramp!r}")
        self.activations = np.asarray(self.activations, dtype=np.float64)
        if self.activations.ndim != 2 or self.activations.shape[0] < 1:
            raise ValueError(f"activations must have shape (frames, muscles), got {self.activations.shape}")
        T, M = self.activations.shape
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be finite and > 0, got {self.fps}")
        self.fps = float(self.fps)
        self.bones = _as_frames("bones", self.bones, T, (24,))
        self.attached_positions_m = _as_frames("attached_positions_m", self.attached_positions_m, T, (None, 3))
        self.reference_positions_m = _as_frames("reference_positions_m", self.reference_positions_m, T, (None, 3))
        self.frames = np.arange(T) if self.frames is None else np.asarray(self.frames, dtype=np.int64)
        if self.frames.shape != (T,):
            raise ValueError(f"frames must have shape ({T},), got {self.frames.shape}")
        if np.any(np.diff(self.frames) <= 0):
            raise ValueError(f"frame numbers must increase, got {self.frames[:8].tolist()}...")
        if self.muscle_names is not None:
            self.muscle_names = [str(n) for n in self.muscle_names]
            if len(self.muscle_names) != M:
                raise ValueError(f"{len(self.muscle_names)} muscle names for {M} activations per frame")
        if self.force_length_scale is not None:
            s = np.asarray(self.force_length_scale, dtype=np.float64)
            if s.shape == (M,):
                s = np.broadcast_to(s, (T, M)).copy()
            if s.shape != (T, M) or not np.all(np.isfinite(s)) or np.any(s < 0):
                raise ValueError(f"force_length_scale must be ({M},) or ({T}, {M}), finite and >= 0, got {s.shape}")
            self.force_length_scale = None if np.all(s == 1.0) else s
        for name in ("activations", "bones", "attached_positions_m"):
            value = getattr(self, name)
            if value is not None and not np.all(np.isfinite(value)):
                raise ValueError(f"take {name} contain NaN or inf")
        if self._poses is not None and len(self._poses) != T:
            raise ValueError(f"{len(self._poses)} poses for {T} frames")

    @property
    def frame_intervals_s(self) -> np.ndarray:
        """(T - 1,) seconds from each frame to the next: the frame numbers' gaps over fps (1 / fps for
        consecutive frames, S / fps for a take that kept every S-th capture frame)."""
        return np.diff(self.frames) / self.fps

    # ------------------------------------------------------------------ construction from poses
    @classmethod
    def from_poses(
        cls,
        poses: list[Pose],
        fps: float,
        muscle_names: list[str],
        joint: JawJoint,
        *,
        source: str = "",
        info: dict | None = None,
        frames: np.ndarray | None = None,
    ) -> Take:
        """A take of edited poses (kept: ``take.poses`` returns these objects). Bones come from
        ``Pose.bones(joint)`` (the jaw clamped into the joint, as the replays simulate it)."""
        poses = list(poses)
        if not poses:
            raise ValueError("a take needs at least one pose")
        M = len(muscle_names)
        bad = [i for i, p in enumerate(poses) if p.n_muscles != M]
        if bad:
            raise ValueError(f"poses {bad[:5]} do not have the take's {M} muscles")
        scales = [p.force_length_scale for p in poses]
        scale = None if all(s is None for s in scales) else np.stack([np.ones(M) if s is None else s for s in scales])
        return cls(
            activations=np.stack([p.activations for p in poses]),
            fps=fps,
            bones=np.stack([p.bones(joint) for p in poses]),
            muscle_names=list(muscle_names),
            frames=frames,
            force_length_scale=scale,
            source=source,
            info=dict(info or {}),
            joint=joint,
            _poses=poses,
        )

    def with_poses(
        self, poses: list[Pose], *, fps: float | None = None, source: str | None = None, info: dict | None = None
    ) -> Take:
        """A take of other poses with this take's muscles, joint and notes (``info`` replaces them). As
        many poses at the same rate keep this take's frame numbers (an edit in place: the capture's time
        codes stay); otherwise frames are renumbered from 0."""
        if self.joint is None or self.muscle_names is None:
            raise ValueError("with_poses needs a take with muscle_names and joint (e.g. from Take.from_poses)")
        return Take.from_poses(
            poses,
            self.fps if fps is None else fps,
            self.muscle_names,
            self.joint,
            source=source or self.source,
            info=self.info if info is None else info,
            frames=self.frames if fps is None and len(poses) == self.n_frames else None,
        )

    # ------------------------------------------------------------------ views
    @property
    def n_frames(self) -> int:
        return int(self.activations.shape[0])

    def __len__(self) -> int:
        return self.n_frames

    def __repr__(self) -> str:
        """A line a console can show (the dataclass's printed every array in full)."""
        span = f"frames {int(self.frames[0])}..{int(self.frames[-1])}" if self.frames is not None else ""
        extras = [n for n in ("bones", "attached_positions_m", "reference_positions_m") if getattr(self, n) is not None]
        return (
            f"Take({self.n_frames} frames at {self.fps:g} fps, {self.n_muscles} muscles, {span}"
            f"{', with ' + ', '.join(extras) if extras else ''}, source={self.source!r})"
        )

    @property
    def n_muscles(self) -> int:
        return int(self.activations.shape[1])

    @property
    def force_length_scales(self) -> np.ndarray:
        """(T, M) per-muscle force-length scales (ones where the take has none)."""
        return np.ones_like(self.activations) if self.force_length_scale is None else self.force_length_scale

    @property
    def drives(self) -> np.ndarray:
        """(T, M) drives s a."""
        return self.activations if self.force_length_scale is None else self.activations * self.force_length_scale

    @property
    def poses(self) -> list[Pose]:
        """The frames as editing ``Pose`` values (computed once; the poses themselves for a take
        made by ``from_poses``)."""
        if self._poses is None:
            if self.joint is None:
                raise ValueError("this take has no jaw joint: construct it with joint=model.jaw_joint to read poses")
            bones = self.bones
            if bones is None:
                bones = np.tile(IDENTITY_BONES, (self.n_frames, 1))
            scale = self.force_length_scale
            self._poses = [
                pose_from_bones(self.joint, a, b, force_length_scale=None if scale is None else scale[k])
                for k, (a, b) in enumerate(zip(self.activations, bones, strict=True))
            ]
        return self._poses

    def select(self, index) -> Take:
        """The frames ``index`` (a slice or integer array) of this take, with their numbers."""
        rows = np.arange(self.n_frames)[index]

        def pick(a):
            return None if a is None else a[rows]

        return Take(
            activations=self.activations[rows],
            fps=self.fps,
            bones=pick(self.bones),
            muscle_names=self.muscle_names,
            frames=self.frames[rows],
            force_length_scale=pick(self.force_length_scale),
            attached_positions_m=pick(self.attached_positions_m),
            reference_positions_m=pick(self.reference_positions_m),
            source=self.source,
            info=dict(self.info),
            activation_ramp=self.activation_ramp,
            joint=self.joint,
            _poses=None if self._poses is None else [self._poses[i] for i in rows],
        )


def frame_step(frames) -> int:
    """Capture frames from one stored frame to the next: 1 for consecutive frames (or one frame), S for a
    take that kept every S-th frame (``wface track --frames A:B:S``); the smallest gap where gaps differ."""
    gaps = np.diff(np.asarray(frames, dtype=np.int64))
    return int(gaps.min()) if gaps.size else 1
