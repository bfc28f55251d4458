"""The files of a tracked take: controls and report (``wface.takes.store``), the USD stage
(``wface.takes.usd``), pictures, plots, a movie and the HTML report (``wface.viz``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.controls import bone_affines
from wface.model import FaceModel
from wface.takes.store import USD, take_from_records, write_controls, write_report
from wface.takes.usd import write_take_usd
from wface.tracking.holdout import plot_holdout
from wface.viz.figures import write_take_figures
from wface.viz.report import write_html_report

__all__ = ["write_tracking_outputs"]


def write_tracking_outputs(
    out_dir: str | Path,
    model: FaceModel,
    records,
    *,
    targets_m: np.ndarray,
    fps: float,
    report: dict,
    truth=None,
    pictures: bool = True,
    movie: bool = True,
    title: str = "wface track",
    render_mesh=None,
) -> list[Path]:
    """Write controls.npz / .csv and report.json, and with ``pictures`` animation.usdc, the figures,
    the movie (``movie``) and report.html. Returns the paths written.

    Args:
        out_dir: the take directory.
        model: the face tracked.
        records: the ``wface.takes.store.FrameRecord`` of every frame, in order.
        targets_m: (F, k, 3) captured markers in the model's frame (NaN = missing).
        fps: the capture rate.
        report: the report (``wface.tracking.report.build_report``).
        truth: a ``wface.tracking.synthetic.SyntheticPerformance`` (its curves join the plots).
        render_mesh: a ``wface.faces.render_mesh.RenderMesh`` to move with the take in the USD.
    A report with held-out markers (``wface.tracking.holdout``) also gets their plot.
    """
    out = Path(out_dir)
    take = take_from_records(model, records, fps=fps)
    written = list(write_controls(out, model, take))
    written.append(write_report(out, report))
    if not pictures:
        return written
    X = np.array([r.x_m for r in records])
    simulated = np.array([r.markers_m for r in records])
    written.append(
        write_take_usd(
            out / USD,
            model,
            X,
            take=take,
            captured_markers_m=targets_m,
            simulated_markers_m=simulated,
            render_mesh=render_mesh,
        )
    )
    M = model.n_muscles
    C = np.array([r.controls for r in records])
    cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(c[M:]) for c in C), strict=True))
    images = write_take_figures(
        out,
        model=model,
        node_positions_m=X,
        fps=fps,
        activations=C[:, :M],
        captured_markers_m=targets_m,
        simulated_markers_m=simulated,
        cranium_affines=cranium,
        jaw_affines=jaw,
        truth_activations=None if truth is None else truth.activations,
        truth_jaw_angle_deg=None if truth is None else truth.jaw_opening_deg,
        movie=movie,
    )
    if report.get("holdout_rms_mm"):
        images = {**images, "held-out markers": plot_holdout(out / "holdout.png", report, fps=fps)}
    written.append(write_html_report(out, report, images, title=title))
    return written
