"""The files of a tracked take: controls and report (``wface.takes.store``), the USD stage
(``wface.takes.usd``), pictures, plots, a movie and the HTML report (``wface.viz``).

The USD stage is written unless ``usd=False``; ``pictures=False`` / ``movie=False`` skip the
pictures and plots / the movie only, and report.html is always written (with whatever pictures
there are) together with the list of every file and what opens it (``OUTPUT_TOOLS``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from wface.controls import bone_affines
from wface.model import FaceModel
from wface.takes.store import USD, take_from_records, write_controls, write_report
from wface.takes.take import frame_step
from wface.takes.usd import render_mesh_layer_path, write_take_usd
from wface.tracking.holdout import plot_holdout
from wface.viz.figures import write_take_figures
from wface.viz.report import write_html_report

__all__ = ["OUTPUT_TOOLS", "describe_outputs", "write_tracking_outputs"]

#: suffix or file name -> (what it is, what opens it)
OUTPUT_TOOLS = {
    "animation.usdc": (
        "the take as USD: exact skin point cache, UsdSkel rig (one blend shape per muscle, cranium and jaw "
        "joints), named marker locators, bones",
        "Blender (File > Import > USD), Maya, Houdini, usdview",
    ),
    "controls.npz": ("activations, bone parameters, jaw pose per frame", "numpy; wface edit / resim --take"),
    "controls.csv": ("the same per frame, one column per muscle", "a spreadsheet, pandas, DCC scripts"),
    "report.json": ("every number of the run", "any text editor, jq, Python json"),
    "report.html": ("this report, pictures embedded", "a web browser"),
    "provenance.json": (
        "what made these files: model and capture hashes, frames, options, wface version",
        "any text editor, jq, Python json",
    ),
    "truth.npz": ("the synthetic take's ground truth", "numpy"),
    "resim.npz": ("the dynamic replay: positions and per-frame stats", "numpy; wface.takes.store"),
    "states.npz": ("every node, marker and activation per frame (wface speech)", "numpy (np.load)"),
    "animation_render_mesh.usdc": (
        "your render mesh moving with the take, in its own units (referenced by the animation stage beside it)",
        "Blender (File > Import > USD: import the animation stage, which brings it), Maya, Houdini, usdview",
    ),
    ".usdc": ("USD stage", "Blender (File > Import > USD), Maya, Houdini, usdview"),
    ".usda": ("USD stage (text)", "Blender (File > Import > USD), Maya, Houdini, usdview, a text editor"),
    ".obj": ("mesh (units in its first line)", "Blender, Maya, Houdini, MeshLab"),
    ".png": ("picture or plot", "any image viewer"),
    ".mp4": ("movie of the take", "a video player, a browser"),
    ".csv": ("table", "a spreadsheet, pandas"),
    ".json": ("numbers of the run", "any text editor, jq, Python json"),
    ".npz": ("arrays", "numpy"),
}


def describe_outputs(paths) -> list[dict]:
    """[{"file", "what", "opens_in"}] of the files written (names relative to their take directory)."""
    rows = []
    for p in paths:
        p = Path(p)
        if p.is_dir():  # frames/ and the earlier passes' survey/, refineN/
            n = sum(1 for _ in p.glob("*.npz"))
            what = "one file per tracked frame" if p.name == "frames" else "the frames of an earlier pass"
            rows.append({"file": f"{p.name}/", "what": f"{what} ({n} files; --resume continues from them)",
                         "opens_in": "numpy; wface track --resume"})  # fmt: skip
            continue
        what, tool = OUTPUT_TOOLS.get(p.name) or OUTPUT_TOOLS.get(p.suffix.lower(), ("", ""))
        rows.append({"file": p.name, "what": what, "opens_in": tool})
    return rows


def _run_records(out: Path) -> list[Path]:
    """provenance.json and the per-frame folders of a take directory, those that exist."""
    dirs = [d for d in ("frames", "survey") if (out / d).is_dir()]
    dirs += sorted(d.name for d in out.glob("refine*") if d.is_dir())
    return [p for p in [out / "provenance.json", *(out / d for d in dirs)] if p.exists()]


def write_tracking_outputs(
    out_dir: str | Path,
    model: FaceModel,
    records,
    *,
    targets_m: np.ndarray,
    fps: float,
    report: dict,
    truth=None,
    usd: bool = True,
    rig: bool = True,
    pictures: bool = True,
    movie: bool = True,
    title: str = "wface track",
    marker_names: list[str] | None = None,
    progress: bool = False,
    render_mesh=None,
) -> list[Path]:
    """Write controls.npz / .csv, report.json, animation.usdc (``usd``; its UsdSkel rig with ``rig``),
    pictures and plots (``pictures``), the movie (``pictures and movie``) and report.html. Returns every
    path written.

    Args:
        out_dir: the take directory.
        model: the face tracked.
        records: the ``wface.takes.store.FrameRecord`` of every frame, in order.
        targets_m: (F, k, 3) captured markers in the model's frame (NaN = missing).
        fps: the capture rate.
        report: the report (``wface.tracking.report.build_report``).
        truth: a ``wface.tracking.synthetic.SyntheticPerformance`` (its curves join the plots).
        usd: write animation.usdc (the take's frame numbers as time codes).
        pictures / movie: write the pictures and plots / the movie.
        title: the HTML report's title.
        marker_names: the k captured markers' names (locators in the USD stage).
        progress: show a progress bar over the stages (USD, pictures, movie, report).
        render_mesh: a ``wface.faces.render_mesh.RenderMesh`` to move with the take in the USD.
    A report with held-out markers (``wface.tracking.holdout``) also gets their plot.
    """
    out = Path(out_dir)
    take = take_from_records(model, records, fps=fps)
    written = list(write_controls(out, model, take))
    written.append(write_report(out, report))
    if (out / "truth.npz").exists():
        written.append(out / "truth.npz")
    X = np.array([r.x_m for r in records])
    simulated = np.array([r.markers_m for r in records])
    stages = [s for s, on in (("USD", usd), ("pictures", pictures), ("movie", pictures and movie)) if on]
    bar = tqdm(total=len(stages) + 1, desc="outputs", unit="step", disable=not progress)
    images: dict = {}
    try:
        if usd:
            bar.set_postfix_str("animation.usdc (rig: one solve per muscle)")
            written.append(
                write_take_usd(
                    out / USD,
                    model,
                    X,
                    take=take,
                    captured_markers_m=targets_m,
                    simulated_markers_m=simulated,
                    marker_names=marker_names,
                    render_mesh=render_mesh,
                    progress=progress,
                    rig="active" if rig else False,
                )
            )
            if render_mesh is not None:
                written.append(render_mesh_layer_path(out / USD))
            bar.update()
        if pictures:
            step = frame_step([r.frame for r in records])  # every S-th capture frame: rows at fps / S
            held = set(report.get("holdout_markers") or [])
            fitted = (
                None
                if not (held and marker_names)
                else np.array([i for i, n in enumerate(marker_names) if n not in held])
            )
            rate = (fps, step, fitted, report.get("outlier_threshold_mm"))
            images = _figures(out, model, records, X, simulated, targets_m, rate, truth, movie, bar)
            if report.get("holdout_rms_mm"):
                images["held-out markers"] = plot_holdout(out / "holdout.png", report, fps=fps / step)
            written.extend(Path(p) for p in images.values())
        bar.set_postfix_str("report.html")
        files = describe_outputs([*written, out / "report.html", *_run_records(out)])
        written.append(write_html_report(out, report, images, title=title, outputs=files))
        bar.update()
    finally:
        bar.close()
    return written


def _figures(out, model, records, X, simulated, targets_m, rate, truth, movie: bool, bar) -> dict:
    """Pictures and plots, then the movie (``wface.viz.figures``), one progress step each; ``rate``:
    (the capture's fps, capture frames per record, the fitted markers' ids or None for all, the outlier
    cut-off in mm or None)."""
    fps, step, fitted, outlier_mm = rate
    M = model.n_muscles
    C = np.array([r.controls for r in records])
    cranium, jaw = (np.stack(a) for a in zip(*(bone_affines(c[M:]) for c in C), strict=True))
    common = dict(
        model=model,
        node_positions_m=X,
        fps=fps / step,  # rows per second
        activations=C[:, :M],
        captured_markers_m=targets_m,
        simulated_markers_m=simulated,
        cranium_affines=cranium,
        jaw_affines=jaw,
        truth_activations=None if truth is None else truth.activations,
        truth_jaw_angle_deg=None if truth is None else truth.jaw_opening_deg,
        truth_markers_m=None if truth is None else truth.clean_markers_m,
        outlier_mm=outlier_mm,
        first_frame=int(records[0].frame) if records else 0,
        frame_step=step,
        error_markers=fitted,
    )
    bar.set_postfix_str("pictures and plots")
    images = write_take_figures(out, **common, movie=False)
    bar.update()
    if movie:
        bar.set_postfix_str("take.mp4")
        images.update(write_take_figures(out, **common, movie=True, stills=False, progress=not bar.disable))
        bar.update()
    return images
