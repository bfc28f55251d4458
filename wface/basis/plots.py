"""Plots of an analysis (after Choe & Ko 2001, fig. 5): contractions over time and marker error."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wface.basis.analysis import Analysis

__all__ = ["plot_analysis"]


def plot_analysis(
    analysis: Analysis, path: str | Path, *, rate_hz: float = 60.0, top: int = 8, title: str = ""
) -> Path:
    """Write a PNG: the ``top`` most used elements' contractions, all contractions as an image,
    and the per-frame RMS marker error (mm).

    Args:
        analysis: result of :func:`wface.basis.analysis.analyze`.
        path: output PNG.
        rate_hz: frame rate for the time axis.
        top: number of elements drawn as curves (largest mean contraction).
        title: figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = analysis.contractions
    t = np.arange(x.shape[0]) / rate_hz
    order = np.argsort(-x.mean(axis=0))[:top]
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=False, gridspec_kw={"height_ratios": [2, 2, 1]})
    for i in order:
        axes[0].plot(t, x[:, i], lw=1, label=analysis.element_names[i])
    axes[0].set_ylabel("contraction")
    axes[0].set_xlim(t[0], t[-1] if len(t) > 1 else 1)
    axes[0].legend(fontsize=7, ncol=4, loc="upper right")
    axes[0].set_title(title or "element contractions")
    im = axes[1].imshow(x.T, aspect="auto", origin="lower", interpolation="nearest", cmap="magma",
                        extent=(t[0], t[-1] if len(t) > 1 else 1, -0.5, x.shape[1] - 0.5), vmin=0)  # fmt: skip
    axes[1].set_yticks(range(x.shape[1]))
    axes[1].set_yticklabels(analysis.element_names, fontsize=4)
    fig.colorbar(im, ax=axes[1], pad=0.01)
    axes[2].plot(t, analysis.marker_rms_mm, color="k", lw=1)
    axes[2].set_ylabel("marker RMS (mm)")
    axes[2].set_xlabel("time (s)")
    axes[2].set_xlim(axes[0].get_xlim())
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
