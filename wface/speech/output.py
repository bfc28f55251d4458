"""The files of a played speech gesture: the lip-opening curve (CSV and plot) and the USD stage."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.model import FaceModel
from wface.speech.playback import GestureResult
from wface.takes.take import Take
from wface.takes.usd import write_take_usd
from wface.viz.plots import _plt

__all__ = ["write_gesture_usd", "write_lip_opening"]


def write_lip_opening(out: Path, result: GestureResult, model: FaceModel) -> tuple[Path, Path]:
    """lip_opening.csv (time_s, lip_opening_mm, driven activations) and lip_opening.png."""
    driven = [i for i in range(model.n_muscles) if np.any(result.activations[:, i] > 0)]
    header = ["time_s", "lip_opening_mm", "lip_vertical_mm"] + [f"a_{model.muscle_names[i]}" for i in driven]
    table = np.column_stack(
        [result.times_s, result.lip_opening_mm, result.lip_vertical_mm, result.activations[:, driven]]
    )
    csv = out / "lip_opening.csv"
    np.savetxt(csv, table, delimiter=",", header=",".join(header), comments="", fmt="%.6g")
    plt = _plt()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    ax1.plot(result.times_s, result.lip_opening_mm, "o-", color="C3", ms=3, label="distance")
    ax1.plot(result.times_s, result.lip_vertical_mm, "--", color="C0", label="vertical part")
    ax1.legend(fontsize=8)
    ax1.set_ylabel("lip opening (mm)\nMouth_Up - Mouth_Down")
    ax1.set_title(f"{result.gesture}: quasistatic Badin face, {len(result.times_s)} frames")
    ax1.grid(alpha=0.3)
    seen = set()
    for i in driven:
        base = model.muscle_names[i].rsplit("_", 1)[0]
        if base in seen:
            continue
        seen.add(base)
        ax2.plot(result.times_s, result.activations[:, i], label=base)
    ax2.set_ylabel("activation (both sides)")
    ax2.set_xlabel("time (s)")
    ax2.legend(fontsize=8, ncol=3)
    ax2.grid(alpha=0.3)
    png = out / "lip_opening.png"
    fig.savefig(png, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return csv, png


def write_gesture_usd(
    path: Path, result: GestureResult, model: FaceModel, *, fps: float, source: str = "", progress: bool = False
) -> Path:
    """The played gesture as a take stage (``wface.takes.usd``): skin, markers, activations; the
    bones stay at rest. ``progress`` shows a bar over the rig's muscle solves."""
    take = Take(
        activations=result.activations,
        fps=fps,
        muscle_names=list(model.muscle_names),
        source=source,
        joint=model.jaw_joint,
    )
    return write_take_usd(
        path,
        model,
        result.node_positions_m,
        take=take,
        simulated_markers_m=result.markers_m,
        marker_names=result.marker_names,
        metadata={"gesture": result.gesture},
        progress=progress,
    )
