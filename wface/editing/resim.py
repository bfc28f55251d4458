"""Re-simulating edited poses through the FEM face (the physics half of an edit; output: ``output``).

Each pose is one quasistatic equilibrium (``Simulator.solve``) in the cranium frame: attached
nodes from the jaw affine, activations (M,) in [0, 1] with the pose's per-muscle force-length
scale set on the simulator, warm-started from the previous frame's equilibrium. World positions
are X = R Y + t with the pose's cranium rotation R and translation t (wface.controls).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from wface.editing.pose import Pose, Take
from wface.model import FaceModel

__all__ = ["EditResult", "simulate_poses"]


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
    from tqdm.auto import tqdm

    from wface.controls import attached_positions
    from wface.physics.simulator import Simulator

    if not isinstance(take, Take):
        take = Take(list(take), fps, list(model.muscle_names), "poses")
    if list(take.muscle_names) != list(model.muscle_names):
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
    from wface.editing.pose import clamp_jaw

    out_take = take.with_poses([clamp_jaw(p, joint) for p in poses])
    return EditResult(out_take, np.stack(ys), np.stack(xs), stats)
