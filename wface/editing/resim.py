"""Re-simulating edited poses through the FEM face, and writing the result (USD, controls, report).

Each pose is one quasistatic equilibrium (``Simulator.solve``) in the cranium frame: attached
nodes from the jaw affine, activations (M,) in [0, 1] with the pose's per-muscle force-length
scale set on the simulator, warm-started from the previous frame's equilibrium. World positions
are X = R Y + t with the pose's cranium rotation R and translation t (wface.controls).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wface.editing.pose import Pose, Take
from wface.model import FaceModel

__all__ = ["EditResult", "simulate_poses", "write_edit"]


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


def _skin_displacement_mm(model: FaceModel, result: EditResult) -> np.ndarray:
    """(F,) largest skin displacement from rest in the cranium frame (expression, not head motion), mm."""
    skin = np.unique(model.skin_triangles)
    d = np.linalg.norm(result.y_m[:, skin] - model.rest_positions_m[skin], axis=2)
    return d.max(axis=1) * 1e3


def write_edit(
    out_dir: str | Path,
    model: FaceModel,
    result: EditResult,
    *,
    info: dict | None = None,
    usd_name: str = "animation.usdc",
    mesh_only: bool = False,
    pictures: bool = False,
    labels: list[str] | None = None,
) -> dict:
    """Write ``usd_name`` (a ``write_take`` stage: skin, bones, activations; or with ``mesh_only``
    the skin alone through ``write_mesh_animation``), ``controls.npz`` (reloadable with
    ``load_take``), ``report.json`` and, with ``pictures``, ``contact_sheet.png`` (panels titled by
    ``labels``, one per frame, default "frame k"). Returns the report."""
    import json

    from wface.controls import bone_affines
    from wface.editing.sources import save_controls

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    take = result.take
    joint = model.jaw_joint
    B = np.stack([p.bones(joint) for p in take.poses])
    cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(b) for b in B), strict=True))
    scales = take.force_length_scales
    usd = out / usd_name
    meta = {"edit": (info or {}).get("edit", ""), "source": take.source}
    if mesh_only:
        from wface.io.usd import write_mesh_animation

        write_mesh_animation(
            usd, points_m=result.x_m, face_vertex_counts=None, face_vertex_indices=model.skin_triangles, fps=take.fps
        )
    else:
        from wface.io.usd import write_take

        write_take(
            usd,
            model=model,
            node_positions_m=result.x_m,
            fps=take.fps,
            cranium_affines=cranium,
            jaw_affines=jaw,
            activations=take.activations,
            metadata=meta,
        )
    save_controls(out, model, take)
    secs = result.seconds_per_frame
    disp = _skin_displacement_mm(model, result)
    report = {
        **(info or {}),
        "source": take.source,
        "frames": len(take.poses),
        "fps": take.fps,
        "tets": model.n_tets,
        "nodes": model.n_nodes,
        "muscles": model.n_muscles,
        "usd": usd.name,
        "converged": result.converged,
        "newton_iterations": [s["newton_iterations"] for s in result.stats],
        "residual_rel_max": float(max(s["residual_rel"] for s in result.stats)),
        "inverted_elements": int(max(s["inverted_elements"] for s in result.stats)),
        "seconds_per_frame": secs.tolist(),
        "seconds_per_frame_median": float(np.median(secs)),
        "activation_min": float(take.activations.min()),
        "activation_max": float(take.activations.max()),
        "force_length_scale_max": float(scales.max()),
        "scaled_muscles": [n for n, s in zip(model.muscle_names, scales.max(axis=0), strict=True) if s > 1.0],
        "jaw_opening_deg": [p.jaw_opening_deg for p in take.poses],
        "skin_displacement_max_mm": disp.tolist(),
        "take_info": take.info,
    }
    if pictures:
        report["contact_sheet"] = write_contact_sheet(out / "contact_sheet.png", model, result, labels=labels)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


def write_contact_sheet(
    path: Path, model: FaceModel, result: EditResult, *, panels: int = 4, labels: list[str] | None = None
) -> str | None:
    """Up to ``panels`` evenly spaced frames side by side (pyvista, off-screen); None when unavailable."""
    try:
        from wface.viz.render import Panel, render_panels
    except ImportError:
        return None
    F = len(result.take.poses)
    idx = sorted({int(round(k)) for k in np.linspace(0, F - 1, min(panels, F))})
    items = [Panel(result.x_m[i], result.take.activations[i], title=labels[i] if labels else f"frame {i}") for i in idx]
    try:
        render_panels(model, items, path, panel_size=(360, 400))
    except Exception as exc:  # noqa: BLE001 - no off-screen GL is not an error of the edit
        print(f"contact sheet skipped: {exc}")
        return None
    return path.name
