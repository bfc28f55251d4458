"""The standard pictures, plots and movie of a take, ready for ``write_html_report``.

One call makes everything a tracking or simulation run shows people::

    images = write_take_figures(out_dir, model=model, node_positions_m=x, fps=60, activations=a,
                                captured_markers_m=cap, simulated_markers_m=sim, jaw_affines=jaw,
                                cranium_affines=cranium)
    write_html_report(out_dir, report, images)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.controls import jaw_limits
from wface.viz import plots, render

__all__ = ["comparison_frame", "peak_frame", "write_take_figures"]


def peak_frame(
    node_positions_m: np.ndarray, rest_positions_m: np.ndarray, activations: np.ndarray | None = None
) -> int:
    """The most expressive frame: largest total activation, else largest mean displacement from rest."""
    if activations is not None and np.asarray(activations).size:
        return int(np.argmax(np.asarray(activations).sum(axis=1)))
    d = np.linalg.norm(np.asarray(node_positions_m) - rest_positions_m[None], axis=2).mean(axis=1)
    return int(np.argmax(d))


def comparison_frame(peak: int, n_frames: int) -> int:
    """The frame drawn beside the first one in before_after.png: the most expressive frame ``peak``,
    or the last frame when the take peaks at its first (two copies of one frame show nothing)."""
    return n_frames - 1 if peak == 0 and n_frames > 1 else peak


def write_take_figures(
    out_dir: str | Path,
    *,
    model,
    node_positions_m: np.ndarray,
    fps: float,
    activations: np.ndarray | None = None,
    captured_markers_m: np.ndarray | None = None,
    simulated_markers_m: np.ndarray | None = None,
    cranium_affines: np.ndarray | None = None,
    jaw_affines: np.ndarray | None = None,
    jaw_frame: str = "cranium",
    jaw_angle_deg: np.ndarray | None = None,
    truth_activations: np.ndarray | None = None,
    truth_jaw_angle_deg: np.ndarray | None = None,
    movie: bool = True,
    movie_max_frames: int = 240,
    panel_size: tuple[int, int] = (720, 800),
    stills: bool = True,
    first_frame: int = 0,
    frame_step: int = 1,
    progress: bool = False,
    error_markers: np.ndarray | None = None,
    truth_markers_m: np.ndarray | None = None,
    outlier_mm: float | None = None,
) -> dict[str, Path]:
    """Write stills, plots and a movie of a take into ``out_dir``.

    Args:
        out_dir: directory (created).
        model: the ``FaceModel``.
        node_positions_m: (F, n, 3) node positions per frame.
        fps: rows per second (a take keeping every S-th capture frame: the capture rate / S).
        activations: (F, M) activations (muscle colours, activation plot).
        captured_markers_m / simulated_markers_m: (F, k, 3) markers (red / green; error plot).
        cranium_affines / jaw_affines: (F, 3, 4) bone motion (jaw opening plot, bones in pictures).
        jaw_frame: "cranium" (default: jaw affines relative to the cranium, as ``wface.controls``)
            or "world".
        jaw_angle_deg: (F,) jaw opening; default: from the affines about the model's jaw axis u.
        truth_activations / truth_jaw_angle_deg: ground truth, drawn dashed.
        movie: also write ``take.mp4`` (every frame up to ``movie_max_frames``, else evenly
            subsampled at a reduced frame rate so the duration stays right).
        panel_size: pixel size of one picture panel.
        stills: write the pictures and plots (False with ``movie``: the movie alone).
        first_frame: the number of the first frame (captions and the movie's frame counter show
            the capture's frame numbers).
        frame_step: capture frames from one row to the next (row f is capture frame
            ``first_frame + f * frame_step``).
        progress: show a progress bar over the movie's frames.
        error_markers: the markers the error plot covers (ids; default all): the fitted ones where some were
            held out, so that the plot reads as the report's ``marker_rms_mm_mean``.
        truth_markers_m: (F, k, 3) a synthetic take's noise-free markers: the error plot leads with them.
        outlier_mm: the report's ``outlier_threshold_mm``: the error plot shows the inliers' RMS and max
            and, in a panel below, the max counting outliers.

    Returns:
        caption -> path, in display order (pass to ``write_html_report``).
    """

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    x = np.asarray(node_positions_m, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (model.n_nodes, 3) or x.shape[0] == 0:
        raise ValueError(f"node_positions_m must have shape (frames, {model.n_nodes}, 3); got {x.shape}")
    F = x.shape[0]
    _check_frame_counts(
        F,
        activations=activations,
        captured_markers_m=captured_markers_m,
        simulated_markers_m=simulated_markers_m,
        jaw_affines=jaw_affines,
        cranium_affines=cranium_affines,
        jaw_angle_deg=jaw_angle_deg,
        truth_activations=truth_activations,
        truth_jaw_angle_deg=truth_jaw_angle_deg,
        truth_markers_m=truth_markers_m,
    )
    jaw_rel = _jaw_relative(jaw_affines, cranium_affines, jaw_frame)
    markers = (captured_markers_m, simulated_markers_m)
    numbers = int(first_frame) + int(frame_step) * np.arange(F)  # the capture's frame number of each row
    images: dict[str, Path] = {}
    if stills:
        images.update(
            _write_pictures(out, model, x, fps, activations, markers, cranium_affines, jaw_rel, panel_size, numbers)
        )
    images.update(
        {}
        if not stills
        else _write_plots(
            out,
            model,
            fps,
            activations,
            markers,
            jaw_affines=jaw_affines,
            cranium_affines=cranium_affines,
            jaw_frame=jaw_frame,
            error=(error_markers, truth_markers_m, outlier_mm),
            jaw_angle_deg=jaw_angle_deg,
            truth_activations=truth_activations,
            truth_jaw_angle_deg=truth_jaw_angle_deg,
        )
    )
    if movie:
        images["Take (movie)"] = _write_movie(
            out,
            model,
            x,
            fps,
            activations,
            markers,
            cranium_affines,
            jaw_affines,
            jaw_frame,
            movie_max_frames,
            panel_size,
            numbers,
            progress,
        )
    return images


def _check_frame_counts(F: int, **arrays) -> None:
    """Every per-frame array given has F rows."""
    for name, arr in arrays.items():
        if arr is not None and len(arr) != F:
            raise ValueError(f"{name} has {len(arr)} frames but node_positions_m has {F}")


def _jaw_relative(jaw_affines, cranium_affines, jaw_frame: str):
    """The jaw affines in the cranium's frame (as the pictures draw them)."""
    if jaw_affines is not None and jaw_frame == "world" and cranium_affines is not None:
        c, j = np.asarray(cranium_affines, float), np.asarray(jaw_affines, float)  # make the jaw relative
        lin = np.linalg.solve(c[:, :, :3], j[:, :, :3])
        jaw_rel = np.concatenate([lin, np.linalg.solve(c[:, :, :3], (j[:, :, 3] - c[:, :, 3])[..., None])], axis=2)
    else:
        jaw_rel = jaw_affines
    return jaw_rel


def _at(arr, f):
    return None if arr is None else np.asarray(arr)[f]


def _write_pictures(out: Path, model, x, fps, activations, markers, cranium_affines, jaw_rel, panel_size, numbers):
    """Stills of the most expressive frame (expression, muscles) and of the first frame beside it."""
    captured_markers_m, simulated_markers_m = markers

    def panel(f: int, title: str) -> render.Panel:
        return render.Panel(
            x[f],
            _at(activations, f),
            _at(captured_markers_m, f),
            _at(simulated_markers_m, f),
            title,
            _at(cranium_affines, f),
            _at(jaw_rel, f),
        )

    images: dict[str, Path] = {}
    f = peak_frame(x, model.rest_positions_m, activations)
    t = f / fps
    n = int(numbers[f])  # the capture's frame number
    images[f"Expression at frame {n} ({t:.2f} s into the take): captured markers red, tracked green"] = (
        render.render_expression(
            model,
            x[f],
            out / "expression.png",
            activations=_at(activations, f),
            captured_markers_m=_at(captured_markers_m, f),
            simulated_markers_m=_at(simulated_markers_m, f),
            panel_size=panel_size,
        )
    )
    if activations is not None:
        images[f"Muscles at frame {n}: yellow active, red inactive"] = render.render_panels(
            model, [panel(f, "")], out / "muscles.png", style="muscles", panel_size=panel_size
        )
    g = comparison_frame(f, len(x))
    caption = "First frame and most expressive frame" if g == f else "First frame (the most expressive) and last frame"
    images[caption] = render.render_before_after(
        model,
        panel(0, f"frame {int(numbers[0])}"),
        panel(g, f"frame {int(numbers[g])}"),
        out / "before_after.png",
        panel_size=panel_size,
    )
    return images


def _write_plots(
    out: Path,
    model,
    fps,
    activations,
    markers,
    *,
    jaw_affines,
    cranium_affines,
    jaw_frame,
    jaw_angle_deg,
    truth_activations,
    truth_jaw_angle_deg,
    error=(None, None, None),
) -> dict[str, Path]:
    """Plots over time: activations, marker error, jaw opening with the joint's limits (each when its data is
    given); ``error``: (the markers the error covers, default all; the true markers or None; the outlier
    cut-off in mm or None)."""
    captured_markers_m, simulated_markers_m = markers
    images: dict[str, Path] = {}
    if activations is not None:
        images["Muscle activations"] = plots.plot_activations(
            activations, model.muscle_names, out / "activations.png", fps=fps, truth=truth_activations
        )
    if captured_markers_m is not None and simulated_markers_m is not None:
        images["Marker error per frame"] = _marker_error_plot(out, fps, markers, *error)
    if jaw_angle_deg is None and jaw_affines is not None:
        jaw_angle_deg = plots.jaw_opening_deg(
            jaw_affines, model.jaw_joint, cranium_affines=cranium_affines, jaw_frame=jaw_frame
        )
    if jaw_angle_deg is not None:
        images["Jaw opening"] = plots.plot_jaw_opening(
            jaw_angle_deg,
            out / "jaw_opening.png",
            fps=fps,
            truth_deg=truth_jaw_angle_deg,
            limits_deg=jaw_limits(model.jaw_joint)["opening_deg"],
        )
    return images


def _marker_error_plot(out: Path, fps, markers, error_markers, truth_markers_m, outlier_mm) -> Path:
    """marker_error.png: against the truth when known, the inliers' RMS and max against the capture (over
    ``error_markers``, default all) and, with an outlier cut-off, the max counting outliers apart."""
    captured_markers_m, simulated_markers_m = markers
    cols = slice(None) if error_markers is None else np.asarray(error_markers)
    cap, sim = captured_markers_m[:, cols], simulated_markers_m[:, cols]
    rms, mx = plots.marker_errors_mm(cap, sim, outlier_mm=outlier_mm)
    truth_rms = None if truth_markers_m is None else plots.marker_errors_mm(truth_markers_m, simulated_markers_m)[0]
    max_all = None if outlier_mm is None else plots.marker_errors_mm(cap, sim)[1]
    title = "Marker error per frame" + ("" if error_markers is None else f" ({len(cols)} fitted markers)")
    return plots.plot_marker_error(
        rms,
        out / "marker_error.png",
        marker_max_mm=mx,
        fps=fps,
        title=title,
        truth_rms_mm=truth_rms,
        outlier_mm=outlier_mm,
        max_all_mm=max_all,
    )


def _write_movie(
    out: Path,
    model,
    x,
    fps,
    activations,
    markers,
    cranium_affines,
    jaw_affines,
    jaw_frame,
    movie_max_frames,
    panel_size,
    numbers: np.ndarray,
    progress: bool = False,
) -> Path:
    """``take.mp4``: every frame up to ``movie_max_frames``, else evenly subsampled at a reduced rate."""
    captured_markers_m, simulated_markers_m = markers
    F = x.shape[0]
    step = max(1, int(np.ceil(F / movie_max_frames)))
    sel = np.arange(0, F, step)

    def sub(arr):
        return None if arr is None else np.asarray(arr)[sel]

    return render.render_take_movie(
        model,
        x[sel],
        out / "take.mp4",
        fps=max(1.0, fps / step),
        activations=sub(activations),
        captured_markers_m=sub(captured_markers_m),
        simulated_markers_m=sub(simulated_markers_m),
        cranium_affines=sub(cranium_affines),
        jaw_affines=sub(jaw_affines),
        jaw_frame=jaw_frame,
        window_size=panel_size,
        frame_numbers=numbers[sel],
        progress=progress,
    )
