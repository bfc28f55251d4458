"""A picture of contact: the lips (and teeth) cut by a sagittal plane, at rest and at equilibria."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["lip_section_figure", "plane_section", "plot_lip_section"]


def plane_section(points_m: np.ndarray, triangles: np.ndarray, x_plane_m: float) -> np.ndarray:
    """Segments (s, 2, 3) where the triangles cross the plane x = x_plane_m."""
    p = np.asarray(points_m, dtype=np.float64)[np.asarray(triangles)]
    d = p[..., 0] - x_plane_m
    segs = []
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        # vertex a alone on its side: the segment joins the crossings of edges ab and ac
        alone = (np.sign(d[:, a]) != np.sign(d[:, b])) & (np.sign(d[:, b]) == np.sign(d[:, c])) & (d[:, b] != 0)
        if not alone.any():
            continue
        q = p[alone]
        da, db, dc = d[alone, a, None], d[alone, b, None], d[alone, c, None]
        e1 = q[:, a] + (q[:, b] - q[:, a]) * (da / (da - db))
        e2 = q[:, a] + (q[:, c] - q[:, a]) * (da / (da - dc))
        segs.append(np.stack([e1, e2], axis=1))
    return np.concatenate(segs) if segs else np.zeros((0, 2, 3))


def plot_lip_section(model, positions: dict, out_path, *, x_plane_m: float = 1e-4, teeth=None) -> Path:
    """Draw the upper / lower lip surfaces (``upper_lip`` / ``lower_lip`` surface groups) cut by the
    plane x = ``x_plane_m`` in the (z, y) plane, one panel per entry of ``positions`` {title: (n, 3)}.

    Args:
        model: the face.
        positions: panel title -> node positions (n, 3) in metres.
        out_path: PNG file to write.
        x_plane_m: the sagittal plane (just off the midline, where the built-in face has nodes).
        teeth: optional {title: {mesh name: (vertices (v, 3), triangles (t, 3))}} posed teeth per panel.

    Returns:
        The written path.
    """
    fig = lip_section_figure(model, positions, x_plane_m=x_plane_m, teeth=teeth)
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=120, bbox_inches="tight", pad_inches=0.08)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return out_path


#: lip lines: (colour, width, style, z-order). The upper lip is drawn dashed over a wider lower lip, so
#: that lips in contact (one line on the other, as at rest) both stay visible.
_LIP_STYLE = {
    "upper_lip": ("tab:red", 1.5, "dashed", 3),
    "lower_lip": ("tab:blue", 3.0, "solid", 2),
}
_TEETH_SHADES = ("0.25", "0.55", "0.4", "0.7")  # upper and lower teeth apart (one grey made them one)
_PAD_MM = 3.0  # around everything drawn


def lip_section_figure(model, positions: dict, *, x_plane_m: float = 1e-4, teeth=None):
    """The figure of ``plot_lip_section``: every panel has the limits of everything drawn in all of
    them (lips and teeth, so that a teeth outline moved by the jaw stays in view), the legend sits
    below the panels, and the height follows the drawing's aspect (no empty bands)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    groups = [g for g in _LIP_STYLE if g in model.surface_groups]
    if not groups:
        raise ValueError(f"the model has no upper_lip / lower_lip surface groups: {list(model.surface_groups)}")
    drawn = {}  # panel title -> [(label, segments (s, 2, 2) in (z, y) mm, style)]
    for title, x in positions.items():
        lines = [(g, _section_zy_mm(x, model.surface_groups[g], x_plane_m), _LIP_STYLE[g]) for g in groups]
        for k, (name, (v, t)) in enumerate(((teeth or {}).get(title, {}) or {}).items()):
            style = (_TEETH_SHADES[k % 4], 1.0, "solid" if k % 2 == 0 else "dashed", 1)
            lines.append((name, _section_zy_mm(v, t, x_plane_m), style))
        drawn[title] = lines
    pts = np.concatenate([seg.reshape(-1, 2) for lines in drawn.values() for _, seg, _ in lines])
    lo, hi = pts.min(axis=0) - _PAD_MM, pts.max(axis=0) + _PAD_MM
    panel_w = 4.2
    panel_h = max(1.5, panel_w * (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9))
    fig, axes = plt.subplots(
        1, len(drawn), figsize=(panel_w * len(drawn), panel_h + 1.0), squeeze=False, layout="constrained"
    )
    for ax, (title, lines) in zip(axes[0], drawn.items(), strict=True):
        for label, seg, (colour, width, style, z) in lines:
            ax.add_collection(
                LineCollection(seg, colors=colour, linewidths=width, linestyles=style, zorder=z, label=label)
            )
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("z (mm, forward)")
        ax.set_aspect("equal")
    axes[0][0].set_ylabel("y (mm, up)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8, frameon=False)
    return fig


def _section_zy_mm(points_m, triangles, x_plane_m: float) -> np.ndarray:
    """``plane_section`` as (s, 2, 2) segments in the drawing's (z, y) plane, mm."""
    return plane_section(points_m, triangles, x_plane_m)[..., [2, 1]] * 1e3
