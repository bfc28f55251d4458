"""The lips-and-teeth section picture (wface.viz.contact, ``wface simulate --picture``)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from wface.faces.builtin import build_face  # noqa: E402
from wface.viz.contact import lip_section_figure, plot_lip_section  # noqa: E402


def test_lip_section_keeps_everything_in_view_and_both_lips_visible(tmp_path):
    face = build_face(2000)
    rest = {n: (m.vertices_m, m.triangles) for n, m in face.bone_meshes.items() if "teeth" in n.lower()}
    assert len(rest) == 2
    dropped = {n: (v - (0.0, 0.025 if "lower" in n else 0.0, 0.0), t) for n, (v, t) in rest.items()}  # jaw open
    x = face.rest_positions_m
    fig = lip_section_figure(face, {"rest": x, "open": x}, teeth={"rest": rest, "open": dropped})
    axes = fig.axes
    assert axes[0].get_xlim() == axes[1].get_xlim() and axes[0].get_ylim() == axes[1].get_ylim()
    for ax in axes:  # every line drawn lies inside its panel (the dropped teeth ran off the bottom)
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        for lines in ax.collections:
            pts = np.concatenate([np.asarray(s) for s in lines.get_segments()])
            assert pts[:, 0].min() >= x0 and pts[:, 0].max() <= x1
            assert pts[:, 1].min() >= y0 and pts[:, 1].max() <= y1
    lips = {c.get_label(): c for c in axes[0].collections if c.get_label() in ("upper_lip", "lower_lip")}
    assert lips["upper_lip"].get_zorder() > lips["lower_lip"].get_zorder()  # on top of it where they touch
    assert lips["upper_lip"].get_linewidth()[0] < lips["lower_lip"].get_linewidth()[0]
    assert all(ax.get_legend() is None for ax in axes) and len(fig.legends) == 1  # beside the data, not on it
    out = plot_lip_section(face, {"rest": x}, tmp_path / "s.png", teeth={"rest": rest})
    assert out.stat().st_size > 1000
