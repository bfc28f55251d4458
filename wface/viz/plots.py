"""Plots people look at (matplotlib, Agg backend): activations, marker error, jaw opening.

Each function writes one PNG (or SVG / PDF by suffix) and returns its path. Time runs along x in
seconds when ``fps`` is given, else in frames. Ground truth, when given, is drawn dashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "ACTIVATION_AXIS_LABEL",
    "activation_ylim",
    "jaw_opening_deg",
    "marker_errors_mm",
    "plot_activations",
    "plot_jaw_opening",
    "plot_marker_error",
]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _time_axis(n: int, fps: float | None) -> tuple[np.ndarray, str]:
    if fps is None:
        return np.arange(n), "frame"
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    return np.arange(n) / fps, "time (s)"


def _save(fig, out_path) -> Path:
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=110, bbox_inches="tight")
    _plt().close(fig)
    return out_path


def marker_errors_mm(
    captured_m: np.ndarray, simulated_m: np.ndarray, *, outlier_mm: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame RMS and max distance (mm) between captured and simulated markers (F, k, 3).

    Missing captured markers (NaN rows) are left out; a frame with none gives NaN. With ``outlier_mm``
    the samples farther than that are left out too: the inliers' RMS and max, as the report's
    ``marker_rms_mm_inliers`` (the tracker's Tukey cut-off, ``outlier_threshold_mm``).
    """
    c, s = np.asarray(captured_m, dtype=np.float64), np.asarray(simulated_m, dtype=np.float64)
    if c.shape != s.shape or c.ndim != 3 or c.shape[2] != 3:
        raise ValueError(f"captured and simulated markers must both be (frames, k, 3); got {c.shape} and {s.shape}")
    d = np.linalg.norm(c - s, axis=2) * 1000.0
    present = np.isfinite(d) if outlier_mm is None else np.isfinite(d) & (np.nan_to_num(d) <= outlier_mm)
    n = present.sum(axis=1)
    d0 = np.where(present, d, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(n > 0, np.sqrt((d0**2).sum(axis=1) / np.maximum(n, 1)), np.nan)
    mx = np.where(n > 0, d0.max(axis=1), np.nan)
    return rms, mx


def jaw_opening_deg(
    jaw_affines: np.ndarray,
    joint=None,
    *,
    cranium_affines: np.ndarray | None = None,
    jaw_frame: str = "cranium",
) -> np.ndarray:
    """Jaw opening angle (degrees) per frame from jaw affines (F, 3, 4), as ``wface.controls``.

    With the jaw's linear part M relative to the cranium, opening = asin(-(w . M v)) with the
    joint's track direction v and w = v x u (``jaw_to_intuitive``): a rotation by alpha about u
    (chin down) gives alpha, whatever the protrusion.

    Args:
        jaw_affines: (F, 3, 4) jaw affines.
        joint: a ``JawJoint`` (u, v); default u = +x, v = +z.
        cranium_affines: (F, 3, 4) cranium affines; needed when ``jaw_frame`` is "world".
        jaw_frame: "cranium" (default; the jaw affines are relative to the cranium, as the 24 bone
            parameters) or "world" (they map rest to world; the cranium's part is divided out).
    """
    j = np.asarray(jaw_affines, dtype=np.float64)
    if j.ndim != 3 or j.shape[1:] != (3, 4):
        raise ValueError(f"jaw_affines must have shape (frames, 3, 4); got {j.shape}")
    M = j[:, :, :3]
    if jaw_frame == "world":
        if cranium_affines is None:
            raise ValueError("jaw_frame='world' needs cranium_affines to take the head motion out")
        c = np.asarray(cranium_affines, dtype=np.float64)
        if c.shape != j.shape:
            raise ValueError(f"cranium_affines {c.shape} and jaw_affines {j.shape} differ in shape")
        M = np.linalg.solve(c[:, :, :3], M)
    elif jaw_frame != "cranium":
        raise ValueError(f"jaw_frame must be 'cranium' or 'world', got {jaw_frame!r}")
    u = np.asarray((1.0, 0.0, 0.0) if joint is None else joint.u, dtype=np.float64)
    v = np.asarray((0.0, 0.0, 1.0) if joint is None else joint.v, dtype=np.float64)
    w = np.cross(v, u)
    return np.degrees(np.arcsin(np.clip(-np.einsum("i,fij,j->f", w, M, v), -1.0, 1.0)))


#: the y axis of activation plots: muscles contract 0..1, the intra-oral pressure is signed (suction < 0)
ACTIVATION_AXIS_LABEL = "activation (0-1; intra-oral pressure -1 to 1)"


def activation_ylim(activations: np.ndarray, truth: np.ndarray | None = None) -> tuple[float, float]:
    """y limits of an activation plot: 0..1 with a small margin, grown to the data's minimum and
    maximum (truth included) when they lie outside: a pressure actuator (``intraoral_pressure``)
    runs from -1 to 1, and its suction (< 0) must not be cut off."""
    values = [np.asarray(activations, dtype=np.float64)]
    if truth is not None:
        values.append(np.asarray(truth, dtype=np.float64))
    finite = np.concatenate([v[np.isfinite(v)] for v in values])
    lo = min(0.0, float(finite.min())) if finite.size else 0.0
    hi = max(1.0, float(finite.max())) if finite.size else 1.0
    pad = 0.03 * (hi - lo)
    return lo - pad, hi + pad


def plot_activations(
    activations: np.ndarray,
    names: list[str],
    out_path: str | Path,
    *,
    fps: float | None = None,
    truth: np.ndarray | None = None,
    title: str = "Muscle activations",
    max_single_axis: int = 8,
) -> Path:
    """Activation curves (F, M) per muscle; small multiples when there are more than ``max_single_axis``."""
    plt = _plt()
    a = np.asarray(activations, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != len(names):
        raise ValueError(f"activations must have shape (frames, {len(names)}) for {len(names)} names; got {a.shape}")
    if truth is not None and np.shape(truth) != a.shape:
        raise ValueError(f"truth has shape {np.shape(truth)}, activations {a.shape}")
    t, xlabel = _time_axis(a.shape[0], fps)
    M = a.shape[1]
    ylim = activation_ylim(a, truth)
    if M <= max_single_axis:
        fig, ax = plt.subplots(figsize=(8, 4))
        for m in range(M):
            (line,) = ax.plot(t, a[:, m], lw=1.8, label=names[m])
            if truth is not None:
                ax.plot(t, truth[:, m], "--", lw=1.2, color=line.get_color())
        ax.set_ylim(*ylim)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ACTIVATION_AXIS_LABEL)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=2 if M > 4 else 1, loc="upper right")
        ax.set_title(title + (" (dashed: truth)" if truth is not None else ""))
    else:
        cols = 4 if M <= 24 else 6
        rows = int(np.ceil(M / cols))
        fig, axes = plt.subplots(
            rows, cols, figsize=(2.6 * cols, 1.55 * rows + 0.6), sharex=True, sharey=True, squeeze=False
        )
        for m, ax in enumerate(axes.ravel()):
            if m >= M:
                ax.axis("off")
                axes.ravel()[m - cols].xaxis.set_tick_params(labelbottom=True)  # the panel above ends its column
                axes.ravel()[m - cols].set_xlabel(xlabel, fontsize=8)
                continue
            ax.plot(t, a[:, m], lw=1.4, color="tab:orange")
            if truth is not None:
                ax.plot(t, truth[:, m], "--", lw=1.0, color="k")
            ax.set_title(names[m], fontsize=8)
            ax.set_ylim(*ylim)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        for ax in axes[-1][: M - (rows - 1) * cols]:
            ax.set_xlabel(xlabel, fontsize=8)
        fig.suptitle(title + (" (dashed: truth)" if truth is not None else ""))
        fig.supylabel(ACTIVATION_AXIS_LABEL, fontsize=9)
        fig.tight_layout()
    return _save(fig, out_path)


def plot_marker_error(
    marker_rms_mm: np.ndarray,
    out_path: str | Path,
    *,
    marker_max_mm: np.ndarray | None = None,
    fps: float | None = None,
    title: str = "Marker error per frame",
    truth_rms_mm: np.ndarray | None = None,
    outlier_mm: float | None = None,
    max_all_mm: np.ndarray | None = None,
) -> Path:
    """Per-frame marker RMS error (mm), and the per-frame maximum when given.

    Drawn as the report reads: ``truth_rms_mm`` (the RMS error against the true, noise-free markers
    of a synthetic take) first, in black; then the error against the capture. With ``outlier_mm``
    the RMS and max are the inliers' (``marker_errors_mm(outlier_mm=...)``) and ``max_all_mm``, the
    largest error counting the outliers (injected ones reach tens of mm), gets a panel of its own
    below with the cut-off dashed, so that it does not squash the curves above.
    """
    plt = _plt()
    rms = np.asarray(marker_rms_mm, dtype=np.float64).reshape(-1)
    t, xlabel = _time_axis(rms.size, fps)
    series = {"marker_max_mm": marker_max_mm, "truth_rms_mm": truth_rms_mm, "max_all_mm": max_all_mm}
    curves = {k: _frames_like(v, rms, k) for k, v in series.items()}
    split = curves["max_all_mm"] is not None
    fig, axes = plt.subplots(
        2 if split else 1, 1, figsize=(8, 4.6 if split else 3.2), sharex=True, squeeze=False, **_two_rows(split)
    )
    ax = axes[0][0]
    which = f"inliers (<= {outlier_mm:g} mm)" if outlier_mm is not None else "all markers"
    if curves["truth_rms_mm"] is not None:
        tr = curves["truth_rms_mm"]
        ax.plot(t, tr, lw=1.8, color="k", label=f"vs truth (clean markers), RMS (mean {np.nanmean(tr):.2f} mm)")
    ax.plot(t, rms, lw=1.8, color="tab:blue", label=f"vs capture, RMS of {which} (mean {np.nanmean(rms):.2f} mm)")
    if curves["marker_max_mm"] is not None:
        mx = curves["marker_max_mm"]
        colour = "tab:blue" if split else "tab:red"
        ax.plot(t, mx, lw=1.0, ls="--", color=colour, label=f"vs capture, max of {which} ({np.nanmax(mx):.2f} mm)")
    _finish_error_axis(ax)
    ax.set_title(title)
    if split:
        _draw_max_all(axes[1][0], t, curves["max_all_mm"], outlier_mm)
    axes[-1][0].set_xlabel(xlabel)
    return _save(fig, out_path)


def _frames_like(values, rms: np.ndarray, name: str) -> np.ndarray | None:
    """``values`` as a float array of the RMS curve's frames (None stays None)."""
    if values is None:
        return None
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.shape != rms.shape:
        raise ValueError(f"{name} has {v.size} frames, marker_rms_mm {rms.size}")
    return v


def _two_rows(split: bool) -> dict:
    return {"gridspec_kw": {"height_ratios": (2.2, 1.0)}} if split else {}


def _finish_error_axis(ax) -> None:
    """Limits from 0, labels, and the legend beside the axes (over them it hid the curves)."""
    ax.set_ylim(bottom=0)
    ax.set_ylabel("error (mm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def _draw_max_all(ax, t: np.ndarray, max_all_mm: np.ndarray, outlier_mm: float | None) -> None:
    """The largest error per frame counting outliers, and the cut-off above which a sample is one."""
    ax.plot(
        t, max_all_mm, lw=1.2, color="tab:red", label=f"vs capture, max incl. outliers ({np.nanmax(max_all_mm):.2f} mm)"
    )
    if outlier_mm is not None:
        ax.axhline(outlier_mm, ls="--", lw=1.0, color="0.4", label=f"outlier cut-off ({outlier_mm:g} mm)")
    _finish_error_axis(ax)


def plot_jaw_opening(
    jaw_angle_deg: np.ndarray,
    out_path: str | Path,
    *,
    truth_deg: np.ndarray | None = None,
    fps: float | None = None,
    title: str = "Jaw opening",
    limits_deg: tuple[float, float] | None = None,
) -> Path:
    """Jaw opening angle (degrees) over time; truth dashed. ``limits_deg``: the joint's (closed, open)
    opening limits (``wface.controls.jaw_limits``), drawn dashed, the closed one always and the open one
    when it lies within the curves' range: a curve flat on a limit is the joint stopping the jaw."""
    plt = _plt()
    ang = np.asarray(jaw_angle_deg, dtype=np.float64).reshape(-1)
    t, xlabel = _time_axis(ang.size, fps)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.plot(t, ang, lw=1.8, color="tab:purple", label="estimated" if truth_deg is not None else "opening")
    if truth_deg is not None:
        tr = np.asarray(truth_deg, dtype=np.float64).reshape(-1)
        if tr.shape != ang.shape:
            raise ValueError(f"truth_deg has {tr.size} frames, jaw_angle_deg {ang.size}")
        ax.plot(t, tr, "--", lw=1.3, color="k", label="truth")
    if limits_deg is not None:
        _draw_jaw_limits(ax, limits_deg, ang if truth_deg is None else np.concatenate([ang, tr]))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("opening (deg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    return _save(fig, out_path)


def _draw_jaw_limits(ax, limits_deg: tuple[float, float], shown_deg: np.ndarray) -> None:
    """The joint's closed limit (always) and open limit (when the curves come within a third of their
    range of it: further away it would only flatten them), dashed grey, labelled."""
    closed, opened = (float(v) for v in limits_deg)
    ax.axhline(closed, ls="--", lw=1.0, color="0.35", label=f"joint limit, closed ({closed:.1f} deg)")
    finite = shown_deg[np.isfinite(shown_deg)]
    top = float(finite.max()) if finite.size else closed
    if opened <= top + max(top - closed, 1.0) / 3:
        ax.axhline(opened, ls="-.", lw=1.0, color="0.35", label=f"joint limit, open ({opened:.1f} deg)")
