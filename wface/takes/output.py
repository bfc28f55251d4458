"""Writing an edit: USD (``wface.takes.usd``), controls and report (``wface.takes.store``) and a
contact sheet (``wface.viz.render``, pyvista off-screen when installed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.model import FaceModel
from wface.takes.quasistatic import EditResult
from wface.takes.store import write_controls, write_report
from wface.takes.usd import write_take_usd
from wface.viz.render import Panel, render_panels

__all__ = ["write_contact_sheet", "write_edit"]


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
    progress: bool = False,
    render_mesh=None,
) -> dict:
    """Write ``usd_name`` (a ``write_take_usd`` stage: skin, bones, activations; or with ``mesh_only``
    the skin alone), ``controls.npz`` / ``controls.csv`` (reloadable with ``load_take``),
    ``report.json`` and, with ``pictures``, ``contact_sheet.png`` (panels titled by ``labels``, one
    per frame, default "frame k"); ``progress`` shows a bar over the rig's solves; ``render_mesh`` (a
    ``wface.faces.render_mesh.RenderMesh``) goes into the stage and its rig (``write_take_usd``). Returns the report."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    take = result.take
    scales = take.force_length_scales
    usd = out / usd_name
    meta = {"edit": (info or {}).get("edit", "")}
    write_take_usd(
        usd,
        model,
        result.x_m,
        take=take,
        metadata=meta,
        mesh_only=mesh_only,
        progress=progress,
        render_mesh=render_mesh,
    )
    write_controls(out, model, take)
    secs = result.seconds_per_frame
    disp = _skin_displacement_mm(model, result)
    report = {
        **(info or {}),
        "source": take.source,
        "frames": take.n_frames,
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
        **_channel_ranges(model, take.activations),
        "force_length_scale_max": float(scales.max()),
        "scaled_muscles": [n for n, s in zip(model.muscle_names, scales.max(axis=0), strict=True) if s > 1.0],
        "jaw_opening_deg": [p.jaw_opening_deg for p in take.poses],
        "skin_displacement_max_mm": disp.tolist(),
        "take_info": take.info,
    }
    if pictures:
        report["contact_sheet"] = write_contact_sheet(out / "contact_sheet.png", model, result, labels=labels)
    write_report(out, report)
    return report


def write_contact_sheet(
    path: Path, model: FaceModel, result: EditResult, *, panels: int = 4, labels: list[str] | None = None
) -> str | None:
    """Up to ``panels`` evenly spaced frames side by side (pyvista, off-screen); None when unavailable."""
    F = result.take.n_frames
    idx = sorted({int(round(k)) for k in np.linspace(0, F - 1, min(panels, F))})
    items = [Panel(result.x_m[i], result.take.activations[i], title=labels[i] if labels else f"frame {i}") for i in idx]
    try:
        render_panels(model, items, path, panel_size=(360, 400))
    except Exception as exc:  # noqa: BLE001 - no off-screen GL is not an error of the edit
        print(f"contact sheet skipped: {exc}")
        return None
    return path.name


def _channel_ranges(model, activations: np.ndarray) -> dict:
    """The muscles' activation range ([0, 1]) and, apart, each pressure actuator's ([-1, 1]: signed)."""
    signed = np.isin(model.muscle_names, list(model.pressure_actuators))
    muscles = activations[:, ~signed] if (~signed).any() else np.zeros((1, 1))
    out = {"activation_min": float(muscles.min()), "activation_max": float(muscles.max())}
    for name in model.pressure_actuators:
        column = activations[:, model.muscle_names.index(name)]
        out[f"{name}_range"] = [float(column.min()), float(column.max())]
    return out
