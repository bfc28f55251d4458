"""The files of a played speech gesture: the lip-opening curve (CSV and plot) and the USD stage."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from wface.files import save_npz
from wface.model import FaceModel
from wface.speech.aperture import ApertureResult, ApertureView, aperture_area
from wface.speech.playback import GestureResult
from wface.takes.take import Take
from wface.takes.usd import write_take_usd
from wface.viz.plots import _plt

__all__ = [
    "write_aperture_picture",
    "write_aperture_pictures",
    "write_gesture_usd",
    "write_lip_opening",
    "write_states",
]


def write_lip_opening(
    out: Path, result: GestureResult, model: FaceModel, *, reference: np.ndarray | None = None
) -> tuple[Path, Path]:
    """lip_opening.csv and lip_opening.png of a played gesture.

    CSV columns: time_s, lip_opening_area_mm2 (the mouth aperture, ``wface.speech.aperture``),
    lip_opening_area_error_mm2, lip_opening_width_mm, lip_opening_height_mm, window_seen_mm2 (all of
    the window seen, mouth or not: ArtiSynth's green-pixel measure), lip_opening_mm and
    lip_vertical_mm (Mouth_Up - Mouth_Down distance and its vertical part), lip_gap_mm (smallest
    signed lip-lip distance), then the activation of each driven muscle. The picture: the area (with
    ``reference``, (k, 2) time and area of the original, when given), the marker distance and the
    activations over time.
    """
    driven = [i for i in range(model.n_muscles) if np.any(result.activations[:, i] > 0)]
    F = len(result.times_s)
    area = result.lip_opening_area_mm2 if result.lip_opening_area_mm2 is not None else np.full(F, np.nan)
    cols = {
        "time_s": result.times_s,
        "lip_opening_area_mm2": area,
        "lip_opening_area_error_mm2": _or_nan(result.lip_opening_area_error_mm2, F),
        "lip_opening_width_mm": _or_nan(result.lip_opening_width_mm, F),
        "lip_opening_height_mm": _or_nan(result.lip_opening_height_mm, F),
        "window_seen_mm2": _or_nan(result.window_seen_mm2, F),
        "lip_opening_mm": result.lip_opening_mm,
        "lip_vertical_mm": result.lip_vertical_mm,
        "lip_gap_mm": _or_nan(result.lip_gap_mm, F),
    }
    header = list(cols) + [f"a_{model.muscle_names[i]}" for i in driven]
    table = np.column_stack([*cols.values(), result.activations[:, driven]])
    csv = out / "lip_opening.csv"
    np.savetxt(csv, table, delimiter=",", header=",".join(header), comments="", fmt="%.6g")
    plt = _plt()
    fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    ax0.plot(result.times_s, area, "o-", color="C2", ms=3, label=f"wface ({result.mode})")
    if reference is not None and len(reference):
        ax0.plot(reference[:, 0], reference[:, 1], "k--", lw=1.2, label="original (ArtiSynth, recorded)")
    ax0.set_ylabel("lip opening area (mm$^2$)")
    ax0.legend(fontsize=8)
    ax0.grid(alpha=0.3)
    view = (result.area_view or {}).get("name", "")
    contact = f", contact {result.contact}" if result.contact else ", no contact"
    ax0.set_title(f"{result.gesture}: {result.mode} Badin face{contact}, {F} frames (view {view})", fontsize=10)
    ax1.plot(result.times_s, result.lip_opening_mm, "o-", color="C3", ms=3, label="distance")
    ax1.plot(result.times_s, result.lip_vertical_mm, "--", color="C0", label="vertical part")
    ax1.legend(fontsize=8)
    ax1.set_ylabel("Mouth_Up - Mouth_Down (mm)")
    ax1.grid(alpha=0.3)
    curves: dict[str, np.ndarray] = {}  # one line per distinct curve, named by every muscle that plays it
    for i in driven:
        base = model.muscle_names[i].rsplit("_", 1)[0]
        if base not in curves:
            curves[base] = result.activations[:, i]
    groups: list[tuple[list[str], np.ndarray]] = []
    for base, curve in curves.items():
        same = next((g for g in groups if np.array_equal(g[1], curve)), None)
        if same is None:
            groups.append(([base], curve))
        else:
            same[0].append(base)  # drawn once: identical curves used to hide each other
    for names, curve in groups:
        ax2.plot(result.times_s, curve, label=" = ".join(names))
    ax2.set_ylabel("activation (both sides)")
    ax2.set_xlabel("time (s)")
    ax2.legend(fontsize=8, ncol=3)
    ax2.grid(alpha=0.3)
    png = out / "lip_opening.png"
    fig.savefig(png, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return csv, png


def write_states(path: Path, result: GestureResult, model: FaceModel) -> Path:
    """states.npz of a played gesture, every frame's state for measures of one's own (lip protrusion,
    a different aperture): ``times_s`` (F,), ``node_positions_m`` (F, n, 3) of every FEM node in the
    model's frame and order, ``markers_m`` (F, k, 3) with ``marker_names``, ``activations`` (F, M) with
    ``muscle_names``, ``lip_opening_area_mm2`` (F,; NaN where not measured), ``converged`` (F,) and, for a
    dynamic playback, ``kinetic_energy_j`` (F,). Compressed; ``np.load(path)`` reads it back."""
    F = len(result.times_s)
    arrays = {
        "times_s": np.asarray(result.times_s, dtype=np.float64),
        "node_positions_m": np.asarray(result.node_positions_m, dtype=np.float64),
        "markers_m": np.asarray(result.markers_m, dtype=np.float64),
        "marker_names": np.array(result.marker_names, dtype=str),
        "activations": np.asarray(result.activations, dtype=np.float64),
        "muscle_names": np.array(model.muscle_names, dtype=str),
        "lip_opening_area_mm2": _or_nan(result.lip_opening_area_mm2, F),
        "converged": np.asarray(result.converged, dtype=bool),
    }
    if result.kinetic_energy_j is not None:
        arrays["kinetic_energy_j"] = np.asarray(result.kinetic_energy_j, dtype=np.float64)
    if arrays["node_positions_m"].shape != (F, model.n_nodes, 3):
        shape = arrays["node_positions_m"].shape
        raise ValueError(f"node positions {shape} do not match {F} frames of {model.n_nodes} nodes")
    return save_npz(path, compressed=True, **arrays)


def _or_nan(a, n: int) -> np.ndarray:
    return np.full(n, np.nan) if a is None else np.asarray(a, dtype=np.float64)


def write_gesture_usd(
    path: Path,
    result: GestureResult,
    model: FaceModel,
    *,
    fps: float,
    source: str = "",
    progress: bool = False,
    rig: bool | str = "active",
) -> Path:
    """The played gesture as a take stage (``wface.takes.usd``): skin, markers, activations; the
    bones stay at rest. The lip opening area goes into the layer metadata (customLayerData["wface"]:
    ``lip_opening_area_mm2`` per frame as a JSON list, the view, the mode) and, time-sampled like the skin, onto the
    root prim as ``wface:lipOpeningArea_mm2`` (float, one sample per frame at time code f).
    ``progress`` shows a bar over the rig's muscle solves; ``rig`` as in ``write_take_usd`` (False: none)."""
    take = Take(
        activations=result.activations,
        fps=fps,
        muscle_names=list(model.muscle_names),
        source=source,
        joint=model.jaw_joint,
    )
    meta = {"gesture": result.gesture, "mode": result.mode, "contact": result.contact}
    if result.lip_opening_area_mm2 is not None:
        meta["lip_opening_area_mm2"] = [float(v) for v in result.lip_opening_area_mm2]
        meta["lip_opening_area_view"] = result.area_view
        meta["times_s"] = [float(t) for t in result.times_s]
    if result.dynamics is not None:
        meta["dynamics"] = result.dynamics
    path = write_take_usd(
        path,
        model,
        result.node_positions_m,
        take=take,
        simulated_markers_m=result.markers_m,
        marker_names=result.marker_names,
        metadata=meta,
        progress=progress,
        rig=rig,
        edit=None
        if result.lip_opening_area_mm2 is None
        else functools.partial(_area_samples, result.lip_opening_area_mm2),
    )
    return path


def _area_samples(area_mm2: np.ndarray, stage) -> None:
    """Add ``wface:lipOpeningArea_mm2`` time samples to the stage's default prim (before it is saved)."""
    from pxr import Sdf, Usd

    prim = stage.GetDefaultPrim()
    attr = prim.CreateAttribute("wface:lipOpeningArea_mm2", Sdf.ValueTypeNames.Float)
    attr.SetDocumentation("mouth aperture in an orthographic view, mm^2 (wface.speech.aperture)")
    for f, v in enumerate(area_mm2):
        attr.Set(float(v), Usd.TimeCode(f))


#: the aperture picture's colours: (face colour, what it shows); white is the background
_APERTURE_COLOURS = {
    "occluders": ("#c0392b", "face (occluders)"),
    "enclosed": ("#2ecc40", "lip opening (counted)"),
    "elsewhere": ("#3498db", "enclosed away from the lips, e.g. nostrils (not counted)"),
    "outline": ("#f1c40f", "seen past the face's outline (not counted)"),
}


def write_aperture_picture(
    path: Path,
    x_m: np.ndarray,
    occluders: np.ndarray,
    view: ApertureView,
    *,
    resolution_m: float = 5e-5,
    near_points_m: np.ndarray | None = None,
    title: str = "",
    margin_mm: float = 6.0,
) -> ApertureResult:
    """A picture of the aperture measure of one frame (``write_aperture_pictures``); returns the measure."""
    return write_aperture_pictures(
        [path],
        [x_m],
        occluders,
        view,
        resolution_m=resolution_m,
        near_points_m=[near_points_m],
        titles=[title],
        margin_mm=margin_mm,
    )[0]


def write_aperture_pictures(
    paths: list[Path],
    xs_m: list[np.ndarray],
    occluders: np.ndarray,
    view: ApertureView,
    *,
    resolution_m: float = 5e-5,
    near_points_m: list | None = None,
    titles: list[str] | None = None,
    margin_mm: float = 6.0,
) -> list[ApertureResult]:
    """Pictures of the aperture measure (``wface.speech.aperture``), one per frame ``xs_m[i]``: the
    occluders projected in the camera's image plane (red), the seen window enclosed by them near
    ``near_points_m[i]`` (green: the lip opening), enclosed elsewhere (blue, e.g. open nostrils) and
    seen past their outline (yellow); the window's edge dashed (white outside it: not measured), and
    a legend of the colours. Every picture shows the same window (the union of each frame's frame),
    so that the first and last frames of a gesture compare at one scale. Returns the measures."""
    near = list(near_points_m) if near_points_m is not None else [None] * len(xs_m)
    results = [
        aperture_area(x, occluders, view, resolution_m=resolution_m, near_points_m=n, keep_intervals=True)
        for x, n in zip(xs_m, near, strict=True)
    ]
    boxes = np.array([_aperture_box_mm(res, view, n) for res, n in zip(results, near, strict=True)])
    u0, v0 = boxes[:, 0].min(), boxes[:, 2].min()
    u1, v1 = boxes[:, 1].max(), boxes[:, 3].max()
    half = max(u1 - u0, v1 - v0) / 2 + margin_mm
    limits = ((u0 + u1) / 2 - half, (u0 + u1) / 2 + half), ((v0 + v1) / 2 - half, (v0 + v1) / 2 + half)
    for path, x, res, title in zip(paths, xs_m, results, titles or [""] * len(xs_m), strict=True):
        _draw_aperture(path, x, occluders, view, res, limits, title)
    return results


def _aperture_box_mm(res: ApertureResult, view: ApertureView, near_points_m) -> tuple[float, float, float, float]:
    """(u0, u1, v0, v1) in the image plane, mm: the enclosed apertures; when closed, the lips (the
    window centre can lie 10-20 mm off them), else the window centre."""
    e1, e2 = view.image_axes
    iv = res.intervals
    enclosed = iv["enclosed"]
    if enclosed.any():
        u0, u1 = iv["u_lo_m"][enclosed].min() * 1e3, iv["u_hi_m"][enclosed].max() * 1e3
        v0, v1 = iv["v_m"][enclosed].min() * 1e3, iv["v_m"][enclosed].max() * 1e3
    elif near_points_m is not None and len(near_points_m):
        near = np.asarray(near_points_m, dtype=np.float64).reshape(-1, 3)
        u0, u1 = float((near @ e1).min()) * 1e3, float((near @ e1).max()) * 1e3
        v0, v1 = float((near @ e2).min()) * 1e3, float((near @ e2).max()) * 1e3
    else:
        c = np.asarray(view.window_center_m)
        u0 = u1 = float(c @ e1) * 1e3
        v0 = v1 = float(c @ e2) * 1e3
    return u0, u1, v0, v1


def _draw_aperture(path: Path, x_m, occluders, view: ApertureView, res: ApertureResult, limits, title: str) -> None:
    """One aperture picture inside ``limits`` ((u0, u1), (v0, v1)) mm, the legend below the axes."""
    from matplotlib.collections import PolyCollection

    e1, e2 = view.image_axes
    uv = np.stack([x_m @ e1, x_m @ e2], axis=1) * 1e3
    iv = res.intervals
    h = res.resolution_m * 1e3
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 7.4))
    colour = {k: c for k, (c, _) in _APERTURE_COLOURS.items()}
    ax.add_collection(
        PolyCollection(uv[occluders], facecolors=colour["occluders"], edgecolors="#7b241c", linewidths=0.2)
    )
    enclosed, other = iv["enclosed"], iv["elsewhere"]
    shown = {"occluders", "enclosed"}  # the measure's two colours, listed even when nothing is open
    for key, sel in (("enclosed", enclosed), ("elsewhere", other), ("outline", ~enclosed & ~other)):
        v, lo, hi = iv["v_m"][sel] * 1e3, iv["u_lo_m"][sel] * 1e3, iv["u_hi_m"][sel] * 1e3
        rects = np.stack([np.stack([lo, v - h / 2], 1), np.stack([hi, v - h / 2], 1), np.stack([hi, v + h / 2], 1)], 1)
        rects = np.concatenate([rects, np.stack([lo, v + h / 2], 1)[:, None]], axis=1)
        ax.add_collection(PolyCollection(rects, facecolors=colour[key], edgecolors="none"))
        if sel.any():
            shown.add(key)
    corners = view.window_corners_m()
    window = np.stack([corners @ e1, corners @ e2], axis=1) * 1e3
    ax.plot(*np.vstack([window, window[:1]]).T, ls="--", lw=1.2, color="k")
    ax.set_xlim(*limits[0])
    ax.set_ylim(*limits[1])
    ax.set_aspect("equal")
    ax.set_xlabel("image right (mm)")
    ax.set_ylabel("image up (mm)")
    ax.set_title(
        (title + "\n" if title else "")
        + f"lip opening {res.area_mm2:.2f} $\\pm$ {res.error_mm2:.2f} mm$^2$, {res.regions} region(s); "
        + f"view {view.name}",
        fontsize=9,
    )
    ax.legend(handles=_aperture_legend(shown), loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=7.5)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _aperture_legend(shown: set[str]) -> list:
    """Legend handles: the colours drawn (in ``_APERTURE_COLOURS`` order), the window's edge, white."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=c, label=text) for k, (c, text) in _APERTURE_COLOURS.items() if k in shown]
    handles.append(Line2D([], [], ls="--", lw=1.2, color="k", label="window behind the face (edge)"))
    handles.append(Patch(facecolor="white", edgecolor="0.5", label="outside the window: not measured"))
    return handles
