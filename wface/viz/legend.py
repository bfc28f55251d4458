"""The legends of pictures (``wface.viz.render``): the colour bar of the muscle heat map, red
(inactive, 0) to yellow (fully active, 1), labelled ``ACTIVATION_LEGEND`` at the bottom of each panel,
and the markers' colours (captured red, the face's green; Sifakis et al. 2005) at its top left."""

from __future__ import annotations

import numpy as np

from wface.viz.muscles import ACTIVE_RGB, INACTIVE_RGB

__all__ = [
    "ACTIVATION_LEGEND",
    "CAPTURED_RGB",
    "LEGEND_BAND",
    "SIMULATED_RGB",
    "add_activation_legend",
    "add_marker_legend",
]

ACTIVATION_LEGEND = "muscle activation (0-1, dimensionless)"
LEGEND_BAND = 0.16  # share of a panel's height the activation colour bar and its title take at the bottom
CAPTURED_RGB = (0.90, 0.05, 0.05)  # captured markers
SIMULATED_RGB = (0.05, 0.75, 0.10)  # the face's markers: tracked or simulated
_LEGEND_PX_PER_POINT = 38.0  # width of ACTIVATION_LEGEND in pixels per point of font size (measured)


def add_activation_legend(pv, plotter) -> None:
    """A colour bar for the muscle heat map: red (inactive, 0) to yellow (fully active, 1).

    The skin and muscle colours are written as RGB, which VTK cannot label, so an invisible
    two-point mesh carries the lookup table of the bar. The tick labels go below the bar and the
    title is a text of its own above it: VTK's own title overlapped the "0.0" and "1.0" labels.
    """
    from matplotlib.colors import LinearSegmentedColormap

    cmap = LinearSegmentedColormap.from_list("activation", [INACTIVE_RGB, ACTIVE_RGB])
    probe = pv.PolyData(np.zeros((2, 3)))
    probe["activation"] = np.array([0.0, 1.0])
    first = ACTIVATION_LEGEND not in plotter.scalar_bars  # one bar per plotter (pyvista keys them by title)
    x, y, w, h = 0.2, 0.01, 0.6, 0.09  # the bar and its labels, share of the panel
    plotter.add_mesh(
        probe,
        scalars="activation",
        cmap=cmap,
        clim=(0.0, 1.0),
        opacity=0.0,
        reset_camera=False,
        scalar_bar_args={
            "title": ACTIVATION_LEGEND,
            "n_labels": 2,
            "fmt": "%.1f",
            "color": "black",
            "vertical": False,
            "position_x": x,
            "position_y": y,
            "width": w,
            "height": h,
            "label_font_size": 12,
            "unconstrained_font_size": True,
        },
    )
    if first:
        bar = plotter.scalar_bars[ACTIVATION_LEGEND]
        bar.SetTitle("")
        bar.SetTextPositionToPrecedeScalarBar()
        panel_px = plotter.window_size[0] / getattr(plotter, "shape", (1, 1))[1]
        size = int(np.clip(0.85 * panel_px / _LEGEND_PX_PER_POINT, 6, 10))  # the title fits the panel's width
        title = plotter.add_text(
            ACTIVATION_LEGEND, position=(x + w / 2, y + h), viewport=True, font_size=size, color="black"
        )
        title.GetTextProperty().SetJustificationToCentered()


def marker_legend_labels(captured: bool, simulated: bool) -> list[tuple[str, tuple[float, float, float]]]:
    """The marker legend's entries for a picture showing captured and/or the face's markers."""
    face = "tracked (the face's)" if captured else "the face's markers"
    entries = ((captured, "captured", CAPTURED_RGB), (simulated, face, SIMULATED_RGB))
    return [(text, rgb) for on, text, rgb in entries if on]


def add_marker_legend(plotter, *, captured: bool, simulated: bool) -> float:
    """Which colour is which marker, at the panel's top left (nothing when it shows no markers).
    Returns the share of the panel's height it takes at the top (0 without markers)."""
    labels = marker_legend_labels(captured, simulated)
    if not labels:
        return 0.0
    height = 0.05 * len(labels)  # share of the panel's height, one line per entry
    plotter.add_legend(
        labels=[[text, rgb] for text, rgb in labels],
        bcolor="white",
        face="circle",
        size=(0.3, height),
        loc="upper left",
        background_opacity=0.8,
    )
    return height + 0.01
