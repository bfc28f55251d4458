"""Plots of an analysis (after Choe & Ko 2001, fig. 5): contractions over time and marker error."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.basis.analysis import Analysis

__all__ = ["CONTRACTION_LABEL", "frames_title", "plot_analysis"]

#: the contraction image's colour bar: contractions are fractions of full contraction
CONTRACTION_LABEL = "contraction (0-1, dimensionless)"


def frames_title(source: str, frames: tuple | None) -> str:
    """``source`` and the frames analysed: "JawMoCap.c3d, frames 0:600:5" (slice A:B:S of the file's
    frames; "all frames" without one), so that the picture says which part of the take it shows."""
    if not frames:
        return f"{source}, all frames"
    a, b, step = (list(frames) + [1])[:3]
    return f"{source}, frames {'' if a is None else a}:{'' if b is None else b}:{step}"


def plot_analysis(
    analysis: Analysis, path: str | Path, *, rate_hz: float = 60.0, top: int = 8, title: str = ""
) -> Path:
    """Write a PNG: the ``top`` most used elements' contractions, all contractions as an image,
    and the per-frame RMS marker error (mm).

    Args:
        analysis: result of :func:`wface.basis.analysis.analyze`.
        path: output PNG.
        rate_hz: frame rate for the time axis.
        top: number of elements drawn as curves (largest 95th percentile of the contraction: the
            elements that peak, such as a jaw opening, rather than those that idle high).
        title: figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = analysis.contractions
    t = np.arange(x.shape[0]) / rate_hz
    order = np.argsort(-np.percentile(x, 95, axis=0))[:top]  # what peaks (a jaw opening), not what idles high
    n = x.shape[1]
    heat_in = max(3.0, 0.15 * n)  # a readable row per element
    fig, axes = plt.subplots(
        3,
        1,
        figsize=(11, 5.0 + heat_in),
        sharex=True,
        gridspec_kw={"height_ratios": [3.0, heat_in, 1.6]},
        layout="constrained",  # the three panels keep one width beside the legend and the colour bar
    )
    for i in order:
        axes[0].plot(t, x[:, i], lw=1.2, label=analysis.element_names[i])
    axes[0].set_ylabel("contraction")
    axes[0].set_xlim(t[0], t[-1] if len(t) > 1 else 1)
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), title=f"top {len(order)} (95th pct)")
    axes[0].set_title(title or "element contractions")
    im = axes[1].imshow(x.T, aspect="auto", origin="lower", interpolation="nearest", cmap="magma",
                        extent=(t[0], t[-1] if len(t) > 1 else 1, -0.5, n - 0.5), vmin=0)  # fmt: skip
    axes[1].set_yticks(range(n))
    axes[1].set_yticklabels(analysis.element_names, fontsize=7)
    fig.colorbar(im, ax=list(axes), pad=0.01, shrink=0.5, label=CONTRACTION_LABEL)
    axes[2].plot(t, analysis.marker_rms_mm, color="k", lw=1)
    axes[2].set_ylabel("marker RMS (mm)")
    axes[2].set_xlabel("time (s)")
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
