"""A picture of contact: the lips (and teeth) cut by a sagittal plane, at rest and at equilibria."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plane_section", "plot_lip_section"]


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    groups = [g for g in ("upper_lip", "lower_lip") if g in model.surface_groups]
    if not groups:
        raise ValueError(f"the model has no upper_lip / lower_lip surface groups: {list(model.surface_groups)}")
    fig, axes = plt.subplots(1, len(positions), figsize=(4.2 * len(positions), 4.2), squeeze=False)
    box = []
    for ax, (title, x) in zip(axes[0], positions.items(), strict=True):
        for g, colour in zip(groups, ("tab:red", "tab:blue"), strict=False):
            seg = plane_section(x, model.surface_groups[g], x_plane_m)
            ax.add_collection(LineCollection(seg[..., [2, 1]] * 1e3, colors=colour, linewidths=1.5, label=g))
            box.append(seg.reshape(-1, 3))
        shades = ("0.25", "0.55", "0.4", "0.7")  # upper and lower teeth apart (one grey made them one)
        for k, (name, (v, t)) in enumerate(((teeth or {}).get(title, {}) or {}).items()):
            seg = plane_section(v, t, x_plane_m)
            style = "solid" if k % 2 == 0 else "dashed"
            lines = LineCollection(seg[..., [2, 1]] * 1e3, colors=shades[k % 4], linewidths=1.0, linestyles=style)
            ax.add_collection(lines)
            lines.set_label(name)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("z (mm, forward)")
        ax.set_aspect("equal")
    pts = np.concatenate(box) * 1e3
    for ax in axes[0]:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        ax.set_xlim(lo[2] - 5, hi[2] + 5)
        ax.set_ylim(lo[1] - 5, hi[1] + 5)
    axes[0][0].set_ylabel("y (mm, up)")
    axes[0][0].legend(loc="best", fontsize=8)
    fig.tight_layout()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=120)
    plt.close(fig)
    return out_path
