"""The quasistatic replay: a take played as one equilibrium per frame (no inertia).

``simulate_poses`` re-simulates edited poses through the FEM face (the physics half of an edit; the
files are written by ``wface.takes.output``): each pose is one quasistatic equilibrium
(``Simulator.solve``) in the cranium frame, attached nodes from the jaw affine, activations (M,) in
[0, 1] with the pose's per-muscle force-length scale set on the simulator, warm-started from the
previous frame's equilibrium. World positions are X = R Y + t with the pose's cranium rotation R
and translation t (``wface.controls``).

``quasistatic_frames`` plays raw per-frame activations and attached-node positions the same way;
the dynamic replay (``wface.takes.dynamic``) compares its frames with these.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm.auto import tqdm

from wface.controls import attached_positions
from wface.model import FaceModel
from wface.physics.simulator import Simulator
from wface.takes.pose import Pose, clamp_jaw
from wface.takes.take import Take

__all__ = ["EditResult", "quasistatic_frames", "simulate_poses"]


@dataclass
class EditResult:
    """Equilibria of a take.

    Attributes:
        take: the poses simulated (jaw as simulated, i.e. clamped into the joint).
        y_m: (F, n, 3) equilibria in the cranium frame, metres.
        x_m: (F, n, 3) world positions, metres.
        stats: per frame {newton_iterations, residual_rel, converged, inverted_elements, seconds}.
    """

    take: Take
    y_m: np.ndarray
    x_m: np.ndarray
    stats: list[dict] = field(default_factory=list)

    @property
    def seconds_per_frame(self) -> np.ndarray:
        return np.array([s["seconds"] for s in self.stats])

    @property
    def converged(self) -> bool:
        return all(s["converged"] for s in self.stats)


def simulate_poses(
    model: FaceModel,
    take: Take | list[Pose],
    *,
    simulator=None,
    device: str = "cpu",
    solver: str = "auto",
    tol: float = 1e-6,
    progress: bool = False,
    fps: float = 30.0,
) -> EditResult:
    """Quasistatic equilibrium of every pose, in order, each warm-started from the previous one.

    Args:
        model: the face.
        take: a ``Take`` or a list of poses (then played at ``fps``).
        simulator: a ``wface.physics.Simulator`` of ``model`` to reuse (its force-length scale is
            set per frame and restored afterwards); default: a new one on ``device`` / ``solver``.
        tol: relative residual of each solve.
        progress: show a progress bar (tqdm).
    """
    if not isinstance(take, Take):
        take = Take.from_poses(list(take), fps, list(model.muscle_names), model.jaw_joint, source="poses")
    if take.muscle_names is not None and list(take.muscle_names) != list(model.muscle_names):
        raise ValueError("the take's muscles are not the model's")
    sim = simulator or Simulator(model, device=device, solver=solver)
    saved_scale = sim.force_length_scale
    joint = model.jaw_joint
    ys, xs, stats, poses = [], [], [], []
    y_prev = None
    try:
        for pose in tqdm(take.poses, desc="re-simulating", disable=not progress, unit="frame"):
            t0 = time.perf_counter()
            sim.force_length_scale = pose.simulator_scale()
            targets = attached_positions(model, pose.bones(joint), frame="cranium")
            eq = sim.solve(pose.activations, targets, y_prev, tol=tol)
            y = eq.x
            ys.append(y)
            xs.append(y @ pose.cranium_rotation.T + pose.cranium_translation_m)
            y_prev = y
            stats.append(
                {
                    "newton_iterations": int(eq.iterations),
                    "residual_rel": float(eq.residual_rel),
                    "converged": bool(eq.converged),
                    "inverted_elements": int(eq.inverted_elements),
                    "seconds": time.perf_counter() - t0,
                }
            )
            poses.append(pose)
    finally:
        sim.force_length_scale = saved_scale
    out_take = Take.from_poses(
        [clamp_jaw(p, joint) for p in poses],
        take.fps,
        list(model.muscle_names),
        joint,
        source=take.source,
        info=take.info,
        frames=take.frames,
    )
    return EditResult(out_take, np.stack(ys), np.stack(xs), stats)


def quasistatic_frames(
    sim,
    activations: np.ndarray,
    attached_positions_m: np.ndarray,
    *,
    force_length_scale: np.ndarray | None = None,
    progress: bool = False,
    tol: float = 1e-6,
    contact=None,
) -> np.ndarray:
    """(T, n, 3) quasistatic equilibria of every frame (warm-started from the previous frame),
    with the optional ``contact`` (``wface.physics.contact.Contact``).

    ``force_length_scale``: (T, M) per frame or (M,) for all frames (a take's), set on ``sim`` for
    each frame and restored afterwards; None leaves the simulator's scale as it is.
    """
    scale = None if force_length_scale is None else np.asarray(force_length_scale, dtype=np.float64)
    saved = sim.force_length_scale
    out, x = [], None
    try:
        for k, (a, xc) in enumerate(
            tqdm(
                list(zip(activations, attached_positions_m, strict=True)),
                desc="quasistatic",
                disable=not progress,
                unit="frame",
            )
        ):
            if scale is not None:
                sim.force_length_scale = scale[k] if scale.ndim == 2 else scale
            eq = sim.solve(a, xc, x, tol=tol, contact=contact)
            x = eq.x
            out.append(x)
    finally:
        sim.force_length_scale = saved
    return np.array(out)
